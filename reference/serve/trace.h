// One line per frame for `mbconform serve --trace`: the bytes as hex and what
// they say (slave, function, address, quantity or value, exception code).
#pragma once

#include <cstdint>
#include <cstdio>
#include <map>
#include <span>
#include <string>
#include <string_view>

#include "modbus/pcapng.h"

#include "modbus/pdu.h"

namespace mbc::serve {

// "FC 03 read holding registers addr 0x0023 qty 1", "FC 83 exception 02 (illegal data address)".
std::string describe_pdu(std::span<const uint8_t> pdu, Direction dir);
// An RTU ADU: "slave 1 " + describe_pdu + " CRC ok|BAD".
std::string describe_rtu(std::span<const uint8_t> adu, Direction dir);

// What every trace line starts with: the wall-clock time in ISO 8601 UTC with
// microseconds and a space ("2026-12-01T22:54:29.123456Z "). A frame's line
// is then "LINK rx|tx HEX | what": the serial log format check-capture reads
// (conformance/capture/README.md, "Serial logs").
std::string trace_time();

// serve --pcap FILE: every frame received and sent, as pcapng
// (modbus/pcapng.h; conformance/capture/README.md): TCP links as Ethernet/IPv4/TCP
// from the client's address to port 502, RTU links (pty, RTU over TCP) as
// LINKTYPE_USER0 with a direction byte.
class PcapTrace {
 public:
  explicit PcapTrace(const std::string& path);  // throws std::runtime_error
  ~PcapTrace();
  PcapTrace(const PcapTrace&) = delete;
  PcapTrace& operator=(const PcapTrace&) = delete;
  // A frame on the link with descriptor `fd`, named `name` ("tcp 127.0.0.1:40112").
  void frame(int fd, bool mbap, std::string_view name, bool from_device, std::span<const uint8_t> bytes);
  void closed(int fd);

 private:
  void write(const Bytes& b);
  FILE* f_ = nullptr;
  int ethernet_ = -1, user0_ = -1;  // interface ids, made when first needed
  int next_interface_ = 0;
  std::map<int, pcapng::TcpConversation> conversations_;
};

}  // namespace mbc::serve
