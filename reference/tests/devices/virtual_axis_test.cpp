// The simulated axis: trapezoids end exactly on target, speed never exceeds
// the max, short moves are triangles, stops and switches behave. Expected
// values are worked out from the kinematics in the comments, not from a run.
#include "engine/virtual_axis.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>

namespace mbc::ref {
namespace {

// Advances in `step` seconds until the axis stops (or `limit` s pass);
// returns the elapsed time and the highest |speed| seen.
struct Observed {
  double seconds = 0;
  double peak_speed = 0;
};
Observed run_until_stopped(Axis& axis, double step, double limit = 100) {
  Observed r;
  while (axis.moving() && r.seconds < limit) {
    axis.advance(step);
    r.seconds += step;
    r.peak_speed = std::max(r.peak_speed, std::abs(axis.speed()));
  }
  return r;
}

// a = 10000 pulses/s^2 to 1000 pulses/s: 0.1 s and 50 pulses each ramp, so
// 1000 pulses = 50 + 900 (0.9 s cruise) + 50, 1.1 s in all.
TEST(VirtualAxis, TrapezoidEndsExactlyOnTarget) {
  Axis axis;
  axis.move_to(1000, 0, 1000, 10000, 10000);
  axis.advance(0.1);
  EXPECT_NEAR(axis.speed(), 1000, 1e-6);
  EXPECT_NEAR(axis.position(), 50, 1e-6);
  axis.advance(0.9);
  EXPECT_NEAR(axis.position(), 950, 1e-6);
  EXPECT_TRUE(axis.moving());
  Observed r = run_until_stopped(axis, 0.001);
  EXPECT_NEAR(r.seconds, 0.1, 0.0015);
  EXPECT_EQ(axis.position(), 1000.0);  // exactly, not "near"
  EXPECT_TRUE(axis.in_position());
  EXPECT_EQ(axis.speed(), 0.0);
}

TEST(VirtualAxis, EndsOnTargetWhateverTheStepSize) {
  for (double step : {1e-4, 0.0137, 0.25, 10.0}) {
    Axis axis;
    axis.move_to(-12345, 30, 4000, 25000, 7000);
    run_until_stopped(axis, step);
    EXPECT_EQ(axis.position(), -12345.0) << "step " << step;
    EXPECT_TRUE(axis.in_position());
  }
}

TEST(VirtualAxis, SpeedNeverExceedsMax) {
  Axis axis;
  axis.move_to(5000, 100, 2000, 50000, 20000);
  Observed r = run_until_stopped(axis, 0.0007);
  EXPECT_LE(r.peak_speed, 2000.0);
  EXPECT_GT(r.peak_speed, 1999.0);
  // A new move with a lower max speed, started at full speed, slows to it.
  axis.run_at(3000, 0, 1e6);
  axis.advance(0.1);
  axis.move_to(axis.position() + 10000, 0, 1000, 10000, 10000);
  axis.advance(0.2);
  Observed r2 = run_until_stopped(axis, 0.001);
  EXPECT_LE(r2.peak_speed, 1000.0);
}

// 40 pulses with a = d = 10000: half way (20 pulses) the speed is
// sqrt(2 * 10000 * 20) = 632.5 pulses/s, below the 1000 max; 2 * 0.0632 s.
TEST(VirtualAxis, ShortMoveIsATriangle) {
  Axis axis;
  axis.move_to(40, 0, 1000, 10000, 10000);
  Observed r = run_until_stopped(axis, 0.0001);
  EXPECT_NEAR(r.peak_speed, std::sqrt(2 * 10000.0 * 20), 1.0);
  EXPECT_NEAR(r.seconds, 2 * std::sqrt(2 * 20 / 10000.0), 0.0002);
  EXPECT_EQ(axis.position(), 40.0);
}

// Unequal ramps with a start speed: still exact, still below max.
TEST(VirtualAxis, ShortMoveWithStartSpeedAndUnequalRamps) {
  Axis axis;
  axis.move_to(-7, 100, 5000, 40000, 5000);
  axis.advance(1e-6);
  EXPECT_NEAR(axis.speed(), -100, 0.1);  // jumps to the start speed
  Observed r = run_until_stopped(axis, 0.0003);
  EXPECT_LT(r.peak_speed, 5000.0);
  EXPECT_EQ(axis.position(), -7.0);
}

// 1000 pulses/s, stopped with d = 10000: 0.1 s and 1000^2 / (2 * 10000) = 50 pulses.
TEST(VirtualAxis, NormalStopDecelerates) {
  Axis axis;
  axis.run_at(1000, 0, 10000);
  axis.advance(1.0);  // 0.1 s ramp (50 pulses) + 0.9 s at speed
  EXPECT_NEAR(axis.position(), 950, 1e-6);
  axis.stop(10000);
  Observed r = run_until_stopped(axis, 0.001);
  EXPECT_NEAR(r.seconds, 0.1, 0.0015);
  EXPECT_NEAR(axis.position(), 1000, 1e-6);
  EXPECT_FALSE(axis.in_position());
}

TEST(VirtualAxis, EmergencyStopStopsAtOnce) {
  Axis axis;
  axis.run_at(-1000, 0, 10000);
  axis.advance(0.5);
  double at = axis.position();
  axis.emergency_stop();
  EXPECT_FALSE(axis.moving());
  EXPECT_EQ(axis.speed(), 0.0);
  axis.advance(1.0);
  EXPECT_EQ(axis.position(), at);
}

TEST(VirtualAxis, LimitsStopTheAxis) {
  Axis axis;
  axis.inputs.positive_limit = 500;
  axis.inputs.negative_limit = -200;
  axis.move_to(1000, 0, 1000, 10000, 10000);
  EXPECT_TRUE(axis.advance(2.0));
  EXPECT_EQ(axis.position(), 500.0);
  EXPECT_FALSE(axis.moving());
  EXPECT_FALSE(axis.in_position());
  EXPECT_TRUE(axis.positive_limit_active());
  // Further travel into the limit is refused; moving away is allowed.
  axis.move_to(600, 0, 1000, 10000, 10000);
  EXPECT_TRUE(axis.advance(0.1));
  EXPECT_EQ(axis.position(), 500.0);
  axis.run_at(-1000, 0, 0);
  EXPECT_FALSE(axis.advance(0.1));
  EXPECT_NEAR(axis.position(), 400, 1e-6);
  EXPECT_TRUE(axis.advance(10.0));
  EXPECT_EQ(axis.position(), -200.0);
  EXPECT_TRUE(axis.negative_limit_active());
}

TEST(VirtualAxis, HomeSwitchEdgesAreEvents) {
  Axis axis;
  axis.inputs.home_position = 300;
  axis.inputs.home_width = 50;
  axis.run_at(500, 500, 0);
  Axis::Step s = axis.advance_until(10.0);
  EXPECT_EQ(s.event, Axis::Event::home_on);
  EXPECT_EQ(axis.position(), 250.0);
  EXPECT_NEAR(s.elapsed, 0.5, 1e-9);
  EXPECT_TRUE(axis.home_active());
  s = axis.advance_until(10.0);
  EXPECT_EQ(s.event, Axis::Event::home_off);
  EXPECT_EQ(axis.position(), 350.0);
  EXPECT_NEAR(s.elapsed, 0.2, 1e-9);
  s = axis.advance_until(1.0);
  EXPECT_EQ(s.event, Axis::Event::none);
  EXPECT_FALSE(axis.home_active());
}

// Standing on the switch's edge and moving out turns it off at once, once.
TEST(VirtualAxis, LeavingFromAnEdgeTurnsTheSwitchOffAtOnce) {
  Axis axis;
  axis.inputs.home_position = 300;
  axis.inputs.home_width = 50;
  axis.move_to(250, 1000, 1000, 0, 0);
  axis.advance(1.0);
  EXPECT_TRUE(axis.home_active());
  axis.run_at(-100, 100, 0);
  Axis::Step s = axis.advance_until(1.0);
  EXPECT_EQ(s.event, Axis::Event::home_off);
  EXPECT_EQ(s.elapsed, 0.0);
  s = axis.advance_until(1.0);
  EXPECT_EQ(s.event, Axis::Event::none);
  EXPECT_NEAR(axis.position(), 150, 1e-9);
}

TEST(VirtualAxis, PositionMoveReportsFinished) {
  Axis axis;
  axis.move_to(100, 100, 100, 0, 0);  // constant 100 pulses/s: 1 s
  Axis::Step s = axis.advance_until(5.0);
  EXPECT_EQ(s.event, Axis::Event::finished);
  EXPECT_NEAR(s.elapsed, 1.0, 1e-9);
  EXPECT_EQ(axis.position(), 100.0);
}

TEST(VirtualAxis, SetPositionKeepsTheRemainingDistance) {
  Axis axis;
  axis.move_to(1000, 1000, 1000, 0, 0);
  axis.advance(0.25);
  axis.set_position(0);
  run_until_stopped(axis, 0.01);
  EXPECT_EQ(axis.position(), 750.0);
  EXPECT_EQ(axis.machine_position(), 1000.0);
}

// The switches belong to the machine: re-zeroing the drive does not move them.
TEST(VirtualAxis, SwitchesStayPutWhenTheOriginMoves) {
  Axis axis;
  axis.inputs.positive_limit = 100;
  axis.set_position(-400);  // the machine's 0 is now the drive's -400
  axis.run_at(1000, 0, 0);
  EXPECT_TRUE(axis.advance(1.0));
  EXPECT_EQ(axis.machine_position(), 100.0);
  EXPECT_EQ(axis.position(), -300.0);
}

}  // namespace
}  // namespace mbc::ref
