#include "blackbox/engine.h"

#include <fmt/core.h>
#include <sys/wait.h>
#include <unistd.h>

#include <algorithm>
#include <cstdio>
#include <cstring>
#include <fstream>
#include <sstream>

#include "blackbox/spec_values.h"
#include "modbus/bytes.h"
#include "modbus/crc16.h"
#include "modbus/function_codes.h"
#include "modbus/judge.h"
#include "modbus/limits.h"
#include "modbus/pdu.h"
#include "modbus/rtu.h"
#include "policy/policy.h"
#include "targets/percentile.h"

namespace mbc::conf::blackbox {

namespace {

constexpr const char* kProbeNote = "liveness probe: a read of a register the spec maps";
// Probes a round starts with on a live target: as many replies as a silence
// window needs timed before it is learnt (live::SilenceWindow::kMinSamples).
constexpr int kWarmupProbes = 5;
// The pause inside a split frame that was answered, for its second try, is
// the runner's: check::kSplitGapRecheck (check/check.h).

// After these the target may be gone: nothing more is learnt from it.
bool target_may_be_gone(const Finding& f) {
  return f.kind == FindingKind::no_answer || f.kind == FindingKind::target_error || f.kind == FindingKind::crash;
}

}  // namespace

const char* to_string(FindingKind k) {
  switch (k) {
    case FindingKind::no_answer: return "no-answer";
    case FindingKind::probe_refused: return "probe-refused";
    case FindingKind::malformed_framing: return "malformed-framing";
    case FindingKind::malformed_reply: return "malformed-reply";
    case FindingKind::unknown_exception_code: return "unknown-exception-code";
    case FindingKind::answered_broadcast: return "answered-broadcast";
    case FindingKind::answered_other_slave: return "answered-other-slave";
    case FindingKind::answered_corrupted_frame: return "answered-corrupted-frame";
    case FindingKind::target_error: return "target-error";
    case FindingKind::crash: return "crash";
    case FindingKind::cannot_reopen: return "cannot-reopen";
  }
  return "?";
}

std::optional<FindingKind> finding_kind(std::string_view name) {
  for (FindingKind k : kAllFindingKinds)
    if (name == to_string(k)) return k;
  return std::nullopt;
}

// ---- what the spec and the frame policy allow ----

// A line setting written would take even an in-process device off the line:
// every later frame would go unanswered, a finding of the fuzzer, not of the
// device. The fuzzer leaves them alone on every target (on a live one the
// frame policy never sends them anyway).
bool Plan::line_setting(const spec::Register& r) const { return spec::is_line_setting(role_of(*spec, r)); }

bool Plan::writable_register(const spec::Register& r) const {
  if (r.access == spec::Access::ro || r.table == spec::Table::input || r.table == spec::Table::discrete_input) return false;
  return !line_setting(r) && allowed_write(facts(), r);  // a simulation (not live) allows everything
}

bool Plan::safe(uint8_t unit, std::span<const uint8_t> pdu) const {
  if (pdu.empty()) return true;
  // MB-SL v1.02 §6.1.2 (FC 08/04): Listen Only Mode is a legal way to stop
  // answering; the liveness probe would call it a finding.
  if (pdu[0] == 8 && pdu.size() >= 3 && be16(pdu, 1) == 4) return false;
  if (auto w = writes_of(pdu); w && w->table == spec::Table::holding)
    for (uint32_t a = w->address; a < uint32_t(w->address) + uint32_t(w->count) && a <= 0xFFFF; ++a)
      if (const auto* r = spec->register_covering(uint16_t(a)); r && line_setting(*r)) return false;
  return bool(allowed(facts(), unit, pdu));
}

bool Plan::safe_raw(std::span<const uint8_t> bytes, std::optional<size_t> gap) const {
  for (const auto& [unit, pdu] : frames_in(info.framing, bytes, gap))
    if (!safe(unit, pdu)) return false;
  return bool(allowed_raw(facts(), bytes, gap));
}

Plan make_plan(const spec::Spec& s, const TargetInfo& info, const WritePolicy& policy) {
  Plan p;
  p.spec = &s;
  p.info = info;
  p.policy = policy;
  for (const spec::Register* r : representative_registers(s)) {
    if (r->access != spec::Access::wo && s.profile.function(read_function(r->table))) p.readable.push_back(r);
    if (p.writable_register(*r)) p.writable.push_back(r);
  }
  for (const auto& f : s.profile.function_codes) p.functions.push_back(uint8_t(f.code));
  for (const auto& ex : s.examples) {
    auto adu = parse_hex(ex.resolved_request ? *ex.resolved_request : ex.request);
    if (!adu || adu->size() < 4) continue;
    Bytes pdu = rtu_unframe(*adu).pdu;
    if (p.safe(info.unit, pdu)) p.examples.push_back(pdu);
  }
  // The probe: a read of the first holding register (else any register) the
  // spec maps and the profile can read: a known-good request.
  const spec::Register* probe = nullptr;
  for (const spec::Register* r : p.readable)
    if (!probe || (r->table == spec::Table::holding && probe->table != spec::Table::holding)) probe = r;
  if (!probe) throw std::runtime_error("spec " + s.device.id + " maps no register the profile can read: no liveness probe");
  p.probe = read_request(read_function(probe->table), probe->address, uint16_t(probe->words));
  return p;
}


// ---- steps and their expectations (from the standard, never from an implementation) ----

// An expectation of a kind alone (a designated initializer would leave
// pdu and code to -Wmissing-field-initializers).
check::Expect expecting(check::Expect::Kind k) {
  check::Expect e;
  e.kind = k;
  return e;
}

Step probe_step(const Plan& p) {
  return check::frame(p.info.framing, p.info.unit, p.probe, expecting(check::Expect::Kind::normal), kProbeNote);
}

bool is_probe(const Step& s) { return s.kind == Step::Kind::frame && s.note == kProbeNote; }

check::Expect expect_for(const Plan& p, const Step& s) {
  using K = check::Expect::Kind;
  // A fuzzed request may be one the device drops (its spec's policy, or a
  // request too broken to parse): silence is no finding, a bad reply is.
  if (s.kind == Step::Kind::frame) return expecting(s.unit == 0 ? K::silence : K::any_or_silence);
  if (s.kind != Step::Kind::raw) return {};
  // MB-SL v1.02 §2.1: no reply to another slave id or to broadcast; §2.4.2:
  // none to a frame with a bad CRC, length or gap, unless the device's manual
  // says it answers corrupted frames (its crc_error policy).
  if (check::request_pdu(s, p.info.unit)) return expecting(K::any_or_silence);
  bool addressed = !s.bytes.empty() && s.bytes[0] == p.info.unit;
  auto pe = p.spec->profile.policy(spec::Violation::crc_error);
  if (addressed && pe.kind == spec::PolicyEntry::Kind::exception) return expecting(K::any_or_silence);
  return expecting(K::silence);
}

namespace {
// How the plan's target is judged: a live line may hold other units (check/judge.h).
check::JudgeContext context(const Plan& p) {
  check::JudgeContext c{p.info.unit, p.info.framing, p.spec, {}};
  c.shared_line = p.info.live;
  return c;
}

// A late reply (Reply::late) to a frame that had to stay silent: it came
// after that frame was judged silent, and is still a reply MB-SL v1.02 §2.1
// (broadcast, another slave id) or §2.4.2 (a corrupted frame) forbids. A
// late reply to a well-formed request to the unit is the device's pace, not
// a fault; one the target could not pair with a request says nothing.
std::optional<Finding> late_finding(const Plan& p, const Reply& r) {
  for (const auto& l : r.late) {
    const Bytes& req = l.request;
    if (req.size() < kRtuAddress + 1 + kRtuCrc) continue;
    FindingKind kind;
    std::string why;
    // On a multi-drop line another unit answers its own frames (check/judge.h).
    if (!check::reply_is_targets(req[0], l.frame, context(p))) continue;
    if (req[0] == 0) {
      kind = FindingKind::answered_broadcast;
      why = "broadcast (MB-SL v1.02 §2.1: no response)";
    } else if (req[0] != p.info.unit) {
      kind = FindingKind::answered_other_slave;
      why = "another slave id (MB-SL v1.02 §2.1: no response)";
    } else if ((!crc_ok(req) || rtu_adu_length(req, Direction::request) != req.size()) &&
               p.spec->profile.policy(spec::Violation::crc_error).kind != spec::PolicyEntry::Kind::exception) {
      kind = FindingKind::answered_corrupted_frame;
      why = "a frame with a bad CRC or length (MB-SL v1.02 §2.4.2: no response)";
    } else {
      continue;
    }
    return Finding{kind, fmt::format("a late reply, {:.1f} ms after the request, to a frame for {}\n  sent:  {}\n  reply: {}",
                                     double(l.after.count()) / 1000, why, to_hex(req), to_hex(l.frame))};
  }
  return std::nullopt;
}
}  // namespace

std::optional<Finding> judge(const Plan& p, const Step& s, const Reply& r) {
  auto m = check::judge(s, r, context(p));
  if (!m) return late_finding(p, r);
  std::string why = m->why;
  FindingKind kind = FindingKind::malformed_reply;
  using M = check::Mismatch::Kind;
  uint8_t to = s.kind == Step::Kind::frame ? s.unit : s.bytes.empty() ? p.info.unit : s.bytes[0];
  bool addressed = s.kind != Step::Kind::raw ? s.unit != 0 : to == p.info.unit;
  switch (m->kind) {
    case M::answered:
      // The judge holds only the target's own replies against it (check::reply_is_targets).
      if (!addressed) {
        kind = to == 0 ? FindingKind::answered_broadcast : FindingKind::answered_other_slave;
        why = to == 0 ? "a reply to a broadcast (MB-SL v1.02 §2.1: no response)"
                      : fmt::format("a reply from slave {} (the target) to a frame for slave {} (MB-SL v1.02 §2.2: only the addressed slave answers)",
                                    p.info.unit, to);
      } else if (!r.framing_error.empty()) {
        kind = FindingKind::malformed_framing;
        why = r.framing_error;
      } else {
        kind = FindingKind::answered_corrupted_frame;
        why = "a reply to a frame with a bad CRC, length or gap (MB-SL v1.02 §2.4.2: no response)";
      }
      break;
    case M::malformed_framing: kind = FindingKind::malformed_framing; break;
    case M::malformed_reply: kind = FindingKind::malformed_reply; break;
    case M::unknown_exception: kind = FindingKind::unknown_exception_code; break;
    case M::silent:
      kind = FindingKind::no_answer;
      why = "the target stopped answering: no reply to the liveness probe (a read of a register the spec maps)";
      break;
    case M::refused:
    case M::different:
      kind = FindingKind::probe_refused;
      why = "the liveness probe (a read of a register the spec maps) was refused";
      break;
  }
  std::string msg = fmt::format("{}\n  sent:  {}\n  reply: {}", why, to_hex(r.request),
                                r.silent() ? std::string("(silence)") : to_hex(r.frame));
  if (r.pdu) msg += "  (" + describe_pdu(*r.pdu, false) + ")";
  return Finding{kind, msg};
}

std::optional<Finding> execute(check::Exchange& x, const Plan& p, const Step& s) {
  // As round() waits: the probe for its reply, a generated frame (which may
  // be dropped) the silence window; a live target's reconnect() keeps what
  // it learnt of its latency, so a dropped frame costs a window, not the timeout.
  const Target::Wait wait = is_probe(s) ? Target::Wait::reply : Target::Wait::window;
  Link& t = x.link();
  try {
    Reply r;
    switch (s.kind) {
      case Step::Kind::advance: t.advance(std::chrono::microseconds(s.us)); return std::nullopt;
      case Step::Kind::power_cycle: t.power_cycle(); return std::nullopt;
      case Step::Kind::wait: return std::nullopt;
      case Step::Kind::raw:
      case Step::Kind::frame: r = reply_or_throw(x.send(s, wait), t.info()); break;
    }
    // A split frame answered where the target chose the pause (a live line):
    // a receiver a busy host held up past the pause read both parts as one
    // frame, which says nothing of the device. It is sent again with a pause
    // of kSplitGapRecheck, and that verdict stands (as the runner does).
    if (s.kind == Step::Kind::raw && s.gap && !r.silent())
      if (auto gap = t.split_gap()) {
        t.set_split_gap(std::max<std::chrono::microseconds>(10 * *gap, check::kSplitGapRecheck));
        try {
          r = reply_or_throw(x.send(s, wait), t.info());
        } catch (...) {
          t.set_split_gap(*gap);
          throw;
        }
        t.set_split_gap(*gap);
          }
    return judge(p, s, r);
  } catch (const std::exception& e) {
    return Finding{FindingKind::target_error, fmt::format("the target failed: {}\n  step: {}", e.what(), check::line(s))};
  }
}

// ---- generating steps ----

Step Generator::next() {
  Step s = [&] {
    const auto& info = p_.info;
    if (info.virtual_clock && pick(20) == 0) return check::advance(uint64_t(pick(500'000)));
    for (int attempt = 0; attempt < 20; ++attempt) {
      int strategy = int(pick(info.raw ? 5 : 4));
      Bytes pdu;
      switch (strategy) {
        case 0: pdu = valid_read(); break;
        case 1: pdu = boundary_write(); break;
        case 2: pdu = mutate(base()); break;
        case 3: pdu = p_.examples.empty() ? valid_read() : p_.examples[pick(p_.examples.size())]; break;
        case 4: {
          Bytes b = base();
          if (pick(2)) b = mutate(b);
          if (auto m = malformed(b)) return *m;
          continue;
        }
      }
      if (pdu.empty() || pdu.size() > kMaxPdu || !p_.safe(info.unit, pdu)) continue;
      return check::frame(info.framing, info.unit, pdu);
    }
    return check::frame(info.framing, info.unit, valid_read());
  }();
  s.expect = expect_for(p_, s);
  return s;
}

Bytes Generator::valid_read() {
  if (p_.readable.empty()) return p_.probe;
  const spec::Register& r = any(p_.readable);
  uint8_t fc = read_function(r.table);
  const auto* f = p_.spec->profile.function(fc);
  int max = f && f->max_quantity ? *f->max_quantity : 8;
  uint16_t q = uint16_t(pick(4) ? r.words : 1 + pick(uint64_t(std::min(max, 16))));
  return read_request(fc, r.address, q);
}

Bytes Generator::boundary_write() {
  if (p_.writable.empty()) return valid_read();
  const spec::Register& r = any(p_.writable);
  auto values = boundary_values(*p_.spec, r);
  if (values.empty()) return valid_read();
  auto pdus = write_pdus(*p_.spec, r, values[pick(values.size())]);
  return pdus.empty() ? valid_read() : pdus[pick(pdus.size())];
}

Bytes Generator::base() {
  switch (pick(3)) {
    case 0: return valid_read();
    case 1: return boundary_write();
    default: return p_.examples.empty() ? valid_read() : p_.examples[pick(p_.examples.size())];
  }
}

uint16_t Generator::interesting16(uint16_t near) {
  static const uint16_t values[] = {0, 1, 0x7D, 0x7E, 0x7B, 0x7C, 0x7D0, 0x7D1, 0x7B0, 0x7B1, 0x7F, 0x80, 0xFF, 0x100, 0x7FFF, 0x8000, 0xFF00, 0xFFFE, 0xFFFF};
  switch (pick(4)) {
    case 0: return values[pick(std::size(values))];
    case 1: return uint16_t(near + pick(3) - 1);
    case 2: {
      auto last = p_.spec->last_address(spec::Table::holding);
      return last ? uint16_t(*last + 1) : 0;
    }
    default: return uint16_t(rng_());
  }
}

// One field of a well-formed request changed (MBAP v1.1b3 §6 field layout).
Bytes Generator::mutate(Bytes pdu) {
  if (pdu.empty()) return pdu;
  switch (pick(8)) {
    case 0: {  // function code
      if (pick(2) && !p_.functions.empty()) pdu[0] = p_.functions[pick(p_.functions.size())];
      else pdu[0] = uint8_t(pick(p_.info.live ? 0x80 : 0x100));
      break;
    }
    case 1:  // address
      if (pdu.size() >= 3) {
        uint16_t a = interesting16(be16(pdu, 1));
        pdu[1] = uint8_t(a >> 8), pdu[2] = uint8_t(a);
      }
      break;
    case 2:  // quantity or value
      if (pdu.size() >= 5) {
        uint16_t q = interesting16(be16(pdu, 3));
        pdu[3] = uint8_t(q >> 8), pdu[4] = uint8_t(q);
      }
      break;
    case 3:  // byte count of FC 15/16 (offset 5) and FC 23 (offset 9)
      if ((pdu[0] == 15 || pdu[0] == 16) && pdu.size() >= 6) pdu[5] = uint8_t(rng_());
      else if (pdu[0] == 23 && pdu.size() >= 10) pdu[9] = uint8_t(rng_());
      else if (pdu.size() >= 2) pdu[1 + pick(pdu.size() - 1)] = uint8_t(rng_());
      break;
    case 4: pdu.resize(1 + pick(pdu.size())); break;  // truncated
    case 5: {                                         // trailing bytes
      size_t n = 1 + pick(8);
      for (size_t i = 0; i < n; ++i) pdu.push_back(uint8_t(rng_()));
      break;
    }
    case 6:  // one bit
      pdu[pick(pdu.size())] ^= uint8_t(1u << pick(8));
      break;
    default:  // a longer write: more registers than the profile allows
      if (pdu[0] == 16 && pdu.size() >= 6) {
        uint16_t q = uint16_t(1 + pick(127));
        Bytes b{16, pdu[1], pdu[2], uint8_t(q >> 8), uint8_t(q), uint8_t(2 * q)};
        for (int i = 0; i < 2 * q && b.size() < kMaxPdu; ++i) b.push_back(uint8_t(rng_()));
        pdu = b;
      }
      break;
  }
  return pdu;
}

// Malformed framing (MB-SL v1.02 §2.5.1): the frame a correct device drops.
std::optional<Step> Generator::malformed(const Bytes& pdu) {
  // Over Modbus TCP the frame is the MBAP header's business: RTU bytes would
  // only desynchronise the stream. On a byte stream without timing (TCP,
  // RTU over TCP) a frame whose length is wrong swallows the next request
  // (its end is found by counting bytes), so only length-keeping faults.
  if (p_.info.framing != &mbc::kRtu) return std::nullopt;
  const bool stream = p_.info.kind == TargetKind::tcp || p_.info.kind == TargetKind::rtu_tcp;
  uint8_t unit = p_.info.unit;
  Step s = check::raw_rtu(rtu_frame(unit, pdu));
  Bytes& a = s.bytes;
  static const int kStreamCases[] = {0, 3, 4};
  switch (stream ? kStreamCases[pick(3)] : int(pick(6))) {
    case 0: a[a.size() - 1 - pick(2)] ^= uint8_t(1u << pick(8)); break;  // CRC
    case 1: a.resize(1 + pick(a.size() - 1)); break;                       // truncated
    case 2: {                                                              // over 256 bytes
      while (a.size() < 257 + pick(40)) a.push_back(uint8_t(rng_()));
      break;
    }
    case 3: {  // another slave id, CRC right: must be silent
      uint8_t other = uint8_t(1 + pick(247));
      if (other == unit) other = uint8_t(unit % 247 + 1);
      if (!p_.safe(other, pdu)) return std::nullopt;
      a = rtu_frame(other, pdu);
      break;
    }
    case 4: {  // broadcast, CRC right: executed (writes) but never answered
      if (!p_.spec->serial.broadcast_address || !p_.safe(uint8_t(*p_.spec->serial.broadcast_address), pdu)) return std::nullopt;
      a = rtu_frame(uint8_t(*p_.spec->serial.broadcast_address), pdu);
      break;
    }
    default:  // a pause of more than t1.5 inside the frame (§2.5.1.1): two broken frames
      if (a.size() < 2) return std::nullopt;
      s.gap = 1 + pick(a.size() - 1);
      break;
  }
  if (!p_.safe(unit, pdu) || !p_.safe_raw(s.bytes, s.gap)) return std::nullopt;
  return s;
}

// ---- running and reducing ----

std::optional<Finding> run_fresh(Link& link, const Open& open, const Plan& p, const std::vector<Step>& steps,
                                 const Wanted& wanted) {
  try {
    open();
  } catch (const std::exception& e) {
    return Finding{FindingKind::cannot_reopen, e.what()};
  }
  check::Exchange x(link);
  for (const auto& st : steps) {
    if (auto f = execute(x, p, st)) {
      if (!wanted || wanted(*f, st)) return f;
      if (target_may_be_gone(*f)) return std::nullopt;
    }
  }
  return std::nullopt;
}

std::optional<Finding> isolated(const std::function<std::optional<Finding>()>& fn) {
  int fds[2];
  if (pipe(fds) != 0) return fn();
  std::fflush(nullptr);
  pid_t pid = fork();
  if (pid < 0) return fn();
  if (pid == 0) {
    close(fds[0]);
    auto f = fn();
    std::string out = f ? std::string(to_string(f->kind)) + "\n" + f->message : "";
    (void)!write(fds[1], out.data(), out.size());
    _exit(0);
  }
  close(fds[1]);
  std::string got;
  char buf[4096];
  for (ssize_t n; (n = read(fds[0], buf, sizeof buf)) > 0;) got.append(buf, size_t(n));
  close(fds[0]);
  int status = 0;
  waitpid(pid, &status, 0);
  if (WIFSIGNALED(status))
    return Finding{FindingKind::crash, fmt::format("the target's process died with signal {} ({})", WTERMSIG(status), strsignal(WTERMSIG(status)))};
  if (got.empty()) return std::nullopt;
  auto nl = got.find('\n');
  auto kind = finding_kind(got.substr(0, nl));
  if (!kind) return Finding{FindingKind::target_error, "the isolated round reported an unknown finding: " + got.substr(0, nl)};
  return Finding{*kind, nl == std::string::npos ? "" : got.substr(nl + 1)};
}

namespace {

using Clock = std::chrono::steady_clock;

// One round: the probe, then batches of generated steps each followed by the
// probe, until the deadline or a finding. Every step goes to `journal`
// before it is sent, so a finding can be reproduced from what was sent.
// A finding already reported ends the round only when the target may be
// gone (`known` says whether it is one, and counts it).
using Known = std::function<bool(const Finding&, const Step&)>;


// How long each exchange waits: a generated frame may be dropped (its
// expectation allows silence), so it waits the target's silence window,
// learnt from its latency as the runner's is (targets/live_link.h); the
// probe must be answered, so it waits for the reply.
std::optional<Finding> round(Link& link, const Plan& p, uint64_t seed, int batch, size_t depth, Clock::time_point deadline,
                             const std::function<void(const Step&)>& journal, const Known& known, Outcome& out) {
  check::Exchange x(link, out.counters, Outcome::kKeptLatencies);  // every exchange of the fuzzing counted, as anywhere
  Generator gen(p, seed);
  const Step probe = probe_step(p);
  auto keep = [&](std::optional<Finding> f, const Step& st) -> std::optional<Finding> {
    if (f && !target_may_be_gone(*f) && known(*f, st)) return std::nullopt;
    return f;
  };
  auto send = [&](const Step& st) -> std::optional<Finding> {
    journal(st);
    return keep(execute(x, p, st), st);
  };
  const bool pipelined = depth > 1 && link.pipelines();
  auto send_probe = [&]() { return send(probe); };
  // A live target's silence window is its timeout until a few replies were
  // timed (targets/live_link.h): the probe, answered, teaches it before the
  // first fuzzed frame that may go unanswered has to wait for it.
  for (int i = 0; i < (link.info().live ? kWarmupProbes : 1); ++i)
    if (auto f = send_probe()) return f;
  std::vector<Step> steps;
  while (Clock::now() < deadline) {
    steps.clear();
    for (int i = 0; i < batch; ++i) steps.push_back(gen.next());
    bool all_frames = std::all_of(steps.begin(), steps.end(), [](const Step& s) { return s.kind == Step::Kind::frame; });
    if (pipelined && all_frames) {
      // Modbus TCP: the batch goes out pipelined, every reply is judged in order.
      // Every request passes the session's policy and journal before the
      // batch goes out (Session::transact_all); a refused one is a
      // target-error, as a refused single frame is.
      for (const auto& st : steps) journal(st);
      std::vector<Reply> replies;
      try {
        for (auto& sent : x.send_all(steps, depth, Target::Wait::window)) replies.push_back(reply_or_throw(std::move(sent), link.info()));
        if (replies.size() < steps.size()) throw std::runtime_error("fewer replies than requests");
      } catch (const std::exception& e) {
        return Finding{FindingKind::target_error, fmt::format("the target failed: {}\n  step: {}", e.what(), check::line(steps.back()))};
      }
      out.frames += long(steps.size());
      for (size_t i = 0; i < steps.size(); ++i)
        if (auto f = keep(judge(p, steps[i], replies[i]), steps[i])) return f;
    } else {
      // The deadline is looked at before each exchange: a batch on a slow
      // line (50 frames at 9600 baud take over a second) does not run past
      // --duration. A batch cut short still ends with the probe.
      for (const auto& st : steps) {
        if (Clock::now() >= deadline) break;
        ++out.frames;
        if (auto f = send(st)) return f;
      }
    }
    ++out.batches;
    if (auto f = send_probe()) return f;
  }
  return std::nullopt;
}

// What makes a finding distinct: its kind, and for a reply whose content is
// wrong also the function code it answered (a device that answers every
// broadcast, or garbles every CRC, is one finding; a bad FC 03 reply and a
// bad FC 16 reply are two).
std::string signature(const Finding& f, const Plan& p, const Step& last) {
  if (f.kind != FindingKind::malformed_reply && f.kind != FindingKind::unknown_exception_code) return to_string(f.kind);
  auto pdu = check::request_pdu(last, p.info.unit);
  if (!pdu || pdu->empty()) return to_string(f.kind);
  return fmt::format("{} fc{:02X}", to_string(f.kind), (*pdu)[0]);
}

// The steps since the last probe before the finding (most findings need no earlier state).
std::vector<Step> last_batch(const std::vector<Step>& h) {
  size_t from = 0;
  for (size_t i = 0; i + 1 < h.size(); ++i)
    if (is_probe(h[i])) from = i + 1;
  return {h.begin() + long(from), h.end()};
}

Reported reduce(Link& link, const Open& open, const Plan& p, const Options& o, const Finding& f, const std::vector<Step>& history) {
  Reported rep{f, history.empty() ? to_string(f.kind) : signature(f, p, history.back()), {}, true, false, 0, history.size()};
  // The same finding, past others (already reported) on the way.
  Wanted same = [&](const Finding& g, const Step& st) { return g.kind == f.kind && signature(g, p, st) == rep.signature; };
  auto stopped = [&] { return o.stopped && o.stopped(); };
  // A run that sending stopped before or during (the reopen or a step threw
  // Stopped) says nothing: the reduction is cut off, and ddmin's remaining
  // calls return at once.
  std::function<bool(const std::vector<Step>&)> fails = [&](const std::vector<Step>& steps) {
    if (rep.cut_off || (rep.cut_off = stopped())) return false;
    auto g = o.isolate ? isolated([&] { return run_fresh(link, open, p, steps, same); }) : run_fresh(link, open, p, steps, same);
    if (g && g->kind == f.kind) return true;
    rep.cut_off = stopped();
    return false;
  };
  std::vector<Step> batch = last_batch(history);
  ++rep.runs;
  if (fails(batch)) {
    rep.steps = ddmin<Step>(batch, fails, o.reduce_budget, rep.runs);
    return rep;
  }
  if (!rep.cut_off) {
    ++rep.runs;
    if (batch.size() < history.size() && fails(history)) {
      rep.steps = ddmin<Step>(history, fails, o.reduce_budget, rep.runs);
      return rep;
    }
  }
  // Timing, state outside the frames, a target that is gone, or no time
  // left to try: the last batch as it was sent, unreduced.
  rep.steps = batch;
  rep.reproduced = false;
  return rep;
}

}  // namespace

Outcome fuzz(Link& link, const Open& open, const Plan& p, const Options& o,
             const std::function<void(const Reported&)>& on_finding) {
  Outcome out;
  const auto started = Clock::now();
  std::set<std::string> seen;
  auto declared = [&](const std::string& sig) { return o.declared && o.declared(sig); };
  Known known = [&](const Finding& f, const Step& st) {
    std::string sig = signature(f, p, st);
    if (declared(sig)) {
      ++out.declared;
      return true;
    }
    if (!seen.count(sig)) return false;
    ++out.repeats;
    return true;
  };
  const auto deadline = Clock::now() + o.duration;
  Clock::duration reducing{};
  bool fresh = true;  // round 0: the link as it is
  for (uint64_t r = 0; r == 0 || Clock::now() < deadline; ++r) {
    if (r > 0 && o.stopped && o.stopped()) break;
    ++out.rounds;
    // Round 0 runs the given seed's sequence; later rounds other ones.
    const uint64_t seed = o.seed + r * 0x9E3779B97F4A7C15ull;
    std::vector<Step> history;
    std::optional<Finding> f;
    if (!fresh) {
      try {
        open();
      } catch (const std::exception& e) {
        out.target_lost = true;
        break;
      }
    }
    fresh = false;
    if (o.isolate) {
      // The round in a child, so a plugin crash cannot lose it: the child
      // journals each step before sending it; the parent reduces the journal.
      Outcome child_counts;
      f = isolated([&]() -> std::optional<Finding> {
        std::ofstream j(o.journal, std::ios::trunc);
        j << check::kHeader << "\n";
        return round(link, p, seed, o.batch, o.depth, deadline, [&](const Step& s) { j << check::line(s) << std::endl; },
                     known, child_counts);
      });
      try {
        history = check::parse_file(o.journal).steps;
      } catch (const std::exception&) {
      }
      std::remove(o.journal.c_str());
      for (const auto& s : history) out.frames += !is_probe(s);
    } else {
      f = round(link, p, seed, o.batch, o.depth, deadline, [&](const Step& s) {
        // A bounded history: findings that need state older than this are
        // reported with what is kept (and said not to reproduce, if so).
        if (history.size() > o.history_cap) history.erase(history.begin(), history.end() - long(o.history_cap / 2));
        history.push_back(s);
      }, known, out);
    }
    if (!f) break;
    // The session refused to send once stopped: the stop, not the target's fault.
    if (f->kind == FindingKind::target_error && o.stopped && o.stopped()) break;
    if (f->kind == FindingKind::cannot_reopen) {
      out.target_lost = true;
      break;
    }
    // The target threw and cannot be opened again: it was lost, which is no
    // finding (one whose target comes back is: it is reduced below).
    if (f->kind == FindingKind::target_error) {
      try {
        open();  // the reduction starts afresh again for each of its runs
      } catch (const std::exception&) {
        out.target_lost = true;
        break;
      }
    }
    std::string sig = history.empty() ? to_string(f->kind) : signature(*f, p, history.back());
    if (declared(sig)) {
      ++out.declared;  // declared, and it took the target with it: on a fresh one
      continue;
    }
    if (!seen.insert(sig).second) {
      ++out.repeats;  // one that may have taken the target with it: on a fresh one
      continue;
    }
    // Reduction is not fuzzing: its time is left out of the frames/s.
    auto reduce_from = Clock::now();
    out.findings.push_back(reduce(link, open, p, o, *f, history));
    reducing += Clock::now() - reduce_from;
    if (on_finding) on_finding(out.findings.back());
  }
  out.seconds = std::chrono::duration<double>(Clock::now() - started - reducing).count();
  if (auto& l = out.counters.latencies_us; !l.empty()) out.reply_latency_p99_seconds = percentile(std::span(l), 99) / 1e6;
  return out;
}

check::Script reproducer(const Plan& p, const Reported& r, const std::string& replay_command) {
  check::Script s;
  s.device = p.spec->device.id;
  s.comment = fmt::format("mbconform fuzz reproducer: {}\n", r.signature);
  std::istringstream msg(r.finding.message);
  for (std::string l; std::getline(msg, l);) s.comment += "  " + l + "\n";
  if (r.cut_off && r.reproduced)
    s.comment += "Its reduction was cut off (a stop signal, or the time allowed ran out): these steps reproduce it\n"
                 "on a fresh target, but fewer may.\n";
  else if (r.cut_off)
    s.comment += "Its reduction was cut off (a stop signal, or the time allowed ran out) before a fresh target\n"
                 "reproduced it: these are the last steps sent before it, unreduced.\n";
  else if (!r.reproduced)
    s.comment += "It did not reproduce on a fresh target (timing, state outside the frames, or the target is gone):\n"
                 "these are the last steps sent before it, unreduced.\n";
  s.comment += "replay: " + replay_command;
  s.steps = r.steps;
  return s;
}

}  // namespace mbc::conf::blackbox
