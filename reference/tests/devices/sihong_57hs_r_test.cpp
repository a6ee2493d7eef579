// The 57HS-R reference device driven over RTU as the manual
// (000_6950555f7a269f5a.txt) describes it: the §6.2.5 worked examples, the
// §7.6 start/stop commands, §7.5 homing and the §6.1 status words. Printed
// frames come from the spec's examples; expected values from the manual.
#include <gtest/gtest.h>

#include <algorithm>

#include "changed_spec.h"
#include "engine/device.h"
#include "loader.h"
#include "modbus/crc16.h"
#include "modbus/hex.h"

namespace mbc::ref {
namespace {

// §6.1 0x0007.
constexpr uint16_t kInPosition = 1 << 0, kHomed = 1 << 1, kRunning = 1 << 2, kReleased = 1 << 4;

class Sihong57hsR : public ::testing::Test {
 protected:
  Device dev{spec::load_spec_by_id("sihong-57hs-r"), 1};

  std::optional<Bytes> send(Bytes frame) {
    uint16_t c = crc16(frame);
    frame.push_back(uint8_t(c & 0xFF));
    frame.push_back(uint8_t(c >> 8));
    return dev.handle_rtu(frame);
  }
  uint16_t address(const char* key) const { return dev.reg_by_key(key).address; }
  // FC 06; the drive echoes the request (§6.2.2).
  void write(const char* key, uint16_t value) {
    uint16_t a = address(key);
    Bytes req{1, 6, uint8_t(a >> 8), uint8_t(a), uint8_t(value >> 8), uint8_t(value)};
    auto reply = send(req);
    ASSERT_TRUE(reply) << key;
    EXPECT_EQ(Bytes(reply->begin(), reply->end() - 2), req) << key;
  }
  // FC 16 of a 32-bit register, high word first (§6.2.3).
  void write32(const char* key, int32_t value) {
    uint16_t a = address(key);
    auto u = uint32_t(value);
    auto reply = send(
        {1, 16, uint8_t(a >> 8), uint8_t(a), 0, 2, 4, uint8_t(u >> 24), uint8_t(u >> 16), uint8_t(u >> 8), uint8_t(u)});
    ASSERT_TRUE(reply);
    EXPECT_EQ((*reply)[1], 16) << to_hex(*reply);
  }
  // FC 03 of a register's words, decoded as the spec types it.
  int64_t read(const char* key) {
    const spec::Register& r = dev.reg_by_key(key);
    auto reply = send({1, 3, uint8_t(r.address >> 8), uint8_t(r.address), 0, uint8_t(r.words)});
    EXPECT_TRUE(reply && reply->size() == size_t(5 + 2 * r.words) && (*reply)[1] == 3) << key;
    if (!reply || reply->size() != size_t(5 + 2 * r.words)) return -1;
    uint32_t v = 0;
    for (int i = 0; i < r.words; ++i) v = v << 16 | uint32_t((*reply)[3 + 2 * i] << 8 | (*reply)[4 + 2 * i]);
    if (r.type == spec::DataType::s16) return int16_t(v);
    if (r.type == spec::DataType::s32) return int32_t(v);
    return v;
  }
  // Replays a printed request and checks the printed response; §7.6 prints
  // requests only, and an FC 06 request is answered with its echo (§6.2.2).
  void replay(const spec::Example& e) {
    SCOPED_TRACE(e.id);
    auto reply = dev.handle_rtu(*parse_hex_strict(e.request));
    ASSERT_TRUE(reply);
    EXPECT_EQ(to_hex(*reply), e.response ? *e.response : e.request);
  }
  void replay(const std::string& id) {
    for (const auto& e : dev.spec().examples)
      if (e.id == id) return replay(e);
    FAIL() << "no example " << id;
  }
  void replay_sequence(const std::string& sequence) {
    std::vector<spec::Example> steps;
    for (const auto& e : dev.spec().examples)
      if (e.sequence == sequence) steps.push_back(e);
    ASSERT_FALSE(steps.empty());
    std::sort(steps.begin(), steps.end(), [](auto& a, auto& b) { return a.step < b.step; });
    for (const auto& e : steps) replay(e);
  }
  void wait_ms(uint64_t ms) { dev.advance(ms * 1000); }
  // Advances 10 ms at a time until `done` or `ms` pass; returns the time taken.
  template <class F>
  uint64_t wait_until(F done, uint64_t ms) {
    uint64_t t = 0;
    while (!done() && t < ms) wait_ms(10), t += 10;
    return t;
  }
  bool status(uint16_t bit) { return read("motion_status") & bit; }
};

// §6.2.5 position example, §7.1: start 10 r/min, 100 ms ramps, 500 r/min,
// 1000 pulses (one revolution at the default 1000 pulses/rev). The move
// takes both ramps plus a short cruise, reaches 500 r/min and never exceeds
// it, and ends exactly on +1000 in position.
TEST_F(Sihong57hsR, PositionExampleEndsExactlyAtPlus1000) {
  EXPECT_TRUE(status(kInPosition));
  replay_sequence("position-mode");
  int64_t peak = 0;
  for (int ms = 1; ms <= 199; ++ms) {
    wait_ms(1);
    peak = std::max(peak, read("current_speed"));
    ASSERT_LE(read("current_speed"), 500) << "at " << ms << " ms";
    ASSERT_EQ(read("motion_state"), 1) << "at " << ms << " ms";
  }
  EXPECT_TRUE(status(kRunning));
  EXPECT_FALSE(status(kInPosition));
  EXPECT_EQ(read("motion_direction"), 0);  // counter-clockwise = positive
  EXPECT_EQ(peak, 500);
  wait_ms(51);
  EXPECT_EQ(read("current_position"), 1000);
  EXPECT_EQ(dev.axis().position(), 1000.0);
  EXPECT_EQ(read("motion_state"), 0);
  EXPECT_EQ(read("current_speed"), 0);
  EXPECT_TRUE(status(kInPosition));
  EXPECT_FALSE(status(kRunning));
}

// §7.6.1: 0x0027 = 5 moves to the count, 0x0027 = 1 by the count.
TEST_F(Sihong57hsR, AbsoluteAndRelativeStarts) {
  write32("total_pulses", 3000);
  replay("start-relative-position");
  wait_ms(5000);
  EXPECT_EQ(read("current_position"), 3000);
  write32("total_pulses", 1200);
  replay("start-absolute-position");
  wait_ms(5000);
  EXPECT_EQ(read("current_position"), 1200);
  replay("start-relative-position");
  wait_ms(5000);
  EXPECT_EQ(read("current_position"), 2400);
}

// §7.1: a negative pulse count turns the motor the other way (0x0005 = 1).
TEST_F(Sihong57hsR, NegativePulseCountRunsClockwise) {
  write32("total_pulses", -2500);
  write("start_command", 1);
  wait_ms(100);
  EXPECT_EQ(read("motion_direction"), 1);
  wait_ms(10000);
  EXPECT_EQ(read("current_position"), -2500);
  EXPECT_TRUE(status(kInPosition));
}

// §6.2.5 speed example, §7.2: accelerate from 10 r/min to 500 r/min in
// 100 ms and hold it. The printed frames give +500, i.e. forward (erratum
// speed-example-direction).
TEST_F(Sihong57hsR, SpeedExampleRampsToMaxSpeedAndHoldsIt) {
  replay_sequence("speed-mode");
  wait_ms(50);
  int64_t ramping = read("current_speed");
  EXPECT_GT(ramping, 10);
  EXPECT_LT(ramping, 500);
  wait_ms(60);
  EXPECT_EQ(read("current_speed"), 500);
  int64_t at = read("current_position");
  wait_ms(1000);
  // 500 r/min at 1000 pulses/rev = 8333 pulses/s.
  EXPECT_NEAR(double(read("current_position") - at), 8333, 2);
  EXPECT_TRUE(status(kRunning));
  EXPECT_EQ(read("motion_direction"), 0);
}

// §7.2: a negative max speed runs in reverse.
TEST_F(Sihong57hsR, NegativeMaxSpeedRunsInReverse) {
  write("max_speed", uint16_t(-300));
  write("start_command", 2);
  wait_ms(500);
  EXPECT_EQ(read("current_speed"), 300);
  EXPECT_EQ(read("motion_direction"), 1);
  EXPECT_LT(read("current_position"), 0);
}

// §7.6.2: "收到急停命令 ... 不经过减速直接停止".
TEST_F(Sihong57hsR, EmergencyStopStopsAtOnce) {
  write("max_speed", 600);
  write("start_command", 2);
  wait_ms(1000);
  replay("stop-emergency");
  int64_t at = read("current_position");
  EXPECT_EQ(read("motion_state"), 0);
  EXPECT_EQ(read("current_speed"), 0);
  wait_ms(500);
  EXPECT_EQ(read("current_position"), at);
}

// §7.6.2: a normal stop decelerates over the decel time set BEFORE the move
// started (注意), here 100 ms, though 0x0022 is changed to 2000 ms meanwhile.
TEST_F(Sihong57hsR, NormalStopDeceleratesOverTheDecelTimeSetBeforeTheMove) {
  write("max_speed", 600);
  write("decel_time", 100);
  write("start_command", 2);
  wait_ms(1000);
  write("decel_time", 2000);
  replay("stop-normal");
  wait_ms(40);
  EXPECT_EQ(read("motion_state"), 1);  // decelerating, not stopped at once
  int64_t slowing = read("current_speed");
  EXPECT_GT(slowing, 0);
  EXPECT_LT(slowing, 600);
  wait_ms(61);
  EXPECT_EQ(read("motion_state"), 0);
  EXPECT_FALSE(status(kInPosition));
}

// §6.1 0x0011: the microstep code sets pulses per revolution; 60 r/min is
// 1 rev/s = 400 pulses/s at code 0 and 1000 pulses/s at the default code 8.
TEST_F(Sihong57hsR, MicrostepSetsPulsesPerRevolution) {
  write("accel_time", 0);
  write("max_speed", 60);
  write("start_command", 2);
  wait_ms(1000);
  EXPECT_NEAR(double(read("current_position")), 1000, 1);
  replay("stop-emergency");
  write("position_clear", 1);
  write("microstep", 0);
  write("start_command", 2);
  wait_ms(1000);
  EXPECT_NEAR(double(read("current_position")), 400, 1);
  EXPECT_EQ(read("current_speed"), 60);
}

// §7.5 mode 0 (the default): search forward for the home switch, stop,
// back off, find it again slowly going forward, stop: homing complete, and
// that point is position 0. X0 configured as the home input shows it.
TEST_F(Sihong57hsR, HomingMode0FindsTheHomeSwitch) {
  dev.axis().inputs.home_position = 5000;
  write("input_function.x0", 1);
  EXPECT_EQ(read("input_state") & 1, 0);
  replay("start-homing");
  wait_ms(100);
  EXPECT_EQ(read("work_mode"), 1);
  EXPECT_GT(read("current_position"), 0);
  uint64_t took = wait_until([&] { return status(kHomed); }, 20000);
  EXPECT_LT(took, 20000u);
  wait_ms(1000);  // and it stays there
  EXPECT_EQ(read("work_mode"), 0);
  EXPECT_EQ(read("current_position"), 0);
  EXPECT_EQ(read("motion_state"), 0);
  EXPECT_TRUE(status(kInPosition));
  EXPECT_EQ(read("input_state") & 1, 1);
  // Approached forward, it stops where the switch turns on.
  EXPECT_EQ(dev.axis().machine_position(), 5000.0 - dev.axis().inputs.home_width);
}

// §6.1 0x0009 / 0x004C~0x004D: Y0 as the in-position output, Y1 as the
// homing-complete output.
TEST_F(Sihong57hsR, OutputsFollowTheirFunctions) {
  write("output_function.y0", 4);
  write("output_function.y1", 3);
  EXPECT_EQ(read("output_state"), 0b01);  // in position at power-on, not homed
  write("start_command", 1);
  wait_ms(100);
  EXPECT_EQ(read("output_state"), 0b00);
  dev.axis().inputs.home_position = -100;
  write("homing_mode", 1);
  write("homing_command", 1);
  wait_until([&] { return status(kHomed); }, 20000);
  EXPECT_EQ(read("output_state"), 0b11);
}

// §7.5 mode 0: "碰到正限位后，反向运动继续查找原点".
TEST_F(Sihong57hsR, HomingMode0ReversesAtThePositiveLimit) {
  dev.axis().inputs.home_position = -3000;
  dev.axis().inputs.positive_limit = 2000;
  write("homing_command", 1);
  uint64_t took = wait_until([&] { return status(kHomed); }, 30000);
  EXPECT_LT(took, 30000u);
  EXPECT_EQ(dev.axis().machine_position(), -3000.0 - dev.axis().inputs.home_width);
  EXPECT_EQ(read("current_position"), 0);
}

// §7.5 mode 1: search backwards, then find the switch slowly going forward.
TEST_F(Sihong57hsR, HomingMode1SearchesBackwards) {
  dev.axis().inputs.home_position = -3000;
  write("homing_mode", 1);
  write("homing_command", 1);
  wait_ms(100);
  EXPECT_LT(read("current_position"), 0);
  uint64_t took = wait_until([&] { return status(kHomed); }, 20000);
  EXPECT_LT(took, 20000u);
  EXPECT_EQ(dev.axis().machine_position(), -3000.0 - dev.axis().inputs.home_width);
}

// §7.5 mode 3: search the negative limit, back off, find it again slowly.
TEST_F(Sihong57hsR, HomingMode3FindsTheNegativeLimit) {
  dev.axis().inputs.negative_limit = -4000;
  write("homing_mode", 3);
  write("homing_command", 1);
  uint64_t took = wait_until([&] { return status(kHomed); }, 20000);
  EXPECT_LT(took, 20000u);
  EXPECT_EQ(dev.axis().machine_position(), -4000.0);
  EXPECT_EQ(read("current_position"), 0);
}

// §6.1 0x0029 / 0x0007 bit 4: 0 releases the motor, and bit 4 reads 1
// (inverted sense: 0 = enabled).
TEST_F(Sihong57hsR, ReleaseShowsInBit4AndTheMotorDoesNotMove) {
  EXPECT_FALSE(status(kReleased));
  write("enable", 0);
  EXPECT_TRUE(status(kReleased));
  write("start_command", 1);
  wait_ms(1000);
  EXPECT_EQ(read("current_position"), 0);
  write("enable", 1);
  EXPECT_FALSE(status(kReleased));
  write("start_command", 1);
  wait_ms(10000);
  EXPECT_EQ(read("current_position"), 5000);  // the default count (§6.1 0x0024/0x0025)
}

// §6.1 0x002C: clears the current position.
TEST_F(Sihong57hsR, PositionClear) {
  write("start_command", 1);
  wait_ms(10000);
  EXPECT_EQ(read("current_position"), 5000);
  write("position_clear", 1);
  EXPECT_EQ(read("current_position"), 0);
}

// §6.1 0x002B: 2 saves the RW parameters (kept across a power cycle), 1
// restores the factory settings.
TEST_F(Sihong57hsR, SaveAndFactoryResetCommands) {
  write("max_speed", 1000);
  dev.power_cycle();
  EXPECT_EQ(read("max_speed"), 60);  // RW: not stored until saved
  write("max_speed", 1000);
  write("param_command", 2);
  dev.power_cycle();
  EXPECT_EQ(read("max_speed"), 1000);
  write("param_command", 1);
  EXPECT_EQ(read("max_speed"), 60);
  dev.power_cycle();
  EXPECT_EQ(read("max_speed"), 60);
}

// §6.1 0x0002: the address the drive currently answers to.
TEST_F(Sihong57hsR, ReportsItsSlaveAddress) { EXPECT_EQ(read("current_slave_id"), 1); }

// The device takes its control facts from the spec (issue 38): the same
// spec with one fact changed, loaded as a user's file is, changes it so.
class Sihong57hsRFromAChangedSpec : public Sihong57hsR {
 protected:
  void load_changed(const std::vector<std::pair<std::string, std::string>>& edits) {
    load_changed_spec(dev, "sihong-57hs-r", edits);
  }
};

// The stop and emergency stop words swapped: 0x0028 = 1 decelerates, 0 stops at once.
TEST_F(Sihong57hsRFromAChangedSpec, StopsActOnTheWordsTheSpecGives) {
  load_changed({{"id: stop\n      name: {zh: 正常停止, en: \"normal stop (decelerate)\"}\n      register: stop_command\n"
                 "      mask: 0x0001\n      value: 0x0000",
                 "id: stop\n      name: {zh: 正常停止, en: \"normal stop (decelerate)\"}\n      register: stop_command\n"
                 "      mask: 0x0001\n      value: 0x0001"},
                {"id: emergency_stop\n      name: {zh: 急停, en: \"emergency stop\"}\n      register: stop_command\n"
                 "      mask: 0x0001\n      value: 0x0001",
                 "id: emergency_stop\n      name: {zh: 急停, en: \"emergency stop\"}\n      register: stop_command\n"
                 "      mask: 0x0001\n      value: 0x0000"}});
  write("max_speed", 600);
  write("decel_time", 100);
  write("start_command", 2);
  wait_ms(1000);
  write("stop_command", 1);  // §7.6.2's emergency stop word: now the normal stop
  wait_ms(40);
  EXPECT_EQ(read("motion_state"), 1);
  EXPECT_GT(read("current_speed"), 0);
  wait_ms(100);
  EXPECT_EQ(read("current_speed"), 0);
  write("start_command", 2);
  wait_ms(1000);
  write("stop_command", 0);  // §7.6.2's normal stop word: now at once
  EXPECT_EQ(read("current_speed"), 0);
  EXPECT_EQ(read("motion_state"), 0);
}

// The alarm state read from bits 3 and 6 instead of 0x0007 Bit3 alone: a fault sets both.
TEST_F(Sihong57hsRFromAChangedSpec, TheAlarmBitIsTheAlarmStatesReading) {
  load_changed({{"status: [{register: motion_status, mask: 0x0008, value: 0x0008}]",
                 "status: [{register: motion_status, mask: 0x0048, value: 0x0048}]"}});
  ASSERT_TRUE(dev.trip_fault());
  EXPECT_EQ(read("motion_status") & 0x0048, 0x0048);
}

// A start word outside 7.6.1's: relative moves on 0x0027 = 3, and 1 starts nothing.
TEST_F(Sihong57hsRFromAChangedSpec, StartsActOnTheWordsTheSpecGives) {
  load_changed({{"mask: 0x0007\n      value: 0x0001", "mask: 0x0007\n      value: 0x0003"}});
  write32("total_pulses", 3000);
  write("start_command", 1);
  wait_ms(5000);
  EXPECT_EQ(read("current_position"), 0);
  write("start_command", 3);
  wait_ms(5000);
  EXPECT_EQ(read("current_position"), 3000);
}

}  // namespace
}  // namespace mbc::ref
