// Property tests of the profile invariants (issue 6), with RapidCheck. Each
// invariant is stated once, from the spec and the Modbus standard, and holds
// for every device whose spec has the feature it needs; it runs over any
// Link (session/link.h; the command's Session: its frame policy and journal),
// every frame through check::Exchange: the reference devices in ctest (`ref:ID`, and `ref:ID?fault=`
// to show it can fail), a live drive or a served device from
// `mbconform props --target URI`.
//
// A failing property is shrunk by RapidCheck to a minimal case; the frames of
// that case are kept as a frame script (conformance/check/README.md), with
// the seed, so it can be replayed with `mbconform replay` or any master, or
// added to regressions/.
#pragma once

#include <cstdint>
#include <functional>
#include <memory>
#include <optional>
#include <set>
#include <string>
#include <vector>

#include "properties/facts.h"
#include "properties/spec_view.h"
#include "report/result.h"
#include "safety/safety.h"
#include "check/exchange.h"
#include "check/judge.h"
#include "check/text.h"
#include "spec.h"
#include "session/link.h"
#include "targets/target.h"

namespace mbc::conf::props {

// One thing done to the target, as kept in a counterexample and in a
// regression file (a frame script: conformance/check/README.md).
struct Step {
  enum class Kind { frame, advance, power_cycle } kind = Kind::frame;
  Bytes frame;          // the frame as an RTU ADU (slave, PDU, CRC; possibly corrupted): what the model reads
  Framing framing = &mbc::kRtu;  // how the target framed it: how it is printed
  std::optional<uint16_t> tid;     // MBAP: the transaction id it went with
  uint64_t advance_us = 0;
  std::optional<Bytes> reply;      // as received, in the target's framing; nullopt = silence (frames only)
  std::optional<Bytes> reply_pdu;  // the reply's PDU, when its framing was valid
  check::Expect expect;           // what the model (from the spec) predicted for it
  std::string note;                // what the step meant ("write 0x0020 = 1000")
  // As a frame-script step: a frame with a valid CRC is a unit and a PDU,
  // printed in the framing it was sent in; a corrupted one is raw RTU bytes.
  check::Step script() const;
  std::string line() const;        // check::line(script()), without the note
};

// The target a property case runs on, plus the record of what was done.
// Every frame goes through one check::Exchange over the Link (the
// command's Session: the frame policy, then the journal). A frame the Link
// refuses throws Refused (the case is discarded: extra.held_back), one
// after sending stopped Stopped, a lost target std::runtime_error.
class Session {
 public:
  Session(Link& link, const SpecView& view, const DeviceFacts* facts) : x_(link), view_(view), facts_(facts) {}
  // The exchange, where a property needs the target itself: info(),
  // transact() (not recorded as a step), trip_fault(), link().
  check::Exchange& target() { return x_; }
  const SpecView& view() const { return view_; }
  const spec::Spec& spec() const { return view_.spec(); }
  const DeviceFacts* facts() const { return facts_; }
  uint8_t unit() const { return x_.info().unit; }

  Reply send(std::span<const uint8_t> pdu, const std::string& note = "");                    // to the unit
  Reply send_to(uint8_t unit, std::span<const uint8_t> pdu, const std::string& note = "");   // 0 = broadcast
  Reply send_raw(std::span<const uint8_t> adu, const std::string& note = "");
  void advance(uint64_t us, const std::string& note = "");
  void power_cycle();
  const std::vector<Step>& steps() const { return steps_; }
  // The expectation the model gave the last step sent (kept in counterexamples).
  void expect_last(check::Expect e) {
    if (!steps_.empty()) steps_.back().expect = std::move(e);
  }
  // The set-points of the spec's control modes this session wrote 0 (the
  // drive echoed the write): the frame policy lets a control command that
  // may move go out without --allow-motion while every one is here.
  const std::set<uint16_t>& zeroed() const { return zeroed_; }
  // Whether the frame policy lets `pdu` go out to the unit, with what this session knows.
  Decision allowed(std::span<const uint8_t> pdu) const;
  // send(), as the readers in spec_view.h take it.
  Transact transact() {
    return [this](std::span<const uint8_t> pdu, const std::string& note) { return send(pdu, note); };
  }

 private:
  check::Exchange x_;
  const SpecView& view_;
  const DeviceFacts* facts_;
  std::vector<Step> steps_;
  std::set<uint16_t> zeroed_;
};

struct Options {
  int cases = 100;        // generated cases per invariant
  uint64_t seed = 0;      // RapidCheck seed; 0 = pick one (printed in the result)
  int max_size = 100;     // RapidCheck's size bound (sequence length of the stateful property)
  WritePolicy policy;
  std::vector<std::string> only;  // invariant names; empty = all
};

// What to run on: every frame through `link` (a command's Session, or a
// DirectLink in tests). `afresh`, when set, starts the target afresh before
// each generated case (in-process targets: power-on state,
// Session::restart); unset: the same target throughout (a live one).
struct TargetSource {
  std::string uri;
  const spec::Spec* spec = nullptr;
  Link* link = nullptr;
  std::function<void()> afresh;
  std::shared_ptr<Link> owned;  // source_for's link
};

struct Invariant {
  std::string name;         // prop.<name>.<device>
  std::string clause;       // the standard clause / spec field it rests on
  std::string requirement;  // the requirement, as a sentence
  // Empty when it applies; else why it is skipped for this device/target.
  std::function<std::string(const SpecView&, const TargetInfo&, const DeviceFacts*)> skip_reason;
  // One generated case: generates with *rc::gen, fails with RC_FAIL.
  std::function<void(Session&)> check;
};
const std::vector<Invariant>& invariants();
const Invariant* find_invariant(const std::string& name);

// Runs one invariant on `source` and reports it as `prop.<name>.<device>`:
// extra.cases (generated cases run), extra.seed, extra.counterexample (the
// shrunk case's steps as regression lines) and extra.shrunk (RapidCheck's
// description of it).
CaseResult run_invariant(const Invariant& inv, const TargetSource& source, const Options& options);
std::vector<CaseResult> run_all(const TargetSource& source, const Options& options);

// A TargetSource for a URI with no policy or journal (a DirectLink: tests):
// ref: targets reopen per case; others are opened once.
TargetSource source_for(const std::string& uri, const spec::Spec* spec_override = nullptr);

}  // namespace mbc::conf::props
