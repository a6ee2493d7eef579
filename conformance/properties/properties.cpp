// The property runner: RapidCheck around each invariant, one fresh target per
// generated case (ref:), the shrunk counterexample kept as regression lines.
#include "properties/properties.h"

#include <fmt/core.h>
#include <rapidcheck.h>

#include <algorithm>
#include <chrono>
#include <random>
#include <sstream>

#include "loader.h"
#include "modbus/crc16.h"
#include "modbus/judge.h"
#include "modbus/rtu.h"
#include "properties/stateful.h"
#include "session/session.h"

namespace mbc::conf::props {

check::Step Step::script() const {
  switch (kind) {
    case Kind::advance: {
      check::Step a = check::advance(advance_us);
      a.note = note;  // "trip: ..." marks a fault caused out of band (control properties)
      return a;
    }
    case Kind::power_cycle: return check::power_cycle();
    case Kind::frame: break;
  }
  check::Step s = frame.size() >= 4 && crc_ok(frame)
                       ? check::frame(framing, frame[0], rtu_unframe(frame).pdu)
                       : check::raw_rtu(frame);
  s.tid = tid;
  s.expect = expect;
  s.note = note;
  return s;
}

std::string Step::line() const {
  check::Step s = script();
  s.note.clear();
  return check::line(s);
}

namespace {
uint8_t unit_of(const PolicyFacts& f) { return f.target.unit; }

Step frame_step(const Reply& r, const TargetInfo& info, Bytes rtu, const std::string& note) {
  Step s;
  s.frame = std::move(rtu);
  s.framing = info.framing;
  if (info.framing == &mbc::kTcp && r.request.size() >= 2) s.tid = uint16_t(r.request[0] << 8 | r.request[1]);
  if (!r.silent()) s.reply = r.frame;
  s.reply_pdu = r.pdu;
  s.note = note;
  return s;
}
}  // namespace

Reply Session::send(std::span<const uint8_t> pdu, const std::string& note) { return send_to(unit(), pdu, note); }

Decision Session::allowed(std::span<const uint8_t> pdu) const {
  PolicyFacts f = view_.policy_facts();
  f.zeroed = zeroed_;
  return mbc::conf::allowed(f, unit_of(f), pdu);
}

Reply Session::send_to(uint8_t unit, std::span<const uint8_t> pdu, const std::string& note) {
  // Automatic: up to the timeout to the unit, the silence window otherwise.
  Reply r = reply_or_throw(x_.send(check::frame(x_.info().framing, unit, Bytes(pdu.begin(), pdu.end())), Target::Wait::automatic), x_.info());
  // A write the drive echoed: the control's set-points it made 0 (or not).
  if (unit == this->unit() && r.pdu && !r.pdu->empty() && !((*r.pdu)[0] & 0x80)) note_zeroed(spec(), pdu, zeroed_);
  // The model reads RTU frames; the step prints in the framing that was sent.
  steps_.push_back(frame_step(r, x_.info(), rtu_frame(unit, pdu), note));
  return r;
}

Reply Session::send_raw(std::span<const uint8_t> adu, const std::string& note) {
  Bytes bytes(adu.begin(), adu.end());
  check::Step st = x_.info().framing == &mbc::kRtu ? check::raw_rtu(bytes) : check::raw_mbap(bytes);
  Reply r = reply_or_throw(x_.send(st, Target::Wait::automatic), x_.info());
  steps_.push_back(frame_step(r, x_.info(), Bytes(adu.begin(), adu.end()), note));
  return r;
}

void Session::advance(uint64_t us, const std::string& note) {
  x_.link().advance(std::chrono::microseconds(us));
  Step s;
  s.kind = Step::Kind::advance;
  s.advance_us = us;
  s.note = note;
  steps_.push_back(s);
}

void Session::power_cycle() {
  x_.link().power_cycle();
  Step s;
  s.kind = Step::Kind::power_cycle;
  steps_.push_back(s);
}

const Invariant* find_invariant(const std::string& name) {
  for (const auto& i : invariants())
    if (i.name == name) return &i;
  return nullptr;
}

namespace {

std::vector<FrameRecord> records_of(const std::vector<Step>& steps) {
  std::vector<FrameRecord> out;
  for (const auto& s : steps) {
    FrameRecord f;
    f.step = s.note.empty() ? s.line() : s.note;
    if (s.kind == Step::Kind::frame) {
      check::Step sc = s.script();
      f.request = check::wire_bytes(sc, sc.kind == check::Step::Kind::raw ? &mbc::kRtu : s.framing);
      f.actual = s.reply;
      if (auto pdu = mbc::kRtu.pdu_bytes(s.frame); !pdu.empty()) f.request_decoded = describe_pdu(pdu, true);
      if (s.reply_pdu) f.actual_decoded = describe_pdu(*s.reply_pdu, false);
    }
    out.push_back(std::move(f));
  }
  return out;
}

// The properties report through CaseResult; RapidCheck's own listener would
// also print a "reproduce" line at exit for every falsified property.
struct QuietListener final : rc::detail::TestListener {
  void onTestCaseFinished(const rc::detail::CaseDescription&) override {}
  void onShrinkTried(const rc::detail::CaseDescription&, bool) override {}
  void onTestFinished(const rc::detail::TestMetadata&, const rc::detail::TestResult&) override {}
};

// RapidCheck's description is "file:line:\nRC_FAIL(...)\n\n<message>".
std::string failure_message(const std::string& description) {
  auto at = description.find("\n\n");
  std::string m = at == std::string::npos ? description : description.substr(at + 2);
  while (!m.empty() && m.back() == '\n') m.pop_back();
  return m;
}
// RapidCheck's reason for giving up on one line: "Generation failed with
// message: Failed to generate command after 100 tries." or the precondition
// "RC_PRE(!undefined.empty())" (without the file and the macro's expansion).
std::string why_gave_up(const std::string& description) {
  std::string line, out;
  std::istringstream in(description);
  while (std::getline(in, line)) {
    if (line == "Expands to:") break;
    if (line.empty() || (line.find(".cpp:") != std::string::npos && line.back() == ':')) continue;
    out += (out.empty() ? "" : " ") + line;
  }
  return out;
}
std::string what_failed(const std::string& description) {
  std::string m = failure_message(description);
  return m.substr(0, m.find('\n'));
}

// Empty when the target answers a liveness probe (after one reconnect),
// else why it is taken as lost.
std::string still_there(Link& t, const spec::Spec& spec) {
  Bytes probe = probe_request(spec);
  for (int attempt = 0; attempt < 2; ++attempt) {
    try {
      if (attempt) t.reconnect();
      Reply r = reply_or_throw(t.transact(t.info().unit, probe, Target::Wait::automatic), t.info());
      if (!r.silent()) return "";
    } catch (const std::logic_error&) {
      return "";  // the policy or the target cannot probe (Refused): nothing learnt, the verdict stands
    } catch (const std::exception& e) {
      return fmt::format("it no longer answers ({})", e.what());
    }
  }
  return "it no longer answers a liveness probe, even after a reconnect";
}

// The opt-in a skip is for: the flag which, given, makes the invariant
// apply on this target, asked of the invariant's own skip_reason with the
// flag granted (the frame policy then says what may be written), the flag the
// reason names first. Empty when no single flag would (a reason no opt-in
// lifts; a flag the reason names but which alone does not enable it: `alone`
// then says why, the reason with the flag given).
std::string opt_in_for(const Invariant& inv, const std::string& why, const spec::Spec& spec, const TargetInfo& info,
                       const WritePolicy& given, const DeviceFacts* facts, std::string& alone) {
  static const std::pair<const char*, bool WritePolicy::*> kFlags[] = {
      {"--allow-writes", &WritePolicy::allow_writes},         {"--allow-motion", &WritePolicy::allow_motion},
      {"--allow-eeprom-writes", &WritePolicy::allow_eeprom_writes}, {"--allow-broadcast", &WritePolicy::allow_broadcast},
      {"--allow-disruptive", &WritePolicy::allow_disruptive},
  };
  const std::string named = opt_in_named(why);
  auto lifts = [&](const char* flag, bool WritePolicy::*member) -> std::string {
    WritePolicy p = given;
    p.*member = true;
    std::string still = inv.skip_reason(SpecView(spec, info, p), info, facts);
    if (flag == named && !still.empty()) alone = still;
    return still.empty() ? flag : "";
  };
  for (const auto& [flag, member] : kFlags)
    if (flag == named && !(given.*member))
      if (std::string f = lifts(flag, member); !f.empty()) return f;
  for (const auto& [flag, member] : kFlags)
    if (flag != named && !(given.*member))
      if (std::string f = lifts(flag, member); !f.empty()) return f;
  return "";
}

}  // namespace

CaseResult run_invariant(const Invariant& inv, const TargetSource& source, const Options& options) {
  CaseResult c;
  c.family = "properties";
  c.level = Level::must;
  c.clause = inv.clause;
  c.requirement = inv.requirement;
  c.title = inv.name;
  auto t0 = std::chrono::steady_clock::now();
  Link& link = *source.link;
  const spec::Spec& spec = *source.spec;
  c.id = fmt::format("prop.{}.{}", inv.name, spec.device.id);
  const DeviceFacts* facts = facts_for(spec);
  const TargetInfo info = link.info();
  SpecView probe_view(spec, info, options.policy);
  if (std::string why = inv.skip_reason ? inv.skip_reason(probe_view, info, facts) : ""; !why.empty()) {
    c.outcome = Outcome::skip;
    c.message = why;
    // A MUST skipped for want of an opt-in makes the run PARTIAL (report/result.h's verdict()).
    std::string alone;
    c.opt_in = opt_in_for(inv, why, spec, info, options.policy, facts, alone);
    if (c.opt_in.empty() && !alone.empty()) c.message += fmt::format(" (and with {}: {})", opt_in_named(why), alone);
    return c;
  }
  const bool fresh_per_case = !info.live && source.afresh;

  uint64_t seed = options.seed;
  if (seed == 0) seed = std::random_device{}() | (uint64_t(std::random_device{}()) << 32);

  int runs = 0;
  std::vector<Step> last_failure;
  std::string last_failure_text;
  // Why the target was lost in the last failing run (a transport that threw:
  // the connection closed, the line gone), or empty: that run is no verdict.
  std::string lost;
  // On a live line every drive takes a broadcast write: the report names each one sent.
  nlohmann::json broadcasts = nlohmann::json::array();
  auto note_broadcasts = [&](const Session& session) {
    if (!info.live) return;
    for (const auto& st : session.steps())
      if (st.kind == Step::Kind::frame && st.frame.size() >= 2 && st.frame[0] == 0 && (st.frame[1] < 1 || st.frame[1] > 4))
        broadcasts.push_back(fmt::format("{} ({})", to_hex(st.frame), st.note));
  };
  // Frames the frame policy held back (a live target without the opt-in a
  // generated frame needs): that case is discarded, never a counterexample.
  // The device did nothing wrong; the property ran on the other cases.
  int held_back = 0;
  std::string first_held_back, held_back_opt_in;
  auto property = [&] {
    if (fresh_per_case) source.afresh();  // power-on state (throws Stopped after a stop)
    // One view for every run: RapidCheck keeps generated values (and the
    // stateful commands' model) across runs while it shrinks.
    Session session(link, probe_view, facts);
    ++runs;
    std::string gone;
    bool discarded = false;
    try {
      try {
        inv.check(session);
      } catch (const Refused& r) {
        if (held_back++ == 0) {
          first_held_back = r.refusal.reason;
          held_back_opt_in = r.refusal.opt_in;  // the gate's own word
        }
        discarded = true;
        note_broadcasts(session);
        RC_DISCARD("a generated frame the frame policy holds back");
      } catch (const RecoveredFault&) {
        throw;  // the thing under test failed the exchange: a verdict
      } catch (const std::runtime_error& e) {
        gone = e.what();  // the target is gone (Stopped too: sending stopped): no verdict
        throw;
      }
    } catch (...) {
      if (!discarded) {  // a discarded case is no failure to show
        last_failure = session.steps();
        lost = gone;
        note_broadcasts(session);
      }
      throw;
    }
    note_broadcasts(session);
  };

  rc::detail::TestParams params;
  params.seed = seed;
  params.maxSuccess = options.cases;
  params.maxSize = options.max_size;
  params.maxDiscardRatio = 10;
  rc::detail::TestMetadata meta;
  meta.id = c.id;
  meta.description = inv.requirement;
  QuietListener quiet;
  rc::detail::TestResult result = rc::detail::checkTestable(property, meta, params, quiet);
  // A live target that fails and then no longer answers (its connection
  // closed and cannot be opened again, a line gone) was lost: no verdict.
  rc::detail::FailureResult failure;
  if (lost.empty() && info.live && result.match(failure)) lost = still_there(link, spec);
  if (!broadcasts.empty()) c.extra["broadcast_writes"] = broadcasts;

  if (!probe_view.not_held().empty()) c.extra["not_held"] = probe_view.not_held();
  c.extra["seed"] = seed;
  c.extra["target"] = source.uri;
  rc::detail::SuccessResult ok;
  rc::detail::FailureResult failed;
  rc::detail::GaveUpResult gave_up;
  rc::detail::Error error;
  if (held_back) c.extra["held_back"] = held_back;
  if (result.match(ok)) {
    c.outcome = Outcome::pass;
    c.extra["cases"] = ok.numSuccess;
    c.message = fmt::format("{} generated cases passed (seed {})", ok.numSuccess, seed);
    if (held_back)
      c.message += fmt::format("; {} more held back by the frame policy (first: {})", held_back, first_held_back);
    // What the pass does not cover: facts the manual does not state.
    if (const auto& nh = probe_view.not_held(); !nh.empty())
      c.message += fmt::format("; {} fact{} the manual does not state (inferred, observed or printed two ways) not held "
                               "against the device, first: {}",
                               nh.size(), nh.size() == 1 ? "" : "s", nh.front());
  } else if (result.match(failed) && !lost.empty()) {
    // The target was lost (or sending stopped): INCOMPLETE, never "falsified".
    c.outcome = Outcome::error;
    c.extra["cases"] = failed.numSuccess;
    c.extra["target_lost"] = lost;
    c.message = fmt::format("INCOMPLETE: the target was lost after {} cases (seed {}): {}", failed.numSuccess, seed, lost);
  } else if (result.match(failed)) {
    c.outcome = Outcome::fail;
    c.extra["cases"] = failed.numSuccess + 1;
    std::ostringstream shown;
    for (const auto& [type, value] : failed.counterExample) shown << value << "\n";  // the generated values, as RapidCheck shows them
    std::vector<std::string> lines;
    for (const auto& s : last_failure) lines.push_back(s.line());
    c.extra["counterexample"] = lines;
    std::string fault;
    if (auto f = parse_uri(source.uri).param("fault")) fault = *f;
    c.extra["regression"] = format_regression(
        spec.device.id, fault,
        fmt::format("{} falsified against {} (seed {}, {} cases):\n{}", c.id, source.uri, seed, failed.numSuccess + 1,
                    what_failed(failed.description)),
        last_failure);
    c.extra["shrunk"] = shown.str();
    c.frames = records_of(last_failure);
    std::string frames;
    for (const auto& s : last_failure) {
      frames += "  " + s.line();
      if (s.kind == Step::Kind::frame) frames += s.reply ? "   got " + to_hex(*s.reply) : "   got silence";
      if (!s.note.empty()) frames += "   # " + s.note;
      frames += "\n";
    }
    c.message = fmt::format("falsified after {} cases (seed {}): {}\nshrunk counterexample ({} steps):\n{}",
                            failed.numSuccess + 1, seed, failure_message(failed.description), last_failure.size(), frames);
  } else if (result.match(gave_up)) {
    // Too few cases could be made or sent: no evidence against the device.
    c.outcome = Outcome::skip;
    c.extra["cases"] = gave_up.numSuccess;
    c.message = held_back ? fmt::format("skipped: the frame policy held back {} generated case{} ({} ran): {}", held_back,
                                        held_back == 1 ? "" : "s", gave_up.numSuccess, first_held_back)
                          : fmt::format("skipped: too few cases could be generated ({} ran): {}", gave_up.numSuccess,
                                        why_gave_up(gave_up.description));
    if (held_back) c.opt_in = held_back_opt_in;
    // Cases the generator discarded because the frame policy refused a frame
    // they needed: the opt-in refused most often.
    const auto& refused = probe_view.refused_opt_ins();
    if (c.opt_in.empty() && !refused.empty()) {
      auto most = std::max_element(refused.begin(), refused.end(), [](const auto& a, const auto& b) { return a.second < b.second; });
      c.opt_in = most->first;
      c.message += fmt::format(" (the frame policy refused the frames the cases needed, {} time{}: {})", most->second,
                               most->second == 1 ? "" : "s", c.opt_in);
    }
  } else if (result.match(error)) {
    c.outcome = Outcome::fail;
    c.message = "could not run: " + error.description;
  }
  c.extra["runs"] = runs;  // including shrinking
  c.duration_ms = std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count();
  return c;
}

std::vector<CaseResult> run_all(const TargetSource& source, const Options& options) {
  std::vector<CaseResult> out;
  for (const auto& inv : invariants()) {
    if (!options.only.empty() && std::find(options.only.begin(), options.only.end(), inv.name) == options.only.end())
      continue;
    out.push_back(run_invariant(inv, source, options));
  }
  return out;
}

TargetSource source_for(const std::string& uri, const spec::Spec* spec_override) {
  TargetSource s;
  s.uri = uri;
  std::unique_ptr<Target> first = open_target(uri);
  if (spec_override) {
    s.spec = spec_override;
  } else {
    if (first->info().device_id.empty())
      throw std::invalid_argument(fmt::format("target {}: give the device's spec (--device ID or --spec FILE)", uri));
    static std::map<std::string, std::unique_ptr<spec::Spec>> cache;  // specs outlive every source
    auto& slot = cache[first->info().device_id];
    if (!slot) slot = std::make_unique<spec::Spec>(spec::load_spec_by_id(first->info().device_id));
    s.spec = slot.get();
  }
  auto link = std::make_shared<DirectLink>(std::move(first));
  s.owned = link;
  s.link = link.get();
  if (!link->info().live) s.afresh = [uri, l = link.get()] { l->replace(open_target(uri)); };
  return s;
}

}  // namespace mbc::conf::props
