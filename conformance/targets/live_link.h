// What the live target kinds (tcp_target.cpp, rtu_target.cpp) share: their
// URI parameters, the adaptive silence window, and reading a reply off a byte
// stream (a socket or a serial line) until the frame is complete or the line
// falls silent. Internal to conformance/targets/.
#pragma once

#include <chrono>
#include <cstdint>
#include <functional>
#include <memory>
#include <optional>
#include <span>
#include <string>
#include <vector>

#include "targets/target.h"

namespace mbc::conf::live {

using Clock = std::chrono::steady_clock;
using std::chrono::microseconds;
using std::chrono::milliseconds;

// `key` as an integer lo..hi, `fallback` when absent; std::invalid_argument
// naming the URI otherwise.
int int_param(const Uri& u, const std::string& uri, const std::string& key, int fallback, int lo, int hi);

// Rejects query keys the kind does not know (a typo must not pass silently).
void check_params(const Uri& u, const std::string& uri, std::initializer_list<const char*> known);

// How long to wait for a reply that may never come. Until enough replies were
// timed this is the configured timeout (1 s by default); then it is a bounded
// multiple of the observed p99 latency, never less than the line's frame gap
// plus a floor for the host's scheduling, never more than the timeout.
// Normal and exception replies are timed apart (a server may answer an
// exception far later than a read: libmodbus 3.1.6 sleeps its response
// timeout before an "illegal function" reply), and the window covers the
// slower of the two. A reply that arrives after its window closed widens it:
// to twice the latency it was seen with, when that is known, else doubled.
class SilenceWindow {
 public:
  // The floor covers scheduling jitter of the master's host (pty, loopback).
  static constexpr milliseconds kFloor{20};
  static constexpr int kLatencyMultiple = 4;
  static constexpr size_t kMinSamples = 5;
  static constexpr size_t kMaxSamples = 1024;

  SilenceWindow(milliseconds timeout, microseconds frame_gap, std::optional<milliseconds> fixed);
  void record(microseconds latency, bool exception = false);
  // A late reply; `seen` is how long after its request it was found, when known.
  void late_reply(std::optional<microseconds> seen = std::nullopt);
  microseconds window() const;
  microseconds timeout() const { return timeout_; }
  std::optional<microseconds> p99() const;
  size_t samples() const { return normal_.count + exception_.count; }
  uint64_t late_count() const { return late_; }

 private:
  struct Estimate {
    std::vector<int64_t> ring = std::vector<int64_t>(kMaxSamples);
    size_t count = 0;
    std::optional<microseconds> p99;
    void record(microseconds latency);
  };
  microseconds timeout_;
  microseconds frame_gap_;
  std::optional<milliseconds> fixed_;
  Estimate normal_, exception_;
  microseconds late_floor_{0};
  int widen_ = 1;
  uint64_t late_ = 0;
};

// Reads from `fd`, appending to `buf` (which may already hold bytes): waits
// until `first_byte_by` for a first byte, then until `complete(buf)` holds or
// nothing came for `end_silence` (the end of a frame whose length cannot be
// known, MB-SL v1.02 §2.5.1.1); never past `hard_deadline`. `closed` is set
// when the peer closed the stream.
struct ReadResult {
  Clock::time_point last_byte{};
  bool closed = false;
};
ReadResult read_frame(int fd, std::vector<uint8_t>& buf, Clock::time_point first_byte_by, microseconds end_silence,
                      Clock::time_point hard_deadline, const std::function<bool(std::span<const uint8_t>)>& complete);

// Reads and discards whatever is waiting on `fd` (a late reply); the count.
size_t drain(int fd);

// Writes all of `bytes`; throws std::runtime_error naming `what` on failure.
void write_all(int fd, std::span<const uint8_t> bytes, const std::string& what);

}  // namespace mbc::conf::live

namespace mbc::conf {
std::unique_ptr<Target> make_tcp_target(const Uri& u);  // tcp_target.cpp
std::unique_ptr<Target> make_rtu_target(const Uri& u);  // rtu_target.cpp: rtu and rtu-tcp
}  // namespace mbc::conf
