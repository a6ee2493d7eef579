#include "checks.h"
#include "erratum_extra.h"

#include <algorithm>
#include <cmath>
#include <functional>
#include <map>
#include <set>

#include "modbus/bytes.h"
#include "modbus/hex.h"
#include "modbus/limits.h"

namespace mbc::spec {
namespace {

std::string hex16(unsigned v) {
  char buf[8];
  std::snprintf(buf, sizeof buf, "0x%04X", v & 0xFFFF);
  return buf;
}

struct Checker {
  const Spec& s;
  const JsonDocument& doc;
  Diagnostics& out;

  void error(const std::string& pointer, const std::string& rule, const std::string& msg) {
    SourceLoc l = doc.where(pointer);
    out.push_back({s.path, l.line, l.col, rule, msg});
  }

  bool has_erratum(const std::vector<std::string>& ids) const { return !ids.empty(); }

  static std::pair<double, double> type_bounds(const Register& r) {
    switch (r.type) {
      case DataType::s16: return {-32768, 32767};
      case DataType::u32: return {0, 4294967295.0};
      case DataType::s32: return {-2147483648.0, 2147483647.0};
      case DataType::f32: return {-3.4028234663852886e38, 3.4028234663852886e38};
      case DataType::bit: return {0, 1};
      default: return {0, r.words == 2 ? 4294967295.0 : 65535};
    }
  }

  // Every register an `operations:` or `control.motion` entry names by key exists, and a write's
  // value is one the register can hold.
  void operations() {
    auto key = [&](const std::string& pointer, const std::string& k) -> const Register* {
      if (k.empty()) return nullptr;
      const Register* r = s.find_by_key(k);
      if (!r) error(pointer, "unknown-register-key", "no register has key '" + k + "'");
      return r;
    };
    auto write = [&](const std::string& pointer, const RegisterWrite& w) {
      const Register* r = key(pointer + "/register", w.key);
      if (r && r->access == Access::ro)
        error(pointer + "/register", "operation-writes-read-only", "register '" + w.key + "' is read-only");
    };
    const auto& ops = s.operations;
    if (ops.save) write("/operations/save", *ops.save);
    if (ops.factory_reset) write("/operations/factory_reset", *ops.factory_reset);
    for (size_t i = 0; i < ops.setup.size(); ++i) write("/operations/setup/" + std::to_string(i), ops.setup[i]);
    if (!s.control || !s.control->motion) return;
    const auto& m = *s.control->motion;
    const std::string mp = "/control/motion";
    for (size_t i = 0; i < m.assumes.size(); ++i) key(mp + "/assumes/" + std::to_string(i) + "/register", m.assumes[i].key);
    for (size_t i = 0; i < m.setup.size(); ++i) write(mp + "/setup/" + std::to_string(i), m.setup[i]);
    key(mp + "/distance/register", m.distance_key);
    key(mp + "/distance/reverse_register", m.reverse_distance_key);
    for (auto [name, w] : {std::pair{"start_forward", &m.start_forward}, std::pair{"start_reverse", &m.start_reverse},
                           std::pair{"stop", &m.stop}, std::pair{"emergency_stop", &m.emergency_stop}})
      if (*w) write(mp + "/" + name, **w);
    key(mp + "/position/register", m.position_key);
    key(mp + "/position/high_register", m.position_high_key);
    key(mp + "/status/register", m.status_key);
    key(mp + "/positioning_needs_homing/position_command", m.position_command_key);
  }

  void ids() {
    auto unique = [&](const char* what, const std::string& base, auto const& items) {
      std::map<std::string, size_t> seen;
      for (size_t i = 0; i < items.size(); ++i) {
        auto [it, fresh] = seen.emplace(items[i].id, i);
        if (!fresh)
          error(base + "/" + std::to_string(i) + "/id", "duplicate-id",
                std::string(what) + " id '" + items[i].id + "' is already used by " + what + " #" +
                    std::to_string(it->second + 1));
      }
    };
    unique("example", "/examples", s.examples);
    unique("erratum", "/errata", s.errata);
    // Inline enums are generated after the declared ones; only check declared.
    std::vector<Enumeration> declared;
    for (size_t i = 0; doc.root.contains("enums") && i < doc.root["enums"].size(); ++i) declared.push_back(s.enums[i]);
    unique("enum", "/enums", declared);
    unique("bitfield", "/bitfields", s.bitfields);
  }

  void erratum_refs(const std::string& pointer, const std::vector<std::string>& ids) {
    for (const auto& id : ids)
      if (!s.find_erratum(id)) error(pointer, "unknown-reference", "erratum '" + id + "' is not in errata:");
  }

  void registers() {
    std::map<std::string, const Register*> keys;
    for (const auto& r : s.registers) {
      if (r.key.empty()) continue;
      auto [it, fresh] = keys.emplace(r.key, &r);
      if (!fresh) error(r.origin + "/key", "duplicate-id", "register key '" + r.key + "' is already used by register " + hex16(it->second->address));
    }
    for (const auto& r : s.registers) {
      if (r.block_index > 0) continue;  // a block is checked once, at its first register
      const std::string& p = r.origin;
      std::string label = "register " + hex16(r.address);
      bool wide_type = r.type == DataType::u32 || r.type == DataType::s32 || r.type == DataType::f32;
      if (wide_type && r.words != 2)
        error(p + "/words", "word-order", label + ": type " + to_string(r.type) + " takes 2 words");
      if ((r.type == DataType::u16 || r.type == DataType::s16 || r.type == DataType::bit) && r.words != 1)
        error(p + "/words", "word-order", label + ": type " + to_string(r.type) + " takes 1 word");
      if (r.words == 2 && r.word_order == WordOrder::none)
        error(p, "word-order", label + " spans 2 words but declares no word_order (high_first or low_first)");
      if (r.words == 1 && r.word_order != WordOrder::none)
        error(p + "/word_order", "word-order", label + " is one word; word_order does not apply");
      if ((r.table == Table::coil || r.table == Table::discrete_input) != (r.type == DataType::bit))
        error(p + "/type", "table-type", label + ": coils and discrete inputs have type bit, and only they do");
      if ((r.table == Table::input || r.table == Table::discrete_input) && r.access != Access::ro)
        error(p + "/access", "table-type", label + ": input registers and discrete inputs are read-only");
      erratum_refs(p + "/erratum", r.errata);
      if (r.type == DataType::enumeration) {
        if (r.enum_id.empty()) error(p, "unknown-reference", label + " has type enum but names no enum");
        else if (!s.find_enum(r.enum_id))
          error(p + "/enum", "unknown-reference", label + ": enum '" + r.enum_id + "' is not in enums:");
      } else if (!r.enum_id.empty() && !s.find_enum(r.enum_id)) {
        error(p + "/enum", "unknown-reference", label + ": enum '" + r.enum_id + "' is not in enums:");
      }
      if (r.type == DataType::bitfield) {
        if (r.bitfield_id.empty()) error(p, "unknown-reference", label + " has type bitfield but names no bitfield");
        else if (!s.find_bitfield(r.bitfield_id))
          error(p + "/bitfield", "unknown-reference", label + ": bitfield '" + r.bitfield_id + "' is not in bitfields:");
      }
      if (r.access == Access::command && !r.command)
        error(p, "command", label + " has access command but no command: {effect: ...}");
      auto [lo, hi] = type_bounds(r);
      if (r.range) {
        if (r.range->min > r.range->max)
          error(p + "/range", "range-order", label + ": range min " + fmt(r.range->min) + " > max " + fmt(r.range->max));
        else if (r.range->min < lo || r.range->max > hi)
          error(p + "/range", "range-order",
                label + ": range " + fmt(r.range->min) + ".." + fmt(r.range->max) + " does not fit type " +
                    to_string(r.type) + " (" + fmt(lo) + ".." + fmt(hi) + ")");
      }
      if (r.default_value) {
        double d = *r.default_value;
        bool fits = d >= lo && d <= hi && (r.type == DataType::f32 || d == std::floor(d));
        if (!fits)
          error(p + "/default", "default-in-range", label + ": default " + fmt(d) + " does not fit type " + to_string(r.type));
        else if (r.range && (d < r.range->min || d > r.range->max) && r.errata.empty())
          error(p + "/default", "default-in-range",
                label + ": default " + fmt(d) + " lies outside range " + fmt(r.range->min) + ".." + fmt(r.range->max) +
                    " (record an erratum and cite it if the manual prints it so)");
        else if (!r.range && !r.enum_id.empty() && r.errata.empty()) {
          const Enumeration* e = s.find_enum(r.enum_id);
          if (e && std::none_of(e->values.begin(), e->values.end(), [&](const EnumValue& v) { return double(v.value) == d; }))
            error(p + "/default", "default-in-range", label + ": default " + fmt(d) + " is not one of enum '" + r.enum_id + "'");
        }
      }
      if (r.persistence.command && !s.register_covering(*r.persistence.command))
        error(p + "/persistence/command", "unknown-reference",
              label + ": save command register " + hex16(*r.persistence.command) + " is not in registers:");
      if (r.persistence.unless_register && !s.register_covering(*r.persistence.unless_register))
        error(p + "/persistence/unless", "unknown-reference",
              label + ": register " + hex16(*r.persistence.unless_register) + " is not in registers:");
      if (r.persistence.by == PersistBy::save_command && !r.persistence.command)
        error(p + "/persistence", "unknown-reference", label + ": persistence by save_command names no command register");
    }
    // Overlap, per table; blocks and 2-word registers cover several
    // addresses, so compare each register with the widest-reaching one before it.
    const Register* reach = nullptr;
    for (const auto& b : s.registers) {
      if (reach && reach->table != b.table) reach = nullptr;
      if (reach && reach->last_address() >= b.address) {
        const Register& a = *reach;
        bool b_later = b.loc.line > a.loc.line || (b.loc.line == a.loc.line && b.loc.col > a.loc.col);
        const Register& later = b_later ? b : a;
        const Register& earlier = b_later ? a : b;
        if (later.errata.empty() || earlier.errata.empty())  // an overlap the manual prints is recorded, not an error
          error(later.origin + "/address", "register-overlap",
                "register " + hex16(later.address) + " (" + later.name.en + ") overlaps register " + hex16(earlier.address) +
                    " (" + earlier.name.en + ", line " + std::to_string(earlier.loc.line) + ")");
      }
      if (b.last_address() > 0xFFFF)
        error(b.origin + "/address", "address-overflow", "register " + hex16(b.address) + " runs past address 0xFFFF");
      if (!reach || b.last_address() > reach->last_address()) reach = &b;
    }
  }

  void bitfields() {
    for (size_t i = 0; i < s.bitfields.size(); ++i) {
      const auto& b = s.bitfields[i];
      std::string p = "/bitfields/" + std::to_string(i);
      uint32_t used = 0;
      std::map<std::string, size_t> keys;
      for (size_t k = 0; k < b.fields.size(); ++k) {
        const auto& f = b.fields[k];
        std::string fp = p + "/fields/" + std::to_string(k);
        if (!f.key.empty()) {
          auto [it, fresh] = keys.emplace(f.key, k);
          if (!fresh)
            error(fp + "/key", "duplicate-id", "bitfield '" + b.id + "' field key '" + f.key + "' is already used by field " +
                                                   std::to_string(it->second));
        }
        if (f.hi < f.lo) {
          error(fp, "bitfield", "bitfield '" + b.id + "' field '" + f.name.en + "' needs bit: N or bits: [lo, hi] with lo <= hi");
          continue;
        }
        uint32_t mask = uint32_t(((uint64_t(1) << (f.hi - f.lo + 1)) - 1) << f.lo);
        if ((used & mask) && f.erratum.empty())
          error(fp, "bitfield-overlap", "bitfield '" + b.id + "' field '" + f.name.en + "' (bits " + std::to_string(f.lo) +
                                            "-" + std::to_string(f.hi) + ") overlaps an earlier field");
        used |= mask;
        if (!f.enum_id.empty() && !s.find_enum(f.enum_id))
          error(fp + "/enum", "unknown-reference", "enum '" + f.enum_id + "' is not in enums:");
        if (!f.erratum.empty() && !s.find_erratum(f.erratum))
          error(fp + "/erratum", "unknown-reference", "erratum '" + f.erratum + "' is not in errata:");
      }
    }
  }

  void profile() {
    std::set<int> seen;
    for (size_t i = 0; i < s.profile.function_codes.size(); ++i) {
      const auto& f = s.profile.function_codes[i];
      std::string p = "/profile/function_codes/" + std::to_string(i);
      if (!seen.insert(f.code).second) error(p + "/code", "duplicate-id", "function code " + std::to_string(f.code) + " is listed twice");
      int limit = standard_max_quantity(f.code);
      if (f.max_quantity && limit && *f.max_quantity > limit)
        error(p + "/max_quantity", "function-limit",
              "FC " + std::to_string(f.code) + ": max_quantity " + std::to_string(*f.max_quantity) +
                  " exceeds what fits in one PDU (" + std::to_string(limit) + ", MBAP v1.1b3 §6)");
      if (f.max_read_quantity && *f.max_read_quantity > kMaxReadWriteReadQuantity)
        error(p + "/max_read_quantity", "function-limit", "FC 23: max_read_quantity exceeds 125 (MBAP v1.1b3 §6.17)");
      if (f.max_write_quantity && *f.max_write_quantity > kMaxReadWriteWriteQuantity)
        error(p + "/max_write_quantity", "function-limit", "FC 23: max_write_quantity exceeds 121 (MBAP v1.1b3 §6.17)");
      if (!f.erratum.empty() && !s.find_erratum(f.erratum))
        error(p + "/erratum", "unknown-reference", "erratum '" + f.erratum + "' is not in errata:");
    }
    for (const auto& [v, e] : s.profile.exception_policy)
      if (!e.erratum.empty() && !s.find_erratum(e.erratum))
        error(std::string("/profile/exception_policy/") + to_string(v) + "/erratum", "unknown-reference",
              "erratum '" + e.erratum + "' is not in errata:");
  }

  void serial() {
    const auto& se = s.serial;
    if (se.slave_min > se.slave_max)
      error("/serial/slave_id", "range-order", "slave_id min " + std::to_string(se.slave_min) + " > max " + std::to_string(se.slave_max));
    if (se.baud_default && std::find(se.baud_rates.begin(), se.baud_rates.end(), *se.baud_default) == se.baud_rates.end())
      error("/serial/baud_rates/default", "default-in-range", "default baud rate " + std::to_string(*se.baud_default) + " is not in values");
    if (se.frame_default && std::find(se.frame_formats.begin(), se.frame_formats.end(), *se.frame_default) == se.frame_formats.end())
      error("/serial/frame_formats/default", "default-in-range", "default frame format " + *se.frame_default + " is not in values");
    for (size_t i = 0; i < se.settings.size(); ++i)
      if (!s.register_covering(se.settings[i].register_address))
        error("/serial/settings/" + std::to_string(i) + "/register", "unknown-reference",
              "register " + hex16(se.settings[i].register_address) + " is not in registers:");
    // Erratum references the structs do not keep: check them on the document.
    auto refs_at = [&](const nlohmann::json& j, const std::string& p) {
      if (!j.is_object() || !j.contains("erratum")) return;
      const auto& e = j["erratum"];
      std::vector<std::string> ids;
      if (e.is_string()) ids.push_back(e.get<std::string>());
      else if (e.is_array())
        for (const auto& x : e) ids.push_back(x.get<std::string>());
      erratum_refs(p + "/erratum", ids);
    };
    for (const char* list : {"enums", "bitfields"})
      if (doc.root.contains(list))
        for (size_t i = 0; i < doc.root[list].size(); ++i) refs_at(doc.root[list][i], std::string("/") + list + "/" + std::to_string(i));
    if (doc.root["serial"].contains("settings"))
      for (size_t i = 0; i < doc.root["serial"]["settings"].size(); ++i)
        refs_at(doc.root["serial"]["settings"][i], "/serial/settings/" + std::to_string(i));
    for (const char* part : {"slave_id", "broadcast", "baud_rates", "frame_formats"}) {
      std::string p = std::string("/serial/") + part + "/erratum";
      if (!doc.root["serial"][part].contains("erratum")) continue;
      const auto& e = doc.root["serial"][part]["erratum"];
      std::vector<std::string> ids;
      if (e.is_string()) ids.push_back(e.get<std::string>());
      else for (const auto& x : e) ids.push_back(x.get<std::string>());
      erratum_refs(p, ids);
    }
  }

  // An example must make sense against the map: a request that is not
  // answered with an exception addresses mapped registers with a supported
  // function code, unless the manual is known to be wrong there (erratum).
  void examples() {
    std::map<std::string, std::vector<int>> steps;
    for (const auto& e : s.examples) {
      const std::string& p = e.origin;
      erratum_refs(p + "/erratum", e.errata);
      if (!e.sequence.empty()) steps[e.sequence].push_back(e.step);
      std::optional<Bytes> req = parse_hex_strict(e.request);
      if (!req) error(p + "/request", "hex-frame", "example '" + e.id + "': request is not uppercase hex pairs separated by single spaces");
      std::optional<Bytes> rsp;
      if (e.response) {
        rsp = parse_hex_strict(*e.response);
        if (!rsp) error(p + "/response", "hex-frame", "example '" + e.id + "': response is not uppercase hex pairs separated by single spaces");
      }
      if (e.resolved_request && !parse_hex_strict(*e.resolved_request))
        error(p + "/resolved/request", "hex-frame", "example '" + e.id + "': resolved request is not uppercase hex pairs");
      if (e.resolved_response && !parse_hex_strict(*e.resolved_response))
        error(p + "/resolved/response", "hex-frame", "example '" + e.id + "': resolved response is not uppercase hex pairs");
      if (e.has_resolution() && e.errata.empty())
        error(p + "/resolved", "unknown-reference", "example '" + e.id + "' has a resolved reading but cites no erratum");
      for (size_t i = 0; i < e.given.size(); ++i)
        if (!s.register_covering(e.given[i].address, e.given[i].table))
          error(p + "/given/" + std::to_string(i), "example-map", "example '" + e.id + "': given register " + hex16(e.given[i].address) + " is not in registers:");
      for (size_t i = 0; i < e.after.size(); ++i)
        if (!s.register_covering(e.after[i].address, e.after[i].table))
          error(p + "/after/" + std::to_string(i), "example-map", "example '" + e.id + "': after register " + hex16(e.after[i].address) + " is not in registers:");
      if (!req || req->size() < 2 || !e.errata.empty()) continue;
      bool exception_reply = rsp && rsp->size() >= 2 && ((*rsp)[1] & 0x80);
      if (exception_reply || e.no_reply) continue;
      int fc = (*req)[1];
      if (!s.profile.function(fc)) {
        error(p + "/request", "example-map", "example '" + e.id + "': function code " + std::to_string(fc) + " is not in profile.function_codes");
        continue;
      }
      Table table = table_for_function(fc);
      unsigned start = 0, qty = 0;
      if ((fc >= 1 && fc <= 4) || fc == 15 || fc == 16) {
        if (req->size() < 6) continue;
        start = be16(*req, 2);
        qty = be16(*req, 4);
      } else if (fc == 5 || fc == 6 || fc == 22) {
        if (req->size() < 4) continue;
        start = be16(*req, 2);
        qty = 1;
      } else {
        continue;
      }
      for (unsigned a = start; a < start + qty && a <= 0xFFFF; ++a) {
        const Register* r = s.register_covering(uint16_t(a), table);
        if (!r) {
          error(p + "/request", "example-map",
                "example '" + e.id + "': FC " + std::to_string(fc) + " addresses " + hex16(a) +
                    ", which is not in registers: (cite an erratum, or expect an exception response)");
          break;
        }
        bool reads = fc <= 4;
        if (reads && r->access == Access::wo) {
          error(p + "/request", "example-map", "example '" + e.id + "' reads write-only register " + hex16(a) + " and expects no exception");
          break;
        }
        if (!reads && r->access == Access::ro) {
          error(p + "/request", "example-map", "example '" + e.id + "' writes read-only register " + hex16(a) + " and expects no exception");
          break;
        }
      }
    }
    for (auto& [id, list] : steps) {
      std::sort(list.begin(), list.end());
      for (size_t i = 0; i < list.size(); ++i)
        if (list[i] != int(i + 1)) {
          error("/examples", "sequence-steps", "sequence '" + id + "' has steps that are not 1.." + std::to_string(list.size()));
          break;
        }
    }
  }

  // Rule erratum-contested (issue 26): a fact an erratum names, through the
  // register, example, policy entry or function code that cites it, cannot
  // support a MUST case unless the erratum is settled by a printed frame
  // (`settled_by:`, or a bad CRC the routine settles): its basis is then
  // either, inferred or observed. `contests:` narrows what is in doubt.
  // An example inherits the `either` of the policy it exercises.
  // Rule erratum-linked: every erratum is cited by what it touches, or says
  // with `contests: []` that it touches no fact a case relies on.
  void contested() {
    auto open = [](const FactBasis& b) { return b.basis != Basis::stated; };
    if (!s.device.manual.erratum.empty() && !s.find_erratum(s.device.manual.erratum))
      error("/device/manual/erratum", "unknown-reference", "erratum '" + s.device.manual.erratum + "' is not in errata:");
    for (size_t i = 0; i < s.errata.size(); ++i) {
      const Erratum& e = s.errata[i];
      for (size_t k = 0; k < e.settled_by.size(); ++k) {
        const Example* x = nullptr;
        for (const auto& ex : s.examples)
          if (ex.id == e.settled_by[k]) x = &ex;
        std::string p = "/errata/" + std::to_string(i) + "/settled_by/" + std::to_string(k);
        if (!x) error(p, "unknown-reference", "erratum '" + e.id + "' is settled by example '" + e.settled_by[k] + "', which examples: does not define");
        else if (open(x->basis))
          error(p, "erratum-contested", "erratum '" + e.id + "' is settled by example '" + x->id + "', whose own frame is not stated (" + to_string(x->basis.basis) + ")");
      }
      // Where a printed text (or table) and a printed frame disagree, a frame
      // does not settle it alone: a drive that follows the text does what its
      // manual prints too. Unless the standard decides (decided_by:) or the
      // text is a misprint (class: typo), the facts are either.
      bool text_against_frame = e.kind == "text_vs_frame" || e.kind == "table_vs_example" || e.kind == "table_vs_text";
      ErratumExtra x = erratum_extra(s, e.id);
      if (!e.settled_by.empty() && text_against_frame && x.cls != "typo" && x.decided_by.empty())
        error("/errata/" + std::to_string(i) + "/settled_by", "erratum-contested",
              "erratum '" + e.id + "' (" + e.kind + ") is a printed text against a printed frame: the frame does not settle it. Make the facts either, the text's reading beside the frame's, or name the standard's clause that decides (decided_by:)");
      if (e.settled()) continue;
      auto why = [&](const std::string& what) {
        return what + " is named by erratum '" + e.id + "': mark it either or inferred, or settle the erratum with a printed frame (settled_by:)";
      };
      for (const auto& r : s.registers) {
        if (r.block_index > 0 || std::find(r.errata.begin(), r.errata.end(), e.id) == r.errata.end()) continue;
        for (Fact f : kRegisterFacts) {
          if (!e.contests_fact(to_string(f)) || !relied_on(r, f) || open(r.basis_of(f))) continue;
          error(r.origin + "/erratum", "erratum-contested", why("register " + hex16(r.address) + " " + to_string(f)));
        }
      }
      for (const auto& x : s.examples)
        if (std::find(x.errata.begin(), x.errata.end(), e.id) != x.errata.end() && e.contests_fact("example") && !open(x.basis))
          error(x.origin + "/erratum", "erratum-contested", why("example '" + x.id + "'"));
      for (const auto& [v, pe] : s.profile.exception_policy)
        if (pe.erratum == e.id && e.contests_fact("policy") && pe.kind != PolicyEntry::Kind::unspecified && !open(pe.basis))
          error(std::string("/profile/exception_policy/") + to_string(v), "erratum-contested", why(std::string("exception_policy.") + to_string(v)));
      for (size_t k = 0; k < s.profile.function_codes.size(); ++k) {
        const auto& f = s.profile.function_codes[k];
        if (f.erratum != e.id) continue;
        for (const char* fact : {"supported", "max_quantity"}) {
          if (!e.contests_fact(fact) || (std::string(fact) == "max_quantity" && !f.max_quantity) || open(f.basis_of(fact))) continue;
          error("/profile/function_codes/" + std::to_string(k) + "/erratum", "erratum-contested",
                why("FC " + std::to_string(f.code) + " " + fact));
        }
      }
    }
    for (const auto& x : s.examples) {
      if (!x.exercises) continue;
      PolicyEntry pe = s.profile.policy(*x.exercises);
      if (pe.basis.basis == Basis::either && !open(x.basis))
        error(x.origin, "erratum-contested",
              "example '" + x.id + "' exercises exception_policy." + to_string(*x.exercises) +
                  ", which is printed two ways: it inherits that either (basis: {either: [printed, policy], erratum: " + pe.basis.erratum + "})");
      else if (pe.basis.is_inferred() && !open(x.basis))
        error(x.origin, "erratum-contested",
              "example '" + x.id + "' exercises exception_policy." + to_string(*x.exercises) +
                  ", which is inferred: it inherits the inference (basis: {inferred: ..., searched: ...})");
    }
    // Which errata anything cites: every `erratum:` of the document, and the
    // bases' own erratum references.
    std::set<std::string> cited;
    std::function<void(const nlohmann::json&, bool)> walk = [&](const nlohmann::json& j, bool top) {
      if (j.is_object()) {
        for (auto it = j.begin(); it != j.end(); ++it) {
          if (top && it.key() == "errata") continue;
          if (it.key() == "erratum") {
            if (it->is_string()) cited.insert(it->get<std::string>());
            else if (it->is_array())
              for (const auto& x : *it)
                if (x.is_string()) cited.insert(x.get<std::string>());
          } else {
            walk(*it, false);
          }
        }
      } else if (j.is_array()) {
        for (const auto& x : j) walk(x, false);
      }
    };
    walk(doc.root, true);
    for (const auto& r : s.registers)
      for (const auto& id : r.errata) cited.insert(id);  // area: citations
    for (size_t i = 0; i < s.errata.size(); ++i) {
      const Erratum& e = s.errata[i];
      // contests: [] on an erratum that registers, examples, policy entries or
      // function codes cite says what of them it concerns (about:): parts no
      // case's expectation reads. The facts a case relies on are contested.
      ErratumExtra x = erratum_extra(s, e.id);
      if (cited.count(e.id) && e.contests_given && e.contests.empty() && x.about.empty())
        error("/errata/" + std::to_string(i) + "/contests", "erratum-linked",
              "erratum '" + e.id + "' is cited but contests nothing: say which facts it puts in doubt (contests: [read, ...]), or what of its citers it is about (about: [unit, name, note, ...])");
      if (!x.about.empty() && !(e.contests_given && e.contests.empty()))
        error("/errata/" + std::to_string(i) + "/about", "erratum-linked", "erratum '" + e.id + "': about: goes with contests: [] (an erratum that contests facts names them in contests:)");
      if (cited.count(e.id) || (e.contests_given && e.contests.empty())) continue;
      error("/errata/" + std::to_string(i) + "/id", "erratum-linked",
            "erratum '" + e.id + "' is cited by nothing: cite it from the registers, examples, policy entries or function codes it touches, or say contests: [] (it touches no fact a case relies on)");
    }
  }

  // Whether a register has the fact at all (a case can rely on it).
  static bool relied_on(const Register& r, Fact f) {
    switch (f) {
      case Fact::read: return r.access != Access::wo && r.access != Access::command;
      case Fact::write: return r.access != Access::ro;
      case Fact::range: return r.range.has_value();
      case Fact::default_value: return r.default_value.has_value();
      case Fact::word_order: return r.words == 2;
      case Fact::type: return true;
      case Fact::takes_effect: return r.takes_effect != TakesEffect::immediate;
      case Fact::persistence: return r.persistence.store != Store::none;
      case Fact::persistence_unless: return r.persistence.unless_register.has_value();
    }
    return false;
  }

  static std::string fmt(double d) {
    if (d == std::floor(d) && std::fabs(d) < 1e15) return std::to_string(int64_t(d));
    char buf[32];
    std::snprintf(buf, sizeof buf, "%g", d);
    return buf;
  }
};

}  // namespace

void check_semantics(const Spec& spec, const JsonDocument& doc, const std::string& expected_id, Diagnostics& out) {
  Checker c{spec, doc, out};
  if (!expected_id.empty() && spec.device.id != expected_id)
    c.error("/device/id", "id-matches-file", "device.id '" + spec.device.id + "' does not match the file name '" + expected_id + ".yaml'");
  c.ids();
  c.registers();
  c.bitfields();
  c.profile();
  c.serial();
  c.examples();
  c.operations();
  c.contested();
}

}  // namespace mbc::spec
