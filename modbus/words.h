// 32-bit values in two 16-bit registers. The standard says nothing about the
// order of the two words (MBAP v1.1b3 §4.2 orders bytes only); each device's
// spec states it as word_order, and callers map that to `low_first`: true when
// the register at the LOWER address holds the low 16 bits.
#pragma once

#include <array>
#include <cstdint>

namespace mbc {

// The two words in address order.
inline std::array<uint16_t, 2> split_u32(uint32_t v, bool low_first) {
  uint16_t hi = uint16_t(v >> 16), lo = uint16_t(v & 0xFFFF);
  return low_first ? std::array<uint16_t, 2>{lo, hi} : std::array<uint16_t, 2>{hi, lo};
}

// The value of the words at address a (`first`) and a + 1 (`second`).
inline uint32_t join_u32(uint16_t first, uint16_t second, bool low_first) {
  return low_first ? (uint32_t(second) << 16 | first) : (uint32_t(first) << 16 | second);
}

}  // namespace mbc
