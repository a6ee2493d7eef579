// The one exchange: a step sent through a Link with its wait policy, the
// bytes and the wire time counted; and a whole case run with it: each step
// sent and judged (judge.h), the registers it touches read before and written
// back after, a frame record per step for the reports.
#pragma once

#include <cstdint>
#include <optional>
#include <stdexcept>
#include <string>
#include <vector>

#include "check/check.h"
#include "check/judge.h"
#include "report/result.h"
#include "session/link.h"

namespace mbc::conf::check {

// The target went away (the Link gave up on it): the runner probes and
// reconnects; a replay stops there.
struct TargetLost : std::runtime_error {
  using std::runtime_error::runtime_error;
};

// What the last case met on the line: the runner decides from it whether to
// probe the target and which cases a late reply cancels.
struct LineState {
  bool silence = false;                   // some exchange was judged silent
  bool unanswered = false;                // a step that expected a reply got silence
  bool unanswered_after_silence = false;  // and its request followed an unanswered one
  Bytes last_request;                     // the last frame sent
  std::string last_what;                  // and what it was
};

// The one way a check, a property or the fuzzer sends: every frame through
// the Link (the session's frame policy and journal), counted.
class Exchange {
 public:
  // Counts every frame into `counters` (frames, bytes, latencies, silences,
  // the wire-time lower bound). The latencies kept are at most
  // `keep_latencies`: past that, a uniform sample of every answered exchange
  // counted into `counters` (reservoir sampling), so a percentile of them
  // stands for the whole run and a fuzz run of hours keeps a bounded list.
  Exchange(Link& link, DeviceRun& counters, size_t keep_latencies = SIZE_MAX);
  // Counts into counters() of its own (props, fuzz), without each frame's
  // latency (a fuzz run of hours would keep millions).
  explicit Exchange(Link& link);
  Exchange(const Exchange&) = delete;
  Exchange& operator=(const Exchange&) = delete;

  // Sends a frame or raw step. The wait: a reply that is expected is waited
  // for up to the timeout; an expected silence (or a step that records
  // whatever comes), and a reply the device's documentation says may not
  // come, get the silence window (a late reply re-runs the case, runner/).
  Sent send(const Step& st);
  // The same with the wait given (the fuzzer: the window for a generated
  // frame, the timeout for its probe; props: automatic).
  Sent send(const Step& st, Target::Wait wait);
  // Frame steps, pipelined where the Link pipelines (Modbus TCP; Link::transact_all),
  // one Sent each, in order.
  std::vector<Sent> send_all(std::span<const Step> steps, size_t depth, Target::Wait wait);
  // Quiet traffic (save and restore, liveness): up to the timeout.
  Sent quiet(uint8_t unit, std::span<const uint8_t> pdu);

  // For code that reads a reply or an exception (the properties): quiet()
  // to the target's unit, a refusal thrown as reply_or_throw (session/link.h) says.
  Reply transact(std::span<const uint8_t> pdu);
  const TargetInfo& info() const { return link_.info(); }
  bool trip_fault() { return link_.trip_fault(); }

  Link& link() { return link_; }
  DeviceRun& counters() { return counters_; }
  LineState line;

 private:
  void account(const Reply& r, int extra_gaps);
  void keep_latency(double us);
  Link& link_;
  DeviceRun own_;
  DeviceRun& counters_;
  bool latencies_ = true;
  size_t keep_latencies_ = SIZE_MAX;
  bool last_silent_ = false;
};

// Runs one case: every step sent and judged; the registers it touches (case
// `touches`, holding, rw in `spec`) read before and written back after.
// A step the Link refuses skips the case with the Link's reason.
// Throws TargetLost, or what the target threw.
CaseResult run_case(Exchange& x, const spec::Spec& spec, const Case& c);

// The result a case gets without running (--list, --plan, skipped cases).
CaseResult result_header(const Case& c);

// The wire-time lower bound of one frame of `bytes` at `baud`: its characters
// plus the t3.5 silence that must precede it (MB-SL v1.02 §2.5.1.1).
double frame_wire_seconds(size_t bytes, int baud);

}  // namespace mbc::conf::check
