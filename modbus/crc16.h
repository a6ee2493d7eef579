// Modbus RTU CRC-16 (polynomial 0xA001 reflected, initial 0xFFFF), sent low
// byte first: MB over Serial Line v1.02 §2.5.1.2 and Appendix B.
#pragma once

#include <cstddef>
#include <cstdint>
#include <span>
#include <vector>

namespace mbc {

uint16_t crc16(std::span<const uint8_t> bytes);

// True when the last two bytes are the CRC of the rest (low byte first).
bool crc_ok(std::span<const uint8_t> frame);

// Appends the CRC of everything in `frame` so far, low byte first.
void append_crc(std::vector<uint8_t>& frame);

}  // namespace mbc
