#include "properties/motion.h"

#include <fmt/core.h>
#include <rapidcheck.h>

#include <cmath>

#include "modbus/judge.h"
#include "properties/generators.h"
#include "safety/safety.h"

namespace mbc::conf::props {

using spec::Register;

namespace {

// The virtual clock is sampled every kSampleUs while an axis moves.
constexpr uint64_t kSampleUs = 20'000;
// How long a stop whose time the manual does not state is followed: no
// verdict rests on it (a stop still moving then is not judged).
constexpr uint64_t kObservedStopUs = 10'000'000;

[[noreturn]] void fail(const std::string& message) {
  RC_FAIL(message);
  throw std::logic_error("unreachable");
}

const Register& reg(Session& s, const std::string& key) {
  const Register* r = s.spec().find_by_key(key);
  if (!r) fail(fmt::format("the spec's operations name register key '{}', which spec {} does not have", key, s.spec().device.id));
  return *r;
}

void write_key(Session& s, const std::string& key, int64_t value, const std::string& why) {
  const Register& r = reg(s, key);
  Bytes req = s.view().write_request(r, uint32_t(value));
  std::string what = fmt::format("{} = {} ({})", key, value, why);
  Reply rep = s.send(req, what);
  if (!rep.pdu) fail(fmt::format("{}: {}", what, rep.silent() ? "no reply" : rep.framing_error));
  Judged j = judge_reply(req, *rep.pdu);
  if (j.kind != Judged::Kind::normal) {
    // Refused where the manual does not state the write is taken (FC 16
    // printed two ways, a write inferred): not held, the case ends.
    const bool fc16_open = req[0] == 0x10 && s.spec().profile.function(0x10) &&
                           s.spec().profile.function(0x10)->basis_of("supported").basis != spec::Basis::stated;
    if (fc16_open || r.basis_of(spec::Fact::write).basis != spec::Basis::stated) {
      RC_SUCCEED(fmt::format("{}: refused ({}), and the manual does not state that {} is taken: not held", what,
                             describe_pdu(*rep.pdu, false), fc16_open ? "FC 16" : "this write"));
      throw std::logic_error("unreachable");
    }
    fail(fmt::format("{}: refused: {}", what, describe_pdu(*rep.pdu, false)));
  }
}

int64_t read_key(Session& s, const std::string& key) {
  const Register& r = reg(s, key);
  ReadResult rr = read_register(s.transact(), s.view(), r);
  if (!rr.raw) fail(fmt::format("reading {}: {}", key, rr.error));
  if (r.is_signed()) return r.words == 1 ? int64_t(int16_t(*rr.raw)) : int64_t(int32_t(*rr.raw));
  return int64_t(*rr.raw);
}

struct Sample {
  uint64_t t_us = 0;
  int64_t position = 0;
  std::optional<uint16_t> status;
};

Sample sample(Session& s, const MotionFacts& m, uint64_t t) {
  Sample x;
  x.t_us = t;
  x.position = read_key(s, m.position_key);
  if (!m.position_high_key.empty())
    x.position = int64_t(int32_t(uint32_t(read_key(s, m.position_high_key)) << 16 | uint32_t(x.position & 0xFFFF)));
  if (!m.status_key.empty()) x.status = uint16_t(read_key(s, m.status_key));
  return x;
}

bool running(const MotionFacts& m, const Sample& x) {
  if (!x.status || !m.running_mask) return false;
  bool bits = (*x.status & m.running_mask) != 0;
  return m.running_when_set ? bits : !bits;
}

const MotionFacts& facts_of(Session& s) { return *motion_facts(s.spec()); }

// The profile the facts assume, then the setup writes.
void set_up(Session& s) {
  const MotionFacts& m = facts_of(s);
  for (const auto& a : m.assumes) {
    int64_t v = read_key(s, a.key);
    if (v != a.value)
      fail(fmt::format("{} reads {}, the motion facts assume {} ({}); set it or record other facts", a.key, v, a.value,
                       a.section));
  }
  for (const auto& w : m.setup) write_key(s, w.key, w.value, w.section);
}

void start_move(Session& s, int64_t d) {
  const MotionFacts& m = facts_of(s);
  bool reverse = d < 0;
  if (m.signed_distance) {
    write_key(s, m.distance_key, d, "move distance");
  } else {
    write_key(s, reverse && !m.reverse_distance_key.empty() ? m.reverse_distance_key : m.distance_key, std::llabs(d),
              reverse ? "reverse distance" : "forward distance");
  }
  const auto& start = reverse ? m.start_reverse : m.start_forward;
  if (start) write_key(s, start->key, start->value, start->section);
}

int64_t pick_distance(const MotionFacts& m) {
  int64_t d = pick<int64_t>(1, m.max_distance + 1);
  bool can_reverse = m.signed_distance || m.start_reverse || !m.reverse_distance_key.empty();
  return can_reverse && pick_bool() ? -d : d;
}

// Samples a move until it ends (status says stopped, or the position stands
// for three samples), at most `limit_us` of virtual time.
std::vector<Sample> follow(Session& s, uint64_t limit_us) {
  const MotionFacts& m = facts_of(s);
  std::vector<Sample> xs{sample(s, m, 0)};
  int still = 0;
  for (uint64_t t = kSampleUs; t <= limit_us; t += kSampleUs) {
    s.advance(kSampleUs);
    xs.push_back(sample(s, m, t));
    still = xs.back().position == xs[xs.size() - 2].position ? still + 1 : 0;
    bool stopped = m.running_mask ? !running(m, xs.back()) : still >= 3;
    if (stopped && still >= 1) return xs;
  }
  return xs;
}

uint64_t move_time_bound_us(const MotionFacts& m, int64_t d) {
  double t = double(std::llabs(d)) / m.max_speed_pulses_per_s + 2 * m.decel_seconds + 1.0;
  return uint64_t(t * 1e6);
}

std::string trace_text(const std::vector<Sample>& xs) {
  std::string out;
  for (const auto& x : xs) {
    out += fmt::format("\n    t={:.3f}s position {}", double(x.t_us) / 1e6, x.position);
    if (x.status) out += fmt::format(" status 0x{:04X}", *x.status);
  }
  return out;
}

// ---- the invariants ----------------------------------------------------------

void position_exact(Session& s) {
  const MotionFacts& m = facts_of(s);
  set_up(s);
  int64_t d = pick_distance(m);
  int64_t p0 = sample(s, m, 0).position;
  start_move(s, d);
  auto xs = follow(s, move_time_bound_us(m, d));
  if (running(m, xs.back()) || xs.back().position != xs[xs.size() - 2].position)
    fail(fmt::format("a move of {} pulses had not ended after {:.2f} s:{}", d, double(xs.back().t_us) / 1e6, trace_text(xs)));
  if (xs.back().position != p0 + d)
    fail(fmt::format("a move of {} pulses from {} ended at {}, {} pulses off ({}){}", d, p0, xs.back().position,
                     xs.back().position - (p0 + d), m.section, trace_text(xs)));
}

void speed_limit(Session& s) {
  const MotionFacts& m = facts_of(s);
  set_up(s);
  int64_t d = pick_distance(m);
  start_move(s, d);
  auto xs = follow(s, move_time_bound_us(m, d));
  for (size_t k = 1; k < xs.size(); ++k) {
    double dt = double(xs[k].t_us - xs[k - 1].t_us) / 1e6;
    double travelled = std::abs(double(xs[k].position - xs[k - 1].position));
    // One pulse of rounding at each end of the interval.
    if (travelled > m.max_speed_pulses_per_s * dt + 2)
      fail(fmt::format("{} pulses in {:.3f} s between t={:.3f}s and t={:.3f}s: {:.0f} pulses/s, over the configured "
                       "maximum {:.0f} ({}){}",
                       travelled, dt, double(xs[k - 1].t_us) / 1e6, double(xs[k].t_us) / 1e6, travelled / dt,
                       m.max_speed_pulses_per_s, m.section, trace_text(xs)));
  }
}

void status_agrees(Session& s) {
  const MotionFacts& m = facts_of(s);
  set_up(s);
  int64_t d = pick_distance(m);
  start_move(s, d);
  auto xs = follow(s, move_time_bound_us(m, d));
  for (size_t k = 0; k < xs.size(); ++k) {
    const Sample& x = xs[k];
    bool run = running(m, x);
    bool in_pos = m.in_position_mask && x.status && (*x.status & m.in_position_mask);
    if (run && in_pos)
      fail(fmt::format("t={:.3f}s: status 0x{:04X} says running and in position at once{}", double(x.t_us) / 1e6,
                       *x.status, trace_text(xs)));
    if (k + 1 < xs.size() && xs[k + 1].position != x.position && !run)
      fail(fmt::format("t={:.3f}s: status 0x{:04X} says standing still, and the position moves from {} to {} by the next "
                       "sample{}",
                       double(x.t_us) / 1e6, *x.status, x.position, xs[k + 1].position, trace_text(xs)));
  }
  const Sample& last = xs.back();
  if (running(m, last)) fail(fmt::format("the move of {} ended, and the status 0x{:04X} still says running{}", d, *last.status, trace_text(xs)));
  if (m.in_position_mask && last.status && !(*last.status & m.in_position_mask))
    fail(fmt::format("the move of {} ended, and the status 0x{:04X} does not say in position{}", d, *last.status, trace_text(xs)));
}

void stops(Session& s) {
  const MotionFacts& m = facts_of(s);
  set_up(s);
  bool emergency = m.emergency_stop && (!m.stop || pick_bool());
  int64_t d = m.max_distance * (pick_bool() ? 1 : -1);
  if (!(m.signed_distance || m.start_reverse || !m.reverse_distance_key.empty())) d = m.max_distance;
  start_move(s, d);
  uint64_t run_for = uint64_t(pick<int>(5, 30)) * kSampleUs;  // 0.1..0.6 s into the move
  s.advance(run_for);
  Sample before = sample(s, m, run_for);
  if (before.position == 0 && !running(m, before)) fail("the axis did not start moving");
  const CommandFact& c = emergency ? *m.emergency_stop : *m.stop;
  write_key(s, c.key, c.value, c.section);
  if (emergency) {
    // Stopped at once: where the stop found it, and there it stays.
    Sample at = sample(s, m, run_for);
    s.advance(10 * kSampleUs);
    Sample later = sample(s, m, run_for + 10 * kSampleUs);
    if (later.position != at.position || running(m, later))
      fail(fmt::format("emergency stop ({}) at position {}: {:.2f} s later the position is {}{}", c.section, at.position,
                       10 * kSampleUs / 1e6, later.position, running(m, later) ? " and the status says running" : ""));
    return;
  }
  // A normal stop ends within the deceleration time the manual states (one
  // sample of slack). A time it does not state (control.motion.decel not
  // stated) is observed: the axis is followed until it stands, and only its
  // staying there is held.
  const bool stated = m.decel_basis.basis == spec::Basis::stated;
  uint64_t settle = uint64_t(m.decel_seconds * 1e6) + kSampleUs;
  if (!stated) {
    std::vector<Sample> xs = follow(s, kObservedStopUs);
    settle = xs.back().t_us;
    if (xs.size() < 2 || xs.back().position != xs[xs.size() - 2].position) return;  // still moving: observed, not held
  } else {
    s.advance(settle);
  }
  Sample end = sample(s, m, run_for + settle);
  s.advance(10 * kSampleUs);
  Sample later = sample(s, m, run_for + settle + 10 * kSampleUs);
  if (later.position != end.position || running(m, later))
    fail(fmt::format("normal stop ({}): {:.3f} s after it ({}) the axis is at {}, then at {}{}", c.section, settle / 1e6,
                     stated ? fmt::format("decel time {:.3f} s, stated: {}", m.decel_seconds, m.decel_basis.section)
                            : "it stood: the stop time is not stated, so only staying stopped is held",
                     end.position, later.position, running(m, later) ? " and the status says running" : ""));
}

void homing_gate(Session& s) {
  const MotionFacts& m = facts_of(s);
  set_up(s);
  int64_t p0 = sample(s, m, 0).position;
  int64_t target = pick<int64_t>(1, m.max_distance + 1) * (pick_bool() ? 1 : -1);
  write_key(s, m.position_command_key, p0 + target, "position command before any homing");
  s.advance(move_time_bound_us(m, target));
  int64_t p1 = sample(s, m, 0).position;
  if (p1 != p0)
    fail(fmt::format("positioning to {} before any homing moved the axis from {} to {} ({}: refused until homed)",
                     p0 + target, p0, p1, m.section));
}

std::function<std::string(const SpecView&, const TargetInfo&, const DeviceFacts*)> needs_motion(bool homing_gate = false) {
  return [homing_gate](const SpecView& v, const TargetInfo& t, const DeviceFacts*) -> std::string {
    const MotionFacts* m = motion_facts(v.spec());
    if (!m) {
      const auto& c = v.spec().control;
      if (c && c->no_motion)
        return fmt::format("the manual states no position move these can hold ({}): {}", c->no_motion->section,
                           c->no_motion->why);
      return "the spec has no control: motion: section (spec/README.md)";
    }
    if (homing_gate && !m->positioning_needs_homing) return "the manual does not make positioning wait for homing";
    if (!t.virtual_clock) return "needs a target on a virtual clock (ref:); live motion is not sampled in real time yet";
    if (t.live) return "live target";
    return "";
  };
}

}  // namespace

std::vector<Invariant> motion_invariants() {
  return {
      {"motion-position-exact", "spec control.motion; the manuals' position moves",
       "A completed position move ends exactly at the commanded position.", needs_motion(), position_exact},
      {"motion-speed-limit", "spec control.motion: the speed the setup configures",
       "Between any two samples the axis never travels faster than the configured maximum speed.", needs_motion(),
       speed_limit},
      {"motion-status-agrees", "spec control.motion: the status word's running / in-position bits",
       "The status word says running while the position changes, never running and in position at once, and "
       "stopped (in position) once a move has ended.",
       needs_motion(), status_agrees},
      {"motion-stops", "spec control.motion: stop and emergency-stop commands",
       "An emergency stop stops the axis at once; a normal stop ends within the deceleration time the manual states "
       "(control.motion.decel, its section), and stays stopped; a time not stated is observed, not held.",
       needs_motion(),
       stops},
      {"motion-homing-gate", "7TRSM5740Q §5.2", "A drive that needs homing refuses positioning until it is homed.",
       needs_motion(true), homing_gate},
  };
}

}  // namespace mbc::conf::props
