// Values and request frames derived from a spec, shared by the black-box
// fuzzer (engine.h) and the corpus generator (fuzz/corpus_gen.cc):
// each register's valid and boundary values, encoded through its type and
// word order, and the request PDUs that write them.
#pragma once

#include <algorithm>
#include <bit>
#include <cmath>
#include <cstdint>
#include <utility>
#include <vector>

#include "modbus/hex.h"
#include "modbus/pdu.h"
#include "modbus/words.h"
#include "spec.h"

namespace mbc::conf::blackbox {

// Raw register words of `value` through the register's type and word order.
inline std::vector<uint16_t> words_of(const spec::Register& r, double value) {
  uint32_t raw;
  if (r.type == spec::DataType::f32) raw = std::bit_cast<uint32_t>(float(value));
  else raw = uint32_t(int64_t(value));
  if (r.words == 1) return {uint16_t(raw)};
  auto w = split_u32(raw, r.low_word_first());
  return {w[0], w[1]};
}

// The raw domain of a register's type, for the values just outside its range.
inline std::pair<double, double> type_domain(const spec::Register& r) {
  switch (r.type) {
    case spec::DataType::s16: return {-32768, 32767};
    case spec::DataType::u32: return {0, 4294967295.0};
    case spec::DataType::s32: return {-2147483648.0, 2147483647.0};
    case spec::DataType::f32: return {-3.0e38, 3.0e38};
    case spec::DataType::bit: return {0, 1};
    default: return {0, 65535};
  }
}

// Valid and boundary values: the range's ends, one step outside each end when
// the type can hold it (enumerations: first, last, one past the last), the
// default and the command values.
inline std::vector<double> boundary_values(const spec::Spec& s, const spec::Register& r) {
  auto [lo, hi] = type_domain(r);
  std::vector<double> v;
  if (r.range) {
    v = {r.range->min, r.range->max};
    double step = r.type == spec::DataType::f32 ? std::max(1.0, std::abs(r.range->max) * 0.01) : 1;
    if (r.range->min - step >= lo) v.push_back(r.range->min - step);
    if (r.range->max + step <= hi) v.push_back(r.range->max + step);
  } else if (!r.enum_id.empty()) {
    if (const auto* e = s.find_enum(r.enum_id); e && !e->values.empty()) {
      auto [mn, mx] = std::minmax_element(e->values.begin(), e->values.end(),
                                          [](const auto& a, const auto& b) { return a.value < b.value; });
      v = {double(mn->value), double(mx->value)};
      if (double(mx->value) + 1 <= hi) v.push_back(double(mx->value) + 1);
    }
  } else {
    v = {lo, hi};
  }
  if (r.default_value) v.push_back(*r.default_value);
  if (r.command)
    for (int64_t c : r.command->values) v.push_back(double(c));
  std::sort(v.begin(), v.end());
  v.erase(std::unique(v.begin(), v.end()), v.end());
  return v;
}

inline uint8_t read_function(spec::Table t) {
  switch (t) {
    case spec::Table::coil: return 1;
    case spec::Table::discrete_input: return 2;
    case spec::Table::input: return 4;
    default: return 3;
  }
}

// Write requests (PDUs) for `value` into `r`, with the function codes the
// device's profile supports (FC 05 for coils, FC 06 for one word, else FC 16).
inline std::vector<Bytes> write_pdus(const spec::Spec& s, const spec::Register& r, double value) {
  std::vector<Bytes> out;
  if (r.table == spec::Table::coil) {
    if (s.profile.function(5)) out.push_back(write_single_coil(r.address, value != 0));
    return out;
  }
  if (r.table != spec::Table::holding) return out;
  auto w = words_of(r, value);
  if (w.size() == 1 && s.profile.function(6)) out.push_back(write_single_register(r.address, w[0]));
  else if (s.profile.function(16)) out.push_back(write_multiple_registers(r.address, w));
  return out;
}

// The registers a seed set walks: every register, but of a `count:` block only
// its first and last item (the block's items behave alike).
inline std::vector<const spec::Register*> representative_registers(const spec::Spec& s) {
  std::vector<const spec::Register*> v;
  for (size_t i = 0; i < s.registers.size(); ++i) {
    const spec::Register& r = s.registers[i];
    bool block_inner = r.block_index > 0 && i + 1 < s.registers.size() &&
                       s.registers[i + 1].block_index > r.block_index && s.registers[i + 1].table == r.table;
    if (!block_inner) v.push_back(&r);
  }
  return v;
}

}  // namespace mbc::conf::blackbox
