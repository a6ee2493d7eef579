// A framing as data, in the spirit of libmodbus's modbus_backend_t: what
// surrounds a PDU on the wire. Code that only needs sizes (buffers, limits,
// "is this ADU too long") takes a Framing and never asks which one it is.
#pragma once

#include <cstddef>
#include <cstdint>
#include <span>
#include <string>
#include <string_view>

#include "modbus/bytes.h"
#include "modbus/limits.h"

namespace mbc {

// An ADU split back into what it carries. `error` says why it is not a
// well-formed ADU of its framing (too short, bad CRC, wrong MBAP length or
// protocol); the fields hold whatever could be read all the same.
struct Unframed {
  uint8_t unit = 0;          // RTU slave address or MBAP unit id
  uint16_t transaction = 0;  // MBAP only
  Bytes pdu;
  std::string error;
  bool ok() const { return error.empty(); }
};

struct Framing {
  std::string_view name;   // "rtu", "tcp"
  size_t header_length;    // bytes before the PDU: RTU address (1), MBAP header (7)
  size_t checksum_length;  // bytes after the PDU: RTU CRC (2), none on TCP
  size_t max_adu;          // 256 (MB-SL v1.02 §2.5.1), 260 (MBAP v1.1b3 §4.1)
  // `pdu` for `unit` (MBAP: protocol 0 and `transaction`; RTU ignores it).
  Bytes (*frame)(uint8_t unit, std::span<const uint8_t> pdu, uint16_t transaction);
  Unframed (*unframe)(std::span<const uint8_t> adu);

  size_t max_pdu() const { return max_adu - header_length - checksum_length; }
  size_t adu_size(size_t pdu_size) const { return header_length + pdu_size + checksum_length; }
  // The bytes where an ADU carries its PDU, whatever its checksum or length
  // field says (a trace of a deliberately broken frame); empty when too short.
  std::span<const uint8_t> pdu_bytes(std::span<const uint8_t> adu) const {
    if (adu.size() <= header_length + checksum_length) return {};
    return adu.subspan(header_length, adu.size() - header_length - checksum_length);
  }
};

extern const Framing kRtu;  // rtu.h
extern const Framing kTcp;  // mbap.h

// How ADUs travel between a master and a slave: Modbus TCP, RTU frames over
// TCP, RTU on a serial line (a pty here), MBAP inside TLS (MB-TCP-Security).
// The one transport descriptor of serve, the client's scenario servers and
// the targets' URIs; its framing is one of the two above.
enum class Transport { tcp, rtu_tcp, pty, tls };
const char* to_string(Transport t);      // "tcp", "rtu-tcp", "pty", "tls"
const Framing& framing_of(Transport t);  // kTcp for tcp and tls, kRtu for rtu-tcp and pty

}  // namespace mbc
