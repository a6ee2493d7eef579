// Running checks against a Link: the runner orders the cases, runs one again
// when the line says its verdict cannot stand (a late reply, a split frame a
// busy host joined, a request that followed a silence), probes a target that
// stopped answering, and keeps the run's counts. Each case itself is run by
// check/exchange.h (send, judge, save and restore); the runner never calls
// back into a generator, so a plan read back from its text (check/text.h)
// runs exactly like the cases it was written from.
#pragma once

#include <atomic>
#include <functional>
#include <optional>
#include <string>
#include <vector>

#include "check/check.h"
#include "check/exchange.h"
#include "check/text.h"
#include "report/result.h"
#include "session/link.h"

namespace mbc::conf {

using check::Case;

struct RunOptions {
  // Called after every case (progress on the terminal).
  std::function<void(const CaseResult&, size_t done, size_t total)> on_case;
  // Set (e.g. by SIGINT) to stop after the current case; the run is marked interrupted.
  const std::atomic<bool>* stop = nullptr;
};

// Runs `cases` in order on `link`; the DeviceRun carries every result.
DeviceRun run_cases(Link& link, const spec::Spec& spec, const std::vector<Case>& cases, const RunOptions& = {});
// The same on a Target with no gate (DirectLink): in-process reference
// targets in tests and benchmarks.
DeviceRun run_cases(Target& target, const spec::Spec& spec, const std::vector<Case>& cases, const RunOptions& = {});

// Whether a live target answers at all before a run: one read the spec says
// is answered, retried with a reconnect (3 tries). Empty when it answered,
// else why not (the run cannot be done: exit 2).

// The cases whose id `filter` selects (`run --filter`). A filter matches
// literally, as a part of the id ("fc15/quantity-limit+1" selects that case
// and no other: '+' is a character of ids), unless it asks for a pattern:
// one holding '*' or '?' (which no id holds) is a glob, and "re:PATTERN" a
// regular expression. `pattern` turns the glob or the text after "re:" into
// a matcher (tools/mbconform/cmd_run.cpp's; default: fnmatch for a glob,
// ECMAScript regex search otherwise).
using Matcher = std::function<bool(const std::string&)>;
std::vector<Case> select_cases(std::vector<Case> cases, const std::string& filter,
                               const std::function<Matcher(const std::string&)>& pattern = {});

// What replaying a script came to.
struct ReplayResult {
  enum class Outcome { met, failed, cannot_run } outcome = Outcome::met;  // exit 0, 1, 2
  // Steps without a case (a reproducer, a regression): the step that failed
  // or cannot run, and why; they stop at the first miss.
  int line = 0;
  std::string message;
  bool target_lost = false;  // `failed` because the target went away (not a plugin's crash): INCOMPLETE
  std::vector<Reply> replies;
  // Cases (a plan): every one run the way `run` runs it, OBSERVED and
  // SHOULD outcomes recorded as such; `failed` when a MUST case failed.
  DeviceRun run;
};
// Whether every caseless step can run on a target of `info` (raw bytes in
// its framing, advance/power-cycle only in process); the first that cannot, with why.
std::optional<std::pair<int, std::string>> unsupported(const check::Script& s, const TargetInfo& info);
ReplayResult replay(Link& link, const check::Script& s, const spec::Spec* spec, const RunOptions& = {});

}  // namespace mbc::conf
