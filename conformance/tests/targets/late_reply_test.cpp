// The rtu:// target against a slave played by this test on a real pty: a
// reply that comes after the silence window closed is found before the next
// request (drained, counted as late) and widens the window past the time it
// took, so that a re-run waits for it (README: no verdict from a race).
#include <fcntl.h>
#include <gtest/gtest.h>
#include <poll.h>
#include <pty.h>
#include <termios.h>
#include <unistd.h>

#include <atomic>
#include <chrono>
#include <thread>

#include "modbus/crc16.h"
#include "modbus/pdu.h"
#include "modbus/rtu.h"
#include "loader.h"
#include "runner/runner.h"
#include "targets/target.h"

namespace mbc::conf {
namespace {

using namespace std::chrono_literals;

// A slave on the master side of a pty: answers every 8-byte FC 03 request
// with one register, after `delay` (zero: at once).
class PtySlave {
 public:
  PtySlave() {
    if (openpty(&master_, &slave_, nullptr, nullptr, nullptr) != 0) throw std::runtime_error("openpty");
    termios t{};
    tcgetattr(slave_, &t);
    cfmakeraw(&t);
    tcsetattr(slave_, TCSANOW, &t);
    char name[256];
    ttyname_r(slave_, name, sizeof name);
    path_ = name;
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
  std::atomic<int> answered{0};
  std::atomic<bool> merge{false};

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
      if (in.size() < 8) continue;
      // Not addressed to unit 1: no reply; with `merge`, the next request is
      // taken as the rest of that frame and dropped too (a receiver held up
      // past the window reads both at once).
      if (in[0] != 1 || swallow_next_) {
        swallow_next_ = in[0] != 1 && merge.load();
        in.clear();
        continue;
      }
      std::this_thread::sleep_for(std::chrono::microseconds(delay_us.load()));
      Bytes reply = rtu_frame(in[0], Bytes{3, 2, 0x12, 0x34});
      in.clear();
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
    st.what = "read 0x0000";
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

}  // namespace
}  // namespace mbc::conf
