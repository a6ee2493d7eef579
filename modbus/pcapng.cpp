#include "modbus/pcapng.h"

#include <string>

namespace mbc::pcapng {
namespace {

// pcapng blocks are written little-endian; the byte-order magic says so.
void le16(Bytes& b, uint16_t v) {
  b.push_back(uint8_t(v));
  b.push_back(uint8_t(v >> 8));
}
void le32(Bytes& b, uint32_t v) {
  for (int i = 0; i < 4; ++i) b.push_back(uint8_t(v >> (8 * i)));
}
void pad4(Bytes& b) {
  while (b.size() % 4) b.push_back(0);
}
void option(Bytes& b, uint16_t code, std::span<const uint8_t> value) {
  le16(b, code);
  le16(b, uint16_t(value.size()));
  b.insert(b.end(), value.begin(), value.end());
  pad4(b);
}
void option(Bytes& b, uint16_t code, std::string_view text) {
  option(b, code, std::span(reinterpret_cast<const uint8_t*>(text.data()), text.size()));
}
void end_of_options(Bytes& b) { le32(b, 0); }

// Block type, total length (patched), body, total length again.
Bytes block(uint32_t type, const Bytes& body) {
  Bytes b;
  uint32_t total = uint32_t(12 + body.size());
  le32(b, type);
  le32(b, total);
  b.insert(b.end(), body.begin(), body.end());
  le32(b, total);
  return b;
}

// The Internet checksum (RFC 1071) over `data`, starting from `sum`.
uint32_t sum16(std::span<const uint8_t> data, uint32_t sum = 0) {
  for (size_t i = 0; i + 1 < data.size(); i += 2) sum += uint32_t(data[i] << 8 | data[i + 1]);
  if (data.size() % 2) sum += uint32_t(data.back() << 8);
  return sum;
}
uint16_t fold(uint32_t sum) {
  while (sum >> 16) sum = (sum & 0xFFFF) + (sum >> 16);
  return uint16_t(~sum);
}
void be32(Bytes& b, uint32_t v) {
  for (int i = 3; i >= 0; --i) b.push_back(uint8_t(v >> (8 * i)));
}

constexpr uint8_t kFin = 0x01, kSyn = 0x02, kPsh = 0x08, kAck = 0x10;

}  // namespace

Bytes section_header(std::string_view application) {
  Bytes body;
  le32(body, 0x1A2B3C4D);
  le16(body, 1);
  le16(body, 0);
  le32(body, 0xFFFFFFFF);  // section length: not given (-1)
  le32(body, 0xFFFFFFFF);
  if (!application.empty()) option(body, 4, application);  // shb_userappl
  end_of_options(body);
  return block(0x0A0D0D0A, body);
}

Bytes interface_description(uint16_t linktype, std::string_view name, std::string_view description) {
  Bytes body;
  le16(body, linktype);
  le16(body, 0);
  le32(body, 0);  // snaplen: no limit
  if (!name.empty()) option(body, 2, name);                // if_name
  if (!description.empty()) option(body, 3, description);  // if_description
  const uint8_t tsresol[1] = {6};                           // microseconds
  option(body, 9, tsresol);
  end_of_options(body);
  return block(1, body);
}

Bytes enhanced_packet(uint32_t interface_id, uint64_t time_us, std::span<const uint8_t> data, int direction,
                      std::string_view comment) {
  Bytes body;
  le32(body, interface_id);
  le32(body, uint32_t(time_us >> 32));
  le32(body, uint32_t(time_us));
  le32(body, uint32_t(data.size()));
  le32(body, uint32_t(data.size()));
  body.insert(body.end(), data.begin(), data.end());
  pad4(body);
  bool any = false;
  if (direction == 1 || direction == 2) {
    Bytes flags;
    le32(flags, uint32_t(direction));
    option(body, 2, flags);  // epb_flags: inbound / outbound
    any = true;
  }
  if (!comment.empty()) {
    option(body, 1, comment);  // opt_comment
    any = true;
  }
  if (any) end_of_options(body);
  return block(6, body);
}

TcpConversation::TcpConversation(uint32_t client_ip, uint16_t client_port, uint32_t server_ip, uint16_t server_port)
    : ip_{client_ip, server_ip}, port_{client_port, server_port}, next_seq_{0x10000000u, 0x20000000u} {}

Bytes TcpConversation::handshake(int step) {
  if (step == 0) return frame(true, kSyn, {});
  if (step == 1) return frame(false, kSyn | kAck, {});
  return frame(true, kAck, {});
}

Bytes TcpConversation::data(bool from_client, std::span<const uint8_t> payload) {
  return frame(from_client, kPsh | kAck, payload);
}

Bytes TcpConversation::fin(bool from_client) { return frame(from_client, kFin | kAck, {}); }

Bytes TcpConversation::frame(bool from_client, uint8_t flags, std::span<const uint8_t> payload) {
  int me = from_client ? 0 : 1, peer = 1 - me;
  uint32_t seq = next_seq_[me];
  uint32_t ack = (flags & kAck) ? next_seq_[peer] : 0;
  next_seq_[me] += uint32_t(payload.size()) + ((flags & (kSyn | kFin)) ? 1 : 0);

  Bytes tcp;
  put_be16(tcp, port_[me]);
  put_be16(tcp, port_[peer]);
  be32(tcp, seq);
  be32(tcp, ack);
  tcp.push_back(5 << 4);  // data offset: 20 bytes, no options
  tcp.push_back(flags);
  put_be16(tcp, 65535);  // window
  put_be16(tcp, 0);      // checksum, below
  put_be16(tcp, 0);      // urgent pointer
  tcp.insert(tcp.end(), payload.begin(), payload.end());
  Bytes pseudo;
  be32(pseudo, ip_[me]);
  be32(pseudo, ip_[peer]);
  put_be16(pseudo, 6);
  put_be16(pseudo, uint16_t(tcp.size()));
  set_be16(tcp, 16, fold(sum16(tcp, sum16(pseudo))));

  Bytes ip;
  ip.push_back(0x45);
  ip.push_back(0);
  put_be16(ip, uint16_t(20 + tcp.size()));
  put_be16(ip, 0);       // identification
  put_be16(ip, 0x4000);  // don't fragment
  ip.push_back(64);      // TTL
  ip.push_back(6);       // TCP
  put_be16(ip, 0);
  be32(ip, ip_[me]);
  be32(ip, ip_[peer]);
  set_be16(ip, 10, fold(sum16(ip)));

  Bytes eth = {0x02, 0, 0, 0, 0, uint8_t(peer + 1), 0x02, 0, 0, 0, 0, uint8_t(me + 1), 0x08, 0x00};
  eth.insert(eth.end(), ip.begin(), ip.end());
  eth.insert(eth.end(), tcp.begin(), tcp.end());
  return eth;
}

}  // namespace mbc::pcapng
