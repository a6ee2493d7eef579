#include "serve/rtu_framing.h"

namespace mbc::serve {

using std::chrono::microseconds;

microseconds frame_gap(int baud) {
  if (baud > 19200) return microseconds(1750);  // MB-SL v1.02 §2.5.1.1
  return microseconds(int64_t(3.5 * kBitsPerChar * 1e6 / baud + 0.5));
}

microseconds wire_time(size_t bytes, int baud) {
  return microseconds(int64_t(double(bytes) * kBitsPerChar * 1e6 / baud + 0.5));
}

std::optional<size_t> rtu_request_length(std::span<const uint8_t> head) {
  constexpr size_t crc = 2;
  if (head.size() < 2) return std::nullopt;
  // Bytes after slave+FC up to the PDU's byte count, if it has one.
  auto with_count = [&](size_t count_at) -> std::optional<size_t> {
    if (head.size() <= count_at) return std::nullopt;
    return count_at + 1 + head[count_at] + crc;
  };
  switch (head[1]) {
    case 0x01: case 0x02: case 0x03: case 0x04:  // address, quantity (MBAP §6.1-6.4)
    case 0x05: case 0x06:                        // address, value (§6.5, §6.6)
    case 0x08:                                   // sub-function, data (§6.8)
      return 2 + 4 + crc;
    case 0x07: case 0x0B: case 0x0C: case 0x11:  // no data (§6.7, §6.9, §6.10, §6.13)
      return 2 + crc;
    case 0x0F: case 0x10:  // address, quantity, byte count, values (§6.11, §6.12)
      return with_count(6);
    case 0x14: case 0x15:  // byte count, sub-requests (§6.14, §6.15)
      return with_count(2);
    case 0x16:  // address, AND mask, OR mask (§6.16)
      return 2 + 6 + crc;
    case 0x17:  // read address, quantity, write address, quantity, byte count, values (§6.17)
      return with_count(10);
    case 0x18:  // FIFO pointer address (§6.18)
      return 2 + 2 + crc;
    case 0x2B:  // MEI type 14: read device id code, object id (§6.21)
      if (head.size() < 3) return std::nullopt;
      return head[2] == 0x0E ? std::optional<size_t>(2 + 3 + crc) : std::nullopt;
    default:
      return std::nullopt;
  }
}

}  // namespace mbc::serve
