// Running conformance cases against a Target: each step is sent, its reply
// judged against the step's expectation (exact bytes, exception code,
// silence, register values), and everything kept for the reports (frames,
// latencies, byte counts, the wire-time lower bound). Registers a case writes
// are read before it and written back after it, so cases do not leak state.
#pragma once

#include <atomic>
#include <functional>
#include <optional>
#include <string>
#include <vector>

#include "cases/case.h"
#include "report/result.h"
#include "script/script.h"
#include "targets/target.h"

namespace mbc::conf {

struct RunOptions {
  // Called after every case (progress on the terminal).
  std::function<void(const CaseResult&, size_t done, size_t total)> on_case;
  // Set (e.g. by SIGINT) to stop after the current case; the run is marked interrupted.
  const std::atomic<bool>* stop = nullptr;
};

// Runs `cases` in order on `target`; the DeviceRun carries every result.
DeviceRun run_cases(Target& target, const spec::Spec& spec, const std::vector<Case>& cases, const RunOptions& = {});

// Whether a live target answers at all before a run: one read the spec says
// is answered, retried with a reconnect (kMaxTargetErrors tries). Empty when
// it answered, else why not (the run cannot be done: exit 2).
std::string unreachable(Target& target, const spec::Spec& spec);

// The result a case gets without running (--list, --plan, skipped cases).
CaseResult result_header(const Case& c);

// The wire-time lower bound of one frame of `bytes` at `baud`: its characters
// plus the t3.5 silence that must precede it (MB-SL v1.02 §2.5.1.1).
double frame_wire_seconds(size_t bytes, int baud);

// A case's step as a frame-script step (conformance/script/README.md), framed
// as it goes to a target of `info`, with its expectation.
script::Step to_script(const Step& st, const TargetInfo& info);
// Every step a case would send, as frame-script lines ("rtu 01 03 00 20 00 01
// 85 C0  -> normal   # read 0x0020 x1 (FC 03) | expect ..."); commented out
// when the case is skipped on this target.
std::vector<std::string> plan_lines(const Case& c, const TargetInfo& info);

}  // namespace mbc::conf
