// Bytes on the wire: Modbus sends every 16-bit field big-endian ("the most
// significant byte first", MBAP v1.1b3 §4.2), except the RTU CRC (crc16.h).
#pragma once

#include <cstddef>
#include <cstdint>
#include <span>
#include <vector>

namespace mbc {

using Bytes = std::vector<uint8_t>;

// The big-endian word at p[at], p[at + 1]; the caller checks the size.
inline uint16_t be16(std::span<const uint8_t> p, size_t at) { return uint16_t(p[at] << 8 | p[at + 1]); }

// Appends `v` big-endian.
inline void put_be16(Bytes& b, uint16_t v) {
  b.push_back(uint8_t(v >> 8));
  b.push_back(uint8_t(v & 0xFF));
}

// Overwrites b[at], b[at + 1] with `v` big-endian; the caller checks the size.
inline void set_be16(std::span<uint8_t> b, size_t at, uint16_t v) {
  b[at] = uint8_t(v >> 8);
  b[at + 1] = uint8_t(v & 0xFF);
}

}  // namespace mbc
