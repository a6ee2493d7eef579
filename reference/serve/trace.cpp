#include "serve/trace.h"

#include <fmt/core.h>

#include <arpa/inet.h>

#include <cerrno>
#include <chrono>
#include <cstring>
#include <ctime>
#include <stdexcept>

#include "modbus/bytes.h"
#include "modbus/crc16.h"
#include "modbus/function_codes.h"
#include "modbus/rtu.h"

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
  return fmt::format("slave {} {} CRC {}", adu[0], describe_pdu(kRtu.pdu_bytes(adu), dir),
                     crc_ok(adu) ? "ok" : "BAD");
}

std::string trace_time() {
  auto now = std::chrono::system_clock::now();
  auto us = std::chrono::duration_cast<std::chrono::microseconds>(now.time_since_epoch()).count();
  time_t secs = time_t(us / 1000000);
  std::tm tm{};
  gmtime_r(&secs, &tm);
  char buf[32];
  std::strftime(buf, sizeof buf, "%Y-%m-%dT%H:%M:%S", &tm);
  return fmt::format("{}.{:06d}Z ", buf, int(us % 1000000));
}

PcapTrace::PcapTrace(const std::string& path) {
  f_ = std::fopen(path.c_str(), "wb");
  if (!f_) throw std::runtime_error(fmt::format("--pcap {}: {}", path, std::strerror(errno)));
  write(pcapng::section_header("mbconform serve"));
}

PcapTrace::~PcapTrace() {
  if (f_) std::fclose(f_);
}

void PcapTrace::write(const Bytes& b) {
  std::fwrite(b.data(), 1, b.size(), f_);
  std::fflush(f_);  // a serve that is killed still leaves a readable capture
}

void PcapTrace::frame(int fd, bool mbap, std::string_view name, bool from_device, std::span<const uint8_t> bytes) {
  auto now = uint64_t(
      std::chrono::duration_cast<std::chrono::microseconds>(std::chrono::system_clock::now().time_since_epoch()).count());
  int dir = from_device ? 2 : 1;  // outbound from serve / inbound to it
  if (!mbap) {
    if (user0_ < 0) {
      user0_ = next_interface_++;
      write(pcapng::interface_description(pcapng::kLinkUser0, "serve RTU", "RTU ADUs; first byte: 0 to the device, 1 from it"));
    }
    Bytes p;
    p.push_back(from_device ? 1 : 0);
    p.insert(p.end(), bytes.begin(), bytes.end());
    write(pcapng::enhanced_packet(uint32_t(user0_), now, p, dir));
    return;
  }
  if (ethernet_ < 0) {
    ethernet_ = next_interface_++;
    write(pcapng::interface_description(pcapng::kLinkEthernet, "serve TCP",
                                        "Modbus TCP; the server drawn as 10.0.0.2:502, clients at their own address"));
  }
  auto it = conversations_.find(fd);
  if (it == conversations_.end()) {
    // "tcp 127.0.0.1:40112": the client's address; anything else is drawn as 10.0.0.1.
    uint32_t ip = 0x0A000001;
    uint16_t port = uint16_t(40000 + fd);
    auto sp = name.find(' '), colon = name.rfind(':');
    if (sp != std::string_view::npos && colon != std::string_view::npos && colon > sp) {
      std::string host(name.substr(sp + 1, colon - sp - 1));
      in_addr a{};
      if (inet_pton(AF_INET, host.c_str(), &a) == 1) ip = ntohl(a.s_addr);
      port = uint16_t(std::atoi(std::string(name.substr(colon + 1)).c_str()));
    }
    it = conversations_.emplace(fd, pcapng::TcpConversation(ip, port, 0x0A000002, 502)).first;
    for (int step = 0; step < 3; ++step)
      write(pcapng::enhanced_packet(uint32_t(ethernet_), now, it->second.handshake(step), step == 1 ? 2 : 1));
  }
  write(pcapng::enhanced_packet(uint32_t(ethernet_), now, it->second.data(!from_device, bytes), dir));
}

void PcapTrace::closed(int fd) {
  auto it = conversations_.find(fd);
  if (it == conversations_.end()) return;
  auto now = uint64_t(
      std::chrono::duration_cast<std::chrono::microseconds>(std::chrono::system_clock::now().time_since_epoch()).count());
  write(pcapng::enhanced_packet(uint32_t(ethernet_), now, it->second.fin(true), 1));
  write(pcapng::enhanced_packet(uint32_t(ethernet_), now, it->second.fin(false), 2));
  conversations_.erase(it);
}

}  // namespace mbc::serve
