#include "runner/runner.h"

#include <fmt/core.h>
#include <fnmatch.h>

#include <chrono>
#include <regex>
#include <thread>

#include "check/judge.h"
#include "modbus/pdu.h"
#include "session/session.h"

namespace mbc::conf {
namespace {

using clock_type = std::chrono::steady_clock;
constexpr int kMaxTargetErrors = 3;

// A late reply cancels the verdicts of the cases judged since the silence it
// belonged to; each case is re-run at most this often (a reply that comes
// later than every widened window keeps its last verdict).
constexpr int kMaxReruns = 2;

// A case with a split frame that got a reply runs again once with
// check::kSplitGapRecheck inside the frame (check/check.h).

bool answered_a_split_frame(const Case& c, const CaseResult& r) {
  for (size_t k = 0; k < c.steps.size() && k < r.frames.size(); ++k)
    if (c.steps[k].kind == check::Step::Kind::raw && c.steps[k].gap && r.frames[k].actual) return true;
  return false;
}

std::string lost_message(const check::LineState& line, const std::string& what) {
  return fmt::format("{} after the request {} ({}); the cause cannot be told from outside the device",
                     what, line.last_request.empty() ? "(none)" : to_hex(line.last_request), line.last_what);
}

bool alive(check::Exchange& x, const spec::Spec& s) {
  Sent got = x.quiet(x.link().info().unit, probe_request(s));
  if (got.lost) throw check::TargetLost("the target was lost");
  return got.refused || !got.reply.silent();
}

}  // namespace

DeviceRun run_cases(Link& link, const spec::Spec& spec, const std::vector<Case>& cases, const RunOptions& opt) {
  DeviceRun run;
  run.device_id = spec.device.id;
  run.target_uri = link.info().uri;
  run.spec_path = spec.path;
  run.baud = link.info().baud;
  auto t0 = clock_type::now();
  check::Exchange x(link, run);
  const bool live = link.info().live;
  std::vector<int> reruns(cases.size(), 0);
  std::vector<bool> saw_silence(cases.size(), false);
  // Transport errors and failed liveness probes in a row (never a silence a
  // case expected). Probes until the target answers, reconnecting between
  // tries: how many probes failed, or nullopt when the target is lost.
  int errors = 0;
  auto probe = [&]() -> std::optional<int> {
    for (int failed = 0;; ++failed) {
      bool ok = false;
      try {
        ok = alive(x, spec);
      } catch (const std::exception&) {
      }
      if (ok) {
        errors = 0;
        return failed;
      }
      if (++errors >= kMaxTargetErrors) return std::nullopt;
      link.reconnect();
    }
  };
  // Runs case k; one whose split frame was answered runs again with a
  // longer pause inside the frame, and that verdict stands (kSplitGapRecheck).
  auto run_case = [&](size_t k) {
    CaseResult r = check::run_case(x, spec, cases[k]);
    auto gap = link.split_gap();
    if (!live || !gap || r.outcome != Outcome::fail || !answered_a_split_frame(cases[k], r)) return r;
    auto longer = std::max<std::chrono::microseconds>(10 * *gap, check::kSplitGapRecheck);
    link.set_split_gap(longer);
    try {
      r = check::run_case(x, spec, cases[k]);
    } catch (...) {
      link.set_split_gap(*gap);
      throw;
    }
    link.set_split_gap(*gap);
    r.message += fmt::format("{}(re-run with {} ms inside the split frame: a {} ms pause was answered)",
                             r.message.empty() ? "" : " ", longer.count() / 1000, gap->count() / 1000);
    return r;
  };
  auto report = [&](size_t i) {
    if (opt.on_case) opt.on_case(run.cases[i], i + 1, cases.size());
  };
  for (size_t i = 0; i < cases.size(); ++i) {
    if (opt.stop && opt.stop->load()) {
      run.interrupted = true;
      break;
    }
    uint64_t late_before = link.late_replies();
    CaseResult res;
    bool transport_error = false;
    try {
      res = run_case(i);
      if (!live) errors = 0;
    } catch (const std::exception& e) {
      // The target threw (connection refused or reset, a device that cannot go on).
      transport_error = true;
      res = check::result_header(cases[i]);
      res.outcome = Outcome::fail;
      res.message = fmt::format("target error: {}", e.what());
      if (!dynamic_cast<const RecoveredFault*>(&e)) ++errors;  // a plugin's crash or hang: this case fails, the run goes on
    }
    saw_silence[i] = x.line.silence;
    bool lost = !live && errors >= kMaxTargetErrors;
    if (live && (transport_error || x.line.unanswered)) {
      // A request that should have been answered was not, or the transport
      // failed: is the target still there? A wedged connection (answers
      // again only after a reconnect) or a lost target is one FAIL of this
      // case, naming its last request: a device that dies on a request is a finding.
      if (transport_error) link.reconnect();
      std::optional<int> failed = probe();
      if (failed && *failed == 0 && !transport_error && x.line.unanswered_after_silence && reruns[i] < kMaxReruns) {
        // The request went out as soon as the window of an unanswered one
        // closed: a receiver that a busy host held up (serve on a pty) may
        // have taken both as one frame. The target answers: run it again.
        ++reruns[i];
        try {
          CaseResult again = run_case(i);
          again.message += std::string(again.message.empty() ? "" : " ") +
                           "(re-run: a request that followed a silence went unanswered)";
          res = std::move(again);
          saw_silence[i] = x.line.silence;
        } catch (const std::exception&) {
        }
      } else if (!failed || transport_error || *failed > 0) {
        lost = !failed;
        std::string detail = res.outcome == Outcome::fail && !res.message.empty() ? "; " + res.message : "";
        res.outcome = Outcome::fail;
        res.level = Level::must;
        res.message = lost ? lost_message(x.line, "the target was lost") + detail
                           : lost_message(x.line, transport_error ? "the connection failed" : "the connection stopped answering") +
                                 "; it answered again after a reconnect" + detail;
      }
    }
    run.cases.push_back(std::move(res));
    report(i);
    if (lost) {
      run.error = fmt::format("the target was lost during {} ({} errors in a row)", cases[i].id, kMaxTargetErrors);
      for (size_t k = i + 1; k < cases.size(); ++k) {
        CaseResult nr = check::result_header(cases[k]);
        nr.outcome = Outcome::error;
        nr.message = "not run: the target was lost";
        run.cases.push_back(std::move(nr));
      }
      break;
    }
    // A late reply: the silence it belonged to was no silence. Re-run from
    // the latest case judged silent up to this one, with the widened window.
    if (link.late_replies() > late_before) {
      size_t from = i;
      for (size_t k = i + 1; k-- > 0;)
        if (saw_silence[k]) {
          from = k;
          break;
        }
      for (size_t k = from; k <= i; ++k) {
        if (reruns[k] >= kMaxReruns) continue;
        ++reruns[k];
        try {
          CaseResult again = run_case(k);
          again.message = again.message.empty() ? "re-run after a late reply" : again.message + " (re-run after a late reply)";
          saw_silence[k] = x.line.silence;
          run.cases[k] = std::move(again);
          report(k);
        } catch (const std::exception&) {
          break;  // the next case meets the error again and handles it
        }
      }
    }
  }
  run.wall_seconds = std::chrono::duration<double>(clock_type::now() - t0).count();
  return run;
}

DeviceRun run_cases(Target& target, const spec::Spec& spec, const std::vector<Case>& cases, const RunOptions& opt) {
  DirectLink link(target);
  return run_cases(link, spec, cases, opt);
}

std::vector<Case> select_cases(std::vector<Case> cases, const std::string& f,
                               const std::function<Matcher(const std::string&)>& pattern) {
  if (f.empty()) return cases;
  Matcher keep;
  if (f.rfind("re:", 0) == 0) {
    if (pattern) {
      keep = pattern(f.substr(3));
    } else {
      std::regex re(f.substr(3), std::regex::ECMAScript);  // throws std::regex_error (a std::runtime_error)
      keep = [re](const std::string& id) { return std::regex_search(id, re); };
    }
  } else if (f.find_first_of("*?") != std::string::npos) {
    keep = pattern ? pattern(f) : Matcher([f](const std::string& id) { return fnmatch(f.c_str(), id.c_str(), 0) == 0; });
  } else {
    keep = [f](const std::string& id) { return id.find(f) != std::string::npos; };
  }
  std::vector<Case> out;
  for (auto& c : cases)
    if (keep(c.id)) out.push_back(std::move(c));
  return out;
}

std::optional<std::pair<int, std::string>> unsupported(const check::Script& sc, const TargetInfo& info) {
  const char* kind = info.framing == &mbc::kRtu ? "RTU" : "MBAP";
  for (const auto& s : sc.steps) {
    switch (s.kind) {
      case check::Step::Kind::raw:
        if (s.framing != info.framing)
          return std::pair{s.line, fmt::format("raw {} bytes cannot go to {}, whose frames are {}",
                                               s.framing == &mbc::kRtu ? "RTU" : "MBAP", info.uri, kind)};
        if (!info.raw) return std::pair{s.line, info.uri + " cannot send raw bytes"};
        if (s.gap && info.framing != &mbc::kRtu) return std::pair{s.line, "a pause inside a frame needs an RTU target"};
        break;
      case check::Step::Kind::advance:
        if (!info.virtual_clock) return std::pair{s.line, info.uri + " has no virtual clock to advance (in-process targets only)"};
        break;
      case check::Step::Kind::power_cycle:
        if (!info.power_cycle) return std::pair{s.line, info.uri + " cannot be power-cycled from here (in-process targets only)"};
        break;
      default:
        break;
    }
  }
  return std::nullopt;
}

ReplayResult replay(Link& link, const check::Script& sc, const spec::Spec* spec, const RunOptions& opt) {
  ReplayResult res;
  const TargetInfo& info = link.info();
  if (auto u = unsupported(sc, info)) {
    res.outcome = ReplayResult::Outcome::cannot_run;
    res.line = u->first;
    res.message = u->second;
    return res;
  }
  // Steps without a case: each judged as it comes; the first miss stops the
  // replay and is named by its line (a reproducer shows one failure).
  check::JudgeContext ctx{info.unit, info.framing, spec, {}};
  ctx.shared_line = info.live;  // other drives of the line answer their own frames
  std::vector<std::optional<Bytes>> earlier;
  check::Exchange x(link, res.run);
  for (const auto& s : sc.steps) {
    try {
      switch (s.kind) {
        case check::Step::Kind::advance: link.advance(std::chrono::microseconds(s.us)); continue;
        case check::Step::Kind::power_cycle: link.power_cycle(); continue;
        case check::Step::Kind::wait:
          if (info.virtual_clock) link.advance(std::chrono::microseconds(s.us));
          else std::this_thread::sleep_for(std::chrono::microseconds(s.us));
          continue;
        default: break;
      }
      Sent sent = x.send(s);
      if (sent.refused) {
        res.outcome = ReplayResult::Outcome::cannot_run;
        res.line = s.line;
        res.message = "not sent: " + sent.refused->reason + (sent.refused->opt_in.empty() ? "" : " (" + sent.refused->opt_in + ")");
        return res;
      }
      const Reply& r = sent.reply;
      res.replies.push_back(r);
      ctx.earlier = earlier;
      if (auto m = check::judge(s, r, ctx)) {
        res.outcome = ReplayResult::Outcome::failed;
        res.line = s.line;
        res.message = fmt::format("{}\n  sent:     {}\n  expected: {}\n  got:      {}", m->why, to_hex(r.request),
                                  check::expect_text(s.expect),
                                  r.silent() ? std::string(r.closed ? "(the connection closed)" : "(silence)") : to_hex(r.frame));
        return res;
      }
      earlier.push_back(r.pdu);
    } catch (const std::logic_error& e) {
      res.outcome = ReplayResult::Outcome::cannot_run;
      res.line = s.line;
      res.message = e.what();
      return res;
    } catch (const std::exception& e) {
      // A plugin that crashed or hung on a step failed it; a target that went
      // away (the transport threw) is lost: no verdict (INCOMPLETE).
      res.outcome = ReplayResult::Outcome::failed;
      res.target_lost = !dynamic_cast<const RecoveredFault*>(&e);
      res.line = s.line;
      res.message = fmt::format("the target failed: {}", e.what());
      return res;
    }
  }
  if (sc.cases.empty()) return res;
  // Cases: run exactly as `run` runs them (the same runner, the same judge).
  DeviceRun counted = std::move(res.run);
  static const spec::Spec kNoSpec{};
  res.run = run_cases(link, spec ? *spec : kNoSpec, sc.cases, opt);
  res.run.frames_sent += counted.frames_sent;
  res.run.bytes_sent += counted.bytes_sent;
  res.run.bytes_received += counted.bytes_received;
  for (const auto& c : res.run.cases)
    if (c.outcome == Outcome::fail && c.level == Level::must && c.quirk.empty()) res.outcome = ReplayResult::Outcome::failed;
  return res;
}

}  // namespace mbc::conf
