// The MBAP header of Modbus TCP (MB Messaging on TCP/IP v1.0b §3.1.3):
// transaction id, protocol id (0 = Modbus), length (unit id + PDU), unit id.
#pragma once

#include <cstddef>
#include <cstdint>
#include <optional>
#include <span>

#include "modbus/bytes.h"
#include "modbus/framing.h"
#include "modbus/limits.h"

namespace mbc {

struct Mbap {
  uint16_t transaction = 0;
  uint16_t protocol = 0;
  uint16_t length = 0;  // bytes that follow the length field: unit id + PDU
  uint8_t unit = 0;

  size_t adu_size() const { return 6 + size_t(length); }
  // The length field admits a PDU of 1..253 bytes.
  bool length_ok() const { return length >= 2 && length <= 1 + kMaxPdu; }
};

// The header at the start of `bytes`, once all 7 bytes are there.
std::optional<Mbap> parse_mbap(std::span<const uint8_t> bytes);

// The ADU: header (protocol 0, length from the PDU) and `pdu`.
Bytes mbap_frame(uint16_t transaction, uint8_t unit, std::span<const uint8_t> pdu);
// The reply ADU: the request's transaction, protocol and unit around `pdu`.
Bytes mbap_reply(const Mbap& request, std::span<const uint8_t> pdu);
// The same reply ADU appended to `out` (a server's output, where the replies
// to a batch of requests lie side by side for one send).
void append_mbap_reply(Bytes& out, const Mbap& request, std::span<const uint8_t> pdu);
// The unit and PDU of a whole ADU; `error` when the header is short, the
// protocol is not 0, or the length field disagrees with the bytes.
Unframed mbap_unframe(std::span<const uint8_t> adu);

}  // namespace mbc
