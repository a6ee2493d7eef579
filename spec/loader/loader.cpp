#include "loader.h"

#include <algorithm>
#include <filesystem>
#include <fstream>
#include <set>
#include <sstream>
#include <stdexcept>

#include <valijson/adapters/nlohmann_json_adapter.hpp>
#include <valijson/schema.hpp>
#include <valijson/schema_parser.hpp>
#include <valijson/validation_results.hpp>
#include <valijson/validator.hpp>

#include "checks.h"
#include "control.h"
#include "erratum_extra.h"
#include "modbus/crc16.h"
#include "modbus/hex.h"
#include "yaml_json.h"

namespace mbc::spec {
namespace {

using nlohmann::json;

const valijson::Schema& device_schema() {
  static const valijson::Schema* schema = [] {
    auto* s = new valijson::Schema;  // lives for the process; valijson schemas do not copy
    json doc = json::parse(device_schema_text());
    valijson::SchemaParser parser(valijson::SchemaParser::kDraft7);
    valijson::adapters::NlohmannJsonAdapter adapter(doc);
    parser.populateSchema(adapter, *s);
    return s;
  }();
  return *schema;
}

// valijson contexts look like {"<root>", "[registers]", "[3]", "[access]"}.
std::string context_to_pointer(const std::vector<std::string>& ctx) {
  std::string p;
  for (const auto& c : ctx) {
    if (c == "<root>") continue;
    std::string t = c;
    if (t.size() >= 2 && t.front() == '[' && t.back() == ']') t = t.substr(1, t.size() - 2);
    if (t.size() >= 2 && t.front() == '"' && t.back() == '"') t = t.substr(1, t.size() - 2);
    p += "/" + t;
  }
  return p;
}

std::string pointer_to_path(const std::string& p) {
  // "/registers/3/access" -> "registers[3].access"
  std::string out;
  std::stringstream ss(p);
  std::string tok;
  std::getline(ss, tok, '/');
  while (std::getline(ss, tok, '/')) {
    bool idx = !tok.empty() && std::all_of(tok.begin(), tok.end(), ::isdigit);
    if (idx) out += "[" + tok + "]";
    else out += (out.empty() ? "" : ".") + tok;
  }
  return out.empty() ? "(document)" : out;
}

// A library profile (spec/profiles/<id>.yaml): the same definitions, rooted
// at control_profile.
const valijson::Schema& profile_schema() {
  static const valijson::Schema* schema = [] {
    auto* s = new valijson::Schema;
    json dev = json::parse(device_schema_text());
    json doc = {{"$schema", dev["$schema"]}, {"$ref", "#/definitions/control_profile"}, {"definitions", dev["definitions"]}};
    valijson::SchemaParser parser(valijson::SchemaParser::kDraft7);
    valijson::adapters::NlohmannJsonAdapter adapter(doc);
    parser.populateSchema(adapter, *s);
    return s;
  }();
  return *schema;
}

void validate_schema(const JsonDocument& doc, const std::string& file, Diagnostics& out,
                     const valijson::Schema& schema = device_schema()) {
  valijson::Validator validator;
  valijson::ValidationResults results;
  valijson::adapters::NlohmannJsonAdapter target(doc.root);
  if (validator.validate(schema, target, &results)) return;
  struct Err {
    std::string pointer;
    std::string description;
  };
  std::vector<Err> errs;
  valijson::ValidationResults::Error e;
  while (results.popError(e)) errs.push_back({context_to_pointer(e.context), e.description});
  // valijson reports every enclosing failure too ("failed to validate item #3
  // in array"); keep the innermost ones, which say what is actually wrong.
  std::set<std::string> seen;
  for (const auto& a : errs) {
    bool has_deeper = std::any_of(errs.begin(), errs.end(), [&](const Err& b) {
      return b.pointer.size() > a.pointer.size() && b.pointer.compare(0, a.pointer.size(), a.pointer) == 0 &&
             b.pointer[a.pointer.size()] == '/';
    });
    if (has_deeper) continue;
    std::string msg = pointer_to_path(a.pointer) + ": " + a.description;
    if (!seen.insert(msg).second) continue;
    SourceLoc loc = doc.where(a.pointer);
    out.push_back({file, loc.line, loc.col, "schema", msg});
  }
}

// ---- building the plain structs (the schema has vouched for the types) ----

struct Builder {
  const JsonDocument& doc;
  std::string file;
  Diagnostics& out;

  SourceLoc at(const std::string& p) const { return doc.where(p); }
  static std::string str(const json& j, const char* key, std::string def = "") {
    auto it = j.find(key);
    return it != j.end() && it->is_string() ? it->get<std::string>() : def;
  }
  static Table table_from(const std::string& t) {
    return t == "input" ? Table::input : t == "coil" ? Table::coil : t == "discrete_input" ? Table::discrete_input : Table::holding;
  }
  static Name name(const json& j) {
    Name n;
    if (j.is_object()) {
      n.zh = str(j, "zh");
      n.en = str(j, "en");
    }
    return n;
  }
  static std::vector<std::string> refs(const json& j, const char* key) {
    std::vector<std::string> r;
    auto it = j.find(key);
    if (it == j.end()) return r;
    if (it->is_string()) r.push_back(it->get<std::string>());
    else if (it->is_array())
      for (const auto& x : *it) r.push_back(x.get<std::string>());
    return r;
  }
  static std::string first_ref(const json& j, const char* key) {
    auto r = refs(j, key);
    return r.empty() ? "" : r.front();
  }

  void error(const std::string& p, const char* rule, const std::string& what) {
    SourceLoc l = at(p);
    out.push_back({file, l.line, l.col, rule, what});
  }

  // A basis object ({stated|inferred|observed|either, searched, section,
  // erratum}); `p` is its JSON pointer, `what` names the fact in messages.
  FactBasis fact_basis(const json& j, const std::string& p, const std::string& what) {
    FactBasis b;
    b.loc = at(p);
    int forms = 0;
    for (const char* k : {"stated", "inferred", "observed", "either"}) forms += j.contains(k) ? 1 : 0;
    if (forms > 1)
      error(p, "basis", what + ": give one of stated, inferred, observed, either (found " + std::to_string(forms) + ")");
    if (j.contains("inferred")) {
      b.basis = Basis::inferred;
      b.why = str(j, "inferred");
      if (str(j, "searched").empty())
        error(p, "basis", what + ": an inferred fact names the sections searched for it (searched: \"6.1; 6.2.4\")");
    } else if (j.contains("observed")) {
      b.basis = Basis::observed;
      b.why = str(j, "observed");
    } else if (j.contains("either")) {
      b.basis = Basis::either;
      for (const auto& r : j["either"]) b.readings.push_back(r.dump());
      if (b.readings.size() < 2)
        error(p + "/either", "either-readings", what + ": either gives at least two readings");
      else if (std::set<std::string>(b.readings.begin(), b.readings.end()).size() != b.readings.size())
        error(p + "/either", "either-readings", what + ": the readings of either must differ");
      if (str(j, "erratum").empty())
        error(p, "either-readings", what + ": a fact printed two ways cites the erratum that records it (erratum: <id>)");
    } else {
      b.quote = str(j, "stated", str(j, "quote"));
    }
    b.searched = str(j, "searched");
    b.section = str(j, "section");
    b.erratum = str(j, "erratum");
    return b;
  }

  PolicyEntry policy(const json& j, const std::string& p, bool top = true) {
    PolicyEntry e;
    e.loc = at(p);
    if (j.is_string()) {
      e.kind = j == "silent" ? PolicyEntry::Kind::silent : PolicyEntry::Kind::unspecified;
      return e;
    }
    if (!j.is_object()) {
      error(p, "either-readings", "a policy reading is silent, unspecified, {exception: N} or {silent: true}");
      return e;
    }
    if (j.contains("exception") && j["exception"].is_number_integer()) {
      e.kind = PolicyEntry::Kind::exception;
      e.code = j["exception"].get<int>();
    } else if (j.contains("silent")) {
      e.kind = PolicyEntry::Kind::silent;
    } else if (j.contains("unspecified")) {
      e.kind = PolicyEntry::Kind::unspecified;
    } else if (!top || !j.contains("either")) {
      error(p, "either-readings", "a policy reading is silent, unspecified, {exception: N} or {silent: true}");
    }
    e.section = str(j, "section");
    e.erratum = str(j, "erratum");
    if (!top) return e;
    e.basis = fact_basis(j, p, "exception policy");
    if (e.basis.section.empty()) e.basis.section = e.section;
    if (e.basis.basis == Basis::either) {
      for (size_t i = 0; i < j["either"].size(); ++i)
        e.readings.push_back(policy(j["either"][i], p + "/either/" + std::to_string(i), false));
      if (!e.readings.empty()) {
        e.kind = e.readings.front().kind;
        e.code = e.readings.front().code;
      }
    }
    return e;
  }

  std::vector<EnumValue> enum_values(const json& arr) {
    std::vector<EnumValue> v;
    for (const auto& x : arr) v.push_back({x["value"].get<int64_t>(), name(x["name"]), str(x, "note")});
    return v;
  }

  Spec build() {
    const json& r = doc.root;
    Spec s;
    s.path = file;
    const json& d = r["device"];
    s.device.id = str(d, "id");
    s.device.vendor = str(d, "vendor");
    s.device.title = str(d, "title");
    for (const auto& m : d["models"]) s.device.models.push_back(m.get<std::string>());
    s.device.manual.file = str(d["manual"], "file");
    s.device.manual.address_notation = str(d["manual"], "address_notation");
    s.device.manual.addressing_note = str(d["manual"], "addressing_note");
    s.device.manual.erratum = str(d["manual"], "erratum");
    s.device.manual.source = str(d["manual"], "source", "manual");
    s.device.section = str(d, "section");
    s.device.identification.vendor_name = s.device.vendor;
    s.device.identification.product_code = s.device.models.empty() ? s.device.id : s.device.models.front();
    s.device.identification.additional_data = s.device.id;
    if (d.contains("identification")) {
      const json& idn = d["identification"];
      auto& out = s.device.identification;
      out.vendor_name = str(idn, "vendor_name", out.vendor_name);
      out.product_code = str(idn, "product_code", out.product_code);
      out.revision = str(idn, "revision", out.revision);
      if (idn.contains("server_id")) out.server_id = idn["server_id"].get<int>();
      out.run_indicator = idn.value("run_indicator", out.run_indicator);
      out.additional_data = str(idn, "additional_data", out.additional_data);
    }

    const json& se = r["serial"];
    s.serial.section = str(se, "section");
    const json& sid = se["slave_id"];
    s.serial.slave_min = sid["min"].get<int>();
    s.serial.slave_max = sid["max"].get<int>();
    if (sid.contains("default") && sid["default"].is_number()) s.serial.slave_default = sid["default"].get<int>();
    s.serial.slave_set_by = str(sid, "set_by");
    s.serial.slave_section = str(sid, "section");
    const json& bc = se["broadcast"];
    if (bc.contains("address") && bc["address"].is_number()) s.serial.broadcast_address = bc["address"].get<int>();
    s.serial.broadcast_writes = str(bc, "writes", "unspecified");
    s.serial.broadcast_reply = str(bc, "reply", "unspecified");
    s.serial.broadcast_section = str(bc, "section");
    for (const auto& b : se["baud_rates"]["values"]) s.serial.baud_rates.push_back(b.get<int>());
    if (se["baud_rates"].contains("default") && se["baud_rates"]["default"].is_number())
      s.serial.baud_default = se["baud_rates"]["default"].get<int>();
    s.serial.baud_section = str(se["baud_rates"], "section");
    for (const auto& f : se["frame_formats"]["values"]) s.serial.frame_formats.push_back(f.get<std::string>());
    if (se["frame_formats"].contains("default") && se["frame_formats"]["default"].is_string())
      s.serial.frame_default = se["frame_formats"]["default"].get<std::string>();
    s.serial.frame_section = str(se["frame_formats"], "section");
    if (se.contains("settings"))
      for (const auto& st : se["settings"]) {
        SerialSetting x;
        x.register_address = st["register"].get<uint16_t>();
        x.setting = str(st, "setting");
        x.section = str(st, "section");
        if (st.contains("encoding"))
          for (const auto& e : st["encoding"])
            x.encoding.emplace_back(e["value"].get<int64_t>(),
                                    e["means"].is_string() ? e["means"].get<std::string>() : e["means"].dump());
        s.serial.settings.push_back(x);
      }

    const json& pr = r["profile"];
    s.profile.section = str(pr, "section");
    for (size_t i = 0; i < pr["function_codes"].size(); ++i) {
      const json& f = pr["function_codes"][i];
      FunctionCode fc;
      fc.code = f["code"].get<int>();
      if (f.contains("max_quantity")) fc.max_quantity = f["max_quantity"].get<int>();
      if (f.contains("max_read_quantity")) fc.max_read_quantity = f["max_read_quantity"].get<int>();
      if (f.contains("max_write_quantity")) fc.max_write_quantity = f["max_write_quantity"].get<int>();
      if (f.contains("subfunctions")) fc.subfunctions = f["subfunctions"].get<std::vector<int>>();
      if (f.contains("mei_types")) fc.mei_types = f["mei_types"].get<std::vector<int>>();
      fc.note = str(f, "note");
      fc.section = str(f, "section");
      fc.erratum = str(f, "erratum");
      fc.loc = at("/profile/function_codes/" + std::to_string(i));
      if (f.contains("basis"))
        for (const auto& [k, v] : f["basis"].items()) {
          std::string bp = "/profile/function_codes/" + std::to_string(i) + "/basis/" + k;
          auto b = fact_basis(v, bp, "FC " + std::to_string(fc.code) + " " + k);
          if (b.section.empty()) b.section = fc.section;
          // A function code accepted or refused: two outcomes, in words.
          // A limit printed two ways as numbers stays typed (the cases stay inside both).
          // (const json: operator[] of a missing key is undefined behaviour, so every lookup is checked)
          static const json kNone = json::array();
          const json& either = v.is_object() && v.contains("either") ? v.at("either") : kNone;
          bool numbers = k != "supported" && (!either.is_array() || std::all_of(either.begin(), either.end(), [](const json& x) { return x.is_number_integer(); }));
          if (b.basis == Basis::either && !numbers && words_readings(either, bp + "/either")) b.why = "printed two ways in words: no one expectation holds both readings";
          fc.basis[k] = b;
        }
      if (s.device.manual.source != "manual")
        for (const char* k : {"supported", "max_quantity", "max_read_quantity", "max_write_quantity"})
          if ((f.contains(k) || std::string(k) == "supported") && !fc.basis.count(k)) fc.basis[k] = discovered(s, fc.section, fc.loc);
      s.profile.function_codes.push_back(fc);
    }
    for (Violation v : kAllViolations) {
      const char* key = to_string(v);
      const json& pol = pr["exception_policy"];
      if (!pol.contains(key)) continue;
      std::string p = std::string("/profile/exception_policy/") + key;
      PolicyEntry e = policy(pol[key], p);
      // A policy is stated outside any table: a stated one carries the words.
      if (s.device.manual.source == "manual" && e.kind != PolicyEntry::Kind::unspecified &&
          e.basis.basis == Basis::stated && e.basis.quote.empty())
        error(p, "stated-needs-quote", std::string(key) + ": a stated exception policy quotes the manual (quote: \"...\"), or says why it is inferred (inferred:, searched:)");
      if (s.device.manual.source != "manual" && e.kind != PolicyEntry::Kind::unspecified && e.basis.basis == Basis::stated)
        e.basis = discovered(s, e.section, e.loc);
      s.profile.exception_policy[v] = e;
    }
    if (pr.contains("exception_codes"))
      for (const auto& c : pr["exception_codes"])
        s.profile.exception_codes.push_back({c["code"].get<int>(), name(c["name"]), str(c, "meaning"), str(c, "section")});

    if (r.contains("enums"))
      for (size_t i = 0; i < r["enums"].size(); ++i) {
        const json& e = r["enums"][i];
        s.enums.push_back({str(e, "id"), str(e, "section"), enum_values(e["values"]), at("/enums/" + std::to_string(i))});
      }
    if (r.contains("bitfields"))
      for (size_t i = 0; i < r["bitfields"].size(); ++i) {
        const json& b = r["bitfields"][i];
        Bitfield bf{str(b, "id"), str(b, "section"), {}, at("/bitfields/" + std::to_string(i))};
        for (const auto& f : b["fields"]) {
          BitField x;
          if (f.contains("bit")) x.lo = x.hi = f["bit"].get<int>();
          else if (f.contains("bits")) {
            x.lo = f["bits"][0].get<int>();
            x.hi = f["bits"][1].get<int>();
          } else {
            x.lo = 0;
            x.hi = -1;  // reported by the bitfield rule
          }
          x.key = str(f, "key");
          x.name = name(f["name"]);
          x.reserved = f.value("reserved", false);
          if (f.contains("default")) x.default_value = f["default"].get<int64_t>();
          x.enum_id = str(f, "enum");
          x.erratum = str(f, "erratum");
          bf.fields.push_back(x);
        }
        s.bitfields.push_back(bf);
      }

    for (size_t i = 0; i < r["registers"].size(); ++i) build_register(s, r["registers"][i], i);
    std::stable_sort(s.registers.begin(), s.registers.end(), [](const Register& a, const Register& b) {
      return std::pair(int(a.table), a.address) < std::pair(int(b.table), b.address);
    });

    for (size_t i = 0; i < r["examples"].size(); ++i) {
      const json& e = r["examples"][i];
      Example x;
      x.id = str(e, "id");
      x.section = str(e, "section");
      x.does = str(e, "does");
      x.request = str(e, "request");
      if (e.contains("response")) x.response = str(e, "response");
      for (const char* key : {"given", "after"}) {
        if (!e.contains(key)) continue;
        auto& into = std::string(key) == "given" ? x.given : x.after;
        for (const auto& g : e[key]) {
          RegisterValue v{g["address"].get<uint16_t>(), g["value"].get<double>()};
          if (g.contains("table")) {
            v.table = table_from(str(g, "table"));
            v.table_set = true;
          }
          into.push_back(v);
        }
      }
      if (e.contains("sequence")) {
        x.sequence = str(e["sequence"], "id");
        x.step = e["sequence"]["step"].get<int>();
      }
      if (auto bytes = parse_hex(x.request); bytes && bytes->size() >= 2)
        for (auto* list : {&x.given, &x.after})
          for (auto& v : *list)
            if (!v.table_set) v.table = table_for_function((*bytes)[1]);
      x.errata = refs(e, "erratum");
      x.no_reply = e.value("no_reply", false);
      if (e.contains("resolved")) {
        const json& rs = e["resolved"];
        if (rs.contains("request")) x.resolved_request = str(rs, "request");
        if (rs.contains("response")) x.resolved_response = str(rs, "response");
        x.resolved_silent = rs.value("silent", false);
      }
      x.origin = "/examples/" + std::to_string(i);
      x.loc = at(x.origin);
      if (e.contains("basis")) {
        x.basis = fact_basis(e["basis"], x.origin + "/basis", "example " + x.id);
        if (x.basis.basis == Basis::either) {
          std::set<std::string> rs(x.basis.readings.begin(), x.basis.readings.end());
          std::set<std::string> known{"\"printed\"", "\"resolved\"", "\"policy\""};
          bool ok = rs.size() >= 2 && rs.count("\"printed\"") &&
                    std::all_of(rs.begin(), rs.end(), [&](const std::string& r) { return known.count(r) > 0; });
          if (!ok)
            error(x.origin + "/basis/either", "either-readings",
                  "example " + x.id + ": the readings of an example are [printed, resolved] or [printed, policy]");
          if (rs.count("\"resolved\"") && (!x.has_resolution() || !x.response))
            error(x.origin + "/basis/either", "either-readings", "example " + x.id + ": either needs a printed response and a resolved: reading");
        }
      }
      if (x.basis.section.empty()) x.basis.section = x.section;
      if (e.contains("exercises")) {
        for (Violation v : kAllViolations)
          if (str(e, "exercises") == to_string(v)) x.exercises = v;
      } else {
        x.exercises = exercised(s, x);
      }
      if (x.basis.basis == Basis::either && x.basis.readings.size() >= 2) {
        bool policy_reading = std::find(x.basis.readings.begin(), x.basis.readings.end(), "\"policy\"") != x.basis.readings.end();
        if (policy_reading && !(x.exercises && s.profile.policy(*x.exercises).basis.basis == Basis::either))
          error(x.origin + "/basis/either", "either-readings",
                "example " + x.id + ": the reading `policy` needs an example that exercises a policy printed two ways (exercises:)");
      }
      s.examples.push_back(x);
    }
    std::map<std::string, ErratumExtra> extras;
    for (size_t i = 0; i < r["errata"].size(); ++i) {
      const json& e = r["errata"][i];
      Erratum x;
      x.id = str(e, "id");
      x.section = str(e, "section");
      x.kind = str(e, "kind");
      x.printed = str(e, "printed");
      x.resolved = str(e, "resolved");
      x.why = str(e, "why");
      x.loc = at("/errata/" + std::to_string(i));
      if (e.contains("contests")) {
        x.contests_given = true;
        for (const auto& c : e["contests"]) x.contests.push_back(c.get<std::string>());
      }
      if (e.contains("settled_by"))
        for (const auto& c : e["settled_by"]) x.settled_by.push_back(c.get<std::string>());
      ErratumExtra& xx = extras[x.id];
      xx.cls = str(e, "class", "contradiction");
      if (e.contains("about"))
        for (const auto& c : e["about"]) xx.about.push_back(c.get<std::string>());
      if (e.contains("area")) xx.area = std::pair(e["area"]["from"].get<uint16_t>(), e["area"]["to"].get<uint16_t>());
      xx.decided_by = str(e, "decided_by");
      s.errata.push_back(std::move(x));
    }
    record_erratum_extras(s.path, extras);
    apply_errata_areas(s, extras);
    if (r.contains("operations")) build_operations(s, r["operations"]);
    build_control(s, doc, file, out);
    if (r.contains("timing")) {
      const json& t = r["timing"];
      for (auto [key, field] : {std::pair{"response_timeout_ms", &Timing::response_timeout_ms},
                                std::pair{"frame_timeout_ms", &Timing::frame_timeout_ms},
                                std::pair{"guard_interval_us", &Timing::guard_interval_us},
                                std::pair{"response_time_ms", &Timing::response_time_ms}})
        if (t.contains(key)) s.timing.*field = t[key].get<double>();
      s.timing.section = str(t, "section");
    }
    check_basis_errata(s);
    return s;
  }

  // `area:` makes every holding register of the area cite the erratum. An
  // unsettled erratum that contests `address` puts where each register it
  // names sits in doubt: the register's read and write are printed two ways
  // (at the printed address, or one above it), unless the spec gives them.
  void apply_errata_areas(Spec& s, const std::map<std::string, ErratumExtra>& extras) {
    for (const auto& e : s.errata) {
      auto area = extras.count(e.id) ? extras.at(e.id).area : std::nullopt;
      if (area)
        for (auto& r : s.registers)
          if (r.table == Table::holding && r.address >= area->first && r.last_address() <= area->second &&
              std::find(r.errata.begin(), r.errata.end(), e.id) == r.errata.end())
            r.errata.push_back(e.id);
      if (!e.contests_given || !e.contests_fact("address") || e.settled()) continue;
      // A read answers on either reading wherever the address below holds a
      // register the erratum names too (one above, that register sits here):
      // only the first of a run is read in doubt. Every write lands on another
      // register (its own range and access) on the other reading.
      std::set<uint32_t> named;
      for (const auto& r : s.registers)
        if (r.table == Table::holding && std::find(r.errata.begin(), r.errata.end(), e.id) != r.errata.end())
          for (uint32_t a = r.address; a <= r.last_address(); ++a) named.insert(a);
      for (auto& r : s.registers) {
        if (std::find(r.errata.begin(), r.errata.end(), e.id) == r.errata.end()) continue;
        for (Fact f : {Fact::read, Fact::write}) {
          if (r.basis.count(f)) continue;
          if (f == Fact::read && r.address > 0 && named.count(uint32_t(r.address) - 1)) continue;
          FactBasis b;
          b.basis = Basis::either;
          b.why = "printed two ways in words: no one expectation holds both readings";
          b.erratum = e.id;
          b.section = e.section;
          b.readings = {"\"at the printed address\"", "\"at the printed address + 1\""};
          b.loc = r.loc;
          r.basis[f] = b;
        }
      }
    }
  }

  // Readings of a fact printed two ways that no expectation can hold both
  // of: each says in words what the device does (`["readable (6.1: RW)",
  // "refused (6.2.4)"]`). True when every reading is such words.
  bool words_readings(const json& arr, const std::string& p) {
    bool ok = arr.is_array() && !arr.empty();
    for (size_t i = 0; ok && i < arr.size(); ++i)
      if (!arr[i].is_string() || arr[i].get<std::string>().empty()) {
        error(p + "/" + std::to_string(i), "either-readings", "this fact's readings are words: what the device does on each side (\"readable (6.1: RW)\")");
        ok = false;
      }
    return ok;
  }

  // The kind of violation a printed frame provokes, when the frame says so
  // alone: a function code the profile lacks, a deliberately wrong request
  // CRC, or an exception code that only one policy kind gives.
  static std::optional<Violation> exercised(const Spec& s, const Example& x) {
    auto req = parse_hex(x.request);
    if (!req || req->size() < 4) return std::nullopt;
    if (!s.profile.function((*req)[1] & 0x7F)) return Violation::unsupported_function;
    if (!crc_ok(*req) && !x.resolved_request) return Violation::crc_error;
    auto rsp = parse_hex(x.resolved_response.value_or(x.response.value_or("")));
    if (!rsp || rsp->size() < 3 || !((*rsp)[1] & 0x80)) return std::nullopt;
    int code = (*rsp)[2];
    std::optional<Violation> found;
    int n = 0;
    for (Violation v : kAllViolations) {
      PolicyEntry p = s.profile.policy(v);
      bool gives = p.kind == PolicyEntry::Kind::exception && p.code == code;
      for (const auto& r : p.readings) gives = gives || (r.kind == PolicyEntry::Kind::exception && r.code == code);
      if (gives) found = v, ++n;
    }
    return n == 1 ? found : std::nullopt;
  }

  // Every erratum a basis cites exists (rule unknown-reference).
  void check_basis_errata(const Spec& s) {
    auto check = [&](const FactBasis& b, const std::string& what) {
      if (b.erratum.empty() || s.find_erratum(b.erratum)) return;
      out.push_back({file, b.loc.line, b.loc.col, "unknown-reference", what + " cites erratum '" + b.erratum + "', which errata: does not define"});
    };
    for (const auto& r : s.registers)
      if (r.block_index <= 0)
        for (const auto& [f, b] : r.basis) check(b, std::string(to_string(f)) + " of register " + std::to_string(r.address));
    for (const auto& f : s.profile.function_codes)
      for (const auto& [k, b] : f.basis) check(b, "FC " + std::to_string(f.code) + " " + k);
    for (const auto& e : s.examples) check(e.basis, "example " + e.id);
  }

  RegisterWrite register_write(const json& j, const std::string& p) {
    RegisterWrite w;
    w.key = str(j, "register");
    w.value = j["value"].get<int64_t>();
    w.settle_us = uint64_t(j.value("settle_ms", 0.0) * 1000);
    w.section = str(j, "section");
    w.loc = at(p);
    return w;
  }

  std::optional<RegisterWrite> optional_write(const json& j, const char* key, const std::string& p) {
    if (!j.contains(key)) return std::nullopt;
    return register_write(j[key], p + "/" + key);
  }

  void build_operations(Spec& s, const json& o) {
    const std::string p = "/operations";
    s.operations.section = str(o, "section");
    s.operations.save = optional_write(o, "save", p);
    s.operations.factory_reset = optional_write(o, "factory_reset", p);
    if (o.contains("setup"))
      for (size_t i = 0; i < o["setup"].size(); ++i)
        s.operations.setup.push_back(register_write(o["setup"][i], p + "/setup/" + std::to_string(i)));
  }

  // A fact with no basis of its own in a spec no manual states:
  // `source: discover` was probed (observed); `csv` and `wb-mqtt-serial` are
  // an imported map, the user's claim (inferred).
  static FactBasis discovered(const Spec& s, const std::string& section, SourceLoc loc) {
    FactBasis b;
    const std::string& src = s.device.manual.source;
    b.basis = src == "discover" ? Basis::observed : Basis::inferred;
    b.why = src == "discover" ? "found by probing the target (" + s.device.manual.file + ")"
                              : "claimed by " + s.device.manual.file + " (an imported " + src + " map, not a manual)";
    b.section = section;
    b.loc = loc;
    return b;
  }

  void register_basis(Register& r, const json& j, const std::string& p) {
    for (Fact f : kRegisterFacts) {
      const char* key = to_string(f);
      if (!j.contains(key)) continue;
      std::string fp = p + "/" + key;
      FactBasis b = fact_basis(j[key], fp, std::string(key) + " of register " + std::to_string(r.address));
      if (b.section.empty()) b.section = r.section;
      if (b.basis == Basis::either) {
        if (f == Fact::range || f == Fact::default_value || f == Fact::word_order) either_readings(r, f, j[key]["either"], fp + "/either");
        else if (words_readings(j[key]["either"], fp + "/either")) b.why = "printed two ways in words: no one expectation holds both readings";
      }
      r.basis[f] = b;
    }
  }

  // The typed readings of a register's `either`.
  void either_readings(Register& r, Fact f, const json& arr, const std::string& p) {
    for (size_t i = 0; i < arr.size(); ++i) {
      const json& x = arr[i];
      std::string xp = p + "/" + std::to_string(i);
      if (f == Fact::range && x.is_object() && x.contains("min") && x.contains("max") && x["min"].is_number() &&
          x["max"].is_number() && x["min"].get<double>() <= x["max"].get<double>())
        r.range_readings.push_back({x["min"].get<double>(), x["max"].get<double>()});
      else if (f == Fact::default_value && x.is_number())
        r.default_readings.push_back(x.get<double>());
      else if (f == Fact::word_order && x.is_string() && (x == "high_first" || x == "low_first"))
        r.word_order_readings.push_back(x == "high_first" ? WordOrder::high_first : WordOrder::low_first);
      else
        error(xp, "either-readings", std::string(to_string(f)) + " reading " + x.dump() + " is not " +
                  (f == Fact::range ? "a {min, max} with min <= max" : f == Fact::default_value ? "a number" : "high_first or low_first"));
    }
  }

  void build_register(Spec& s, const json& j, size_t index) {
    const std::string p = "/registers/" + std::to_string(index);
    Register base;
    base.loc = at(p);
    base.origin = p;
    base.address = j["address"].get<uint16_t>();
    base.key = str(j, "key");
    base.name = name(j["name"]);
    base.table = table_from(str(j, "table", "holding"));
    std::string access = str(j, "access");
    base.access = access == "ro" ? Access::ro : access == "wo" ? Access::wo : access == "command" ? Access::command : Access::rw;
    std::string type = str(j, "type");
    static const std::pair<const char*, DataType> types[] = {
        {"u16", DataType::u16}, {"s16", DataType::s16}, {"u32", DataType::u32},     {"s32", DataType::s32},
        {"f32", DataType::f32}, {"bitfield", DataType::bitfield}, {"enum", DataType::enumeration}, {"bit", DataType::bit}};
    for (const auto& [n, t] : types)
      if (type == n) base.type = t;
    bool wide = base.type == DataType::u32 || base.type == DataType::s32 || base.type == DataType::f32;
    base.words = j.contains("words") ? j["words"].get<int>() : (wide ? 2 : 1);
    std::string wo = str(j, "word_order");
    base.word_order = wo == "high_first" ? WordOrder::high_first : wo == "low_first" ? WordOrder::low_first : WordOrder::none;
    if (j.contains("range")) base.range = Range{j["range"]["min"].get<double>(), j["range"]["max"].get<double>()};
    if (j.contains("default") && j["default"].is_number()) base.default_value = j["default"].get<double>();
    base.unit = str(j, "unit");
    base.scale = j.value("scale", 1.0);
    if (j.contains("persistence") && j["persistence"].is_object()) {
      const json& ps = j["persistence"];
      base.persistence.store = str(ps, "store") == "flash" ? Store::flash : Store::eeprom;
      base.persistence.by = str(ps, "by") == "save_command" ? PersistBy::save_command : PersistBy::on_write;
      if (ps.contains("command")) base.persistence.command = ps["command"].get<uint16_t>();
      if (ps.contains("unless")) {
        base.persistence.unless_register = ps["unless"]["register"].get<uint16_t>();
        base.persistence.unless_value = ps["unless"]["value"].get<int64_t>();
      }
      base.persistence.section = str(ps, "section");
    }
    base.takes_effect = str(j, "takes_effect") == "power_cycle" ? TakesEffect::power_cycle : TakesEffect::immediate;
    if (j.contains("enum")) {
      if (j["enum"].is_string()) base.enum_id = j["enum"].get<std::string>();
      else {
        base.enum_id = "register-" + std::to_string(base.address) + "-values";
        s.enums.push_back({base.enum_id, str(j, "section"), enum_values(j["enum"]), at(p + "/enum")});
      }
    }
    base.bitfield_id = str(j, "bitfield");
    if (j.contains("command")) {
      const json& c = j["command"];
      Command cmd;
      cmd.effect = str(c, "effect");
      if (c.contains("reads_back")) cmd.reads_back = c["reads_back"].get<int64_t>();
      cmd.motion = c.value("motion", false);
      cmd.eeprom = c.value("eeprom", false);
      if (c.contains("values")) cmd.values = c["values"].get<std::vector<int64_t>>();
      base.command = cmd;
    }
    if (j.contains("printed"))
      for (const auto& [k, v] : j["printed"].items()) base.printed[k] = v.is_string() ? v.get<std::string>() : v.dump();
    base.errata = refs(j, "erratum");
    base.note = str(j, "note");
    base.section = str(j, "section");
    if (j.contains("basis")) register_basis(base, j["basis"], p + "/basis");
    if (s.device.manual.source != "manual")
      for (Fact f : kRegisterFacts)
        if (!base.basis.count(f)) base.basis[f] = discovered(s, base.section, base.loc);
    int count = j.value("count", 1);
    if (count == 1) {
      s.registers.push_back(base);
      return;
    }
    // A block of `count` registers, each addressable on its own (e.g.
    // 57HS-R 0x0090–0x009F, 16 segments).
    for (int k = 0; k < count; ++k) {
      uint32_t addr = uint32_t(base.address) + uint32_t(k) * uint32_t(base.words);
      if (addr > 0xFFFF) {
        out.push_back({file, base.loc.line, base.loc.col, "address-overflow",
                       "block of " + std::to_string(count) + " registers starting at " + std::to_string(base.address) +
                           " runs past address 65535"});
        return;
      }
      Register r = base;
      r.address = uint16_t(addr);
      r.block_index = k;
      if (!base.key.empty()) r.key = base.key + "[" + std::to_string(k + 1) + "]";
      r.name.en = base.name.en + " [" + std::to_string(k + 1) + "]";
      if (!r.name.zh.empty()) r.name.zh = base.name.zh + " [" + std::to_string(k + 1) + "]";
      s.registers.push_back(r);
    }
  }
};

bool ends_with(const std::string& s, const std::string& suffix) {
  return s.size() >= suffix.size() && s.compare(s.size() - suffix.size(), suffix.size(), suffix) == 0;
}

}  // namespace

std::string Diagnostic::str() const {
  return file + ":" + std::to_string(line) + ":" + std::to_string(col) + ": error: " + rule + ": " + message;
}

LoadResult load_spec_text(std::string_view text, const std::string& file) {
  LoadResult res;
  auto doc = yaml_to_json(text, file, res.diagnostics);
  if (!doc) return res;
  if (!doc->root.is_object()) {
    res.diagnostics.push_back({file, 1, 1, "schema", "(document): a spec is a mapping with device, serial, profile, registers, examples and errata"});
    return res;
  }
  try {
    validate_schema(*doc, file, res.diagnostics);
  } catch (const std::exception& e) {
    res.diagnostics.push_back({file, 1, 1, "schema", std::string("validator failed: ") + e.what()});
  }
  if (!res.diagnostics.empty()) return res;
  Builder b{*doc, file, res.diagnostics};
  res.spec = b.build();
  std::string expected_id;
  if (ends_with(file, ".yaml") || ends_with(file, ".yml")) expected_id = std::filesystem::path(file).stem().string();
  check_semantics(*res.spec, *doc, expected_id, res.diagnostics);
  std::stable_sort(res.diagnostics.begin(), res.diagnostics.end(), [](const Diagnostic& a, const Diagnostic& b) {
    return std::pair(a.line, a.col) < std::pair(b.line, b.col);
  });
  return res;
}

std::optional<JsonDocument> load_profile_document(const std::string& path, Diagnostics& out) {
  std::ifstream in(path, std::ios::binary);
  if (!in) {
    out.push_back({path, 0, 0, "io", "cannot open the profile"});
    return std::nullopt;
  }
  std::string text;
  YamlLimits limits;
  text.resize(limits.max_bytes + 1);
  in.read(text.data(), std::streamsize(text.size()));
  text.resize(size_t(in.gcount()));
  size_t before = out.size();
  auto doc = yaml_to_json(text, path, out);
  if (!doc) return std::nullopt;
  if (!doc->root.is_object()) {
    out.push_back({path, 1, 1, "schema", "(document): a profile is a mapping with profile, roles, states, commands, transitions"});
    return std::nullopt;
  }
  try {
    validate_schema(*doc, path, out, profile_schema());
  } catch (const std::exception& e) {
    out.push_back({path, 1, 1, "schema", std::string("validator failed: ") + e.what()});
  }
  if (out.size() != before) return std::nullopt;
  return doc;
}

LoadResult load_spec_file(const std::string& path) {
  std::error_code ec;
  if (std::filesystem::is_directory(path, ec)) {
    LoadResult r;
    r.diagnostics.push_back({path, 0, 0, "io", "is a directory, not a spec file"});
    return r;
  }
  std::ifstream in(path, std::ios::binary);
  if (!in) {
    LoadResult r;
    r.diagnostics.push_back({path, 0, 0, "io", "cannot open the file"});
    return r;
  }
  std::string text;
  YamlLimits limits;
  text.resize(limits.max_bytes + 1);
  in.read(text.data(), std::streamsize(text.size()));
  text.resize(size_t(in.gcount()));
  return load_spec_text(text, path);
}

Spec load_spec_by_id(const std::string& id) {
  auto r = load_spec_file(spec_path(id));
  if (!r.ok()) {
    std::string msg = "spec '" + id + "' does not load:";
    for (const auto& d : r.diagnostics) msg += "\n" + d.str();
    throw std::runtime_error(msg);
  }
  return std::move(*r.spec);
}

}  // namespace mbc::spec
