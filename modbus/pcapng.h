// Writing what went over the wire as pcapng (IETF draft-ietf-opsawg-pcapng),
// so that any run can be opened in Wireshark. Pure encoding: every timestamp
// is an argument (microseconds since the Unix epoch); nothing here reads a
// clock or opens a file.
//
// Two link types:
//   kLinkEthernet (1): Modbus TCP, each frame wrapped in Ethernet II / IPv4 /
//     TCP with consistent sequence numbers (a handshake first), so that
//     Wireshark's Modbus/TCP dissector decodes it when the server port is 502.
//   kLinkUser0 (147, LINKTYPE_USER0): RTU, one packet per RTU ADU exactly as
//     on the line (slave .. CRC), no header; the direction is the enhanced
//     packet block's epb_flags (inbound = from the slave). Wireshark decodes it
//     with the user DLT table mapping User 0 to "mbrtu"
//     (conformance/capture/README.md gives the tshark option).
#pragma once
#include <cstdint>
#include <span>
#include <string_view>

#include "modbus/bytes.h"

namespace mbc::pcapng {

inline constexpr uint16_t kLinkEthernet = 1;
inline constexpr uint16_t kLinkUser0 = 147;

// Section header block (byte order magic, version 1.0, section length unknown).
Bytes section_header(std::string_view application);
// Interface description block: `linktype`, microsecond timestamps
// (if_tsresol 6), if_name and if_description when not empty.
Bytes interface_description(uint16_t linktype, std::string_view name, std::string_view description);
// Enhanced packet block on interface `interface_id` at `time_us`.
// direction: 0 not given, 1 inbound, 2 outbound (epb_flags bits 0-1).
Bytes enhanced_packet(uint32_t interface_id, uint64_t time_us, std::span<const uint8_t> data, int direction = 0,
                      std::string_view comment = {});

// One TCP connection drawn as Ethernet/IPv4/TCP frames: addresses, ports and
// the sequence numbers both sides have reached. Each call returns one whole
// Ethernet frame (IPv4 and TCP checksums computed).
class TcpConversation {
 public:
  TcpConversation(uint32_t client_ip, uint16_t client_port, uint32_t server_ip, uint16_t server_port);
  // SYN, SYN-ACK, ACK: call each in turn (step 0, 1, 2) before any data.
  Bytes handshake(int step);
  // A segment of `payload` (PSH, ACK) from the client (true) or the server.
  Bytes data(bool from_client, std::span<const uint8_t> payload);
  // FIN, ACK from one side.
  Bytes fin(bool from_client);

 private:
  Bytes frame(bool from_client, uint8_t flags, std::span<const uint8_t> payload);
  uint32_t ip_[2];
  uint16_t port_[2];
  uint32_t next_seq_[2];  // [0] client, [1] server
};

}  // namespace mbc::pcapng
