// Reading a capture into Modbus frames: pcap and pcapng through libpcap, or a
// serial log in the timestamped-hex format (README.md). TCP streams are
// reassembled here (reader.cpp); each whole ADU found is handed to a
// FrameSink as it is found, so a capture of any size is read in bounded
// memory.
#pragma once
#include <cstdint>
#include <span>
#include <string>
#include <vector>

#include "modbus/bytes.h"

namespace mbc::conf::capture {

enum class Carrier { mbap, rtu };

// One Modbus ADU seen in a capture.
struct Frame {
  uint64_t time_us = 0;      // the capture's timestamp (Unix epoch, or from the log's start)
  uint64_t packet = 0;       // 1-based packet number (a log's line number)
  uint32_t stream = 0;       // the conversation it belongs to (a TCP connection, a log's link)
  std::string_view conversation;  // "10.0.0.1:5020 -> 10.0.0.2:502", valid during the call
  bool to_server = true;     // a request (towards port 502 / --port; a log's "rx")
  Carrier carrier = Carrier::mbap;
  bool timed_line = false;   // a serial log: timestamps are the line's, gaps can be judged
  Bytes adu;
};

// What made part of a capture unreadable as Modbus: reported, never fatal.
struct Finding {
  uint64_t packet = 0;
  std::string what;
};

class FrameSink {
 public:
  virtual ~FrameSink() = default;
  virtual void frame(const Frame&) = 0;
  virtual void finding(const Finding&) = 0;
  // The conversation ended (FIN, RST, evicted, end of file): requests still
  // waiting for a reply on it never got one.
  virtual void stream_end(uint32_t stream) = 0;
};

struct ReadOptions {
  std::vector<uint16_t> ports{502};  // server ports: Modbus TCP, or RTU over TCP found by its CRC
  size_t max_streams = 4096;         // open TCP conversations kept at once (the oldest is dropped)
};

struct ReadStats {
  std::string format;        // "pcap", "pcapng", "serial log"
  uint64_t packets = 0;      // packets (lines) read
  uint64_t bytes = 0;        // bytes of the file read
  uint64_t frames = 0;       // Modbus ADUs handed on
  uint64_t streams = 0;      // conversations seen
  std::string error;         // set when the file ended early or could not be read: one line
};

// Reads `path` (pcap, pcapng or a serial log, told apart by the first bytes).
// Never throws for bad content: what cannot be read is a Finding, and a file
// that stops reading (truncated, not a capture) sets `error`.
ReadStats read_capture(const std::string& path, const ReadOptions&, FrameSink&);
// The same from memory (the fuzz harness).
ReadStats read_capture_bytes(std::span<const uint8_t> data, const ReadOptions&, FrameSink&);

}  // namespace mbc::conf::capture
