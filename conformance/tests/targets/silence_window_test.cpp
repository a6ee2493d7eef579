// The silence window's margin over an exchange's line time (live_link.h):
// learnt from the replies' excess over their line time, never below what
// that says a reply may take, and on the floor the line itself gives once
// enough replies were timed. Durations here are computed, never measured.
#include <gtest/gtest.h>

#include "modbus/rtu.h"
#include "targets/live_link.h"

namespace mbc::conf::live {
namespace {

using namespace std::chrono_literals;

TEST(SilenceWindow, TheFloorIsTheLinesOwnT35OnceEnoughRepliesWereTimed) {
  const microseconds t35 = frame_gap(115200);  // MB-SL v1.02 §2.5.1.1: 1.75 ms above 19200 baud
  SilenceWindow w(1000ms, true, std::nullopt, t35);
  const microseconds line = 2ms;
  EXPECT_FALSE(w.margin());
  EXPECT_EQ(w.window(line), 1000ms);  // nothing timed: the timeout
  for (size_t i = 0; i < SilenceWindow::kMinSamples; ++i) w.record(line + 100us, false, line);
  // A few replies: their p99 is their maximum, so the fixed floor stands.
  EXPECT_EQ(w.margin(), microseconds(SilenceWindow::kLineFloor));
  for (size_t i = w.samples(); i < SilenceWindow::kTrustedSamples; ++i) w.record(line + 100us, false, line);
  EXPECT_EQ(w.margin(), t35);
  EXPECT_EQ(w.window(line), line + t35);
}

TEST(SilenceWindow, TheMarginNeverFallsBelowTwiceTheP99Excess) {
  const microseconds t35 = frame_gap(115200);
  SilenceWindow w(1000ms, true, std::nullopt, t35);
  const microseconds line = 2ms;
  // 90 replies 0.2 ms over their line time, 10 of them 3 ms over: a slow
  // drive's tail, which the window must cover, floor or not.
  for (int i = 0; i < 90; ++i) w.record(line + 200us, false, line);
  for (int i = 0; i < 10; ++i) w.record(line + 3ms, false, line);
  ASSERT_EQ(w.p99(), 3ms);
  EXPECT_EQ(w.margin(), 6ms);
  // Exceptions timed apart: the slower kind sets the margin.
  for (int i = 0; i < 10; ++i) w.record(line + 4ms, true, line);
  EXPECT_EQ(w.margin(), 8ms);
}

}  // namespace
}  // namespace mbc::conf::live
