#include "cases/facts.h"

#include "erratum_extra.h"

#include <fmt/core.h>

#include <algorithm>
#include <array>
#include <bit>
#include <cmath>

#include "modbus/function_codes.h"
#include "modbus/limits.h"
#include "modbus/pdu.h"
#include "modbus/words.h"

namespace mbc::conf::facts {

using spec::Basis;
using spec::Fact;
using spec::FactBasis;

namespace {

void note(Relies& into, std::string fact, FactBasis b) {
  for (const auto& r : into)
    if (r.fact == fact) return;
  into.push_back({std::move(fact), std::move(b)});
}

void note(Relies& into, const spec::Register& r, Fact f) {
  note(into, fmt::format("register 0x{:04X} {}", r.address, spec::to_string(f)), r.basis_of(f));
}

}  // namespace

bool readable(Relies& into, const spec::Register& r) {
  note(into, r, Fact::read);
  // A command register reads only where the spec says what a read returns (command.reads_back).
  if (r.access == spec::Access::command) return r.command && r.command->reads_back.has_value();
  return r.access != spec::Access::wo;
}

bool writable(Relies& into, const spec::Register& r) {
  note(into, r, Fact::write);
  return r.access == spec::Access::rw || r.access == spec::Access::wo || r.access == spec::Access::command;
}

const std::optional<spec::Range>& range(Relies& into, const spec::Register& r) {
  note(into, r, Fact::range);
  return r.range;
}

std::optional<double> default_value(Relies& into, const spec::Register& r) {
  note(into, r, Fact::default_value);
  return r.default_value;
}

spec::WordOrder word_order(Relies& into, const spec::Register& r) {
  if (r.words == 2) note(into, r, Fact::word_order);
  return r.word_order;
}

spec::DataType type(Relies& into, const spec::Register& r) {
  note(into, r, Fact::type);
  return r.type;
}

spec::TakesEffect takes_effect(Relies& into, const spec::Register& r) {
  note(into, r, Fact::takes_effect);
  return r.takes_effect;
}

const spec::Persistence& persistence(Relies& into, const spec::Register& r) {
  note(into, r, Fact::persistence);
  return r.persistence;
}

void supported(Relies& into, const spec::FunctionCode& f) {
  note(into, fmt::format("FC {} supported", f.code), f.basis_of("supported"));
}

std::optional<int> limit(Relies& into, const spec::FunctionCode& f, const char* which) {
  std::string w = which;
  std::optional<int> v = w == "max_read_quantity" ? f.max_read_quantity : w == "max_write_quantity" ? f.max_write_quantity : f.max_quantity;
  if (v) note(into, fmt::format("FC {} {}", f.code, w), f.basis_of(w));
  return v;
}

spec::PolicyEntry policy(Relies& into, const spec::Spec& s, spec::Violation v) {
  if (v == spec::Violation::quantity_zero && !s.profile.exception_policy.count(v)) v = spec::Violation::quantity_over_limit;
  spec::PolicyEntry p = s.profile.policy(v);
  if (p.kind != spec::PolicyEntry::Kind::unspecified || p.basis.basis == Basis::either) {
    FactBasis b = p.basis;
    if (b.section.empty()) b.section = p.section;
    note(into, fmt::format("{} exception_policy.{}", s.device.id, spec::to_string(v)), b);
  }
  return p;
}

const spec::Example& example(Relies& into, const spec::Example& e) {
  note(into, "example " + e.id, e.basis);
  return e;
}

std::optional<bool> in_range(Relies& into, const spec::Spec& s, const spec::Register& r, uint32_t raw) {
  note(into, r, Fact::range);
  if (r.type == spec::DataType::f32) {
    // No range: any float (NaN too: nothing in a spec excludes it).
    float f = std::bit_cast<float>(raw);
    if (!r.range) return true;
    return !std::isnan(f) && f >= r.range->min && f <= r.range->max;
  }
  double v = r.words == 1 ? (r.type == spec::DataType::s16 ? double(int16_t(raw)) : double(uint16_t(raw)))
                          : (r.type == spec::DataType::s32 ? double(int32_t(raw)) : double(raw));
  auto inside = [v](const spec::Range& x) { return v >= x.min && v <= x.max; };
  if (!r.range_readings.empty()) {
    size_t in = size_t(std::count_if(r.range_readings.begin(), r.range_readings.end(), inside));
    if (in == r.range_readings.size()) return true;
    if (in == 0) return false;
    return std::nullopt;  // the readings disagree: either answer
  }
  if (r.range) return inside(*r.range);
  if (r.type == spec::DataType::enumeration && !r.enum_id.empty())
    if (const spec::Enumeration* e = s.find_enum(r.enum_id))
      return std::any_of(e->values.begin(), e->values.end(), [&](const spec::EnumValue& x) { return double(x.value) == v; });
  return true;
}

// ---- classify ----

bool Classified::allows_silence() const {
  for (const auto& b : breaches)
    for (const auto& p : b.readings)
      if (p.kind != spec::PolicyEntry::Kind::exception) return true;
  if (maybe)
    for (const auto& p : maybe->readings)
      if (p.kind != spec::PolicyEntry::Kind::exception) return true;
  return false;
}

bool Classified::allows_exception(uint8_t code) const {
  auto any = [code](const Breach& b) {
    return std::any_of(b.readings.begin(), b.readings.end(), [code](const spec::PolicyEntry& p) {
      return p.kind == spec::PolicyEntry::Kind::unspecified || (p.kind == spec::PolicyEntry::Kind::exception && p.code == code);
    });
  };
  return std::any_of(breaches.begin(), breaches.end(), any) || (maybe && any(*maybe));
}

bool Classified::open() const {
  for (const auto& b : breaches)
    for (const auto& p : b.readings)
      if (p.kind == spec::PolicyEntry::Kind::unspecified) return true;
  return false;
}

namespace {

Breach breach(const spec::Spec& s, spec::Violation v, const Relies& why = {}) {
  Breach b;
  b.violation = v;
  b.policy = policy(b.relies, s, v);
  if (!b.policy.readings.empty()) b.readings = b.policy.readings;
  else b.readings.push_back(b.policy);
  b.relies.insert(b.relies.end(), why.begin(), why.end());
  return b;
}

// The spec's registers by wire address, per table: every address of every
// request is looked up (check-capture classifies each distinct request of a
// long capture; a linear search per address cost most of its time).
struct Index {
  const spec::Spec* spec = nullptr;
  const spec::Register* first = nullptr;
  size_t count = 0;
  std::string id;
  std::array<std::vector<const spec::Register*>, 4> cover;
  std::array<std::optional<uint16_t>, 4> last;
  bool for_spec(const spec::Spec& s) const {
    return spec == &s && first == s.registers.data() && count == s.registers.size() && id == s.device.id;
  }
  const spec::Register* at(spec::Table t, uint32_t a) const { return a > 0xFFFF ? nullptr : cover[size_t(t)][a]; }
};

const Index& index_of(const spec::Spec& s) {
  thread_local Index ix;
  if (ix.for_spec(s)) return ix;
  ix = Index{};
  ix.spec = &s;
  ix.first = s.registers.data();
  ix.count = s.registers.size();
  ix.id = s.device.id;
  for (auto& c : ix.cover) c.assign(0x10000, nullptr);
  for (const auto& r : s.registers)
    for (uint32_t a = r.address; a <= r.last_address() && a <= 0xFFFF; ++a) {
      auto t = size_t(r.table);
      ix.cover[t][a] = &r;
      ix.last[t] = std::max<uint16_t>(ix.last[t].value_or(0), uint16_t(a));
    }
  return ix;
}

// The address check (MBAP v1.1b3 §6, "Starting Address + Quantity" -> 02):
// past the map, a gap, an access the register does not allow.
void check_range(const spec::Spec& s, Classified& c, spec::Table table, uint32_t first, uint32_t count, bool write) {
  const Index& ix = index_of(s);
  auto last = ix.last[size_t(table)];
  bool unmapped = false, past = first + count > 0x10000, denied = false;
  Relies access;
  for (uint32_t a = first; a < first + count && a <= 0xFFFF; ++a) {
    const spec::Register* r = ix.at(table, a);
    if (!r) {
      if (!last || a > *last) past = true;
      else unmapped = true;
      continue;
    }
    if (c.registers.size() < 256 && (c.registers.empty() || c.registers.back() != std::make_pair(table, r->address)))
      c.registers.emplace_back(table, r->address);
    if (!(write ? writable(access, *r) : readable(access, *r))) denied = true;
  }
  if (past) c.breaches.push_back(breach(s, spec::Violation::address_past_map));
  if (unmapped) c.breaches.push_back(breach(s, spec::Violation::unmapped_address));
  if (denied) c.breaches.push_back(breach(s, write ? spec::Violation::write_read_only : spec::Violation::read_write_only, access));
  else c.relies.insert(c.relies.end(), access.begin(), access.end());
}

// The value check of a register write: each register the words cover, its
// value made of the words written and, for a word not written, `known`.
void check_values(const spec::Spec& s, Classified& c, uint16_t start, const std::vector<uint16_t>& words, const KnownWord& known) {
  const Index& ix = index_of(s);
  const spec::Register* prev = nullptr;
  for (size_t i = 0; i < words.size(); ++i) {
    const spec::Register* r = ix.at(spec::Table::holding, uint32_t(start) + i);
    if (!r || r == prev) continue;
    prev = r;
    std::vector<uint16_t> w;
    for (int k = 0; k < r->words; ++k) {
      uint32_t a = uint32_t(r->address) + uint32_t(k);
      if (a >= start && a < start + words.size()) w.push_back(words[a - start]);
      else if (auto x = known ? known(spec::Table::holding, uint16_t(a)) : std::nullopt) w.push_back(*x);
    }
    Relies rel;
    if (w.size() != size_t(r->words)) {
      // A word of it is neither written nor known: its range cannot be told.
      if (r->range || !r->range_readings.empty() || r->type == spec::DataType::enumeration) {
        (void)in_range(rel, s, *r, 0);
        if (!c.maybe) c.maybe = breach(s, spec::Violation::value_out_of_range, rel);
      }
      continue;
    }
    uint32_t raw = r->words == 1 ? w[0] : join_u32(w[0], w[1], r->low_word_first());
    std::optional<bool> ok = in_range(rel, s, *r, raw);
    if (ok == false) {
      c.breaches.push_back(breach(s, spec::Violation::value_out_of_range, rel));
      return;
    }
    if (!ok && !c.maybe) c.maybe = breach(s, spec::Violation::value_out_of_range, rel);
    c.relies.insert(c.relies.end(), rel.begin(), rel.end());
  }
}

}  // namespace

Classified classify(const spec::Spec& s, std::span<const uint8_t> pdu, const KnownWord& known) {
  Classified c;
  using V = spec::Violation;
  // A frame without a function code, or too long to be a PDU (MBAP v1.1b3
  // §4.1: 253 bytes): its length is wrong.
  if (pdu.empty()) {
    c.breaches.push_back(breach(s, V::wrong_byte_count));
    return c;
  }
  // 1. The function code (MBAP v1.1b3 §4.5 Figure 9 -> 01). The exception
  // bit makes it no request code (§7).
  uint8_t code = pdu[0];
  const spec::FunctionCode* f = (code & kExceptionBit) ? nullptr : s.profile.function(code);
  if (!f) {
    c.breaches.push_back(breach(s, V::unsupported_function));
    return c;
  }
  supported(c.relies, *f);
  // 2. The quantity and the byte count (§6.1-6.4, 6.11, 6.12, 6.17: "0x0001
  // <= Quantity <= N AND Byte Count == ..." -> 03); a PDU whose layout does
  // not decode has a length its fields do not account for.
  ParsedRequest pr = parse_request(pdu);
  if (!pr.request) {
    c.breaches.push_back(breach(s, V::wrong_byte_count));
    return c;
  }
  const Request& r = *pr.request;
  // A sub-function of FC 08, or an MEI type of FC 43, that the spec does not
  // list is a function not supported (§6.8 Figure 18; §6.19-6.21: "Function
  // code supported AND MEI Type supported", else 01).
  if ((code == fc::diagnostics && !f->subfunctions.empty() &&
       std::find(f->subfunctions.begin(), f->subfunctions.end(), int(r.sub_function)) == f->subfunctions.end()) ||
      (code == fc::encapsulated_interface && !f->mei_types.empty() &&
       std::find(f->mei_types.begin(), f->mei_types.end(), int(r.mei_type)) == f->mei_types.end())) {
    c.breaches.push_back(breach(s, V::unsupported_function));
    return c;
  }
  for (const auto& p : pr.problems)
    if (p.find("byte count") != std::string::npos || p.find("over the 253") != std::string::npos) {
      c.breaches.push_back(breach(s, V::wrong_byte_count));
      break;
    }
  auto quantity = [&](uint32_t q, const char* which, int standard) {
    if (q == 0) {
      c.breaches.push_back(breach(s, V::quantity_zero));
      return;
    }
    // The spec's limit, capped by the standard's; where the spec states none,
    // the standard's (stated by the standard: no fact of the spec).
    Relies rel;
    std::optional<int> lim = limit(rel, *f, which);
    if (lim && standard) lim = std::min(*lim, standard);
    if (!lim && standard) lim = standard;
    if (lim && int(q) > *lim) c.breaches.push_back(breach(s, V::quantity_over_limit, rel));
    else c.relies.insert(c.relies.end(), rel.begin(), rel.end());
  };
  switch (code) {
    case fc::read_coils: case fc::read_discrete_inputs: case fc::read_holding_registers: case fc::read_input_registers:
    case fc::write_multiple_coils: case fc::write_multiple_registers:
      quantity(r.quantity, "max_quantity", standard_max_quantity(code));
      break;
    case fc::read_write_multiple_registers:
      quantity(r.quantity, "max_read_quantity", kMaxReadWriteReadQuantity);
      quantity(r.write_quantity, "max_write_quantity", kMaxReadWriteWriteQuantity);
      break;
    default: break;
  }
  if (!c.breaches.empty()) return c;
  // 3. The addresses (§6 "Starting Address + Quantity of ... == OK" -> 02),
  // with the access the spec gives each register.
  spec::Table table = spec::table_for_function(code);
  switch (code) {
    case fc::read_coils: case fc::read_discrete_inputs: case fc::read_holding_registers: case fc::read_input_registers:
      check_range(s, c, table, r.address, r.quantity, false);
      break;
    case fc::write_single_coil: case fc::write_single_register: case fc::mask_write_register:
      check_range(s, c, table, r.address, 1, true);
      break;
    case fc::write_multiple_coils: case fc::write_multiple_registers:
      check_range(s, c, table, r.address, r.quantity, true);
      break;
    case fc::read_write_multiple_registers:
      check_range(s, c, table, r.write_address, r.write_quantity, true);
      check_range(s, c, table, r.address, r.quantity, false);
      break;
    default: break;
  }
  if (!c.breaches.empty()) return c;
  // 4. The values written, against each register's range or values.
  if (code == fc::write_single_register) check_values(s, c, r.address, {r.value}, known);
  else if (code == fc::write_multiple_registers || code == fc::read_write_multiple_registers)
    check_values(s, c, code == fc::write_multiple_registers ? r.address : r.write_address, r.registers, known);
  return c;
}

void settle_level(Case& c) {
  if (c.requirement.find(" [relies on ") != std::string::npos) return;
  std::vector<std::string> inferred;
  for (const auto& r : all_relies(c))
    if (spec::demotes(r.basis)) {
      inferred.push_back(describe(r));  // inferred, or printed two ways in words
      // The erratum the doubt comes from is one the case relies on (issue 37).
      if (!r.basis.erratum.empty() && std::find(c.errata.begin(), c.errata.end(), r.basis.erratum) == c.errata.end())
        c.errata.push_back(r.basis.erratum);
    }
  if (inferred.empty()) return;
  if (c.level == Level::must || c.level == Level::should) {
    c.level_if_stated = c.level;
    c.level = Level::observed;
  }
  std::string s;
  for (const auto& x : inferred) s += (s.empty() ? "" : "; ") + x;
  c.requirement += " [relies on " + s + "]";
}

}  // namespace mbc::conf::facts
