// The Hanstar 7TRSM5740Q reference device driven over RTU as its manual
// (002_20d5da5312f4fe5b.txt, §5-§6) describes it: the power-on state, homing
// (§5.2 figures 5/6), positioning, forward/reverse and speed mode (§5.3,
// §5.4), 到位 mode (§5.5), speed changes (表 16), limit alarms (表 M01), the
// hardware configuration (表 M02) and saving to flash (4002). Printed frames
// come from the spec's examples; expected values from the manual's rules.
#include <gtest/gtest.h>

#include <bit>
#include <filesystem>
#include <fstream>
#include <sstream>

#include "changed_spec.h"
#include "engine/device.h"
#include "loader.h"
#include "modbus/crc16.h"
#include "modbus/hex.h"

namespace mbc::ref {
namespace {

// 表 M01 status values.
constexpr uint16_t kIdle = 0x00, kRunning = 0x01, kHoming = 0x08, kUndefined = 0xFF;
constexpr uint16_t kHomingFailed = 0x10, kUpWhileForward = 0x60, kDownWhileReverse = 0x70;
// 表 M02 bits.
constexpr uint16_t kUpActiveHigh = 1 << 0, kReverseMotor = 1 << 7;

// The parameters a master sets first (§5.6 第六步); the manual prints no defaults.
constexpr uint16_t kMicrostep = 16;
constexpr uint16_t kHomingPeriod = 500;  // us: 2000 steps/s
constexpr uint16_t kRunPeriod = 100;     // us: 10000 steps/s
constexpr double kHomingSpeed = 1e6 / kHomingPeriod, kRunSpeed = 1e6 / kRunPeriod;

class Hanstar : public ::testing::Test {
 protected:
  Device dev{spec::load_spec_by_id("hanstar-7trsm5740q"), 1};

  std::optional<Bytes> send(Bytes frame) {
    uint16_t c = crc16(frame);
    frame.push_back(uint8_t(c & 0xFF));
    frame.push_back(uint8_t(c >> 8));
    return dev.handle_rtu(frame);
  }
  // FC 06 (§6.3.2): the drive echoes the request.
  void write(const char* key, uint16_t value) {
    uint16_t a = dev.reg_by_key(key).address;
    Bytes req{1, 6, uint8_t(a >> 8), uint8_t(a), uint8_t(value >> 8), uint8_t(value)};
    auto reply = send(req);
    ASSERT_TRUE(reply);
    EXPECT_EQ(Bytes(reply->begin(), reply->end() - 2), req);
  }
  // FC 16 of a 32-bit register, high word first (§6.3.3): echoes address and quantity.
  void write32(const char* key, uint32_t value) {
    uint16_t a = dev.reg_by_key(key).address;
    auto reply = send({1, 16, uint8_t(a >> 8), uint8_t(a), 0, 2, 4, uint8_t(value >> 24), uint8_t(value >> 16),
                       uint8_t(value >> 8), uint8_t(value)});
    ASSERT_TRUE(reply);
    EXPECT_EQ(to_hex(*reply).substr(0, 17), to_hex(Bytes{1, 16, uint8_t(a >> 8), uint8_t(a), 0, 2}));
  }
  std::vector<uint16_t> read_words(uint16_t a, uint16_t count) {
    auto reply = send({1, 3, uint8_t(a >> 8), uint8_t(a), 0, uint8_t(count)});
    EXPECT_TRUE(reply && reply->size() == size_t(5 + 2 * count)) << (reply ? to_hex(*reply) : "silence");
    if (!reply || reply->size() != size_t(5 + 2 * count)) return std::vector<uint16_t>(count, 0xDEAD);
    std::vector<uint16_t> words;
    for (int i = 0; i < count; ++i) words.push_back(uint16_t((*reply)[3 + 2 * i] << 8 | (*reply)[4 + 2 * i]));
    return words;
  }
  uint16_t read(const char* key) { return read_words(dev.reg_by_key(key).address, 1)[0]; }
  int32_t read32(const char* key) {  // 表 12: high 16 bits at the lower address
    auto w = read_words(dev.reg_by_key(key).address, 2);
    return int32_t(uint32_t(w[0]) << 16 | w[1]);
  }
  uint16_t status() { return read("motor_status"); }
  int32_t position() { return read32("current_position"); }
  void replay(const std::string& id) {
    for (const auto& e : dev.spec().examples)
      if (e.id == id) {
        auto reply = dev.handle_rtu(*parse_hex_strict(e.resolved_request.value_or(e.request)));
        ASSERT_TRUE(reply);
        EXPECT_EQ(to_hex(*reply), e.resolved_response.value_or(*e.response));
        return;
      }
    FAIL() << "no example " << id;
  }
  void wait_s(double s) { dev.advance(uint64_t(s * 1e6)); }

  // Parameters survive the power cycle only when saved (4002); save them.
  void configure(uint32_t accel_steps = 0) {
    write("microstep", kMicrostep);
    write("homing_period", kHomingPeriod);
    write("run_period", kRunPeriod);
    write32("accel_steps", accel_steps);
    write32("homing_max_steps", 20000);
    write32("release_steps", 500);
    write("save_command", 1);
    dev.power_cycle();
  }
};

// 表 M01: "0xff 开机未定义状态"; the spec's default for 1004 says the same.
TEST_F(Hanstar, StatusIsUndefinedAfterPowerOn) {
  EXPECT_EQ(status(), kUndefined);
  EXPECT_EQ(int64_t(*dev.reg_by_key("motor_status").default_value), kUndefined);
  configure();
  write32("forward_command", 10);
  wait_s(1);
  EXPECT_EQ(status(), kIdle);
  dev.power_cycle();
  EXPECT_EQ(status(), kUndefined);
}

// 表 15 / §5.2: positioning only "步进一体机正确复位情况下". The write is
// acknowledged (no exception reply is printed) but the motor does not move.
TEST_F(Hanstar, PositioningIsRefusedBeforeHoming) {
  configure();
  write32("position_command", 5000);
  wait_s(5);
  EXPECT_EQ(position(), 0);
  EXPECT_EQ(read32("target_position"), 0);
  EXPECT_EQ(status(), kUndefined);
}

// §5.2 figure 5: home signal inactive at the start; the drive runs in reverse
// at the homing speed until the signal turns active, and that point is zero.
TEST_F(Hanstar, HomingSearchesInReverseAndZeroesAtTheSwitch) {
  configure();
  dev.axis().inputs.home_position = -3000;  // active from -3050 to -2950
  write("home_command", 0x1234);            // "写任何值"
  wait_s(0.5);
  EXPECT_EQ(status(), kRunning | kHoming);
  EXPECT_EQ(position(), -int32_t(0.5 * kHomingSpeed));
  wait_s(1.5);  // 2950 steps at 2000 steps/s = 1.475 s
  EXPECT_EQ(status(), kIdle);
  EXPECT_EQ(position(), 0);
  EXPECT_NEAR(dev.axis().position(), -2950, 1e-6);

  // Positioning now works and ends on the target.
  write32("position_command", 5000);
  EXPECT_EQ(read32("target_position"), 5000);
  wait_s(0.1);
  EXPECT_EQ(status(), kRunning);
  wait_s(1);  // 5000 steps at 10000 steps/s
  EXPECT_EQ(position(), 5000);
  EXPECT_EQ(status(), kIdle);
  EXPECT_NEAR(dev.axis().position(), 2050, 1e-6);
  // §5.2: a new target replaces an unfinished one.
  write32("position_command", 0);
  wait_s(0.2);
  write32("position_command", 8000);
  wait_s(2);
  EXPECT_EQ(position(), 8000);
}

// §5.2 figure 6: signal active at the start: forward the release steps
// (3014), then the reverse search finds the switch's upper edge.
TEST_F(Hanstar, HomingOnTheSwitchFirstRunsTheReleaseSteps) {
  configure();
  dev.axis().inputs.home_position = 0;  // active from -50 to +50
  write("home_command", 1);
  wait_s(0.2);  // 400 of the 500 release steps
  EXPECT_EQ(position(), 400);
  EXPECT_EQ(status(), kRunning | kHoming);
  wait_s(1);  // 500 forward, back 450 to the edge at +50
  EXPECT_EQ(status(), kIdle);
  EXPECT_EQ(position(), 0);
  EXPECT_NEAR(dev.axis().position(), 50, 1e-6);
}

// §5.2: still on the switch after the release steps: homing error (表 M01 0x1).
TEST_F(Hanstar, HomingFailsWhenTheReleaseStepsDoNotLeaveTheSwitch) {
  configure();
  dev.axis().inputs.home_position = 0;
  dev.axis().inputs.home_width = 1000;
  write("home_command", 1);
  wait_s(1);
  EXPECT_EQ(status(), kHomingFailed);
  write32("position_command", 100);
  wait_s(1);
  EXPECT_EQ(position(), 500);  // positioning refused: not homed
}

// §5.2: no signal within the maximum search steps (3010): stop with the
// homing error alarm.
TEST_F(Hanstar, HomingFailsAfterTheMaximumSearchSteps) {
  configure();
  write("home_command", 1);
  wait_s(20000 / kHomingSpeed + 1);
  EXPECT_EQ(status(), kHomingFailed);
  EXPECT_EQ(position(), -20000);
}

// §6.3.3: 01 10 07 D4 00 02 04 00 00 03 E8 D9 8E, "正转 1000 步". 表 15: works
// in any state and forces "correctly homed", so positioning works afterwards.
TEST_F(Hanstar, ForwardThousandStepsFromTheManualFrame) {
  configure();
  replay("forward-1000-steps");
  EXPECT_EQ(read32("target_position"), 1000);
  wait_s(0.05);
  EXPECT_EQ(status(), kRunning);
  wait_s(0.1);
  EXPECT_EQ(position(), 1000);
  EXPECT_EQ(status(), kIdle);
  write32("position_command", 300);
  wait_s(0.1);
  EXPECT_EQ(position(), 300);
}

// §6.2: the four values are one 8-register read from 1000.
TEST_F(Hanstar, StatusBlockReadsAsEightRegisters) {
  configure();
  write32("reverse_command", 0);
  wait_s(0.01);
  auto w = read_words(1000, 8);
  EXPECT_EQ(int32_t(uint32_t(w[0]) << 16 | w[1]), -100);
  EXPECT_EQ(w[4], kRunning);
  EXPECT_EQ(w[5], kRunPeriod);  // 1005: current pulse period (erratum status-block-layout)
}

// §5.4: 0 steps runs on (speed mode); §6.3.2: 2001 stops it.
TEST_F(Hanstar, ZeroStepsRunsUntilStopped) {
  configure();
  write32("reverse_command", 0);
  wait_s(1);
  EXPECT_EQ(position(), -int32_t(kRunSpeed));
  EXPECT_EQ(status(), kRunning);
  replay("stop-motor");
  wait_s(0.01);
  EXPECT_EQ(status(), kIdle);
  EXPECT_EQ(position(), -int32_t(kRunSpeed));
}

// §5.3 / 表 M01: UP hit running forward is alarm 6, DW running in reverse 7.
// In forward/reverse mode the drive takes the next command; with the limit
// still there it does not move in that direction, but moves away from it.
TEST_F(Hanstar, LimitAlarmsInForwardReverseMode) {
  configure();
  dev.axis().inputs.positive_limit = 2000;
  dev.axis().inputs.negative_limit = -1000;
  write32("forward_command", 0);
  wait_s(1);
  EXPECT_EQ(position(), 2000);
  EXPECT_EQ(status(), kUpWhileForward);
  write32("forward_command", 100);
  wait_s(0.1);
  EXPECT_EQ(position(), 2000);
  EXPECT_EQ(status(), kUpWhileForward);
  write32("reverse_command", 5000);
  wait_s(1);
  EXPECT_EQ(position(), -1000);
  EXPECT_EQ(status(), kDownWhileReverse);
}

// §5.2: a limit during positioning stops with the alarm, and the drive then
// takes no positioning command ("步进一体机不响应定位指令"); §5.3 "在定位模式下，
// 这两种情况，步进一体机都不动作".
TEST_F(Hanstar, LimitDuringPositioningBlocksPositioning) {
  configure();
  dev.axis().inputs.home_position = -100;
  dev.axis().inputs.positive_limit = 2000;
  write("home_command", 1);
  wait_s(1);
  ASSERT_EQ(status(), kIdle);
  write32("position_command", 5000);
  wait_s(1);
  EXPECT_EQ(status(), kUpWhileForward);
  int32_t stopped = position();
  EXPECT_EQ(stopped, 2000 + 50);  // the limit at machine 2000; zero at machine -50
  write32("position_command", 0);
  wait_s(1);
  EXPECT_EQ(position(), stopped);
}

// §5.5 / 表 17: 到位 commands turn UP/DW into arrival signals: the motor
// stops where it meets ("碰到") the chosen signal, with no alarm, and neither
// signal stops it as a limit.
TEST_F(Hanstar, ArrivalCommandsStopOnTheSignalWithoutAlarm) {
  configure();
  dev.axis().inputs.positive_limit = 2000;
  dev.axis().inputs.negative_limit = -1000;
  write32("forward_command", 1);  // forces "correctly homed" (表 15)
  wait_s(0.01);
  write32("arrival_forward_up", 10000);
  wait_s(2);
  EXPECT_EQ(status(), kIdle);
  EXPECT_NEAR(position(), 2000, 1);  // met within one step
  // 2206: reverse, stopping on UP: DW is no limit now and is passed.
  write32("arrival_reverse_up", 6000);
  wait_s(1);
  EXPECT_EQ(status(), kIdle);
  EXPECT_NEAR(position(), -4000, 1);
  // 2202: positioning, stopping on UP: ends on the target short of UP.
  write32("arrival_position_up", 0);
  wait_s(1);
  EXPECT_EQ(status(), kIdle);
  EXPECT_EQ(position(), 0);
  // 2406: reverse, stopping on DW (met at -1000).
  write32("arrival_reverse_dw", 5000);
  wait_s(1);
  EXPECT_EQ(status(), kIdle);
  EXPECT_NEAR(position(), -1000, 1);
}

// 表 17: "到位功能均在步进一体机正确复位情况下".
TEST_F(Hanstar, ArrivalCommandsNeedHoming) {
  configure();
  write32("arrival_forward_up", 1000);
  wait_s(1);
  EXPECT_EQ(position(), 0);
  EXPECT_EQ(status(), kUndefined);
}

// 表 16 and §5.7: 2008 is the pulse period; 2010 an IEEE-754 rpm with
// rpm = 300000 / (period * 细分), so 375 rpm at 细分 16 is a 50 us period.
TEST_F(Hanstar, SpeedChangesByPeriodAndByRpm) {
  configure();
  write32("forward_command", 0);
  wait_s(0.1);
  write("speed_period_command", 200);
  wait_s(0.01);
  EXPECT_EQ(read("current_period"), 200);
  int32_t before = position();
  wait_s(1);
  EXPECT_EQ(position() - before, 5000);
  write32("speed_rpm_command", std::bit_cast<uint32_t>(375.0f));
  wait_s(0.01);
  EXPECT_EQ(read("current_period"), 50);
}

// §5.7: the start speed (3008) ramps to the running speed over
// (PlusStartTime + PlusConstantTime) * AccSteps * 0.5 us = (500 + 100) * 100 * 0.5 us = 30 ms.
TEST_F(Hanstar, AccelerationTimeFollowsTheSCurveParameters) {
  configure(100);
  write32("forward_command", 0);
  wait_s(0.001);
  EXPECT_GT(read("current_period"), kRunPeriod * 2);
  wait_s(0.028);
  EXPECT_GT(read("current_period"), kRunPeriod);
  wait_s(0.002);
  EXPECT_EQ(read("current_period"), kRunPeriod);
}

// 表 M02 bit 0: UP active high. With no switch wired the line floats high, so
// the drive sees UP everywhere: forward does not move and alarms.
TEST_F(Hanstar, InvertedUpPolarityBlocksForward) {
  configure();
  write("hw_config", kUpActiveHigh);
  write32("forward_command", 100);
  wait_s(1);
  EXPECT_EQ(position(), 0);
  EXPECT_EQ(status(), kUpWhileForward);
  write32("reverse_command", 100);
  wait_s(1);
  EXPECT_EQ(position(), -100);
}

// 表 M02 bit 7: the motor turns the other way; the drive's count does not care.
TEST_F(Hanstar, ReversedMotorMovesTheMachineTheOtherWay) {
  configure();
  write("hw_config", kReverseMotor);
  write32("forward_command", 1000);
  wait_s(1);
  EXPECT_EQ(position(), 1000);
  EXPECT_NEAR(dev.axis().position(), -1000, 1e-6);
}

// 4002: "参数存储到内部 flash": saved parameters survive a power cycle, others do not.
TEST_F(Hanstar, SaveToFlashKeepsParameters) {
  write("run_period", 123);
  dev.power_cycle();
  EXPECT_NE(read("run_period"), 123);
  write("run_period", 123);
  write("save_command", 1);
  write("run_period", 456);
  dev.power_cycle();
  EXPECT_EQ(read("run_period"), 123);
}

// §6.1: "一次最多只能写 2 个寄存器" (spec: FC 16 max_quantity 2). The manual
// prints no exception reply (quantity_over_limit: unspecified), so the
// reference answers as the standard does: ILLEGAL DATA VALUE (MBAP v1.1b3
// §6.12), and nothing is written.
TEST_F(Hanstar, WriteOfThreeRegistersIsRefused) {
  const auto& s = dev.spec();
  ASSERT_EQ(s.profile.function(16)->max_quantity, 2);
  ASSERT_EQ(s.profile.policy(spec::Violation::quantity_over_limit).kind, spec::PolicyEntry::Kind::unspecified);
  auto before = dev.holding_image();
  uint16_t a = dev.reg_by_key("microstep").address;
  auto reply = send({1, 16, uint8_t(a >> 8), uint8_t(a), 0, 3, 6, 0, 16, 0, 0, 0, 1});
  ASSERT_TRUE(reply);
  EXPECT_EQ(Bytes(reply->begin(), reply->end() - 2), (Bytes{1, 0x90, 3}));
  EXPECT_EQ(dev.holding_image(), before);
}

// The device takes what its spec states from the spec (issue 38): the
// control's command words, its states' status readings, whether positioning
// waits for homing, and the 表 M02 fields by key. The shipped spec with one
// of them changed, written to a temporary directory and loaded as a user's
// spec file is, changes the device the same way.
class HanstarFromAChangedSpec : public Hanstar {
 protected:
  void load_changed(const std::vector<std::pair<std::string, std::string>>& edits) {
    load_changed_spec(dev, "hanstar-7trsm5740q", edits);
  }
};

// control.commands stop: "any word" (mask 0) becomes the word 1 alone.
TEST_F(HanstarFromAChangedSpec, StopActsOnTheWordTheSpecGives) {
  load_changed({{"register: stop_command\n      mask: 0x0000\n      value: 0x0000",
                 "register: stop_command\n      mask: 0xFFFF\n      value: 0x0001"}});
  configure();
  write32("forward_command", 0);  // §5.4: speed mode
  wait_s(0.5);
  write("stop_command", 0);  // the 6.3.2 frame's word: no longer the stop
  wait_s(0.5);
  EXPECT_EQ(status(), kRunning);
  EXPECT_NEAR(position(), kRunSpeed, 1);
  write("stop_command", 1);
  wait_s(0.5);
  EXPECT_EQ(status(), kIdle);
  EXPECT_NEAR(position(), kRunSpeed, 1);
}

// The homing_failed state reads Bit[7:4] = 0x2 instead of 表 M01's 0x1.
TEST_F(HanstarFromAChangedSpec, AlarmCodesAreTheStatesReadings) {
  load_changed({{"status: [{register: motor_status, mask: 0x00F0, value: 0x0010}]",
                 "status: [{register: motor_status, mask: 0x00F0, value: 0x0020}]"}});
  configure();
  write("home_command", 1);
  wait_s(20000 / kHomingSpeed + 1);
  EXPECT_EQ(status(), 0x20);
}

// No control.motion.positioning_needs_homing: 2002 acts before any homing.
TEST_F(HanstarFromAChangedSpec, PositioningWaitsForHomingOnlyWhereTheSpecSaysSo) {
  load_changed({{"    positioning_needs_homing: {position_command: position_command, section: \"5.2\"}\n", ""}});
  configure();
  write32("position_command", 5000);
  wait_s(1.5);
  EXPECT_EQ(position(), 5000);
  EXPECT_EQ(status(), kIdle);
}

// 表 M02 by key: with the keys of bits 4 and 7 swapped, bit 4 reverses the motor.
TEST_F(HanstarFromAChangedSpec, TheMotorDirectionBitIsTheKeyedField) {
  load_changed({{"{bit: 4, key: idle_hold,", "{bit: 4, key: reverse_direction,"},
                {"{bit: 7, key: reverse_direction,", "{bit: 7, key: idle_hold,"}});
  configure();
  write("hw_config", kReverseMotor);  // bit 7: now the idle hold
  write32("forward_command", 1000);
  wait_s(1);
  EXPECT_EQ(position(), 1000);
  EXPECT_NEAR(dev.axis().position(), 1000, 1e-6);
  write("hw_config", 1 << 4);  // bit 4: now the direction
  write32("forward_command", 1000);
  wait_s(1);
  EXPECT_EQ(position(), 2000);
  EXPECT_NEAR(dev.axis().position(), 0, 1e-6);
}

}  // namespace
}  // namespace mbc::ref
