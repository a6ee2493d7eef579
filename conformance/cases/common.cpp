#include "cases/common.h"

#include <fmt/core.h>

#include <bit>
#include <cmath>
#include <limits>

#include "cases/facts.h"
#include "policy/policy.h"
#include "modbus/pdu.h"
#include "modbus/words.h"

namespace mbc::conf::cases {

using spec::Access;
using spec::DataType;
using spec::Register;
using spec::Table;
using spec::Violation;

std::string clause(const spec::Spec& s, const std::string& section) {
  if (section.rfind("MBAP", 0) == 0 || section.rfind("MB-SL", 0) == 0) return section;
  if (section.empty()) return s.device.id;
  return fmt::format("{} §{}", s.device.id, section);
}

std::string hex16(unsigned v) { return fmt::format("0x{:04X}", v); }

int64_t type_min(const Register& r) {
  switch (r.type) {
    case DataType::s16: return -32768;
    case DataType::s32: return std::numeric_limits<int32_t>::min();
    case DataType::bit: return 0;
    case DataType::f32: return std::numeric_limits<int32_t>::min();
    default: return 0;
  }
}

int64_t type_max(const Register& r) {
  switch (r.type) {
    case DataType::s16: return 32767;
    case DataType::s32: return std::numeric_limits<int32_t>::max();
    case DataType::bit: return 1;
    case DataType::f32: return std::numeric_limits<int32_t>::max();
    default: return r.words == 2 ? int64_t(0xFFFFFFFF) : 0xFFFF;
  }
}

std::vector<uint16_t> encode(const Register& r, int64_t raw) {
  if (r.words == 1) return {uint16_t(uint64_t(raw) & 0xFFFF)};
  // word_order names the word at the LOWER address (spec/README.md).
  auto w = split_u32(uint32_t(uint64_t(raw) & 0xFFFFFFFF), r.low_word_first());
  return {w[0], w[1]};
}

bool has_fc(const spec::Spec& s, int fc) { return s.profile.function(fc) != nullptr; }

std::optional<Step> read_range_step(const GenContext& g, Table t, uint16_t address, uint16_t quantity, Expect e) {
  int fc = t == Table::holding ? 3 : t == Table::input ? 4 : t == Table::coil ? 1 : 2;
  if (!has_fc(g.spec, fc)) return std::nullopt;
  Step s;
  s.unit = g.target.unit;
  s.pdu = read_request(uint8_t(fc), address, quantity);
  s.note = fmt::format("read {} x{} (FC {:02})", hex16(address), quantity, fc);
  s.expect = std::move(e);
  return s;
}

std::optional<Step> read_step(const GenContext& g, const Register& r, Expect e) {
  return read_range_step(g, r.table, r.address, uint16_t(r.words), std::move(e));
}

Expect write_echo(const Bytes& req) {
  Expect e;
  e.kind = Expect::Kind::reply;
  uint8_t fc = req.empty() ? 0 : req[0];
  if (fc == 5 || fc == 6 || fc == 22) {
    e.pdu = req;  // MBAP v1.1b3 §6.5, §6.6, §6.16: the response is an echo of the request
    e.text = "echo of the request";
  } else {
    e.pdu.assign(req.begin(), req.begin() + std::min<size_t>(5, req.size()));  // §6.11, §6.12: FC, address, quantity
    e.text = "FC, address and quantity of the request";
  }
  return e;
}

std::optional<Step> write_step(const GenContext& g, const Register& r, const std::vector<uint16_t>& words,
                               std::optional<Expect> e) {
  Step s;
  s.unit = g.target.unit;
  if (r.table == Table::coil) {
    if (words.size() == 1 && has_fc(g.spec, 5)) {
      s.pdu = write_single_coil(r.address, words[0] != 0);
    } else if (has_fc(g.spec, 15)) {
      std::vector<bool> bits;
      for (auto w : words) bits.push_back(w != 0);
      bool arr[2000];
      for (size_t i = 0; i < bits.size(); ++i) arr[i] = bits[i];
      s.pdu = write_multiple_coils(r.address, std::span<const bool>(arr, bits.size()));
    } else {
      return std::nullopt;
    }
  } else if (r.table == Table::holding) {
    if (words.size() == 1 && has_fc(g.spec, 6)) {
      s.pdu = write_single_register(r.address, words[0]);
    } else if (has_fc(g.spec, 16)) {
      s.pdu = write_multiple_registers(r.address, words);
    } else {
      return std::nullopt;
    }
  } else {
    return std::nullopt;
  }
  std::string vals;
  for (auto w : words) vals += fmt::format("{}{:04X}", vals.empty() ? "" : " ", w);
  s.note = fmt::format("write {} = [{}] (FC {:02})", hex16(r.address), vals, s.pdu[0]);
  s.expect = e ? std::move(*e) : write_echo(s.pdu);
  return s;
}

namespace {
// One reading of a policy entry as an expectation.
Expect policy_reading(const spec::PolicyEntry& p, Violation v) {
  if (p.kind == spec::PolicyEntry::Kind::exception)
    return exception(uint8_t(p.code), fmt::format("exception {:02X} (policy {})", p.code, spec::to_string(v)));
  if (p.kind == spec::PolicyEntry::Kind::silent) return silence(fmt::format("silence (policy {})", spec::to_string(v)));
  Expect e;
  e.text = "not stated";
  return e;
}
}  // namespace

PolicyExpect policy_expect(const GenContext& g, Violation v) {
  PolicyExpect out;
  facts::Relies relies;
  spec::PolicyEntry p = facts::policy(relies, g.spec, v);
  out.erratum = p.erratum.empty() ? p.basis.erratum : p.erratum;
  if (p.kind == spec::PolicyEntry::Kind::unspecified && p.readings.empty()) {
    out.level = Level::observed;
    // The manual is silent: record what the device does beside the standard's answer.
    spec::PolicyEntry std_p = g.standard ? g.standard->profile.policy(v) : spec::PolicyEntry{};
    out.clause = g.standard ? clause(*g.standard, std_p.section) : "MBAP v1.1b3 §7";
    if (std_p.kind == spec::PolicyEntry::Kind::exception)
      out.expect = exception(uint8_t(std_p.code), fmt::format("the standard's exception {:02X} ({} is not stated in the manual)", std_p.code, spec::to_string(v)));
    else if (std_p.kind == spec::PolicyEntry::Kind::silent)
      out.expect = silence(fmt::format("silence, as the standard ({} is not stated in the manual)", spec::to_string(v)));
    else
      out.expect.text = "not stated";
    return out;
  }
  out.clause = clause(g.spec, p.section.empty() ? g.spec.profile.section : p.section);
  if (p.readings.empty()) {
    out.expect = policy_reading(p, v);
  } else {
    // Printed two ways: either reading passes, and the runner records which.
    out.expect = policy_reading(p.readings.front(), v);
    out.expect.reading = out.expect.text;
    for (size_t i = 1; i < p.readings.size(); ++i) {
      Expect alt = policy_reading(p.readings[i], v);
      alt.reading = alt.text;
      out.expect.either.push_back(std::move(alt));
    }
    std::string all;
    for (const auto& r : p.readings) all += (all.empty() ? "" : " or ") + policy_reading(r, v).text;
    out.expect.text = all + " (printed two ways)";
  }
  if (p.basis.is_inferred()) out.expect.text += fmt::format(" (inferred: {})", p.basis.why);
  out.expect.relies = std::move(relies);
  return out;
}

std::string write_forbidden(const GenContext& g, const Register& r) {
  // A line setting that takes effect at once would cut the run off from the device.
  for (const auto& st : g.spec.serial.settings)
    if (st.register_address == r.address && r.table == Table::holding &&
        r.takes_effect == spec::TakesEffect::immediate)
      return fmt::format("{} sets the {} at once; writing it would lose the device for the rest of the run",
                         hex16(r.address), st.setting);
  // What may go out to this target: the frame policy's to say.
  if (Decision d = allowed_write(PolicyFacts{&g.spec, g.target, g.policy}, r); !d) return d.refused->reason;
  return "";
}

const Register* plain_register(const GenContext& g) {
  // A register with a stated range first; else any plain u16 (the values 0
  // and 1 are then written, and the cases using it are OBSERVED or check
  // only what the standard fixes). Registers whose reading, writing or range
  // is only inferred come last: cases built on them are OBSERVED.
  for (bool stated_only : {true, false}) {
    const Register* fallback = nullptr;
    for (const auto& r : g.spec.registers) {
      if (r.table != Table::holding || r.access != Access::rw || r.words != 1) continue;
      if (!write_forbidden(g, r).empty()) continue;
      if (r.persistence.store != spec::Store::none && g.target.live && !g.policy.allow_eeprom_writes) continue;
      bool stated = true;
      for (spec::Fact f : {spec::Fact::read, spec::Fact::write, spec::Fact::range})
        stated = stated && r.basis_of(f).basis == spec::Basis::stated;
      if (stated_only && !stated) continue;
      if (r.range && r.range->max > r.range->min) return &r;
      if (!r.range && !fallback && r.type == DataType::u16) fallback = &r;
    }
    if (fallback) return fallback;
  }
  return nullptr;
}

std::pair<int64_t, int64_t> plain_values(const Register& r) {
  if (r.range) return {int64_t(r.range->min), int64_t(r.range->max)};
  return {0, 1};
}

std::vector<std::string> planned_broadcast_writes(const std::vector<Case>& cases) {
  std::vector<std::string> out;
  for (const auto& c : cases)
    if (c.skip_reason.empty())
      for (const auto& st : c.steps)
        if (is_broadcast_write(st)) out.push_back(fmt::format("{}: {}", c.id, st.note));
  return out;
}

void plain_relies(std::vector<Reliance>& into, const Register& r) {
  facts::readable(into, r);
  facts::writable(into, r);
  facts::range(into, r);
}

Expect exact(Bytes pdu, std::string text) {
  Expect e;
  e.kind = Expect::Kind::reply;
  e.pdu = std::move(pdu);
  e.text = std::move(text);
  return e;
}
Expect exception(uint8_t code, std::string text) {
  Expect e;
  e.kind = Expect::Kind::exception;
  e.code = code;
  e.text = text.empty() ? fmt::format("exception {:02X}", code) : std::move(text);
  return e;
}
Expect silence(std::string text) {
  Expect e;
  e.kind = Expect::Kind::silence;
  e.text = text.empty() ? "silence" : std::move(text);
  return e;
}
Expect normal(std::string text) {
  Expect e;
  e.kind = Expect::Kind::normal;
  e.text = text.empty() ? "a well-formed normal reply" : std::move(text);
  return e;
}

}  // namespace mbc::conf::cases
