// --pcap FILE: what went over the wire, as pcapng with real timestamps, for
// any command that talks to a Target (run, props, fuzz, client, replay). A tap
// wraps the Target and writes every request and reply it exchanges; the
// encoding is modbus/pcapng.h's (Modbus TCP in Ethernet/IPv4/TCP towards
// port 502; RTU as LINKTYPE_USER0 with one direction byte: README.md).
#pragma once
#include <cstdint>
#include <chrono>
#include <cstdio>
#include <functional>
#include <tuple>
#include <vector>
#include <memory>
#include <mutex>
#include <span>
#include <string>

#include "targets/target.h"

namespace mbc::conf::capture {

// One pcapng file being written; every tap of a command shares it.
class PcapFile {
 public:
  // Creates (truncates) `path`; throws std::runtime_error when it cannot.
  explicit PcapFile(const std::string& path);
  ~PcapFile();
  PcapFile(const PcapFile&) = delete;
  PcapFile& operator=(const PcapFile&) = delete;
  // A new interface (one per target); its id for packet().
  uint32_t add_interface(uint16_t linktype, const std::string& name, const std::string& description);
  // direction: 1 inbound (from the device), 2 outbound (to it).
  void packet(uint32_t interface_id, uint64_t time_us, std::span<const uint8_t> data, int direction);
  const std::string& path() const { return path_; }

 private:
  void write(std::span<const uint8_t> bytes);
  std::mutex mu_;
  std::string path_;
  FILE* f_ = nullptr;
  uint32_t interfaces_ = 0;
};

// `inner`, with every exchange also written to `file`.
std::unique_ptr<Target> tap(std::unique_ptr<Target> inner, std::shared_ptr<PcapFile> file);
// The one line a command adds: `path` empty returns `inner` unchanged; the
// same path shares one file for the whole process (several targets).
std::unique_ptr<Target> tap_pcap(std::unique_ptr<Target> inner, const std::string& path);

// `mbconform client --pcap`: a writer for ClientOptions::on_wire. Each
// scenario's frames (requests the scenario server saw, frames it sent), in
// time order; TCP as one conversation per scenario, RTU as USER0.
using ClientFrame = std::tuple<std::chrono::steady_clock::time_point, bool /*from the master*/, Bytes>;
std::function<void(std::vector<ClientFrame>)> client_pcap(const std::string& path, bool mbap, const std::string& name);

// The microseconds since the Unix epoch now (the pcap's timestamps).
uint64_t wall_clock_us();

}  // namespace mbc::conf::capture
