// One line per frame for `mbconform serve --trace`: the bytes as hex and what
// they say (slave, function, address, quantity or value, exception code).
#pragma once

#include <cstdint>
#include <span>
#include <string>

#include "modbus/pdu.h"

namespace mbc::serve {

// "FC 03 read holding registers addr 0x0023 qty 1", "FC 83 exception 02 (illegal data address)".
std::string describe_pdu(std::span<const uint8_t> pdu, Direction dir);
// An RTU ADU: "slave 1 " + describe_pdu + " CRC ok|BAD".
std::string describe_rtu(std::span<const uint8_t> adu, Direction dir);

}  // namespace mbc::serve
