#include "serve/trace.h"

#include <fmt/core.h>

#include "modbus/bytes.h"
#include "modbus/crc16.h"
#include "modbus/function_codes.h"

namespace mbc::serve {
namespace {

std::string words(std::span<const uint8_t> data) {
  std::string s;
  for (size_t i = 0; i + 1 < data.size() && i < 16; i += 2) s += fmt::format(" {}", be16(data, i));
  if (data.size() > 16) s += " ...";
  return s;
}

}  // namespace

std::string describe_pdu(std::span<const uint8_t> pdu, Direction dir) {
  if (pdu.empty()) return "empty PDU";
  uint8_t fc = pdu[0];
  if (dir == Direction::reply && (fc & 0x80)) {
    if (pdu.size() < 2) return fmt::format("FC {:02X} exception (no code)", fc);
    return fmt::format("FC {:02X} exception {:02X} ({})", fc, pdu[1], exception_name(pdu[1]));
  }
  std::string s = fmt::format("FC {:02X} {}", fc, function_name(fc));
  bool has_addr_word = pdu.size() >= 5;
  switch (fc) {
    case 0x01: case 0x02: case 0x03: case 0x04:
      if (dir == Direction::request && has_addr_word)
        s += fmt::format(" addr 0x{:04X} qty {}", be16(pdu, 1), be16(pdu, 3));
      else if (dir == Direction::reply && pdu.size() >= 2)
        s += fmt::format(" {} bytes", pdu[1]) + (fc >= 3 ? ":" + words(pdu.subspan(2)) : "");
      break;
    case 0x05: case 0x06:
      if (has_addr_word) s += fmt::format(" addr 0x{:04X} value {} (0x{:04X})", be16(pdu, 1), be16(pdu, 3), be16(pdu, 3));
      break;
    case 0x08:
      if (has_addr_word) s += fmt::format(" sub-function {} data 0x{:04X}", be16(pdu, 1), be16(pdu, 3));
      break;
    case 0x0F: case 0x10:
      if (has_addr_word) s += fmt::format(" addr 0x{:04X} qty {}", be16(pdu, 1), be16(pdu, 3));
      if (fc == 0x10 && dir == Direction::request && pdu.size() > 6) s += ":" + words(pdu.subspan(6));
      break;
    case 0x16:
      if (pdu.size() >= 7)
        s += fmt::format(" addr 0x{:04X} and 0x{:04X} or 0x{:04X}", be16(pdu, 1), be16(pdu, 3), be16(pdu, 5));
      break;
    case 0x17:
      if (dir == Direction::request && pdu.size() >= 9)
        s += fmt::format(" read 0x{:04X} qty {} write 0x{:04X} qty {}", be16(pdu, 1), be16(pdu, 3), be16(pdu, 5),
                         be16(pdu, 7));
      break;
    default:
      s += fmt::format(", {} data bytes", pdu.size() - 1);
  }
  return s;
}

std::string describe_rtu(std::span<const uint8_t> adu, Direction dir) {
  if (adu.size() < 4) return fmt::format("{} bytes: too short for an RTU frame", adu.size());
  return fmt::format("slave {} {} CRC {}", adu[0], describe_pdu(adu.subspan(1, adu.size() - 3), dir),
                     crc_ok(adu) ? "ok" : "BAD");
}

}  // namespace mbc::serve
