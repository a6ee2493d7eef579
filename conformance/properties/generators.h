// RapidCheck generators drawn from the spec: registers, values in and out
// of range, valid and invalid requests. Used inside a property (they call
// *gen), never at namespace scope.
#pragma once

#include <cstdint>
#include <functional>
#include <string>
#include <vector>

#include <rapidcheck.h>

#include "modbus/hex.h"
#include "properties/spec_view.h"

namespace mbc::conf::props {

// Choices drawn uniformly whatever RapidCheck's current size (its inRange and
// elementOf stay near the start at small sizes); they still shrink.
inline constexpr int kFullSize = 100;
template <typename T>
T pick(T lo, T hi_exclusive) {
  return *rc::gen::resize(kFullSize, rc::gen::inRange<T>(lo, hi_exclusive));
}
template <typename C>
auto pick_of(const C& c) -> typename C::value_type {
  return c[pick<size_t>(0, c.size())];
}
inline bool pick_bool() { return pick<int>(0, 2) == 1; }

// An in-range raw value for r: a boundary (min, max, middle) half of the
// time, else anywhere in the range (float32: any float in range, bit-exact).
uint32_t pick_in_range(const SpecView& view, const spec::Register& r);
const spec::Register& pick_writable(const SpecView& view);

// A valid request the device must answer normally, and what it does.
struct Request {
  Bytes pdu;
  std::string note;
};
// A read (FC 03) of a run of readable registers, sometimes exactly the limit.
Request pick_valid_read(const SpecView& view);
// A write of an in-range value to a writable register (FC 06 or FC 16).
Request pick_valid_write(const SpecView& view);

// An invalid request: what it violates (for the policy) and what it does.
struct Bad {
  Bytes pdu;
  spec::Violation violation;
  std::string note;
};
// Makers of the rejections the spec gives this device: out-of-range value,
// write to read-only, quantity over the limit or zero, unsupported FC.
std::vector<std::function<Bad()>> rejection_kinds(const SpecView& view);

std::string describe(const spec::Register& r);  // "0x0020 start speed"

}  // namespace mbc::conf::props
