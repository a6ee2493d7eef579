#include "properties/generators.h"

#include <fmt/core.h>
#include <rapidcheck.h>

#include <bit>
#include <cmath>

#include "modbus/limits.h"
#include "modbus/pdu.h"

namespace mbc::conf::props {

using spec::DataType;
using spec::Register;
using spec::Access;
using spec::Violation;

std::string describe(const Register& r) { return fmt::format("0x{:04X} ({}) {}", r.address, r.address, r.name.en); }

const Register& pick_writable(const SpecView& view) { return *pick_of(view.writable()); }

uint32_t pick_in_range(const SpecView& view, const Register& r) {
  auto bounds = view.boundary_values(r);
  if (!bounds.empty() && pick<int>(0, 2) == 0) return pick_of(bounds);
  if (r.type == DataType::f32) {
    if (r.range) {
      // Any float in [min, max], bit-exact: a fraction of the span, rounded to float.
      for (int tries = 0; tries < 8; ++tries) {
        double k = double(pick<int>(0, 1'000'001)) / 1e6;
        uint32_t raw = std::bit_cast<uint32_t>(float(r.range->min + (r.range->max - r.range->min) * k));
        if (view.in_range(r, raw)) return raw;
      }
      return bounds.empty() ? std::bit_cast<uint32_t>(float(r.range->min)) : bounds.front();
    }
    uint32_t raw = pick<uint32_t>(0, 0xFFFFFFFFu);
    return view.in_range(r, raw) ? raw : 0;
  }
  if (r.type == DataType::enumeration && !r.range && !bounds.empty()) return pick_of(bounds);
  int64_t lo, hi;
  if (r.range) {
    lo = int64_t(std::ceil(r.range->min)), hi = int64_t(std::floor(r.range->max));
  } else if (r.is_signed()) {
    lo = r.words == 1 ? -32768 : INT32_MIN, hi = r.words == 1 ? 32767 : INT32_MAX;
  } else {
    lo = 0, hi = r.words == 1 ? 0xFFFF : 0xFFFFFFFFLL;
  }
  int64_t v = pick<int64_t>(lo, hi + 1);
  uint32_t raw = r.words == 1 ? uint32_t(uint16_t(v)) : uint32_t(v);
  if (!view.in_range(r, raw) && !bounds.empty()) return bounds.front();
  return raw;
}

Request pick_valid_read(const SpecView& view) {
  const auto& runs = view.image_reads();
  auto [start, qty] = pick_of(runs);
  // Sometimes the whole run (up to the FC 03 limit itself), else a part of it
  // on register boundaries.
  if (pick<int>(0, 4) != 0) {
    std::vector<const Register*> regs;
    for (const Register* r : view.image_registers())
      if (r->address >= start && r->last_address() < uint32_t(start) + qty) regs.push_back(r);
    size_t i = pick<size_t>(0, regs.size());
    size_t j = pick<size_t>(i, regs.size());
    start = regs[i]->address;
    qty = uint16_t(regs[j]->last_address() + 1 - start);
  }
  return {read_request(3, start, qty), fmt::format("read 0x{:04X} x{}", start, qty)};
}

Request pick_valid_write(const SpecView& view) {
  const Register& r = pick_writable(view);
  uint32_t raw = pick_in_range(view, r);
  bool fc16 = pick_bool();
  return {view.write_request(r, raw, fc16), fmt::format("write {} = 0x{:X}", describe(r), raw)};
}

std::vector<std::function<Bad()>> rejection_kinds(const SpecView& v) {
  std::vector<std::function<Bad()>> kinds;
  std::vector<const Register*> ranged;
  for (const Register* r : v.writable())
    if (!v.out_of_range_values(*r).empty() && (r->words == 1 || v.supports(16))) ranged.push_back(r);
  if (!ranged.empty())
    kinds.push_back([&v, ranged] {
      const Register& r = *pick_of(ranged);
      uint32_t raw = pick_of(v.out_of_range_values(r));
      return Bad{v.write_request(r, raw, pick_bool()), Violation::value_out_of_range,
                 fmt::format("write {} = 0x{:X}, outside its range", describe(r), raw)};
    });
  std::vector<const Register*> ro;
  for (const Register* r : v.read_only())
    if (r->words == 1 || v.supports(16)) ro.push_back(r);
  if (!ro.empty() && (v.supports(6) || v.supports(16)))
    kinds.push_back([&v, ro] {
      const Register& r = *pick_of(ro);
      uint32_t raw = pick<uint32_t>(0, 0x10000);
      return Bad{v.write_request(r, raw, pick_bool()), Violation::write_read_only,
                 fmt::format("write read-only {} = 0x{:X}", describe(r), raw)};
    });
  if (v.supports(3) && !v.image_reads().empty()) {
    kinds.push_back([&v] {
      // Exactly limit+1 most of the time, from a run long enough that only
      // the quantity is wrong; else anything above the limit.
      int limit = v.quantity_limit(3);
      uint16_t start = v.image_reads().front().first;
      for (const auto& [a, q] : v.image_reads())
        if (q >= limit) start = a;
      uint16_t qty = pick<int>(0, 3) ? uint16_t(limit + 1) : pick<uint16_t>(uint16_t(limit + 1), 0xFFFF);
      return Bad{read_request(3, start, qty), Violation::quantity_over_limit,
                 fmt::format("read 0x{:04X} x{} (limit {})", start, qty, limit)};
    });
    kinds.push_back([&v] {
      uint16_t start = (pick_of(v.image_reads())).first;
      return Bad{read_request(3, start, 0), Violation::quantity_zero, fmt::format("read 0x{:04X} x0", start)};
    });
  }
  if (v.supports(16) && !v.writable().empty() && 6 + 2 * (v.quantity_limit(16) + 1) <= int(kMaxPdu))
    kinds.push_back([&v] {
      int limit = v.quantity_limit(16);
      const Register& r = pick_writable(v);
      std::vector<uint16_t> words(size_t(limit + 1), 0);
      return Bad{write_multiple_registers(r.address, words), Violation::quantity_over_limit,
                 fmt::format("write {} registers from 0x{:04X} (limit {})", limit + 1, r.address, limit)};
    });
  if (!v.unsupported_functions().empty())
    kinds.push_back([&v] {
      int fc = pick_of(v.unsupported_functions());
      Bytes pdu{uint8_t(fc)};
      for (int i = 0; i < 4; ++i) pdu.push_back(uint8_t(pick<int>(0, 256)));
      return Bad{pdu, Violation::unsupported_function, fmt::format("FC {:02} (not in the profile)", fc)};
    });
  return kinds;
}

}  // namespace mbc::conf::props
