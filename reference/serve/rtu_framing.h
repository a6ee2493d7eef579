// Where an RTU frame ends on a byte stream (a pty or RTU over TCP): the
// inter-frame silence of MB over Serial Line v1.02 §2.5.1.1, and the request
// length the function code implies (MBAP v1.1b3 §6) for streams whose
// timing says nothing (TCP).
#pragma once

#include <chrono>
#include <cstddef>
#include <cstdint>
#include <optional>
#include <span>

namespace mbc::serve {

// An RTU ADU is at most 256 bytes: address, 253-byte PDU, CRC (MB-SL §2.5.1.1).
inline constexpr size_t kMaxRtuAdu = 256;
// One character on the line: start bit, 8 data bits, parity or second stop, stop (MB-SL §2.5.1).
inline constexpr int kBitsPerChar = 11;

// t3.5: 3.5 character times at `baud`; above 19200 baud the fixed 1.75 ms
// MB-SL §2.5.1.1 recommends (timers that short are impractical).
std::chrono::microseconds frame_gap(int baud);

// How long `bytes` characters take on the wire at `baud`.
std::chrono::microseconds wire_time(size_t bytes, int baud);

// The length of the request ADU that starts with `head` (slave, FC, ...) when
// the function code fixes it or the bytes seen so far carry its byte count;
// nullopt when unknown yet (too few bytes) or unknowable (unknown FC).
std::optional<size_t> rtu_request_length(std::span<const uint8_t> head);

}  // namespace mbc::serve
