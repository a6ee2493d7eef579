// The simulated axis behind a drive, on a virtual clock that tests advance
// explicitly: position and speed follow the commanded profile; home and limit
// switches sit at positions a test or `serve` sets.
#pragma once

#include <cstdint>
#include <limits>
#include <optional>

namespace mbc::ref {

struct AxisInputs {
  std::optional<int64_t> home_position;   // the home switch is active within ±home_width of it
  int64_t home_width = 50;                // pulses
  std::optional<int64_t> positive_limit;  // active at or beyond this position
  std::optional<int64_t> negative_limit;  // active at or below this position
};

// A motion profile in pulses and pulses/s. Position moves are trapezoids
// (start speed, acceleration, deceleration, max speed) that end exactly on
// the target; speed moves ramp to a signed speed and hold it; a normal stop
// decelerates, an emergency stop stops at once.
//
// Conventions: the start speed is the speed a stepper jumps to from
// standstill and stops from without a ramp; an acceleration or deceleration
// <= 0 means "no ramp" (instant). A limit switch stops the axis at once at the
// switch, as an emergency stop would.
class Axis {
 public:
  AxisInputs inputs;

  // Positions are the drive's (set_position moves its origin); the switches
  // in `inputs` are fixed to the machine, at machine positions.
  double position() const { return position_ - origin_; }
  double machine_position() const { return position_; }
  double speed() const { return speed_; }  // signed
  bool moving() const { return mode_ != Mode::idle; }
  bool in_position() const { return mode_ == Mode::idle && reached_target_; }
  std::optional<double> target() const { return target_ ? std::optional<double>(*target_ - origin_) : std::nullopt; }
  // +1 or -1 while moving (the sign of travel), 0 at standstill.
  int direction() const;

  // accel/decel in pulses/s^2 (> 0); speeds in pulses/s (>= 0).
  // A target closer than the stopping distance is reached with a harder
  // deceleration, never overshot. Moving the other way, the axis reverses at
  // once (no ramp down first). max_speed <= 0 leaves the axis where it is.
  void move_to(double target, double start_speed, double max_speed, double accel, double decel);
  void run_at(double signed_speed, double start_speed, double accel);
  void stop(double decel);  // decelerate to standstill
  void emergency_stop();    // standstill now
  // Redefines the current position (position clear, homing done): the
  // origin moves, the machine and its switches do not. A position move in
  // progress keeps its remaining distance.
  void set_position(double p);

  // Advances dt seconds. Stops on an active limit in the direction of travel
  // (returns true if a limit stopped the axis during this step).
  bool advance(double dt_s);

  // What ended one call of advance_until().
  enum class Event {
    none,      // dt ran out
    finished,  // the motion ended by itself (target reached, ramp to standstill done)
    home_on,   // the home switch turned active during travel
    home_off,  // the home switch turned inactive during travel
    limit,     // a limit switch stopped the axis
  };
  struct Step {
    double elapsed = 0;  // seconds consumed, <= dt
    Event event = Event::none;
  };
  // Advances at most dt seconds and stops the clock at the first event, so a
  // behaviour (a homing sequence) reacts at the exact position it happened.
  Step advance_until(double dt_s);

  bool home_active() const;
  bool positive_limit_active() const;
  bool negative_limit_active() const;

 private:
  enum class Mode { idle, position, velocity, stopping };
  // One phase of constant acceleration along the direction of travel.
  struct Phase {
    int dir = 0;        // +1 / -1
    double accel = 0;   // along dir, pulses/s^2
    double length = 0;  // seconds until the profile changes by itself
  };
  // What the current phase does when it runs its full length.
  enum class Kind { ramp, cruise, ramp_down, brake_to_target };
  Phase plan();  // may change speed_ at zero time (start-speed jumps)
  Event finish_phase(int dir);
  void halt(bool reached);

  Mode mode_ = Mode::idle;
  double position_ = 0, speed_ = 0;  // machine position
  double origin_ = 0;                // machine position of the drive's 0
  std::optional<double> target_;     // machine position
  bool reached_target_ = true;
  double start_speed_ = 0, max_speed_ = 0, accel_ = 1, decel_ = 1, cruise_ = 0;
  double left_home_at_ = std::numeric_limits<double>::quiet_NaN();  // last home_off: where, which way
  int left_home_dir_ = 0;
  Kind kind_ = Kind::cruise;
  double phase_end_speed_ = 0;  // |speed| at the end of a ramp phase
};

}  // namespace mbc::ref
