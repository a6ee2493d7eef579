#include "readings.h"

#include "erratum_extra.h"

#include <algorithm>
#include <cstdio>
#include <stdexcept>

#include "modbus/crc16.h"
#include "modbus/hex.h"

namespace mbc::spec {
namespace {

std::string hex4(unsigned v) {
  char buf[8];
  std::snprintf(buf, sizeof buf, "0x%04X", v & 0xFFFF);
  return buf;
}

std::string reg_key(const Register& r) {
  return std::string(r.table == Table::holding ? "" : std::string(to_string(r.table)) + ":") + hex4(r.address);
}

std::pair<double, double> type_bounds(DataType t, int words) {
  switch (t) {
    case DataType::s16: return {-32768, 32767};
    case DataType::s32: return {-2147483648.0, 2147483647.0};
    case DataType::bit: return {0, 1};
    default: return {0, words == 2 ? 4294967295.0 : 65535};
  }
}

// The other reading of one register fact; nullopt when the fact has none a
// register table can express (the reading stays as it is).
std::optional<std::string> flip(Register& r, Fact f, const FactBasis& b) {
  switch (f) {
    case Fact::read:
      if (r.access == Access::wo) {
        r.access = Access::rw;  // a read answers the value
        return "readable (reads answered)";
      }
      if (r.access != Access::rw && r.access != Access::ro) return std::nullopt;
      r.access = Access::wo;  // a read gets the policy's read_write_only answer
      return "not readable (reads refused)";
    case Fact::write:
      if (r.access != Access::rw && r.access != Access::command) return std::nullopt;
      r.access = Access::ro;  // a write gets the policy's write_read_only answer
      return "not writable (read-only)";
    case Fact::range: {
      if (!r.range) return std::nullopt;
      if (b.basis == Basis::either) {
        for (const auto& x : r.range_readings)
          if (!(x == *r.range)) {
            r.range = x;
            return "range " + std::to_string(int64_t(x.min)) + ".." + std::to_string(int64_t(x.max));
          }
        return std::nullopt;
      }
      // An inferred range read the other way: no range check at all; or, for a
      // range that is already the type's, the range as printed ("-32767~32768").
      auto [lo, hi] = type_bounds(r.type, r.words);
      if (r.range->min == lo && r.range->max == hi) {
        auto printed = r.printed.find("range");
        double a = 0, b = 0;
        if (printed == r.printed.end() || std::sscanf(printed->second.c_str(), "%lf~%lf", &a, &b) != 2 || a > b || a < lo || b > hi)
          return std::nullopt;
        r.range = Range{a, b};
        return "range " + std::to_string(int64_t(a)) + ".." + std::to_string(int64_t(b)) + " (as printed)";
      }
      r.range = Range{lo, hi};
      return "no range check (the type's bounds)";
    }
    case Fact::default_value: {
      if (!r.default_value) return std::nullopt;
      for (double x : r.default_readings)
        if (x != *r.default_value) {
          r.default_value = x;
          return "default " + std::to_string(int64_t(x));
        }
      double d = *r.default_value;
      double alt = r.range ? (d != r.range->min ? r.range->min : r.range->max) : d + 1;
      if (alt == d) return std::nullopt;
      r.default_value = alt;
      return "default " + std::to_string(int64_t(alt));
    }
    case Fact::word_order:
      if (r.words != 2) return std::nullopt;
      r.word_order = r.word_order == WordOrder::high_first ? WordOrder::low_first : WordOrder::high_first;
      return std::string("word order ") + to_string(r.word_order);
    case Fact::type:
      switch (r.type) {
        case DataType::u16: r.type = DataType::s16; return "signed";
        case DataType::s16: r.type = DataType::u16; return "unsigned";
        case DataType::u32: r.type = DataType::s32; return "signed";
        case DataType::s32: r.type = DataType::u32; return "unsigned";
        case DataType::f32: r.type = DataType::u32; return "an unsigned 32-bit integer, not a float";
        default: return std::nullopt;
      }
    case Fact::takes_effect:
      r.takes_effect = r.takes_effect == TakesEffect::immediate ? TakesEffect::power_cycle : TakesEffect::immediate;
      return r.takes_effect == TakesEffect::immediate ? "takes effect at once" : "takes effect after a power cycle";
    case Fact::persistence:
      if (r.persistence.store != Store::none) {
        r.persistence = Persistence{};
        return "volatile";
      }
      r.persistence.store = Store::eeprom;
      r.persistence.by = PersistBy::on_write;
      return "stored on every write";
    case Fact::persistence_unless:
      if (!r.persistence.unless_register) return std::nullopt;
      r.persistence.unless_register.reset();
      return "stored whatever the do-not-persist switch holds";
  }
  return std::nullopt;
}

std::string policy_words(const PolicyEntry& p) {
  switch (p.kind) {
    case PolicyEntry::Kind::exception: return "exception " + std::to_string(p.code);
    case PolicyEntry::Kind::silent: return "no reply";
    case PolicyEntry::Kind::unspecified: return "the standard's answer";
  }
  return "?";
}

// The other answer to a policy kind: the other printed reading, else (an
// inferred answer) silence for an exception and exception 03 for silence.
std::optional<PolicyEntry> other_policy(const PolicyEntry& p) {
  if (p.basis.basis == Basis::either) {
    for (size_t i = 1; i < p.readings.size(); ++i) {
      PolicyEntry x = p.readings[i];
      if (x.kind != p.kind || x.code != p.code) {
        x.basis = p.basis;
        return x;
      }
    }
    return std::nullopt;
  }
  if (!p.basis.is_inferred()) return std::nullopt;
  PolicyEntry x = p;
  if (p.kind == PolicyEntry::Kind::exception) x.kind = PolicyEntry::Kind::silent;
  else if (p.kind == PolicyEntry::Kind::silent) x.kind = PolicyEntry::Kind::exception, x.code = 3;
  else return std::nullopt;
  return x;
}

// The PDU of an RTU frame as printed (slave and CRC dropped), when it is one.
std::optional<Bytes> pdu_of(const std::optional<std::string>& hex) {
  if (!hex) return std::nullopt;
  auto b = parse_hex(*hex);
  if (!b || b->size() < 4) return std::nullopt;
  return Bytes(b->begin() + 1, b->end() - 2);
}

// A printed frame read the other way: the answer the device gives to the
// request instead of the one the cases expect first.
std::optional<std::pair<Bytes, std::optional<Bytes>>> other_answer(const Spec& s, const Example& x, std::string& words) {
  auto req = pdu_of(x.resolved_request ? x.resolved_request : std::optional<std::string>(x.request));
  if (!req || req->empty()) return std::nullopt;
  // A frame sent with a deliberately wrong CRC is a crc_error: the policy's
  // variant takes its other reading (a PDU match would catch good frames too).
  if (auto raw = parse_hex(x.resolved_request.value_or(x.request)); !raw || !crc_ok(*raw)) return std::nullopt;
  if (x.basis.basis == Basis::either) {
    // [printed, resolved]: the cases expect the resolved reading first; this
    // device answers as printed.
    if (x.response && x.has_resolution()) {
      words = "answers as printed (" + *x.response + ")";
      return std::pair{*req, pdu_of(x.response)};
    }
    return std::nullopt;  // [printed, policy]: the policy's variant covers it
  }
  if (!x.basis.is_inferred()) return std::nullopt;
  // No reply printed, or one we inferred: this device refuses the request.
  PolicyEntry ro = s.profile.policy(Violation::write_read_only);
  uint8_t code = ro.kind == PolicyEntry::Kind::exception ? uint8_t(ro.code) : 4;
  words = "answers exception " + std::to_string(code);
  return std::pair{*req, std::optional<Bytes>(Bytes{uint8_t((*req)[0] | 0x80), code})};
}

// A register whose read or write is printed two ways in words, one way being
// that it is not there at all ("no register (4.2.2: only X0-X3)"): the
// variant leaves it out of the map. A write-only register read the other way
// is readable instead (flip).
bool absent(const Register& r, Fact f, const FactBasis& b) {
  return (f == Fact::read || f == Fact::write) && words_only(b) && r.access != Access::wo;
}

// The errata a fact's doubt comes from: the basis's own, and those its owner
// cites that contest `what`.
std::vector<std::string> doubt_from(const Spec& s, const FactBasis& b, const std::vector<std::string>& cited, const std::string& what) {
  std::vector<std::string> out;
  if (!b.erratum.empty()) out.push_back(b.erratum);
  for (const auto& id : cited)
    if (const Erratum* e = s.find_erratum(id); e && e->contests_fact(what) && std::find(out.begin(), out.end(), id) == out.end())
      out.push_back(id);
  return out;
}

// Errata that contest where the registers they name sit.
bool contests_address(const Erratum& e) { return e.contests_given && e.contests_fact("address") && !e.settled(); }

}  // namespace

std::vector<Reading> contested_readings(const Spec& s) {
  std::vector<Reading> out;
  for (const auto& r : s.registers) {
    if (r.block_index > 0) continue;
    for (Fact f : kRegisterFacts) {
      FactBasis b = r.basis_of(f);
      if (b.basis == Basis::stated) continue;
      // Read and write at a contested address: the address variant covers them.
      if (const Erratum* e = s.find_erratum(b.erratum); e && contests_address(*e)) continue;
      Register probe = r;
      auto words = absent(r, f, b) ? std::optional<std::string>("no register there (absent)") : flip(probe, f, b);
      if (!words) continue;
      out.push_back({reg_key(r) + "." + to_string(f), "register " + hex4(r.address) + " " + to_string(f), b.basis, *words,
                     doubt_from(s, b, r.errata, to_string(f))});
    }
  }
  for (const auto& e : s.errata)
    if (contests_address(e))
      out.push_back({"address." + e.id, "the addresses erratum " + e.id + " names", Basis::either,
                     "every register it names sits one above its printed address", {e.id}});
  std::vector<std::string> none;
  for (const auto& f : s.profile.function_codes) {
    std::vector<std::string> cites = f.erratum.empty() ? none : std::vector<std::string>{f.erratum};
    FactBasis sup = f.basis_of("supported");
    if (sup.basis != Basis::stated)
      out.push_back({"fc" + std::to_string(f.code) + ".supported", "FC " + std::to_string(f.code) + " supported", sup.basis,
                     "not supported", doubt_from(s, sup, cites, "supported")});
    FactBasis mq = f.basis_of("max_quantity");
    if (f.max_quantity && mq.basis != Basis::stated)
      out.push_back({"fc" + std::to_string(f.code) + ".max_quantity", "FC " + std::to_string(f.code) + " max_quantity", mq.basis,
                     "the standard's limit", doubt_from(s, mq, cites, "max_quantity")});
  }
  for (Violation v : kAllViolations) {
    PolicyEntry p = s.profile.policy(v);
    std::vector<std::string> cites = p.erratum.empty() ? none : std::vector<std::string>{p.erratum};
    if (auto o = other_policy(p))
      out.push_back({std::string("policy.") + to_string(v), std::string("exception_policy.") + to_string(v), p.basis.basis,
                     policy_words(*o), doubt_from(s, p.basis, cites, "policy")});
  }
  for (const auto& x : s.examples) {
    std::string words;
    if (other_answer(s, x, words))
      out.push_back({"example." + x.id, "example " + x.id, x.basis.basis, words, doubt_from(s, x.basis, x.errata, "example")});
  }
  return out;
}

Variant other_reading(const Spec& s, const std::string& key) {
  Variant v{s, {}, {}};
  for (const auto& rd : contested_readings(s)) {
    if (rd.key != key) continue;
    v.describe = rd.fact + ": " + rd.other;
    auto dot = key.rfind('.');
    std::string head = key.substr(0, dot), tail = key.substr(dot + 1);
    if (head == "address") {
      // Every register the erratum names sits one above its printed address.
      for (auto& r : v.spec.registers)
        if (std::find(r.errata.begin(), r.errata.end(), tail) != r.errata.end()) r.address = uint16_t(r.address + 1);
      std::stable_sort(v.spec.registers.begin(), v.spec.registers.end(), [](const Register& a, const Register& b) {
        return std::pair(int(a.table), a.address) < std::pair(int(b.table), b.address);
      });
    } else if (head.rfind("0x", 0) == 0 || head.find(':') != std::string::npos) {
      // Every register of the declaration (a block) takes the other reading.
      const Register* first = nullptr;
      for (const auto& r : s.registers)
        if (r.block_index <= 0 && reg_key(r) == head) first = &r;
      for (Fact f : kRegisterFacts)
        if (first && to_string(f) == tail && absent(*first, f, first->basis_of(f))) {
          std::string origin = first->origin;
          std::erase_if(v.spec.registers, [&](const Register& r) { return r.origin == origin; });
          first = nullptr;
        }
      for (auto& r : v.spec.registers)
        if (first && r.origin == first->origin)
          for (Fact f : kRegisterFacts)
            if (to_string(f) == tail) flip(r, f, r.basis_of(f));
    } else if (head.rfind("fc", 0) == 0) {
      int code = std::stoi(head.substr(2));
      auto& fcs = v.spec.profile.function_codes;
      for (size_t i = 0; i < fcs.size(); ++i) {
        if (fcs[i].code != code) continue;
        if (tail == "supported") fcs.erase(fcs.begin() + long(i));
        else fcs[i].max_quantity.reset();
        break;
      }
    } else if (head == "policy") {
      for (Violation x : kAllViolations)
        if (to_string(x) == tail) v.spec.profile.exception_policy[x] = *other_policy(s.profile.policy(x));
    } else if (head == "example") {
      for (const auto& x : s.examples) {
        std::string words;
        if (x.id == tail)
          if (auto a = other_answer(s, x, words)) v.answers.push_back(*a);
      }
    }
    return v;
  }
  std::string known;
  for (const auto& rd : contested_readings(s)) known += (known.empty() ? "" : ", ") + rd.key;
  throw std::invalid_argument("reading=" + key + ": not a contested fact of " + s.device.id + " (" +
                              (known.empty() ? "it has none" : known) + ")");
}

}  // namespace mbc::spec
