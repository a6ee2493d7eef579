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
// timed this is the configured timeout (1 s by default); then it is the line
// time of the exchange plus a margin over the observed latencies, never more
// than the timeout. Only the first byte is waited for this long: a reply that
// started is read to its end.
// - With a line model (a serial line at a known baud), the line time of an
//   exchange is known: the request's and the reply's characters plus t3.5
//   before each (MB-SL v1.02 §2.5.1.1). Each latency is recorded as its
//   excess over that line time, and the window for a request is its line time
//   (with the longest reply the request can get) plus a margin over what
//   varies, not a multiple of the characters' fixed wire time: 2 x the p99
//   excess (the p99 and as much again, which covers the p99 plus its spread
//   over the median), at least kLineFloor until kTrustedSamples replies were
//   timed (the p99 of a few is their maximum), then at least the line's own
//   t3.5 (the standard names no turnaround a device must keep within; the
//   samples hold this host's and the device's).
// - Without one (Modbus TCP), the window is 4 x the p99 latency, at least
//   kFloor.
// Normal and exception replies are timed apart (a server may answer an
// exception far later than a read: libmodbus 3.1.6 sleeps its response
// timeout before an "illegal function" reply), and the window covers the
// slower of the two. A reply that arrives after its window closed widens it:
// to twice the latency it was seen with, when that is known, else doubled;
// the runner re-runs the cases judged silent since (runner.cpp).
class SilenceWindow {
 public:
  // The floor covers scheduling jitter of the master's host (pty, loopback).
  static constexpr milliseconds kFloor{20};
  static constexpr int kLatencyMultiple = 4;
  // With a line model: the samples already hold this host's jitter beyond
  // the line time; the floor is for what few samples do not show.
  static constexpr milliseconds kLineFloor{5};
  static constexpr int kExcessMultiple = 2;
  static constexpr size_t kMinSamples = 5;
  static constexpr size_t kTrustedSamples = 100;
  static constexpr size_t kMaxSamples = 1024;

  // `line_model`: the caller passes each exchange's line time to record() and
  // window(); `frame_gap`: the line's t3.5 (with a line model).
  SilenceWindow(milliseconds timeout, bool line_model, std::optional<milliseconds> fixed,
                microseconds frame_gap = microseconds(0));
  // `line`: the exchange's line time (with a line model).
  void record(microseconds latency, bool exception = false, microseconds line = microseconds(0));
  // A late reply; `seen` is how long after its request it was found, when known.
  void late_reply(std::optional<microseconds> seen = std::nullopt);

  // `line`: the line time of the request about to wait, with its longest reply.
  microseconds window(microseconds line = microseconds(0)) const;
  microseconds timeout() const { return timeout_; }
  std::optional<microseconds> p99() const;
  // The margin over an exchange's line time that replies were seen to need
  // (with a line model): what window() adds to the line time before a late
  // reply widened it; nullopt until kMinSamples replies were timed.
  std::optional<microseconds> margin() const;
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
  bool line_model_ = false;
  microseconds frame_gap_{0};
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
// `arrivals`, when given, gets each read as it came (when, how many bytes).
struct ReadResult {
  Clock::time_point last_byte{};
  bool closed = false;
};
ReadResult read_frame(int fd, std::vector<uint8_t>& buf, Clock::time_point first_byte_by, microseconds end_silence,
                      Clock::time_point hard_deadline, const std::function<bool(std::span<const uint8_t>)>& complete,
                      std::vector<Reply::Arrival>* arrivals = nullptr);

// Reads whatever is waiting on `fd` (a late reply); the count. The bytes
// are appended to `kept` when given, else discarded.
size_t drain(int fd, std::vector<uint8_t>* kept = nullptr);

// Writes all of `bytes`; throws std::runtime_error naming `what` on failure.
void write_all(int fd, std::span<const uint8_t> bytes, const std::string& what);

}  // namespace mbc::conf::live

namespace mbc::conf {
std::unique_ptr<Target> make_tcp_target(const Uri& u);  // tcp_target.cpp
std::unique_ptr<Target> make_rtu_target(const Uri& u);  // rtu_target.cpp: rtu and rtu-tcp
}  // namespace mbc::conf
