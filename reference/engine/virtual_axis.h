// The simulated axis behind a drive, on a virtual clock that tests advance
// explicitly: position and speed follow the commanded profile; home and limit
// switches sit at positions a test or `serve` sets.
#pragma once

#include <cstdint>
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
class Axis {
 public:
  AxisInputs inputs;

  double position() const { return position_; }
  double speed() const { return speed_; }  // signed
  bool moving() const { return mode_ != Mode::idle; }
  bool in_position() const { return mode_ == Mode::idle && reached_target_; }
  std::optional<double> target() const { return target_; }

  // accel/decel in pulses/s^2 (> 0); speeds in pulses/s (>= 0).
  void move_to(double target, double start_speed, double max_speed, double accel, double decel);
  void run_at(double signed_speed, double start_speed, double accel);
  void stop(double decel);  // decelerate to standstill
  void emergency_stop();    // standstill now
  void set_position(double p);  // e.g. position clear, homing done

  // Advances dt seconds. Stops on an active limit in the direction of travel
  // (returns true if a limit stopped the axis during this step).
  bool advance(double dt_s);

  bool home_active() const;
  bool positive_limit_active() const;
  bool negative_limit_active() const;

 private:
  enum class Mode { idle, position, velocity, stopping };
  Mode mode_ = Mode::idle;
  double position_ = 0, speed_ = 0;
  std::optional<double> target_;
  bool reached_target_ = true;
  double start_speed_ = 0, max_speed_ = 0, accel_ = 1, decel_ = 1, cruise_ = 0;
};

}  // namespace mbc::ref
