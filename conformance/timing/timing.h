// RTU timing checks with figures (MB-SL v1.02 §2.5.1.1, §2.4.1): what a
// drive does in time on a serial line, judged from the moments the RTU
// target read each chunk of a reply (Reply::arrivals), where the cases of
// cases/ (frames and their contents) cannot look. Each check becomes one
// CaseResult in the run's report, like security/'s checks on mbtls://.
//
// A check is MUST only on a line that can measure it, else OBSERVED with
// the reason (README.md, "A line that can measure it"): bytes must arrive
// paced at the line's rate (a pty without a line model delivers a frame at
// once), and this host must see them finer than the silence judged (a USB
// adapter's latency timer batches them: read from sysfs, or found in the
// arrival times). Every figure errs toward the drive: a host that reads late
// only makes a turnaround look longer and hides an early reply, never makes
// one; a silence inside a reply is judged on the median reply, so one read
// held up by a busy host does not make it.
#pragma once

#include <chrono>
#include <cstdint>
#include <optional>
#include <string>
#include <vector>

#include "report/result.h"
#include "spec.h"
#include "session/link.h"
#include "targets/target.h"

namespace mbc::conf::timing {

using std::chrono::microseconds;

// The line as the checks see it.
struct LineFacts {
  bool serial = false;       // rtu:// (a serial line), not a gateway or TCP
  bool pty = false;          // a pseudo-terminal (a served line): paced only behind a line model
  int baud = 0;
  double char_us = 0;        // one character's time at the line's format (start, data, parity, stop bits)
  microseconds t15{0}, t35{0};  // MB-SL v1.02 §2.5.1.1 (fixed 750 us / 1.75 ms above 19200 baud)
  std::optional<int> latency_timer_ms;  // the adapter's, read on open (TargetInfo)
};
LineFacts line_facts(const TargetInfo&);

// One reply, timed. Figures in microseconds.
struct Timed {
  bool usable = false;    // a whole reply, no late frame in front, arrivals that add up
  bool paced = false;     // its bytes took at least their line time to come
  double turnaround = 0;  // from the request's end on the line to the reply's first character (an upper bound)
  double inner_gap = 0;   // the longest silence seen inside the reply (its reads' times less their characters')
  size_t echo = 0;        // bytes of the adapter's echo in front
  Bytes noise;            // bytes in front that were no frame
  size_t reads = 0;       // reads that held bytes of the reply
};
// `request_bytes`: the request as framed (its line time ends the request).
Timed measure(const Reply&, size_t request_bytes, const LineFacts&);

// The period of batches the replies' reads fall on (a latency timer of
// 2..16 ms), found in their arrival times: most reads fall just after a
// multiple of it on this host's monotonic clock (as serve --latency-timer
// delivers them; a real adapter's is read from sysfs). nullopt when they do
// not. The requests must not go out in a steady rhythm (check_line pauses a
// random time between them).
std::optional<int> batch_period_ms(const std::vector<Reply>&);

struct Options {
  int samples = 20;  // replies timed per function code
  int tries = 5;     // gapped requests sent (most answered: failed); requests sent t3.5 after a reply: 2 x tries
};

// Each check as --list shows it (its level on a line that can measure it).
struct CheckListing {
  std::string id, clause, title, requirement;
  Level level = Level::observed;
};
std::vector<CheckListing> check_listing();

// Runs every check against `t` (a serial RTU target); ids are
// "<device>/timing/<what>". Reads only: the spec's first readable register of
// each table its profile reads (FC 01-04).
std::vector<CaseResult> check_line(Link& t, const spec::Spec& s, const Options& o = {});

}  // namespace mbc::conf::timing
