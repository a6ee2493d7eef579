#include "properties/spec_view.h"

#include <fmt/core.h>

#include <algorithm>
#include <bit>
#include <cmath>
#include <limits>

#include "cases/facts.h"
#include "modbus/judge.h"
#include "modbus/limits.h"
#include "modbus/pdu.h"
#include "modbus/words.h"

namespace mbc::conf::props {

using spec::Access;
using spec::DataType;
using spec::Register;
using spec::Table;
using spec::Violation;

std::string Expected::text() const {
  if (!either.empty()) {
    Expected first = *this;
    first.either.clear();
    std::string t = first.text();
    for (const auto& alt : either) t += " or " + alt.text();
    return t + " (printed two ways)";
  }
  switch (kind) {
    case Kind::exception: return fmt::format("exception {:02X}", code);
    case Kind::silence: return "silence";
    case Kind::refused: return "an exception or silence (the manual leaves the answer open)";
  }
  return "?";
}

bool Expected::allows(const Reply& reply) const {
  for (const auto& alt : either)
    if (alt.allows(reply)) return true;
  if (reply.silent()) return kind != Kind::exception;
  if (!reply.pdu || reply.pdu->size() != 2 || !((*reply.pdu)[0] & 0x80)) return false;
  return kind == Kind::refused || (kind == Kind::exception && (*reply.pdu)[1] == code);
}

namespace {

bool is_serial_setting(const spec::Spec& s, uint16_t address) {
  for (const auto& st : s.serial.settings)
    if (st.register_address == address) return true;
  return false;
}

double type_min(const Register& r) {
  switch (r.type) {
    case DataType::s16: return -32768;
    case DataType::s32: return -2147483648.0;
    default: return 0;
  }
}
double type_max(const Register& r) {
  switch (r.type) {
    case DataType::s16: return 32767;
    case DataType::s32: return 2147483647.0;
    case DataType::u32: return 4294967295.0;
    default: return r.words == 2 ? 4294967295.0 : 65535;
  }
}

// A number as raw bits of the register's type (signed ones two's complement).
uint32_t to_raw(const Register& r, double v) {
  if (r.type == DataType::f32) return std::bit_cast<uint32_t>(float(v));
  int64_t i = int64_t(v);
  return r.words == 1 ? uint32_t(uint16_t(i)) : uint32_t(i);
}

}  // namespace

SpecView::SpecView(const spec::Spec& s, const TargetInfo& target, const WritePolicy& policy)
    : spec_(&s), policy_facts_{&s, target, policy} {
  const PolicyFacts& facts = policy_facts_;
  broadcast_unavailable_ = broadcast_not_applicable(target);
  // A broadcast write of a register that may be written: what the frame
  // policy says of unit 0 (policy/policy.h).
  if (broadcast_unavailable_.empty())
    if (Decision d = allowed(facts, 0, write_single_register(0, 0)); !d && d.refused->opt_in == "--allow-broadcast")
      broadcast_unavailable_ = d.refused->reason;
  auto note = [&](const std::string& fact, const spec::FactBasis& b) {
    if (b.basis == spec::Basis::stated) return;
    std::string why = b.basis == spec::Basis::either ? "printed two ways (erratum " + b.erratum + ")" : std::string(to_string(b.basis)) + " (" + b.why + ")";
    not_held_.push_back(fact + ": " + why);
  };
  for (const auto& f : s.profile.function_codes)
    if (f.basis_of("supported").is_inferred()) note(fmt::format("FC {} supported", f.code), f.basis_of("supported"));
  for (Violation v : spec::kAllViolations)
    if (auto p = s.profile.policy(v); p.kind != spec::PolicyEntry::Kind::unspecified || p.basis.basis == spec::Basis::either)
      note(std::string("exception_policy.") + spec::to_string(v), p.basis);
  for (const auto& r : s.registers) {
    if (r.table != Table::holding) continue;
    for (spec::Fact f : spec::kRegisterFacts)
      if (r.basis.count(f)) note(fmt::format("register 0x{:04X} {}", r.address, spec::to_string(f)), r.basis_of(f));
    // A property never fails on an inferred fact (spec/README.md): registers
    // whose readability or writability is only inferred stay out of it.
    if (r.basis_of(spec::Fact::read).is_inferred() || r.basis_of(spec::Fact::write).is_inferred()) continue;
    // What may be written on this target is the frame policy's to say
    // (policy/policy.h). A line setting is never written, even in-process:
    // the properties would lose the device. A write whose value or words
    // rest on an inferred range, type or word order is not held against the
    // device either: such registers are read, not written.
    bool inferred_value = r.basis_of(spec::Fact::range).is_inferred() || r.basis_of(spec::Fact::type).is_inferred() ||
                          r.basis_of(spec::Fact::word_order).is_inferred();
    if (r.access == Access::rw && !inferred_value && !is_serial_setting(s, r.address) && allowed_write(facts, r))
      writable_.push_back(&r);
    if (r.access == Access::ro) read_only_.push_back(&r);
    if (r.access == Access::wo) continue;
    if (r.access == Access::command && !r.command) continue;
    if (target.live && r.access != Access::rw) continue;
    // Command registers are readable (most print R/W) but what they read is
    // the device's own business (reads_back); the image keeps them only when
    // the spec says what they read.
    if (r.access == Access::command && !r.command->reads_back) continue;
    image_.push_back(&r);
  }
  // Image reads: runs of registers at consecutive addresses.
  int limit = supports(3) ? quantity_limit(3) : 0;
  for (size_t i = 0; i < image_.size() && limit > 0;) {
    uint16_t start = image_[i]->address;
    uint32_t end = image_[i]->last_address() + 1;
    size_t j = i + 1;
    while (j < image_.size() && image_[j]->address == end && image_[j]->last_address() + 1 - start <= uint32_t(limit)) {
      end = image_[j]->last_address() + 1;
      ++j;
    }
    image_reads_.emplace_back(start, uint16_t(end - start));
    i = j;
  }
}

int SpecView::quantity_limit(int fc) const {
  int standard = standard_max_quantity(fc);
  const spec::FunctionCode* f = spec_->profile.function(fc);
  return f && f->max_quantity ? std::min(*f->max_quantity, standard) : standard;
}

std::vector<int> SpecView::unsupported_functions() const {
  std::vector<int> out;
  for (int fc = 1; fc < 128; ++fc)
    if (!in_profile(fc)) out.push_back(fc);
  return out;
}

Expected expected_of(const spec::PolicyEntry& p) {
  // An inferred, observed or twice-printed answer is not held against the
  // device: any refusal passes.
  if (p.basis.is_inferred()) return {Expected::Kind::refused, 0};
  if (p.basis.basis == spec::Basis::either && !p.readings.empty()) {
    auto one = [](const spec::PolicyEntry& r) -> Expected {
      if (r.kind == spec::PolicyEntry::Kind::exception) return {Expected::Kind::exception, r.code};
      if (r.kind == spec::PolicyEntry::Kind::silent) return {Expected::Kind::silence, 0};
      return {Expected::Kind::refused, 0};
    };
    Expected e = one(p.readings.front());
    for (size_t i = 1; i < p.readings.size(); ++i) e.either.push_back(one(p.readings[i]));
    return e;
  }
  switch (p.kind) {
    case spec::PolicyEntry::Kind::exception: return {Expected::Kind::exception, p.code};
    case spec::PolicyEntry::Kind::silent: return {Expected::Kind::silence, 0};
    case spec::PolicyEntry::Kind::unspecified: return {Expected::Kind::refused, 0};
  }
  return {};
}

Expected SpecView::expected(Violation v) const {
  facts::Relies ignored;
  return expected_of(facts::policy(ignored, *spec_, v));  // the one policy lookup (quantity_zero's fallback there)
}

bool SpecView::in_range(const Register& r, uint32_t raw) const {
  // In range means inside every reading of a range printed two ways.
  facts::Relies ignored;
  return facts::in_range(ignored, *spec_, r, raw).value_or(false);
}

std::vector<uint32_t> SpecView::boundary_values(const Register& r) const {
  std::vector<uint32_t> out;
  if (r.type == DataType::enumeration && !r.range && !r.enum_id.empty())
    if (const spec::Enumeration* e = spec_->find_enum(r.enum_id)) {
      for (const auto& x : e->values) out.push_back(to_raw(r, double(x.value)));
      return out;
    }
  double lo = r.range ? r.range->min : type_min(r), hi = r.range ? r.range->max : type_max(r);
  if (r.type == DataType::f32 && !r.range) lo = -1e6, hi = 1e6;
  for (double v : {lo, hi, std::floor((lo + hi) / 2)}) {
    uint32_t raw = to_raw(r, v);
    if (in_range(r, raw)) out.push_back(raw);
  }
  return out;
}

std::vector<uint32_t> SpecView::out_of_range_values(const Register& r) const {
  std::vector<uint32_t> out;
  if (r.basis_of(spec::Fact::range).basis != spec::Basis::stated) return out;  // no stated range to be outside of
  if (r.type == DataType::f32) {
    if (r.range) out.push_back(0x7FC00000u);  // NaN is in no range
    if (r.range) out.push_back(to_raw(r, r.range->max * 2 + 1)), out.push_back(to_raw(r, r.range->min * 2 - 1));
  } else if (r.range) {
    if (r.range->min > type_min(r)) out.push_back(to_raw(r, r.range->min - 1));
    if (r.range->max < type_max(r)) out.push_back(to_raw(r, r.range->max + 1));
    if (r.range->max + 1000 < type_max(r)) out.push_back(to_raw(r, type_max(r)));
  } else if (r.type == DataType::enumeration) {
    for (uint32_t raw = 0; raw < 0x10000 && out.size() < 3; raw = raw * 2 + 1)
      if (!in_range(r, raw)) out.push_back(raw);
  }
  std::erase_if(out, [&](uint32_t raw) { return in_range(r, raw); });
  return out;
}

std::vector<uint16_t> SpecView::words_of(const Register& r, uint32_t raw) const {
  if (r.words == 1) return {uint16_t(raw)};
  auto w = split_u32(raw, r.low_word_first());
  return {w[0], w[1]};
}

uint32_t SpecView::raw_of(const Register& r, std::span<const uint16_t> w) const {
  if (r.words == 1) return w[0];
  return join_u32(w[0], w[1], r.low_word_first());
}

std::optional<uint32_t> SpecView::default_raw(const Register& r) const {
  // Only a stated default is held against the device.
  if (!r.default_value || r.basis_of(spec::Fact::default_value).basis != spec::Basis::stated) return std::nullopt;
  return to_raw(r, *r.default_value);
}

Bytes SpecView::write_request(const Register& r, uint32_t raw, bool prefer_fc16) const {
  auto w = words_of(r, raw);
  if (w.size() == 1 && supports(6) && !(prefer_fc16 && supports(16))) return write_single_register(r.address, w[0]);
  return write_multiple_registers(r.address, w);
}

std::vector<std::string> Image::differences(const Image& after) const {
  std::vector<std::string> out;
  for (const auto& [a, v] : words) {
    auto it = after.words.find(a);
    if (it == after.words.end()) out.push_back(fmt::format("0x{:04X}: {} -> (not read)", a, v));
    else if (it->second != v) out.push_back(fmt::format("0x{:04X}: {} (0x{:04X}) -> {} (0x{:04X})", a, v, v, it->second, it->second));
  }
  return out;
}

Image read_image(const Transact& transact, const SpecView& view) {
  Image img;
  for (const auto& [start, qty] : view.image_reads()) {
    Bytes req = read_request(3, start, qty);
    Reply rep = transact(req, fmt::format("read image 0x{:04X} x{}", start, qty));
    if (!rep.pdu) {
      img.error = fmt::format("reading the image at 0x{:04X} x{}: {}", start, qty,
                              rep.silent() ? "no reply" : rep.framing_error);
      return img;
    }
    Judged j = judge_reply(req, *rep.pdu);
    if (j.kind != Judged::Kind::normal) {
      img.error = fmt::format("reading the image at 0x{:04X} x{}: {}", start, qty,
                              j.kind == Judged::Kind::exception ? fmt::format("exception {:02X}", j.exception_code)
                                                                : j.problems.front());
      return img;
    }
    for (uint16_t i = 0; i < qty; ++i) img.words[uint16_t(start + i)] = j.registers[i];
  }
  return img;
}

ReadResult read_register(const Transact& transact, const SpecView& view, const Register& r) {
  Bytes req = read_request(3, r.address, uint16_t(r.words));
  Reply rep = transact(req, fmt::format("read {} (0x{:04X})", r.key.empty() ? r.name.en : r.key, r.address));
  if (!rep.pdu) return {std::nullopt, rep.silent() ? "no reply to the read" : rep.framing_error};
  Judged j = judge_reply(req, *rep.pdu);
  if (j.kind == Judged::Kind::exception) return {std::nullopt, fmt::format("the read got exception {:02X}", j.exception_code)};
  if (j.kind != Judged::Kind::normal) return {std::nullopt, "malformed read reply: " + j.problems.front()};
  return {view.raw_of(r, j.registers), ""};
}

}  // namespace mbc::conf::props
