// The simulated axis. Motion is integrated phase by phase in closed form
// (constant acceleration within a phase), so a trapezoid ends exactly on its
// target and a switch is met at its exact position, whatever dt a caller uses.
#include "engine/virtual_axis.h"

#include <algorithm>
#include <cmath>
#include <limits>

namespace mbc::ref {

namespace {

constexpr double kInf = std::numeric_limits<double>::infinity();
constexpr double kInstant = 1e12;  // pulses/s^2 standing in for "no ramp"
constexpr double kTiny = 1e-9;     // pulses: closer than this is "there"

double ramp(double a) { return a > 0 ? a : kInstant; }
int sign(double x) { return x > 0 ? 1 : x < 0 ? -1 : 0; }

// Time to cover x >= 0 pulses from speed v >= 0 at constant acceleration a
// (the stable root of a/2 t^2 + v t - x = 0); infinity if never reached.
double time_to_cover(double x, double v, double a) {
  if (x <= 0) return 0;
  double disc = v * v + 2 * a * x;
  if (disc < 0) return kInf;
  double den = v + std::sqrt(disc);
  return den > 0 ? 2 * x / den : kInf;
}

}  // namespace

int Axis::direction() const {
  if (mode_ == Mode::idle) return 0;
  if (speed_ != 0) return sign(speed_);
  if (mode_ == Mode::position) return *target_ >= position_ ? 1 : -1;
  return sign(cruise_);
}

void Axis::halt(bool reached) {
  mode_ = Mode::idle;
  speed_ = 0;
  reached_target_ = reached;
}

void Axis::move_to(double target, double start_speed, double max_speed, double accel, double decel) {
  target += origin_;
  if (max_speed <= 0) {
    halt(false);
    return;
  }
  int dir = target >= position_ ? 1 : -1;
  if (speed_ * dir < 0) speed_ = 0;
  mode_ = Mode::position;
  target_ = target;
  reached_target_ = false;
  start_speed_ = std::max(0.0, start_speed);
  max_speed_ = max_speed;
  accel_ = accel;
  decel_ = decel;
  if (std::abs(target - position_) <= kTiny && speed_ == 0) {
    position_ = target;
    halt(true);
  }
}

void Axis::run_at(double signed_speed, double start_speed, double accel) {
  if (signed_speed == 0 && speed_ == 0) {
    halt(false);
    return;
  }
  mode_ = Mode::velocity;
  target_.reset();
  reached_target_ = false;
  cruise_ = signed_speed;
  start_speed_ = std::max(0.0, start_speed);
  accel_ = accel;
}

void Axis::stop(double decel) {
  if (mode_ == Mode::idle) return;
  if (mode_ == Mode::position) {
    // A target nearer than the stopping distance is where the stop ends anyway.
    double v = std::abs(speed_), vs = std::min(start_speed_, max_speed_);
    double brake = v > vs ? (v * v - vs * vs) / (2 * ramp(decel)) : 0;
    if (std::abs(*target_ - position_) <= brake) {
      decel_ = decel;
      return;
    }
  }
  mode_ = Mode::stopping;
  target_.reset();
  reached_target_ = false;
  cruise_ = 0;
  decel_ = decel;
}

void Axis::emergency_stop() {
  if (mode_ != Mode::idle) halt(false);
}

void Axis::set_position(double p) { origin_ = position_ - p; }

bool Axis::home_active() const {
  return inputs.home_position && std::abs(position_ - double(*inputs.home_position)) <= double(inputs.home_width);
}
bool Axis::positive_limit_active() const {
  return inputs.positive_limit && position_ >= double(*inputs.positive_limit);
}
bool Axis::negative_limit_active() const {
  return inputs.negative_limit && position_ <= double(*inputs.negative_limit);
}

// The phase the axis is in now. Jumps to the start speed happen here, at zero time.
Axis::Phase Axis::plan() {
  Phase p;
  if (mode_ == Mode::position) {
    double r = *target_ - position_;
    p.dir = r >= 0 ? 1 : -1;
    r = std::abs(r);
    double vs = std::min(start_speed_, max_speed_);
    double v = std::max(vs, speed_ * p.dir);
    speed_ = p.dir * v;
    double acc = ramp(accel_), dec = ramp(decel_);
    double brake = v > vs ? (v * v - vs * vs) / (2 * dec) : 0;
    if (r <= brake * (1 + 1e-9) + kTiny) {
      // Brake onto the target: the deceleration is recomputed from the
      // distance left, so the phase ends exactly there.
      kind_ = Kind::brake_to_target;
      if (v <= vs) {
        p.length = r / v;
      } else {
        p.length = 2 * r / (v + vs);
        p.accel = -(v - vs) / p.length;
      }
    } else if (v < max_speed_) {
      // Accelerate to max speed, or to the peak of a triangle when the move
      // is too short to reach it (57HS-R §7.1, second figure).
      double peak = std::sqrt((r + v * v / (2 * acc) + vs * vs / (2 * dec)) / (1 / (2 * acc) + 1 / (2 * dec)));
      phase_end_speed_ = std::max(v, std::min(max_speed_, peak));
      kind_ = Kind::ramp;
      p.accel = acc;
      p.length = (phase_end_speed_ - v) / acc;
    } else if (v > max_speed_) {
      kind_ = Kind::ramp;  // entered faster than this move's max speed
      phase_end_speed_ = max_speed_;
      p.accel = -dec;
      p.length = (v - max_speed_) / dec;
    } else {
      kind_ = Kind::cruise;
      p.length = (r - brake) / v;
    }
    return p;
  }
  // velocity / stopping: ramp towards cruise_ (0 when stopping).
  double goal = mode_ == Mode::stopping ? 0 : cruise_;
  double rate = ramp(mode_ == Mode::stopping ? decel_ : accel_);
  p.dir = speed_ != 0 ? sign(speed_) : sign(goal);
  double v = std::abs(speed_), g = p.dir * goal, vs = start_speed_;
  if (g <= 0) {  // to standstill, or reversing through it
    kind_ = Kind::ramp_down;
    p.accel = -rate;
    p.length = std::max(0.0, v - vs) / rate;
  } else {
    v = std::max(v, std::min(vs, g));
    speed_ = p.dir * v;
    if (v == g) {
      kind_ = Kind::cruise;
      p.length = kInf;
    } else {
      kind_ = Kind::ramp;
      phase_end_speed_ = g;
      p.accel = v < g ? rate : -rate;
      p.length = std::abs(g - v) / rate;
    }
  }
  return p;
}

// The current phase ran its full length; returns finished when motion ended.
Axis::Event Axis::finish_phase(int dir) {
  switch (kind_) {
    case Kind::brake_to_target:
      position_ = *target_;
      halt(true);
      return Event::finished;
    case Kind::ramp:
      speed_ = dir * phase_end_speed_;
      return Event::none;
    case Kind::ramp_down:
      if (mode_ == Mode::stopping || cruise_ == 0) {
        halt(false);
        return Event::finished;
      }
      speed_ = sign(cruise_) * std::min(start_speed_, std::abs(cruise_));
      return Event::none;
    case Kind::cruise:
      return Event::none;
  }
  return Event::none;
}

Axis::Step Axis::advance_until(double dt_s) {
  Step s;
  // Each pass ends a phase, an event or dt; a move has only a few phases.
  for (int pass = 0; pass < 1000; ++pass) {
    double left = dt_s - s.elapsed;
    if (mode_ == Mode::idle || left <= 0) break;
    if (mode_ == Mode::position && std::abs(*target_ - position_) <= kTiny) {
      position_ = *target_;
      halt(true);
      s.event = Event::finished;
      return s;
    }
    Phase p = plan();

    // A limit stops travel towards it; moving away from it is allowed.
    double to_limit = kInf, limit_at = 0;
    if (p.dir > 0 && inputs.positive_limit) limit_at = double(*inputs.positive_limit), to_limit = limit_at - position_;
    if (p.dir < 0 && inputs.negative_limit) limit_at = double(*inputs.negative_limit), to_limit = position_ - limit_at;
    if (to_limit <= 0) {
      halt(false);
      s.event = Event::limit;
      return s;
    }
    // The next home switch edge ahead, if any. The switch is active on the
    // closed interval [lo, hi], so standing on an edge and moving out turns
    // it off at once; that is reported once, not again on the next call.
    double to_home = kInf, edge = 0;
    Event home_event = Event::none;
    if (inputs.home_position) {
      double lo = double(*inputs.home_position - inputs.home_width);
      double hi = double(*inputs.home_position + inputs.home_width);
      if (p.dir > 0 ? position_ < lo : position_ > hi) {
        edge = p.dir > 0 ? lo : hi;
        home_event = Event::home_on;
      } else if (position_ >= lo && position_ <= hi) {
        edge = p.dir > 0 ? hi : lo;
        home_event = Event::home_off;
        if (position_ == edge && edge == left_home_at_ && p.dir == left_home_dir_) home_event = Event::none;
      }
      if (home_event != Event::none) to_home = std::abs(edge - position_);
    }

    double v = std::abs(speed_);
    double t_limit = time_to_cover(to_limit, v, p.accel);
    double t_home = time_to_cover(to_home, v, p.accel);
    double t = std::min({left, p.length, t_limit, t_home});
    position_ += p.dir * (v * t + 0.5 * p.accel * t * t);
    speed_ = p.dir * std::max(0.0, v + p.accel * t);
    s.elapsed = t == left ? dt_s : s.elapsed + t;

    if (t == t_limit) {
      position_ = limit_at;
      halt(false);
      s.event = Event::limit;
      return s;
    }
    if (t == t_home) {
      position_ = edge;
      if (home_event == Event::home_off) left_home_at_ = edge, left_home_dir_ = p.dir;
      s.event = home_event;
      return s;
    }
    if (t == p.length) {
      s.event = finish_phase(p.dir);
      if (s.event != Event::none) return s;
    }
  }
  s.elapsed = dt_s;
  return s;
}

bool Axis::advance(double dt_s) {
  bool limited = false;
  for (double left = dt_s; left > 0;) {
    Step s = advance_until(left);
    limited |= s.event == Event::limit;
    if (s.event == Event::none) break;
    left -= s.elapsed;
  }
  return limited;
}

}  // namespace mbc::ref
