#include "modbus/crc16.h"

#include <array>

namespace mbc {
namespace {

constexpr std::array<uint16_t, 256> make_table() {
  std::array<uint16_t, 256> t{};
  for (unsigned i = 0; i < 256; ++i) {
    uint16_t c = uint16_t(i);
    for (int k = 0; k < 8; ++k) c = (c & 1) ? uint16_t((c >> 1) ^ 0xA001) : uint16_t(c >> 1);
    t[i] = c;
  }
  return t;
}
constexpr auto kTable = make_table();

}  // namespace

uint16_t crc16(std::span<const uint8_t> bytes) {
  uint16_t crc = 0xFFFF;
  for (uint8_t b : bytes) crc = uint16_t((crc >> 8) ^ kTable[(crc ^ b) & 0xFF]);
  return crc;
}

bool crc_ok(std::span<const uint8_t> frame) {
  if (frame.size() < 3) return false;
  uint16_t c = crc16(frame.first(frame.size() - 2));
  return frame[frame.size() - 2] == (c & 0xFF) && frame[frame.size() - 1] == (c >> 8);
}

void append_crc(std::vector<uint8_t>& frame) {
  uint16_t c = crc16(frame);
  frame.push_back(uint8_t(c & 0xFF));
  frame.push_back(uint8_t(c >> 8));
}

}  // namespace mbc
