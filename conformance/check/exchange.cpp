#include "check/exchange.h"

#include <fmt/core.h>
#include <fmt/ranges.h>

#include <algorithm>
#include <chrono>
#include <thread>

#include "modbus/crc16.h"
#include "modbus/judge.h"
#include "modbus/pdu.h"
#include "modbus/rtu.h"

namespace mbc::conf::check {

using clock_type = std::chrono::steady_clock;

double frame_wire_seconds(size_t bytes, int baud) {
  return std::chrono::duration<double>(wire_time(bytes, baud) + frame_gap(baud)).count();
}

Exchange::Exchange(Link& link, DeviceRun& counters, size_t keep_latencies)
    : link_(link), counters_(counters), keep_latencies_(keep_latencies) {}
Exchange::Exchange(Link& link) : link_(link), counters_(own_), latencies_(false) {}

namespace {
bool wants_reply(const Step& st) {
  return st.expect.kind != Expect::Kind::silence && st.expect.kind != Expect::Kind::none &&
         st.expect.kind != Expect::Kind::any_or_silence;
}
}  // namespace

Sent Exchange::send(const Step& st) {
  bool want_reply = wants_reply(st);
  Target::Wait wait = want_reply ? Target::Wait::reply : Target::Wait::automatic;
  if (st.expect.kind == Expect::Kind::silence || (want_reply && st.may_go_unanswered)) wait = Target::Wait::window;
  return send(st, wait);
}

std::vector<Sent> Exchange::send_all(std::span<const Step> steps, size_t depth, Target::Wait wait) {
  std::vector<Target::Request> requests;
  for (const auto& st : steps) requests.push_back({st.unit, st.pdu});
  std::vector<Sent> out = link_.transact_all(requests, depth, wait);
  for (size_t k = 0; k < out.size() && k < steps.size(); ++k) {
    if (out[k].refused) continue;
    account(out[k].reply, 0);
    line.last_request = out[k].reply.request;
    line.last_what = steps[k].note;
    if (out[k].reply.silent()) {
      line.silence = true;
      line.unanswered |= wants_reply(steps[k]);
    }
  }
  return out;
}

Reply Exchange::transact(std::span<const uint8_t> pdu) { return reply_or_throw(quiet(link_.info().unit, pdu), link_.info()); }

Sent Exchange::send(const Step& st, Target::Wait wait) {
  bool want_reply = wants_reply(st);
  bool after_silence = last_silent_;
  Sent s = st.kind == Step::Kind::raw ? link_.send_raw(st.bytes, st.gap, wait) : link_.transact(st.unit, st.pdu, wait);
  if (s.refused) return s;
  account(s.reply, st.kind == Step::Kind::raw && st.gap ? 1 : 0);
  line.last_request = s.reply.request;
  line.last_what = st.note;
  if (s.reply.silent()) {
    line.silence = true;
    line.unanswered |= want_reply;
    line.unanswered_after_silence |= want_reply && after_silence;
  }
  return s;
}

Sent Exchange::quiet(uint8_t unit, std::span<const uint8_t> pdu) {
  Sent s = link_.transact(unit, pdu, Target::Wait::reply);
  if (!s.refused) account(s.reply, 0);
  return s;
}

// Algorithm R over every answered exchange counted into counters_ (the
// n-th replaces a kept one with probability keep / n), with a fixed hash of
// n for the draw: the same run keeps the same sample.
void Exchange::keep_latency(double us) {
  auto& kept = counters_.latencies_us;
  if (kept.size() < keep_latencies_) {
    kept.push_back(us);
    return;
  }
  uint64_t n = counters_.frames_sent - counters_.silences;  // answered so far, this one included
  uint64_t z = n + 0x9E3779B97F4A7C15ull;  // splitmix64
  z = (z ^ (z >> 30)) * 0xBF58476D1CE4E5B9ull;
  z = (z ^ (z >> 27)) * 0x94D049BB133111EBull;
  z ^= z >> 31;
  if (uint64_t j = z % n; j < kept.size()) kept[j] = us;
}

void Exchange::account(const Reply& r, int extra_gaps) {
  last_silent_ = r.silent();
  counters_.frames_sent++;
  counters_.bytes_sent += r.request.size();
  counters_.bytes_received += r.frame.size();
  if (r.silent()) counters_.silences++;
  else if (latencies_) keep_latency(double(r.latency.count()));
  if (auto baud = link_.info().baud) {
    double b = frame_wire_seconds(r.request.size(), *baud) +
               extra_gaps * std::chrono::duration<double>(frame_gap(*baud)).count();
    if (!r.silent()) b += frame_wire_seconds(r.frame.size(), *baud);
    counters_.wire_time_bound_seconds += b;
  }
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
  for (const auto& rel : all_relies(c)) {
    if (rel.basis.basis == spec::Basis::stated) continue;
    r.extra[rel.basis.is_inferred() ? "inferred" : "printed_two_ways"].push_back(describe(rel));
  }
  return r;
}

namespace {

std::string hex_or_silence(const std::optional<Bytes>& b) { return b ? to_hex(*b) : "silence"; }

// Whether a Modbus TCP gateway is in front of the device: tcp://...?gateway=1,
// or a gateway the target recognised by its exception 0A/0B (tcp_target.cpp
// adds "gateway=1" to the URI then).
bool behind_gateway(const TargetInfo& i) {
  return i.framing == &mbc::kTcp && i.uri.find("gateway=1") != std::string::npos;
}

// A gateway's own exception (0A path unavailable, 0B target device failed to
// respond; MBAP v1.1b3 §7) to the step's request, where the step lets the
// device stay silent.
bool gateway_exception(const Step& st, const Bytes& pdu, uint8_t unit) {
  bool may_be_silent = st.expect.kind == Expect::Kind::silence || st.expect.kind == Expect::Kind::any_or_silence;
  for (const auto& e : st.expect.either) may_be_silent |= e.kind == Expect::Kind::silence;
  auto req = request_pdu(st, unit);
  return may_be_silent && pdu.size() == 2 && (pdu[0] & 0x80) && (pdu[1] == 0x0A || pdu[1] == 0x0B) &&
         (!req || req->empty() || (pdu[0] & 0x7F) == (*req)[0]);
}

bool has_fc(const spec::Spec& s, int fc) { return s.profile.function(fc) != nullptr; }

struct Saved {
  const spec::Register* reg;
  std::vector<uint16_t> words;
};

// Reads the registers a case touches, so they can be put back.
std::vector<Saved> save(Exchange& x, const spec::Spec& s, const Case& c) {
  std::vector<Saved> out;
  if (c.touches.empty() || !has_fc(s, 3)) return out;
  for (auto [addr, n] : c.touches) {
    for (uint32_t a = addr; a < uint32_t(addr) + uint32_t(n) && a <= 0xFFFF;) {
      const spec::Register* r = s.register_covering(uint16_t(a));
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
      Sent got = x.quiet(x.link().info().unit, req);
      if (!got.reply.pdu) continue;
      Judged j = judge_reply(req, *got.reply.pdu);
      if (j.ok() && j.kind == Judged::Kind::normal && int(j.registers.size()) == r->words) out.push_back({r, j.registers});
    }
  }
  return out;
}

// Writes back what save() read: FC 06 for one word when the profile has it,
// else FC 16 (holding registers only: save() reads FC 03). What could not be
// written back, one line each (a refused, unanswered or refused-by-the-drive
// write leaves the next case a state it did not expect, and the drive changed).
std::vector<std::string> restore(Exchange& x, const spec::Spec& s, const std::vector<Saved>& saved) {
  std::vector<std::string> failed;
  for (const auto& sv : saved) {
    Bytes pdu;
    if (sv.words.size() == 1 && has_fc(s, 6)) pdu = write_single_register(sv.reg->address, sv.words[0]);
    else if (has_fc(s, 16)) pdu = write_multiple_registers(sv.reg->address, sv.words);
    else continue;
    Sent got = x.quiet(x.link().info().unit, pdu);
    std::string why;
    if (got.refused) why = "not sent: " + got.refused->reason;
    else if (got.lost) why = "the target was lost";
    else if (!got.reply.pdu) why = "no reply";
    else if (Judged j = judge_reply(pdu, *got.reply.pdu); j.kind == Judged::Kind::exception)
      why = fmt::format("exception {:02X}", j.exception_code);
    else if (!j.ok()) why = j.problems.empty() ? "malformed reply" : j.problems.front();
    if (!why.empty())
      failed.push_back(fmt::format("0x{:04X} {}: writing back {:04X} after the case failed: {}", sv.reg->address,
                                   sv.reg->name.en.empty() ? sv.reg->name.zh : sv.reg->name.en, fmt::join(sv.words, " "), why));
  }
  return failed;
}

// The function code a step was refused with exception 01 (illegal
// function) for, when the step expected anything else. Only the code the
// step sent counts: an exception 01 for another code (a raw frame the
// server misread) answers nothing the step asked.
std::optional<int> not_implemented(const Case& c, const std::vector<std::optional<Bytes>>& replies, uint8_t unit) {
  for (size_t i = 0; i < c.steps.size() && i < replies.size(); ++i) {
    const Step& st = c.steps[i];
    if (st.expect.kind == Expect::Kind::exception && st.expect.code == 1) continue;
    if (!replies[i]) continue;
    auto req = request_pdu(st, unit);
    const Bytes& a = *replies[i];
    if (req && !req->empty() && a.size() == 2 && a[0] == ((*req)[0] | 0x80) && a[1] == 1) return (*req)[0];
  }
  return std::nullopt;
}

std::string observed_summary(const CaseResult& r) {
  std::string s;
  for (const auto& f : r.frames) {
    if (f.request.empty()) continue;
    s += fmt::format("{}{} -> {}", s.empty() ? "" : "; ", f.step,
                     f.actual ? (f.actual_decoded.empty() ? to_hex(*f.actual) : f.actual_decoded) : "silence");
  }
  return s.empty() ? "documented in the spec: " + r.title : s;
}

// A skipped case; `opt_in` the flag that would let it run (a refusal names
// it; a generator's reason says "needs --flag").
CaseResult& skipped(CaseResult& r, const std::string& why) {
  r.outcome = Outcome::skip;
  r.message = why;
  r.opt_in = opt_in_named(why);
  return r;
}

}  // namespace

CaseResult run_case(Exchange& x, const spec::Spec& spec, const Case& c) {
  x.line = LineState{};
  CaseResult res = result_header(c);
  auto t0 = clock_type::now();
  if (!c.skip_reason.empty()) return skipped(res, c.skip_reason);
  const TargetInfo& info = x.link().info();
  for (const auto& st : c.steps) {
    if (st.kind == Step::Kind::advance && !info.virtual_clock) return skipped(res, "the target has no virtual clock");
    if (st.kind == Step::Kind::power_cycle && !info.power_cycle) return skipped(res, "the target cannot be power-cycled");
    if (st.kind == Step::Kind::raw && !info.raw) return skipped(res, "the target cannot send raw frames");
    if (st.kind == Step::Kind::raw && st.framing != info.framing)
      return skipped(res, fmt::format("raw {} bytes; the target frames {}", st.framing == &mbc::kRtu ? "RTU" : "MBAP",
                                      info.framing == &mbc::kRtu ? "RTU" : "MBAP"));
  }
  auto saved = save(x, spec, c);

  std::vector<std::optional<Bytes>> replies;
  std::vector<std::string> failures;
  bool setup_failed = false;
  std::optional<Refusal> refused;
  JudgeContext ctx{info.unit, info.framing, &spec, {}};
  for (const auto& step : c.steps) {
    auto filled = fill_words(step, step.words_from >= 0 && size_t(step.words_from) < replies.size()
                                       ? replies[size_t(step.words_from)] : std::nullopt);
    if (!filled) {  // what the target held could not be read: nothing is written back blind
      failures.push_back(fmt::format("{}: not sent: step {} read no value to write", step.note, step.words_from));
      replies.push_back(std::nullopt);
      continue;
    }
    const Step& st = *filled;
    FrameRecord fr;
    fr.step = st.note;
    fr.expected_text = describe(st.expect);
    if (st.kind == Step::Kind::advance || st.kind == Step::Kind::wait) {
      if (info.virtual_clock || st.kind == Step::Kind::advance) x.link().advance(std::chrono::microseconds(st.us));
      else std::this_thread::sleep_for(std::chrono::microseconds(st.us));
      replies.push_back(std::nullopt);
      res.frames.push_back(std::move(fr));
      continue;
    }
    if (st.kind == Step::Kind::power_cycle) {
      x.link().power_cycle();
      replies.push_back(std::nullopt);
      res.frames.push_back(std::move(fr));
      continue;
    }
    Sent sent = x.send(st);
    if (sent.refused) {  // the gate held it back: no verdict, the case is skipped with its reason
      refused = sent.refused;
      break;
    }
    if (sent.lost) throw TargetLost(fmt::format("the target was lost at: {}", st.note));
    const Reply& reply = sent.reply;
    if (is_broadcast_write(st)) x.counters().broadcast_writes.push_back(fmt::format("{}: {}", c.id, st.note));
    auto req = request_pdu(st, info.unit);
    fr.request = reply.request;
    fr.request_decoded = req ? describe_pdu(*req, true) : "(not a frame)";
    if (!reply.silent()) fr.actual = reply.frame;
    if (reply.pdu) fr.actual_decoded = describe_pdu(*reply.pdu, false);
    else if (!reply.framing_error.empty()) fr.actual_decoded = reply.framing_error;
    fr.latency_us = double(reply.latency.count());
    ctx.earlier = replies;
    fr.expected = expected_bytes(st, ctx);
    if (fr.expected) {
      const Bytes& e = *fr.expected;
      bool adu = info.framing == &mbc::kRtu && e.size() >= 4 && crc_ok(e);
      fr.expected_decoded = describe_pdu(adu ? rtu_unframe(e).pdu : e, false);
    }
    auto miss = judge_expect(st.expect, st, reply, ctx);
    if (miss && behind_gateway(info) && reply.pdu && gateway_exception(st, *reply.pdu, info.unit)) {
      // Where the device stays silent (or may), the gateway in front of it
      // answers 0A/0B itself (MBAP v1.1b3 §7): the device's silence, said by
      // the gateway.
      miss.reset();
      res.extra["gateway"].push_back(fmt::format("{}: the gateway answered {} for the device, which stayed silent "
                                                 "(MBAP v1.1b3 §7: 0A/0B are a gateway's own)", st.note, to_hex(*reply.pdu)));
    } else if (miss && behind_gateway(info) && st.expect.kind == Expect::Kind::silence && reply.pdu && !reply.pdu->empty() &&
               !((*reply.pdu)[0] & 0x80)) {
      // A gateway that retries sends a request the device left unanswered
      // again; one that changed the device's state (Restart Communications
      // ends Listen Only Mode, MB-SL v1.02 §6.1.2) is answered the second
      // time. What comes back is the gateway's behaviour, not the device's.
      miss.reset();
      res.extra["gateway"].push_back(fmt::format("{}: {} came back where the device stays silent: a retrying gateway sent the "
                                                 "request again and the device answered the retry (the gateway's behaviour)",
                                                 st.note, to_hex(*reply.pdu)));
    }
    if (!st.expect.either.empty()) {
      // Printed two ways: the step passes on any reading; record which one.
      std::string chosen = judge_reading(st, reply, ctx);
      if (!chosen.empty()) miss.reset();
      res.extra["either"].push_back({{"step", st.note}, {"chose", chosen.empty() ? "neither reading" : chosen}});
    }
    replies.push_back(reply.pdu);
    if (miss) {
      if (st.setup) setup_failed = true;
      if (!res.cause) res.cause = Cause{miss->kind, miss->due, miss->did, req && !req->empty() ? std::optional<uint8_t>((*req)[0]) : std::nullopt};
      std::string got = reply.silent() && reply.closed ? "nothing" : hex_or_silence(fr.actual);
      failures.push_back(fmt::format("{}{}: expected {}; got {}: {}", st.setup ? "setup: " : "", st.note, fr.expected_text, got, miss->why));
    }
    res.frames.push_back(std::move(fr));
  }
  if (res.extra.contains("gateway")) {
    std::string note = fmt::format("a gateway is in front of the device ({}): where the device stays silent, its exception 0A/0B "
                                   "is accepted as the gateway's own answer (MBAP v1.1b3 §7), and a silence is waited for "
                                   "as long as the gateway takes to give up",
                                   x.counters().target_uri.find("gateway=1") != std::string::npos ? "gateway=1"
                                                                                                   : "detected from a 0A/0B reply");
    auto& notes = x.counters().notes;
    if (std::find(notes.begin(), notes.end(), note) == notes.end()) notes.push_back(note);
  }
  for (auto& f : restore(x, spec, saved)) {
    res.extra["restore_failed"].push_back(f);
    x.counters().restore_failures.push_back(fmt::format("{}: {}", c.id, f));
  }
  res.duration_ms = std::chrono::duration<double, std::milli>(clock_type::now() - t0).count();
  if (refused) {
    skipped(res, fmt::format("not sent: {}{}", refused->reason, refused->opt_in.empty() ? "" : " (" + refused->opt_in + ")"));
    res.opt_in = refused->opt_in;  // the gate's own word, not read from its sentence
    return res;
  }
  if (c.functions_optional && !failures.empty())
    if (auto fc = not_implemented(c, replies, info.unit))
      return skipped(res, fmt::format("the server does not implement FC {:02} (exception 01); every function is optional "
                                      "(MBAP v1.1b3 §5.1)", *fc));
  if (failures.empty()) {
    res.outcome = c.level == Level::observed ? Outcome::observed : Outcome::pass;
    if (c.level == Level::observed) res.message = observed_summary(res);
  } else {
    res.outcome = c.level == Level::observed ? Outcome::observed : Outcome::fail;
    res.message = failures.front();
    if (failures.size() > 1) res.message += fmt::format(" (+{} more)", failures.size() - 1);
    if (c.level == Level::observed && !c.incomparable.empty()) {
      // The device's own data against the values the source prints for a
      // state the bus cannot set: no comparison can be made.
      res.message = fmt::format("not comparable: {}; the device answered: {}", c.incomparable, observed_summary(res));
      res.extra["not_comparable"] = c.incomparable;
      res.cause.reset();
    } else if (c.level == Level::observed) {
      res.message = "differs from the expectation: " + res.message;
    }
    if (setup_failed && c.level != Level::observed) res.message = "could not establish the state: " + res.message;
  }
  return res;
}

}  // namespace mbc::conf::check
