// The black-box fuzzer behind `mbconform fuzz`: structure-aware frames from
// a device's spec sent through check::Exchange over any Link (the command's
// Session: the frame policy, then the journal), every reply judged from the standard,
// each distinct finding reduced by delta debugging to a minimal reproducer
// in the frame-script format (conformance/check/README.md).
//
// Frames come from the spec: reads of its registers, writes of each
// register's valid and boundary values, the manual's example requests, and
// those frames with one field mutated (function code, address, quantity,
// byte count, value, length); with raw access (TargetInfo::raw) also
// malformed RTU framing (bad CRC, truncated, over-long, another slave id,
// broadcast, an inter-character gap). Each step carries the expectation the
// standard gives it (a reply, or silence); a reply to a frame that must stay
// silent is a finding even when it comes late, after its window (the target
// hands it over with a later exchange: Reply::late); after each batch a
// liveness probe (a read of a register the spec maps) must be answered normally.
//
// On a live RTU line other drives may answer frames for their own address:
// a reply to a frame for another slave id is a finding (answered-other-slave)
// only when it carries the target's address (check::reply_is_targets); in
// process the target is alone and every reply is its own. A target that
// throws and cannot be opened again is lost (Outcome::target_lost), which is
// no finding: `fuzz` says INCOMPLETE and exits 2.
//
// Safety with live drives: every frame the fuzzer makes is one the frame
// policy (policy/policy.h) lets out to this target, raw bytes judged by every
// frame a receiver could take from them; the session asks again before
// sending. The line settings are never written, even in-process.
#pragma once

#include <chrono>
#include <cstdint>
#include <functional>
#include <memory>
#include <optional>
#include <random>
#include <set>
#include <string>
#include <string_view>
#include <vector>

#include "policy/policy.h"
#include "check/exchange.h"
#include "check/judge.h"
#include "check/text.h"
#include "spec.h"
#include "targets/target.h"

namespace mbc::conf::blackbox {

using Step = check::Step;

// What a finding is. Its name (to_string) is stable: reports, JSON, the
// reproducers' file names and `fuzz --quirks` signatures use it.
enum class FindingKind : uint8_t {
  no_answer,                 // "no-answer": the liveness probe got no reply
  probe_refused,             // "probe-refused": the liveness probe got an exception or another reply
  malformed_framing,         // "malformed-framing": a reply whose framing is wrong (CRC, unit, length)
  malformed_reply,           // "malformed-reply": a reply PDU that breaks MBAP v1.1b3 §6 for its request
  unknown_exception_code,    // "unknown-exception-code": neither MBAP v1.1b3 §7 nor the spec knows the code
  answered_broadcast,        // "answered-broadcast": MB-SL v1.02 §2.1
  answered_other_slave,      // "answered-other-slave": the target answered a frame for another unit (MB-SL v1.02 §2.2)
  answered_corrupted_frame,  // "answered-corrupted-frame": MB-SL v1.02 §2.4.2
  target_error,              // "target-error": the target threw (connection lost, plugin error)
  crash,                     // "crash": the target's process died by a signal
  cannot_reopen,             // "cannot-reopen": the target could not be opened again
};
inline constexpr FindingKind kAllFindingKinds[] = {
    FindingKind::no_answer,           FindingKind::probe_refused,          FindingKind::malformed_framing,
    FindingKind::malformed_reply,     FindingKind::unknown_exception_code, FindingKind::answered_broadcast,
    FindingKind::answered_other_slave, FindingKind::answered_corrupted_frame, FindingKind::target_error,
    FindingKind::crash,               FindingKind::cannot_reopen};
const char* to_string(FindingKind);
std::optional<FindingKind> finding_kind(std::string_view name);

struct Finding {
  FindingKind kind = FindingKind::no_answer;
  std::string message;  // what was sent, what came, why it is wrong
};

// What the spec and the frame policy allow on one target.
struct Plan {
  const spec::Spec* spec = nullptr;
  TargetInfo info;
  WritePolicy policy;
  std::vector<const spec::Register*> readable, writable;
  std::vector<Bytes> examples;   // example request PDUs the policy lets out
  std::vector<uint8_t> functions;
  Bytes probe;                   // the liveness probe's PDU

  PolicyFacts facts() const { return PolicyFacts{spec, info, policy}; }
  bool line_setting(const spec::Register& r) const;
  bool writable_register(const spec::Register& r) const;
  // Whether a request PDU may be sent to `unit` (0 = broadcast): the frame
  // policy, and never FC 08/04 (Listen Only is a legal way to stop answering)
  // nor a write of a line setting.
  bool safe(uint8_t unit, std::span<const uint8_t> pdu) const;
  // The same for raw bytes, for every frame a receiver could take from them.
  bool safe_raw(std::span<const uint8_t> bytes, std::optional<size_t> gap) const;
};
// Throws std::runtime_error when the spec maps no register to probe.
Plan make_plan(const spec::Spec& s, const TargetInfo& info, const WritePolicy& policy);

// The liveness probe as a step (expects a normal reply).
Step probe_step(const Plan& p);
bool is_probe(const Step& s);
// The expectation the standard gives a generated step on this plan's target:
// silence for broadcast, another slave id or a corrupted frame (unless the
// spec's crc_error policy answers), else any well-formed reply.
check::Expect expect_for(const Plan& p, const Step& s);

// Judges one exchange from the standard (check::judge) and names the finding.
std::optional<Finding> judge(const Plan& p, const Step& s, const Reply& r);
// Runs one step through the exchange (the Link: the session's policy and
// journal): the probe waits for its reply, a generated frame the target's
// silence window. A target that throws (connection lost, plugin error), or a
// frame refused or stopped on the way, is a target-error finding.
// The exchange counts it (check::Exchange's counters).
std::optional<Finding> execute(check::Exchange& x, const Plan& p, const Step& s);

class Generator {
 public:
  Generator(const Plan& p, uint64_t seed) : p_(p), rng_(seed) {}
  Step next();  // with its expectation set

 private:
  uint64_t pick(uint64_t n) { return n ? rng_() % n : 0; }
  const spec::Register& any(const std::vector<const spec::Register*>& v) { return *v[pick(v.size())]; }
  Bytes valid_read();
  Bytes boundary_write();
  Bytes base();
  uint16_t interesting16(uint16_t near);
  Bytes mutate(Bytes pdu);
  std::optional<Step> malformed(const Bytes& pdu);

  const Plan& p_;
  std::mt19937_64 rng_;
};

// ddmin (Zeller & Hildebrandt 2002): a smaller sequence for which `fails`
// still holds, within `budget` calls of it (`runs` counts them).
template <class T>
std::vector<T> ddmin(std::vector<T> steps, const std::function<bool(const std::vector<T>&)>& fails, int budget, int& runs) {
  size_t n = 2;
  while (steps.size() >= 2 && runs < budget) {
    size_t chunk = (steps.size() + n - 1) / n;
    bool reduced = false;
    for (size_t i = 0; i < steps.size() && runs < budget; i += chunk) {
      std::vector<T> complement(steps.begin(), steps.begin() + long(i));
      complement.insert(complement.end(), steps.begin() + long(std::min(steps.size(), i + chunk)), steps.end());
      if (complement.empty()) continue;
      ++runs;
      if (fails(complement)) {
        steps = std::move(complement);
        n = std::max<size_t>(n - 1, 2);
        reduced = true;
        break;
      }
    }
    if (!reduced) {
      if (n >= steps.size()) break;
      n = std::min(n * 2, steps.size());
    }
  }
  return steps;
}

// Runs `fn` in a child process: a target in this process (a plugin) that
// crashes cannot take the fuzzer down; a child killed by a signal is a "crash".
std::optional<Finding> isolated(const std::function<std::optional<Finding>()>& fn);

// Starts the Link afresh (Session::restart: a new in-process target at
// power-on, a live connection reopened); throws when it cannot.
using Open = std::function<void()>;

// Whether a finding on a step is the one looked for.
using Wanted = std::function<bool(const Finding&, const Step&)>;
// Runs `steps` on `link` started afresh (`open`); the first finding (the first `wanted` one,
// going on past others while the target answers), if any. A target that
// cannot be opened again (a server that died) gives "cannot-reopen". Each
// step waits as it did while fuzzing (round() in engine.cpp): the probe for
// its reply, a generated frame only the target's silence window.
std::optional<Finding> run_fresh(Link& link, const Open& open, const Plan& p, const std::vector<Step>& steps,
                                 const Wanted& wanted = {});

struct Options {
  std::chrono::milliseconds duration{10'000};
  uint64_t seed = 0;
  int batch = 50;          // frames between two liveness probes
  // Requests out at once where the target pairs replies by itself (Modbus
  // TCP transaction ids; Target::transact_all); 1: one exchange at a time.
  size_t depth = 16;
  bool isolate = false;    // each round in a child process (plugin targets)
  std::string journal;     // isolate: the file the child writes each step to before sending it
  int reduce_budget = 400; // fresh-target runs per reduction; each costs a connection on live targets
  size_t history_cap = 20000;
  // Findings declared known (`fuzz --quirks`, by kind or signature, e.g.
  // "malformed-reply fc2B"): left aside, counted in Outcome::declared.
  std::function<bool(const std::string& signature)> declared;
  // Whether sending stopped (a stop signal, the command's deadline): a
  // reduction under way is cut off (Reported::cut_off) and its finding kept,
  // and a target error it causes is no finding.
  std::function<bool()> stopped;
};

struct Reported {
  Finding finding;
  std::string signature;     // what makes it distinct: kind and the function code it came on
  std::vector<Step> steps;   // the reduced reproducer
  bool reproduced = true;    // false: it did not reproduce on a fresh target; steps are the last batch, unreduced
  // Sending stopped before the reduction ended (Options::stopped): steps are
  // as far as it got (reproduced: they reproduce it, maybe not minimal;
  // else the last batch, unreduced, not yet reproduced on a fresh target).
  bool cut_off = false;
  int runs = 0;              // fresh-target runs the reduction took
  size_t history = 0;        // steps sent since the target was opened, when it was found
};

struct Outcome {
  long frames = 0, batches = 0, rounds = 0;
  double seconds = 0;  // time spent fuzzing (reductions left out)
  // What the fuzzing's exchanges (probes included; reductions left out)
  // counted, as check::Exchange counts every frame: frames, silences, bytes,
  // on a serial line at a known baud the wire-time bound (characters + t3.5
  // per frame, MB-SL v1.02 §2.5.1.1) and a sample of at most
  // kKeptLatencies reply latencies (request sent -> the reply's last byte).
  DeviceRun counters;
  static constexpr size_t kKeptLatencies = 100'000;
  // Their p99 once fuzzing ended: a silence costs a master at least that long
  // to call, which no wire-time bound counts.
  double reply_latency_p99_seconds = 0;
  // The wire-time bound plus the p99 reply latency for each exchange that
  // got no reply (bench/bench_run.cpp's second bound for the runner).
  double bound_with_silences_seconds() const {
    return counters.wire_time_bound_seconds + double(counters.silences) * reply_latency_p99_seconds;
  }
  double frames_per_second() const { return seconds > 0 ? double(frames) / seconds : 0; }
  std::vector<Reported> findings;  // each distinct finding once, in the order found
  long repeats = 0;                // findings of a signature already reported
  long declared = 0;               // findings Options::declared left aside
  bool target_lost = false;        // the target could not be opened again: fuzzing stopped early
};

// Fuzzes until the duration runs out: a finding is reduced (when its
// signature is new), reported through `on_finding`, and fuzzing goes on on a
// fresh target. Every frame goes through `link` (the session); round 0 runs
// on it as it is, every later round and reduction run after `open`.
Outcome fuzz(Link& link, const Open& open, const Plan& p, const Options& o,
             const std::function<void(const Reported&)>& on_finding);

// The reproducer of a finding as a frame script (comments say what was found).
check::Script reproducer(const Plan& p, const Reported& r, const std::string& replay_command);

}  // namespace mbc::conf::blackbox
