// Modbus RTU (MB over Serial Line v1.02 §2.5.1): the frame around a PDU, where
// a frame ends on a byte stream, and the line's character timing. Pure
// arithmetic: nothing here reads a clock.
#pragma once

#include <chrono>
#include <cstddef>
#include <cstdint>
#include <optional>
#include <span>

#include "modbus/bytes.h"
#include "modbus/framing.h"
#include "modbus/pdu.h"

namespace mbc {

// One character on the line: start bit, 8 data bits, parity or second stop, stop (MB-SL §2.5.1).
inline constexpr int kBitsPerChar = 11;

// slave, PDU, CRC low byte first (MB-SL v1.02 §2.5.1.2).
Bytes rtu_frame(uint8_t slave, std::span<const uint8_t> pdu);
// The slave and PDU of an RTU ADU; `error` when it is shorter than address +
// function code + CRC, longer than 256 bytes, or its CRC does not match.
Unframed rtu_unframe(std::span<const uint8_t> adu);

// The length of the RTU ADU that starts with `head` (slave, FC, ...), when its
// function code fixes it (MBAP v1.1b3 §6 request and response layouts, §7 for
// exception replies) or the bytes seen so far carry its byte count; nullopt
// when unknown yet (too few bytes) or unknowable (FC 43 replies, unknown FCs:
// the line's silence ends those frames).
std::optional<size_t> rtu_adu_length(std::span<const uint8_t> head, Direction dir);
// Whether `bytes` are one whole ADU that needs no silence to end: the length
// rtu_adu_length knows from them, and a CRC that checks. A receiver may end
// the frame there; a prefix, trailing bytes, a bad CRC or a function code
// whose length only the line's silence settles are left to t3.5 (MB-SL
// v1.02 §2.5.1.1).
bool rtu_adu_complete(std::span<const uint8_t> bytes, Direction dir);

// t3.5: 3.5 character times at `baud`; above 19200 baud the fixed 1.75 ms
// MB-SL §2.5.1.1 recommends (timers that short are impractical).
std::chrono::microseconds frame_gap(int baud);
// t1.5: the longest silence inside a frame; 750 us above 19200 baud (MB-SL §2.5.1.1).
std::chrono::microseconds char_gap(int baud);
// How long `bytes` characters take on the wire at `baud`.
std::chrono::microseconds wire_time(size_t bytes, int baud);

}  // namespace mbc
