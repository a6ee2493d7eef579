// The wire maxima of the Modbus standards, stated once, and the standard's
// per-function-code quantity limits (125 registers, 2000 coils, ...). A
// device's manual may state lower limits (spec/devices/*.yaml); the spec
// language states the standard's own in spec/devices/modbus-standard.yaml, and
// spec/tests/wire_limits_test.cpp checks that file against this table.
#pragma once

#include <cstddef>

namespace mbc {

// MBAP v1.1b3 §4.1: "the size of the Modbus PDU is limited by the size
// constraint inherited from the first MODBUS implementation on Serial Line
// network (max. RS485 ADU = 256 bytes)": 256 - address (1) - CRC (2).
inline constexpr size_t kMaxPdu = 253;
// MB-SL v1.02 §2.5.1: an RTU frame is at most 256 bytes.
inline constexpr size_t kMaxRtuAdu = 256;
// MBAP v1.1b3 §4.1: "TCP MODBUS ADU = 253 bytes + MBAP (7 bytes) = 260 bytes".
inline constexpr size_t kMaxTcpAdu = 260;
// MB Messaging on TCP/IP v1.0b §3.1.3: transaction (2), protocol (2), length (2), unit (1).
inline constexpr size_t kMbapHeader = 7;
// MB-SL v1.02 §2.5.1.2: the RTU ADU is address (1), PDU, CRC (2).
inline constexpr size_t kRtuAddress = 1;
inline constexpr size_t kRtuCrc = 2;

// MBAP v1.1b3 §6.17 (FC 23): "Quantity to Read 2 Bytes 0x0001 to 0x007D",
// "Quantity to Write 2 Bytes 0x0001 to 0X0079".
inline constexpr int kMaxReadWriteReadQuantity = 125;
inline constexpr int kMaxReadWriteWriteQuantity = 121;

// The standard's quantity limit of one request, or 0 when the function has no
// quantity field. For FC 23 the read quantity; the write one is above.
constexpr int standard_max_quantity(int function_code) {
  switch (function_code) {
    case 1:  // §6.1 "Quantity of coils 2 Bytes 1 to 2000 (0x7D0)"
    case 2:  // §6.2 "Quantity of Inputs 2 Bytes 1 to 2000 (0x7D0)"
      return 2000;
    case 3:  // §6.3 "Quantity of Registers 2 Bytes 1 to 125 (0x7D)"
    case 4:  // §6.4 "Quantity of Input Registers 2 Bytes 0x0001 to 0x007D"
      return 125;
    case 15: return 1968;  // §6.11 "Quantity of Outputs 2 Bytes 0x0001 to 0x07B0"
    case 16: return 123;   // §6.12 "Quantity of Registers 2 Bytes 0x0001 to 0x007B"
    case 23: return kMaxReadWriteReadQuantity;
    default: return 0;
  }
}

static_assert(kMaxRtuAdu == kRtuAddress + kMaxPdu + kRtuCrc);
static_assert(kMaxTcpAdu == kMbapHeader + kMaxPdu);

}  // namespace mbc
