#include "runner/runner.h"

#include <fmt/core.h>

#include <chrono>

#include "cases/common.h"
#include "cases/facts.h"
#include "modbus/crc16.h"
#include "modbus/judge.h"
#include "modbus/limits.h"
#include "modbus/pdu.h"
#include "modbus/rtu.h"
#include "script/script.h"

namespace mbc::conf {
namespace {

using clock_type = std::chrono::steady_clock;
constexpr int kMaxTargetErrors = 3;

struct Exchange {
  Reply reply;
  Bytes request_pdu;  // what the reply is judged against
};

std::string hex_or_silence(const std::optional<Bytes>& b) { return b ? to_hex(*b) : "silence"; }

class CaseRunner {
 public:
  CaseRunner(Target& t, const spec::Spec& s, DeviceRun& run) : t_(t), s_(s), run_(run) {
    baud_ = t.info().baud;
  }

  // What the last case met on the line: the runner decides from it whether
  // to probe the target and which cases a late reply cancels.
  struct LineState {
    bool silence = false;             // some exchange was judged silent
    bool unanswered = false;          // a step that expected a reply got silence
    bool unanswered_after_silence = false;  // and its request followed an unanswered one
    Bytes last_request;               // the last frame sent
    std::string last_what;            // and what it was
  };
  LineState line;

  Exchange send(const Step& st) {
    Exchange x;
    // A reply that is expected is waited for up to the timeout; only an
    // expected silence (or a step that records whatever comes) gets the
    // window, and so does a reply the device's documentation says may not
    // come (a late one re-runs the case, run_cases).
    bool want_reply = st.expect.kind != Expect::Kind::silence && st.expect.kind != Expect::Kind::none;
    t_.set_wait(want_reply ? Target::Wait::reply : Target::Wait::automatic);
    if (st.expect.kind == Expect::Kind::silence || (want_reply && st.may_go_unanswered)) t_.set_wait(Target::Wait::window);
    bool after_silence = last_silent_;
    if (st.kind == Step::Kind::raw) {
      x.reply = t_.send_raw(st.adu, st.gap_after);
      if (st.adu.size() >= 4) x.request_pdu.assign(st.adu.begin() + 1, st.adu.end() - 2);
      account(x.reply, st.gap_after ? 1 : 0);
    } else {
      x.reply = t_.transact(st.unit, st.pdu);
      x.request_pdu = st.pdu;
      account(x.reply, 0);
    }
    line.last_request = x.reply.request;
    line.last_what = st.what;
    if (x.reply.silent()) {
      line.silence = true;
      line.unanswered |= want_reply;
      line.unanswered_after_silence |= want_reply && after_silence;
    }
    return x;
  }

  // One read the spec says is answered (any reply, even an exception, shows
  // the target is there); waits up to the timeout.
  bool alive() {
    Bytes probe = probe_request();
    t_.set_wait(Target::Wait::reply);
    Reply r = t_.transact(t_.info().unit, probe);
    account(r, 0);
    return !r.silent();
  }

  // Quiet traffic of the runner itself (per-case save and restore).
  std::optional<Bytes> quiet(uint8_t unit, const Bytes& pdu) {
    t_.set_wait(Target::Wait::reply);
    Reply r = t_.transact(unit, pdu);
    account(r, 0);
    return r.pdu;
  }

  CaseResult run(const Case& c) {
    line = LineState{};
    CaseResult res = result_header(c);
    auto t0 = clock_type::now();
    if (!c.skip_reason.empty()) {
      res.outcome = Outcome::skip;
      res.message = c.skip_reason;
      return res;
    }
    const auto& info = t_.info();
    for (const auto& st : c.steps) {
      if (st.kind == Step::Kind::advance && !info.virtual_clock) return skipped(res, "the target has no virtual clock");
      if (st.kind == Step::Kind::power_cycle && !info.power_cycle) return skipped(res, "the target cannot be power-cycled");
      if (st.kind == Step::Kind::raw && !info.raw) return skipped(res, "the target cannot send raw frames");
    }
    auto saved = save(c);

    std::vector<std::optional<Bytes>> replies;
    std::vector<std::string> failures;
    bool setup_failed = false;
    for (const auto& step : c.steps) {
      auto filled = cases::fill_words(step, step.words_from >= 0 && size_t(step.words_from) < replies.size()
                                                ? replies[size_t(step.words_from)] : std::nullopt);
      if (!filled) {  // what the target held could not be read: nothing is written back blind
        failures.push_back(fmt::format("{}: not sent: step {} read no value to write", step.what, step.words_from));
        replies.push_back(std::nullopt);
        continue;
      }
      const Step& st = *filled;
      FrameRecord fr;
      fr.step = st.what;
      fr.expected_text = cases::describe(st.expect);
      if (st.kind == Step::Kind::advance) {
        t_.advance(st.dt);
        replies.push_back(std::nullopt);
        res.frames.push_back(std::move(fr));
        continue;
      }
      if (st.kind == Step::Kind::power_cycle) {
        t_.power_cycle();
        replies.push_back(std::nullopt);
        res.frames.push_back(std::move(fr));
        continue;
      }
      Exchange x = send(st);
      if (cases::is_broadcast_write(st)) run_.broadcast_writes.push_back(fmt::format("{}: {}", c.id, st.what));
      fr.request = x.reply.request;
      fr.request_decoded = x.request_pdu.empty() ? "(not a frame)" : describe_pdu(x.request_pdu, true);
      if (!x.reply.silent()) fr.actual = x.reply.frame;
      if (x.reply.pdu) fr.actual_decoded = describe_pdu(*x.reply.pdu, false);
      else if (!x.reply.framing_error.empty()) fr.actual_decoded = x.reply.framing_error;
      fr.latency_us = double(x.reply.latency.count());
      if (st.expect.kind == Expect::Kind::exact) {
        fr.expected = st.expect.adu && info.framing == Framing::rtu ? *st.expect.adu : st.expect.pdu;
      } else if (st.expect.kind == Expect::Kind::exception && !x.request_pdu.empty()) {
        Bytes e{uint8_t(x.request_pdu[0] | 0x80), st.expect.code};
        fr.expected = info.framing == Framing::rtu && st.kind == Step::Kind::pdu ? rtu_frame(st.unit, e) : e;
      } else if (st.expect.kind == Expect::Kind::registers && !x.request_pdu.empty() &&
                 (x.request_pdu[0] == 3 || x.request_pdu[0] == 4)) {
        // MBAP v1.1b3 §6.3/§6.4: FC, byte count, the registers high byte first.
        Bytes e{x.request_pdu[0], uint8_t(2 * st.expect.words.size())};
        for (uint16_t w : st.expect.words) {
          e.push_back(uint8_t(w >> 8));
          e.push_back(uint8_t(w & 0xFF));
        }
        fr.expected = info.framing == Framing::rtu && st.kind == Step::Kind::pdu ? rtu_frame(st.unit, e) : e;
      } else if (st.expect.kind == Expect::Kind::unchanged && st.expect.memo >= 0 && size_t(st.expect.memo) < replies.size() &&
                 replies[st.expect.memo]) {
        const Bytes& e = *replies[st.expect.memo];
        fr.expected = info.framing == Framing::rtu && st.kind == Step::Kind::pdu ? rtu_frame(st.unit, e) : e;
      }
      if (fr.expected) {
        const Bytes& e = *fr.expected;
        bool adu = info.framing == Framing::rtu && e.size() >= 4 && crc_ok(e) && !(e.size() == 2);
        fr.expected_decoded = describe_pdu(adu ? std::span<const uint8_t>(e).subspan(1, e.size() - 3) : std::span<const uint8_t>(e), false);
      }
      std::string why = judge(st.expect, x, replies);
      if (!st.expect.either.empty()) {
        // Printed two ways: the step passes on any reading; record which one.
        std::string chosen = why.empty() ? st.expect.reading : "";
        for (const auto& alt : st.expect.either) {
          if (!chosen.empty()) break;
          if (judge(alt, x, replies).empty()) chosen = alt.reading;
        }
        if (!chosen.empty()) why.clear();
        res.extra["either"].push_back({{"step", st.what}, {"chose", chosen.empty() ? "neither reading" : chosen}});
      }
      replies.push_back(x.reply.pdu);
      if (!why.empty()) {
        if (st.setup) setup_failed = true;
        failures.push_back(fmt::format("{}{}: expected {}; got {}: {}", st.setup ? "setup: " : "", st.what,
                                       fr.expected_text, hex_or_silence(fr.actual), why));
      }
      res.frames.push_back(std::move(fr));
    }
    restore(saved);
    if (c.functions_optional && !failures.empty())
      if (auto fc = not_implemented(c, res, t_.info().framing); fc) {
        res.duration_ms = std::chrono::duration<double, std::milli>(clock_type::now() - t0).count();
        return skipped(res, fmt::format("the server does not implement FC {:02} (exception 01); every function is optional "
                                        "(MBAP v1.1b3 §5.1)", *fc));
      }
    res.duration_ms = std::chrono::duration<double, std::milli>(clock_type::now() - t0).count();
    if (failures.empty()) {
      res.outcome = c.level == Level::observed ? Outcome::observed : Outcome::pass;
      if (c.level == Level::observed) res.message = observed_summary(res);
    } else {
      res.outcome = c.level == Level::observed ? Outcome::observed : Outcome::fail;
      res.message = failures.front();
      if (failures.size() > 1) res.message += fmt::format(" (+{} more)", failures.size() - 1);
      if (c.level == Level::observed) res.message = "differs from the expectation: " + res.message;
      if (setup_failed && c.level != Level::observed) res.message = "could not establish the state: " + res.message;
    }
    return res;
  }

 private:
  CaseResult& skipped(CaseResult& r, const std::string& why) {
    r.outcome = Outcome::skip;
    r.message = why;
    return r;
  }

  // The function code a step was refused with exception 01 (illegal
  // function) for, when the step expected anything else. Only the code the
  // step sent counts: an exception 01 for another code (a raw frame the
  // server misread) answers nothing the step asked.
  static std::optional<int> not_implemented(const Case& c, const CaseResult& r, Framing framing) {
    const size_t fc_at = framing == Framing::rtu ? 1 : kMbapHeader;  // in the request as framed on the wire
    for (size_t i = 0; i < c.steps.size() && i < r.frames.size(); ++i) {
      const auto& f = r.frames[i];
      if (c.steps[i].expect.kind == Expect::Kind::exception && c.steps[i].expect.code == 1) continue;
      if (!f.actual || f.actual_decoded.empty() || f.request.size() <= fc_at) continue;
      const Bytes& a = *f.actual;
      // The PDU's last two bytes of an exception reply: FC | 0x80, 01 (RTU: before the CRC).
      size_t at = a.size() >= 4 && (a[a.size() - 4] & 0x80) && a[a.size() - 3] == 1 ? a.size() - 4
                  : a.size() >= 2 && (a[a.size() - 2] & 0x80) && a.back() == 1 ? a.size() - 2
                                                                                  : a.size();
      if (at < a.size() && f.request[fc_at] == (a[at] & 0x7F)) return f.request[fc_at];
    }
    return std::nullopt;
  }

  static std::string observed_summary(const CaseResult& r) {
    std::string s;
    for (const auto& f : r.frames) {
      if (f.request.empty()) continue;
      s += fmt::format("{}{} -> {}", s.empty() ? "" : "; ", f.step, f.actual ? (f.actual_decoded.empty() ? to_hex(*f.actual) : f.actual_decoded) : "silence");
    }
    return s.empty() ? "documented in the spec: " + r.title : s;
  }

  // Empty when the reply meets the expectation, else why not.
  std::string judge(const Expect& e, const Exchange& x, const std::vector<std::optional<Bytes>>& replies) {
    const Reply& r = x.reply;
    if (e.kind == Expect::Kind::none) return "";
    if (e.kind == Expect::Kind::silence) return r.silent() ? "" : "a reply came";
    if (r.silent()) return "no reply";
    if (!r.pdu) return "unusable reply: " + r.framing_error;
    const Bytes& pdu = *r.pdu;
    switch (e.kind) {
      case Expect::Kind::exact:
        if (pdu != e.pdu) return fmt::format("PDU differs (expected {})", to_hex(e.pdu));
        if (e.adu && t_.info().framing == Framing::rtu && r.frame != *e.adu)
          return fmt::format("frame differs (expected {})", to_hex(*e.adu));
        return "";
      case Expect::Kind::exception: {
        if (pdu.size() < 2 || !(pdu[0] & 0x80)) return "not an exception reply";
        if (!x.request_pdu.empty() && pdu[0] != (x.request_pdu[0] | 0x80))
          return fmt::format("exception to FC {:02X}, request was FC {:02X}", pdu[0] & 0x7F, x.request_pdu[0]);
        if (pdu[1] != e.code) return fmt::format("exception {:02X} instead of {:02X}", pdu[1], e.code);
        if (pdu.size() != 2) return "exception reply longer than 2 bytes";
        return "";
      }
      case Expect::Kind::normal:
      case Expect::Kind::registers: {
        Judged j = judge_reply(x.request_pdu, pdu);
        if (j.kind == Judged::Kind::exception) return fmt::format("exception {:02X}", j.exception_code);
        if (!j.ok()) return j.problems.empty() ? "malformed reply" : j.problems.front();
        if (e.kind == Expect::Kind::registers) {
          std::vector<uint16_t> got = j.registers;
          if (got.empty() && !j.bits.empty())
            for (bool b : j.bits) got.push_back(b ? 1 : 0);
          if (got != e.words) {
            std::string g;
            for (auto w : got) g += fmt::format("{}{:04X}", g.empty() ? "" : " ", w);
            return fmt::format("read [{}]", g);
          }
        }
        return "";
      }
      case Expect::Kind::answered: {
        uint8_t fc = x.request_pdu.empty() ? 0 : x.request_pdu[0];
        if (pdu.empty() || (pdu[0] & 0x7F) != fc) return fmt::format("reply to FC {:02X}, request was FC {:02X}", pdu.empty() ? 0 : pdu[0] & 0x7F, fc);
        if ((pdu[0] & 0x80) && pdu.size() != 2) return "exception reply longer than 2 bytes";
        return "";
      }
      case Expect::Kind::unchanged: {
        if (e.memo < 0 || size_t(e.memo) >= replies.size() || !replies[e.memo]) return "no earlier value to compare";
        if (pdu != *replies[e.memo]) return fmt::format("value changed (before: {})", to_hex(*replies[e.memo]));
        return "";
      }
      default: return "";
    }
  }

  struct Saved {
    const spec::Register* reg;
    std::vector<uint16_t> words;
  };

  // Reads the registers a case touches, so they can be put back.
  std::vector<Saved> save(const Case& c) {
    std::vector<Saved> out;
    if (c.touches.empty() || !cases::has_fc(s_, 3)) return out;
    for (auto [addr, n] : c.touches) {
      for (uint32_t a = addr; a < uint32_t(addr) + uint32_t(n) && a <= 0xFFFF;) {
        const spec::Register* r = s_.register_covering(uint16_t(a));
        if (!r) {
          ++a;
          continue;
        }
        a = r->last_address() + 1;
        if (r->access != spec::Access::rw) continue;
        bool dup = false;
        for (const auto& sv : out) dup |= sv.reg == r;
        if (dup) continue;
        Bytes req = read_request(3, r->address, uint16_t(r->words));
        auto pdu = quiet(t_.info().unit, req);
        if (!pdu) continue;
        Judged j = judge_reply(req, *pdu);
        if (j.ok() && j.kind == Judged::Kind::normal && int(j.registers.size()) == r->words)
          out.push_back({r, j.registers});
      }
    }
    return out;
  }

  void restore(const std::vector<Saved>& saved) {
    GenContext g{s_, t_.info(), {}, nullptr};
    for (const auto& sv : saved) {
      auto st = cases::write_step(g, *sv.reg, sv.words);
      if (st) quiet(t_.info().unit, st->pdu);
    }
  }

  // The first readable item the profile can read (FC 03/04/01/02), one item.
  Bytes probe_request() const {
    for (const auto& r : s_.registers) {
      if (r.access == spec::Access::wo || r.access == spec::Access::command) continue;
      int fc = r.table == spec::Table::holding ? 3 : r.table == spec::Table::input ? 4 : r.table == spec::Table::coil ? 1 : 2;
      if (cases::has_fc(s_, fc)) return read_request(uint8_t(fc), r.address, 1);
    }
    return read_request(3, 0, 1);
  }

  void account(const Reply& r, int extra_gaps) {
    last_silent_ = r.silent();
    run_.frames_sent++;
    run_.bytes_sent += r.request.size();
    run_.bytes_received += r.frame.size();
    if (!r.silent()) run_.latencies_us.push_back(double(r.latency.count()));
    else run_.silences++;
    if (baud_) {
      double b = frame_wire_seconds(r.request.size(), *baud_) +
                 extra_gaps * std::chrono::duration<double>(frame_gap(*baud_)).count();
      if (!r.silent()) b += frame_wire_seconds(r.frame.size(), *baud_);
      run_.wire_time_bound_seconds += b;
    }
  }

  Target& t_;
  const spec::Spec& s_;
  DeviceRun& run_;
  std::optional<int> baud_;
  bool last_silent_ = false;  // the last exchange got no reply
};

}  // namespace

double frame_wire_seconds(size_t bytes, int baud) {
  return std::chrono::duration<double>(wire_time(bytes, baud) + frame_gap(baud)).count();
}

CaseResult result_header(const Case& c) {
  CaseResult r;
  r.id = c.id;
  r.family = c.family;
  r.clause = c.clause;
  r.level = c.level;
  r.title = c.title;
  r.requirement = c.requirement;
  r.register_address = c.register_address;
  r.errata = c.errata;
  r.outcome = Outcome::skip;
  if (c.level_if_stated) r.extra["level_if_stated"] = to_string(*c.level_if_stated);
  // What the case relies on that the manual does not simply state.
  for (const auto& rel : facts::all_relies(c)) {
    if (rel.basis.basis == spec::Basis::stated) continue;
    r.extra[rel.basis.is_inferred() ? "inferred" : "printed_two_ways"].push_back(facts::describe(rel));
  }
  return r;
}

namespace {

// A late reply cancels the verdicts of the cases judged since the silence it
// belonged to; each case is re-run at most this often (a reply that comes
// later than every widened window keeps its last verdict).
constexpr int kMaxReruns = 2;

// A case with a split frame that got a reply runs again once with this pause
// inside the frame (at least ten times the first): a receiver that the host
// held up past the first pause may have read both parts as one frame, which
// says nothing of the device; one that joins them again does so for real.
constexpr std::chrono::milliseconds kSplitGapRecheck{250};

bool answered_a_split_frame(const Case& c, const CaseResult& r) {
  for (size_t k = 0; k < c.steps.size() && k < r.frames.size(); ++k)
    if (c.steps[k].kind == Step::Kind::raw && c.steps[k].gap_after && r.frames[k].actual) return true;
  return false;
}

std::string lost_message(const CaseRunner::LineState& line, const std::string& what) {
  return fmt::format("{} after the request {} ({}); the cause cannot be told from outside the device",
                     what, line.last_request.empty() ? "(none)" : to_hex(line.last_request), line.last_what);
}

}  // namespace

DeviceRun run_cases(Target& target, const spec::Spec& spec, const std::vector<Case>& cases, const RunOptions& opt) {
  DeviceRun run;
  run.device_id = spec.device.id;
  run.target_uri = target.info().uri;
  run.spec_path = spec.path;
  run.baud = target.info().baud;
  auto t0 = clock_type::now();
  CaseRunner runner(target, spec, run);
  const bool live = target.info().live;
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
        ok = runner.alive();
      } catch (const std::exception&) {
      }
      if (ok) {
        errors = 0;
        return failed;
      }
      if (++errors >= kMaxTargetErrors) return std::nullopt;
      target.reconnect();
    }
  };
  // Runs case k; one whose split frame was answered runs again with a
  // longer pause inside the frame, and that verdict stands (kSplitGapRecheck).
  auto run_case = [&](size_t k) {
    CaseResult r = runner.run(cases[k]);
    auto gap = target.split_gap();
    if (!live || !gap || r.outcome != Outcome::fail || !answered_a_split_frame(cases[k], r)) return r;
    auto longer = std::max<std::chrono::microseconds>(10 * *gap, kSplitGapRecheck);
    target.set_split_gap(longer);
    try {
      r = runner.run(cases[k]);
    } catch (...) {
      target.set_split_gap(*gap);
      throw;
    }
    target.set_split_gap(*gap);
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
    uint64_t late_before = target.late_replies();
    CaseResult res;
    bool transport_error = false;
    try {
      res = run_case(i);
      if (!live) errors = 0;
    } catch (const std::exception& e) {
      // The target threw (connection refused or reset, a device that cannot go on).
      transport_error = true;
      res = result_header(cases[i]);
      res.outcome = Outcome::fail;
      res.message = fmt::format("target error: {}", e.what());
      if (!dynamic_cast<const RecoveredFault*>(&e)) ++errors;  // a plugin's crash or hang: this case fails, the run goes on
    }
    saw_silence[i] = runner.line.silence;
    bool lost = !live && errors >= kMaxTargetErrors;
    if (live && (transport_error || runner.line.unanswered)) {
      // A request that should have been answered was not, or the transport
      // failed: is the target still there? A wedged connection (answers
      // again only after a reconnect) or a lost target is one FAIL of this
      // case, naming its last request: a device that dies on a request is a finding.
      if (transport_error) target.reconnect();
      std::optional<int> failed = probe();
      if (failed && *failed == 0 && !transport_error && runner.line.unanswered_after_silence && reruns[i] < kMaxReruns) {
        // The request went out as soon as the window of an unanswered one
        // closed: a receiver that a busy host held up (serve on a pty) may
        // have taken both as one frame. The target answers: run it again.
        ++reruns[i];
        try {
          CaseResult again = run_case(i);
          again.message += std::string(again.message.empty() ? "" : " ") +
                           "(re-run: a request that followed a silence went unanswered)";
          res = std::move(again);
          saw_silence[i] = runner.line.silence;
        } catch (const std::exception&) {
        }
      } else if (!failed || transport_error || *failed > 0) {
        lost = !failed;
        std::string detail = res.outcome == Outcome::fail && !res.message.empty() ? "; " + res.message : "";
        res.outcome = Outcome::fail;
        res.level = Level::must;
        res.message = lost ? lost_message(runner.line, "the target was lost") + detail
                           : lost_message(runner.line, transport_error ? "the connection failed" : "the connection stopped answering") +
                                 "; it answered again after a reconnect" + detail;
      }
    }
    run.cases.push_back(std::move(res));
    report(i);
    if (lost) {
      run.error = fmt::format("the target was lost during {} ({} errors in a row)", cases[i].id, kMaxTargetErrors);
      for (size_t k = i + 1; k < cases.size(); ++k) {
        CaseResult nr = result_header(cases[k]);
        nr.outcome = Outcome::error;
        nr.message = "not run: the target was lost";
        run.cases.push_back(std::move(nr));
      }
      break;
    }
    // A late reply: the silence it belonged to was no silence. Re-run from
    // the latest case judged silent up to this one, with the widened window.
    if (target.late_replies() > late_before) {
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
          saw_silence[k] = runner.line.silence;
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

script::Step to_script(const Step& st, const TargetInfo& info) {
  script::Step s;
  switch (st.kind) {
    case Step::Kind::pdu: s = script::frame(info.framing, st.unit, st.pdu); break;
    case Step::Kind::raw: s = script::raw_rtu(st.adu, st.gap_after); break;  // the framing cases' bytes are RTU
    case Step::Kind::advance: s = script::advance(uint64_t(st.dt.count())); break;
    case Step::Kind::power_cycle: s = script::power_cycle(); break;
  }
  using K = script::Expect::Kind;
  const Expect& e = st.expect;
  switch (e.kind) {
    case Expect::Kind::none: break;
    case Expect::Kind::exact: s.expect = {K::reply, e.pdu, 0}; break;
    case Expect::Kind::exception: s.expect = {K::exception, {}, e.code}; break;
    case Expect::Kind::silence: s.expect = {K::silence, {}, 0}; break;
    case Expect::Kind::normal: s.expect = {K::normal, {}, 0}; break;
    case Expect::Kind::registers:
      // A read reply holding exactly these words (MBAP v1.1b3 §6.3): the function code, the byte count, the words.
      if (st.kind == Step::Kind::pdu && !st.pdu.empty()) {
        Bytes r{st.pdu[0], uint8_t(2 * e.words.size())};
        for (uint16_t w : e.words) r.insert(r.end(), {uint8_t(w >> 8), uint8_t(w)});
        s.expect = {K::reply, r, 0};
      } else {
        s.expect = {K::normal, {}, 0};
      }
      break;
    case Expect::Kind::unchanged: s.expect = {K::normal, {}, 0}; break;  // equal to an earlier reply: checked by the runner only
    case Expect::Kind::answered: break;  // a normal reply or any exception: checked by the runner only
  }
  s.note = st.what;
  if (e.kind != Expect::Kind::none) s.note += " | " + cases::describe(e);
  if (st.setup) s.note += " (setup)";
  return s;
}

std::string unreachable(Target& target, const spec::Spec& spec) {
  DeviceRun scratch;
  CaseRunner runner(target, spec, scratch);
  std::string why = "no reply";
  for (int attempt = 0; attempt < kMaxTargetErrors; ++attempt) {
    if (attempt > 0) target.reconnect();
    try {
      if (runner.alive()) return "";
    } catch (const std::exception& e) {
      why = e.what();
    }
  }
  return fmt::format("{} does not answer ({} tries, with reconnects; last: {})", target.info().uri, kMaxTargetErrors, why);
}

std::vector<std::string> plan_lines(const Case& c, const TargetInfo& info) {
  std::vector<std::string> out;
  for (const auto& st : c.steps) out.push_back((c.skip_reason.empty() ? "" : "# ") + script::line(to_script(st, info)));
  return out;
}

}  // namespace mbc::conf
