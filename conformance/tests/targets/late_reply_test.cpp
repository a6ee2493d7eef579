// The rtu:// target and the runner against a slave played by this test on a
// real pty (README: no verdict from a race): a reply that comes after the
// silence window closed is found before the next request (drained, counted
// as late) and widens the window past the time it took, so that a re-run
// waits for it; a split frame answered because the receiver was held up is
// run again with a longer pause; exception 01 skips a case only for the
// function code it sent.
#include <fcntl.h>
#include <gtest/gtest.h>
#include <poll.h>
#include <unistd.h>

#include <atomic>
#include <chrono>
#include <thread>

#include "modbus/crc16.h"
#include "modbus/pdu.h"
#include "modbus/rtu.h"
#include "loader.h"
#include "blackbox/engine.h"
#include "check/check.h"
#include "runner/runner.h"
#include "serve/endpoint.h"
#include "targets/target.h"

namespace mbc::conf {
namespace {

using check::Expect;
using check::Step;

using namespace std::chrono_literals;

// A slave on the master side of a pty: answers every 8-byte FC 03 request
// with one register, after `delay` (zero: at once).
class PtySlave {
 public:
  PtySlave() {
    serve::RawPty pty = serve::open_raw_pty();  // a raw line, as the master's end is
    master_ = pty.master;
    slave_ = pty.slave;
    path_ = pty.name;
    thread_ = std::thread([this] { serve(); });
  }
  ~PtySlave() {
    stop_ = true;
    thread_.join();
    close(master_);
    close(slave_);
  }
  const std::string& path() const { return path_; }
  std::atomic<int64_t> delay_us{0};
  // Replies begun (counted before the write: a reply taken is counted) and
  // written (after it: a reply counted is on the line).
  std::atomic<int> begun{0}, answered{0};
  std::atomic<bool> merge{false};
  // With `gap_us`, a frame also ends when the line is silent that long after
  // the receiver looks again, which it does `held_us` after it read the first
  // bytes (a receiver a busy host held up). Without, frames end by length.
  std::atomic<int64_t> gap_us{0}, held_us{0};
  // Nonzero: every answer is exception 01 (illegal function) for this code.
  std::atomic<int> illegal_fc{0};
  // Broadcasts (slave id 0) are answered too, from 0 (MB-SL v1.02 §2.1 forbids it).
  std::atomic<bool> answer_broadcast{false};

 private:
  void serve() {
    Bytes in;
    while (!stop_) {
      pollfd p{master_, POLLIN, 0};
      if (poll(&p, 1, 20) <= 0) continue;
      uint8_t buf[256];
      ssize_t n = read(master_, buf, sizeof buf);
      if (n <= 0) continue;
      in.insert(in.end(), buf, buf + n);
      if (in.size() < 8 && gap_us.load() > 0) {
        std::this_thread::sleep_for(std::chrono::microseconds(held_us.load()));
        pollfd more{master_, POLLIN, 0};
        if (poll(&more, 1, int(gap_us.load() / 1000)) == 0) in.clear();  // a silence ended an incomplete frame
        continue;
      }
      if (in.size() < 8) continue;
      // Not addressed to unit 1: no reply; with `merge`, the next request is
      // taken as the rest of that frame and dropped too (a receiver held up
      // past the window reads both at once).
      bool ours = in[0] == 1 || (in[0] == 0 && answer_broadcast.load());
      if (!ours || swallow_next_) {
        swallow_next_ = !ours && merge.load();
        in.clear();
        continue;
      }
      std::this_thread::sleep_for(std::chrono::microseconds(delay_us.load()));
      Bytes reply = illegal_fc.load() ? rtu_frame(in[0], Bytes{uint8_t(illegal_fc.load() | 0x80), 1})
                                      : rtu_frame(in[0], Bytes{3, 2, 0x12, 0x34});
      in.clear();
      ++begun;
      if (write(master_, reply.data(), reply.size()) == ssize_t(reply.size())) ++answered;
    }
  }
  bool swallow_next_ = false;
  int master_ = -1, slave_ = -1;
  std::string path_;
  std::atomic<bool> stop_{false};
  std::thread thread_;
};

TEST(RtuLateReply, IsDrainedCountedAndWidensTheWindowPastItsTime) {
  PtySlave slave;
  auto target = open_target("rtu://" + slave.path() + "?baud=115200&parity=N&unit=1");
  Bytes read = read_request(3, 0, 1);
  target->set_wait(Target::Wait::reply);
  for (int i = 0; i < 20; ++i) ASSERT_TRUE(target->transact(1, read).pdu) << i;
  auto window = target->silence_window();
  ASSERT_LT(window, 1000ms) << "the window did not adapt";

  // The next reply comes 50 ms after the window closes: judged silent.
  auto delay = std::chrono::duration_cast<std::chrono::microseconds>(window + 50ms);
  slave.delay_us = delay.count();
  target->set_wait(Target::Wait::window);
  EXPECT_TRUE(target->transact(1, read).silent());
  EXPECT_EQ(target->late_replies(), 0u);
  while (slave.answered.load() < 21) std::this_thread::sleep_for(5ms);  // the late reply is on the line

  // The next exchange finds it first, counts it, and still gets its own reply.
  slave.delay_us = 0;
  target->set_wait(Target::Wait::reply);
  Reply r = target->transact(1, read);
  ASSERT_TRUE(r.pdu);
  EXPECT_EQ(*r.pdu, (Bytes{3, 2, 0x12, 0x34}));
  EXPECT_EQ(target->late_replies(), 1u);
  // Widened past the time the late reply took (twice what it was seen with),
  // not merely doubled.
  EXPECT_GE(target->silence_window(), std::min<std::chrono::microseconds>(2 * delay, 1000ms));
}

// A broadcast answered after its window closed (MB-SL v1.02 §2.1: never
// answered at all): the next exchange hands the late reply over with the
// broadcast it answers, widens the window past the time it took (as any
// late reply does, so that the runner's re-run sees it in time), and the
// fuzzer's judge calls it a finding.
TEST(RtuLateReply, ALateReplyToABroadcastIsHandedOverAndIsAFinding) {
  PtySlave slave;
  slave.answer_broadcast = true;
  auto target = open_target("rtu://" + slave.path() + "?baud=115200&parity=N&unit=1");
  Bytes read = read_request(3, 0, 1);
  target->set_wait(Target::Wait::reply);
  for (int i = 0; i < 20; ++i) ASSERT_TRUE(target->transact(1, read).pdu) << i;
  auto window = target->silence_window();
  ASSERT_LT(window, 1000ms) << "the window did not adapt";

  auto delay = std::chrono::duration_cast<std::chrono::microseconds>(window + 50ms);
  slave.delay_us = delay.count();
  target->set_wait(Target::Wait::window);
  Reply bc = target->transact(0, read);
  EXPECT_TRUE(bc.silent());
  EXPECT_TRUE(bc.late.empty());
  while (slave.answered.load() < 21) std::this_thread::sleep_for(5ms);  // the late reply is on the line

  slave.delay_us = 0;
  target->set_wait(Target::Wait::reply);
  Reply r = target->transact(1, read);
  ASSERT_TRUE(r.pdu) << r.framing_error << " " << to_hex(r.frame);
  ASSERT_EQ(r.late.size(), 1u);
  EXPECT_EQ(r.late[0].frame, rtu_frame(0, Bytes{3, 2, 0x12, 0x34}));
  EXPECT_EQ(r.late[0].request, rtu_frame(0, read));
  // It came after the window the broadcast waited (the slave's own clock
  // starts when it has the request: under ASan a few ms off the target's).
  EXPECT_GT(r.late[0].after, window);
  EXPECT_EQ(target->late_replies(), 1u);
  EXPECT_GE(target->silence_window(), std::min<std::chrono::microseconds>(2 * r.late[0].after, 1000ms));

  spec::Spec s = spec::load_spec_by_id("hsc60");
  auto plan = blackbox::make_plan(s, target->info(), WritePolicy{});
  Step st = check::frame(plan.info.framing, 1, read);
  st.expect = blackbox::expect_for(plan, st);
  auto f = blackbox::judge(plan, st, r);
  ASSERT_TRUE(f);
  EXPECT_EQ(f->kind, blackbox::FindingKind::answered_broadcast) << f->message;
}

// The pause inside a split frame: 20 ms until a reply was timed, then the
// line's t3.5 (MB-SL v1.02 §2.5.1.1) plus the margin the silence window
// learnt, never above the 20 ms; a pause set from outside (the runner's
// re-run with a longer one) is kept until set again.
TEST(RtuSplitGap, IsTheLinesT35PlusTheLearntMargin) {
  PtySlave slave;
  auto target = open_target("rtu://" + slave.path() + "?baud=115200&parity=N&unit=1");
  ASSERT_EQ(target->split_gap(), std::optional<std::chrono::microseconds>(20ms));
  target->set_wait(Target::Wait::reply);
  for (int i = 0; i < 20; ++i) ASSERT_TRUE(target->transact(1, read_request(3, 0, 1)).pdu) << i;
  auto gap = target->split_gap();
  ASSERT_TRUE(gap);
  EXPECT_GE(*gap, 2 * frame_gap(115200));
  EXPECT_LE(*gap, 20ms);
  target->set_split_gap(250ms);
  EXPECT_EQ(target->split_gap(), std::optional<std::chrono::microseconds>(250ms));
  // gap= fixes it: no derived pause, none to set.
  auto fixed = open_target("rtu://" + slave.path() + "?baud=115200&parity=N&unit=1&gap=30");
  EXPECT_FALSE(fixed->split_gap());
}

// A request that follows an unanswered one and goes unanswered itself is run
// again once the target answers the liveness probe: the verdict is not the
// race of a receiver that took both frames as one.
TEST(RtuLateReply, AnUnansweredRequestAfterASilenceIsRunAgain) {
  PtySlave slave;
  slave.merge = true;
  auto target = open_target("rtu://" + slave.path() + "?baud=115200&parity=N&unit=1&timeout=300");
  auto spec = spec::load_spec_by_id("modbus-standard");
  auto step = [](uint8_t unit, Expect::Kind kind) {
    Step st;
    st.unit = unit;
    st.pdu = read_request(3, 0, 1);
    st.note = "read 0x0000";
    st.expect.kind = kind;
    return st;
  };
  Case foreign, answered;
  foreign.id = "t/foreign";
  foreign.steps = {step(2, Expect::Kind::silence)};
  answered.id = "t/answered";
  answered.steps = {step(1, Expect::Kind::normal)};
  DeviceRun run = run_cases(*target, spec, {foreign, answered});
  ASSERT_EQ(run.cases.size(), 2u);
  EXPECT_EQ(run.cases[0].outcome, Outcome::pass) << run.cases[0].message;
  EXPECT_EQ(run.cases[1].outcome, Outcome::pass) << run.cases[1].message;
  EXPECT_NE(run.cases[1].message.find("re-run"), std::string::npos) << run.cases[1].message;
}

// A request split by a pause inside it (framing/rtu/split-by-gap).
Case split_request_case() {
  Case c;
  c.id = "t/split-by-gap";
  Step st;
  st.kind = Step::Kind::raw;
  st.bytes = rtu_frame(1, read_request(3, 0, 1));
  st.gap = 3;
  st.note = "a request split by a pause";
  st.expect.kind = Expect::Kind::silence;
  c.steps = {st};
  return c;
}

// A receiver that detects the pause, but that the host held up longer than
// the target's own pause, reads both parts at once and answers: the case
// runs again with a longer pause, and that verdict stands (no verdict from a
// race).
TEST(RtuSplitFrame, AnsweredBecauseTheReceiverWasHeldUpIsRunAgainWithALongerPause) {
  PtySlave slave;
  slave.gap_us = 5000;
  slave.held_us = 100000;  // past the target's 20 ms, short of the re-run's 250 ms
  auto target = open_target("rtu://" + slave.path() + "?baud=115200&parity=N&unit=1&timeout=300");
  DeviceRun run = run_cases(*target, spec::load_spec_by_id("modbus-standard"), {split_request_case()});
  ASSERT_EQ(run.cases.size(), 1u);
  EXPECT_GE(slave.answered.load(), 1) << "the slave did not join the parts: the test shows nothing";
  EXPECT_EQ(run.cases[0].outcome, Outcome::pass) << run.cases[0].message;
  EXPECT_NE(run.cases[0].message.find("re-run with 250 ms"), std::string::npos) << run.cases[0].message;
  EXPECT_EQ(target->split_gap(), std::optional<std::chrono::microseconds>(20ms)) << "the pause was not put back";
}

// A receiver that joins the parts whatever the pause (frames by length) fails
// the re-run too; and a pause the user fixed with `gap=` is kept as given.
TEST(RtuSplitFrame, JoinedWhateverThePauseFailsAndAFixedGapIsKept) {
  PtySlave slave;
  auto target = open_target("rtu://" + slave.path() + "?baud=115200&parity=N&unit=1&timeout=300");
  DeviceRun run = run_cases(*target, spec::load_spec_by_id("modbus-standard"), {split_request_case()});
  ASSERT_EQ(run.cases.size(), 1u);
  EXPECT_EQ(run.cases[0].outcome, Outcome::fail) << run.cases[0].message;
  EXPECT_NE(run.cases[0].message.find("re-run with 250 ms"), std::string::npos) << run.cases[0].message;

  auto fixed = open_target("rtu://" + slave.path() + "?baud=115200&parity=N&unit=1&timeout=300&gap=30");
  EXPECT_EQ(fixed->split_gap(), std::nullopt);
  int before = slave.begun.load();
  run = run_cases(*fixed, spec::load_spec_by_id("modbus-standard"), {split_request_case()});
  EXPECT_EQ(run.cases[0].outcome, Outcome::fail) << run.cases[0].message;
  EXPECT_EQ(run.cases[0].message.find("re-run with"), std::string::npos) << run.cases[0].message;
  EXPECT_EQ(slave.begun.load(), before + 1) << "sent more than once with a fixed gap";
}

// Every function but the standard's is optional (MBAP v1.1b3 §5.1): a case
// whose request is refused with exception 01 for its own function code is
// skipped, but exception 01 for a code it did not send answers nothing it
// asked, and fails.
TEST(RtuOptionalFunction, SkippedOnlyForTheCodeTheStepSent) {
  PtySlave slave;
  auto target = open_target("rtu://" + slave.path() + "?baud=115200&parity=N&unit=1&timeout=300");
  Case c;
  c.id = "t/read";
  c.functions_optional = true;
  Step st;
  st.unit = 1;
  st.pdu = read_request(3, 0, 1);
  st.note = "read 0x0000";
  st.expect.kind = Expect::Kind::normal;
  c.steps = {st};
  auto spec = spec::load_spec_by_id("modbus-standard");
  slave.illegal_fc = 3;
  DeviceRun run = run_cases(*target, spec, {c});
  EXPECT_EQ(run.cases.at(0).outcome, Outcome::skip) << run.cases[0].message;
  slave.illegal_fc = 0x7E;
  run = run_cases(*target, spec, {c});
  EXPECT_EQ(run.cases.at(0).outcome, Outcome::fail) << run.cases[0].message;
}

}  // namespace
}  // namespace mbc::conf
