// The wire maxima of the Modbus standards, stated once. The per-function-code
// quantity limits (125 registers, 2000 coils, ...) are device facts and live
// in spec/devices/modbus-standard.yaml; a test checks they fit these.
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

static_assert(kMaxRtuAdu == kRtuAddress + kMaxPdu + kRtuCrc);
static_assert(kMaxTcpAdu == kMbapHeader + kMaxPdu);

}  // namespace mbc
