// check::Exchange's counters: every exchange counted, and the latencies it
// keeps bounded by a uniform sample of the whole run (a fuzz run of hours on
// a serial line answers millions of frames; its p99 comes from the sample).
#include <gtest/gtest.h>

#include <algorithm>
#include <vector>

#include "check/exchange.h"
#include "session/link.h"
#include "targets/percentile.h"

namespace mbc::conf {
namespace {

// Answers every request; the n-th reply took n microseconds, so the kept
// sample shows where in the run each kept latency came from.
class CountingTarget final : public Target {
 public:
  explicit CountingTarget(bool silent_every_other) : silent_every_other_(silent_every_other) {
    info_.uri = "test://counting";
    info_.baud = 19200;
  }
  const TargetInfo& info() const override { return info_; }
  Reply transact(uint8_t unit, std::span<const uint8_t> pdu) override {
    Reply r;
    r.request.assign(pdu.begin(), pdu.end());
    r.request.insert(r.request.begin(), unit);
    ++n_;
    if (silent_every_other_ && n_ % 2 == 0) return r;
    r.frame = {unit, 0x03, 0x02, 0x00, 0x00, 0x00, 0x00};
    r.pdu = Bytes{0x03, 0x02, 0x00, 0x00};
    r.latency = std::chrono::microseconds(n_);
    return r;
  }
  Reply send_raw(std::span<const uint8_t> bytes, std::optional<size_t>) override {
    return transact(bytes.empty() ? 1 : bytes[0], bytes.size() > 1 ? bytes.subspan(1) : bytes);
  }
  void advance(std::chrono::microseconds) override {}
  void power_cycle() override {}

 private:
  TargetInfo info_;
  bool silent_every_other_;
  long n_ = 0;
};

const Bytes kRead = {0x03, 0x00, 0x00, 0x00, 0x01};

TEST(ExchangeCounters, KeepAllLatenciesUnlessBounded) {
  CountingTarget t(false);
  DirectLink link(t);
  DeviceRun run;
  check::Exchange x(link, run);
  for (int i = 0; i < 500; ++i) x.quiet(1, kRead);
  EXPECT_EQ(run.frames_sent, 500u);
  ASSERT_EQ(run.latencies_us.size(), 500u);
  EXPECT_EQ(run.latencies_us.front(), 1.0);
  EXPECT_EQ(run.latencies_us.back(), 500.0);
  EXPECT_GT(run.wire_time_bound_seconds, 0.0);
}

TEST(ExchangeCounters, ABoundedSampleStandsForTheWholeRunAcrossExchanges) {
  CountingTarget t(true);  // every other exchange silent: 20,000 answered of 40,000
  DirectLink link(t);
  DeviceRun run;
  const size_t keep = 1000;
  // As the fuzzer does: a new Exchange per round, one DeviceRun for the run.
  for (int round = 0; round < 8; ++round) {
    check::Exchange x(link, run, keep);
    for (int i = 0; i < 5000; ++i) x.quiet(1, kRead);
  }
  EXPECT_EQ(run.frames_sent, 40000u);
  EXPECT_EQ(run.silences, 20000u);
  ASSERT_EQ(run.latencies_us.size(), keep);
  // Latency n came from the n-th exchange: a uniform sample of 1..39,999 has
  // about a quarter in each quarter of the run, the last included.
  std::vector<int> quarter(4, 0);
  for (double us : run.latencies_us) quarter[std::min(3, int((us - 1) / 10000))]++;
  for (int q = 0; q < 4; ++q) {
    EXPECT_GT(quarter[q], 200) << "quarter " << q;
    EXPECT_LT(quarter[q], 300) << "quarter " << q;
  }
  // Its p99 is the run's (39,600 us) within 2 %.
  std::vector<double> kept = run.latencies_us;
  double p99 = percentile(std::span(kept), 99);
  EXPECT_NEAR(p99, 39600.0, 0.02 * 39600.0);
}

}  // namespace
}  // namespace mbc::conf
