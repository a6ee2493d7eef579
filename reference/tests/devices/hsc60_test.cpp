// The HSC60 reference device driven over RTU as its manual
// (001_f56de7e2fd70f1f6.txt, 四) describes it: the motion command (70), the
// status (75) and control (73) words, the counters (39~42) and the save (90)
// and factory reset (91) commands. Printed frames come from the spec's
// examples; expected values from the manual's register table.
#include <gtest/gtest.h>

#include "changed_spec.h"
#include "engine/device.h"
#include "loader.h"
#include "modbus/crc16.h"
#include "modbus/hex.h"

namespace mbc::ref {
namespace {

// 四 驱动器状态寄存器.
constexpr uint16_t kPositiveLimit = 1 << 4, kNegativeLimit = 1 << 5, kMotionComplete = 1 << 7;

class Hsc60 : public ::testing::Test {
 protected:
  Device dev{spec::load_spec_by_id("hsc60"), 1};

  std::optional<Bytes> send(Bytes frame) {
    uint16_t c = crc16(frame);
    frame.push_back(uint8_t(c & 0xFF));
    frame.push_back(uint8_t(c >> 8));
    return dev.handle_rtu(frame);
  }
  // FC 06 to one word; the drive echoes it (四 1.2.2).
  void write_word(uint16_t a, uint16_t value) {
    Bytes req{1, 6, uint8_t(a >> 8), uint8_t(a), uint8_t(value >> 8), uint8_t(value)};
    auto reply = send(req);
    ASSERT_TRUE(reply);
    EXPECT_EQ(Bytes(reply->begin(), reply->end() - 2), req);
  }
  void write(const char* key, uint16_t value) { write_word(dev.reg_by_key(key).address, value); }
  // FC 16 of a 32-bit register, low word first (四 1.2.3).
  void write32(const char* key, uint32_t value) {
    uint16_t a = dev.reg_by_key(key).address;
    auto reply = send({1, 16, uint8_t(a >> 8), uint8_t(a), 0, 2, 4, uint8_t(value >> 8), uint8_t(value),
                       uint8_t(value >> 24), uint8_t(value >> 16)});
    ASSERT_TRUE(reply);
    EXPECT_EQ((*reply)[1], 16) << to_hex(*reply);
  }
  // FC 03 of `count` words from `a`.
  std::vector<uint16_t> read_words(uint16_t a, uint16_t count) {
    auto reply = send({1, 3, uint8_t(a >> 8), uint8_t(a), 0, uint8_t(count)});
    std::vector<uint16_t> words;
    EXPECT_TRUE(reply && reply->size() == size_t(5 + 2 * count)) << (reply ? to_hex(*reply) : "silence");
    if (!reply || reply->size() != size_t(5 + 2 * count)) return std::vector<uint16_t>(count, 0xDEAD);
    for (int i = 0; i < count; ++i) words.push_back(uint16_t((*reply)[3 + 2 * i] << 8 | (*reply)[4 + 2 * i]));
    return words;
  }
  uint16_t read(const char* key) { return read_words(dev.reg_by_key(key).address, 1)[0]; }
  // A low-word-first 32-bit value (四: "低16bit" at the lower address).
  uint32_t read32(const char* key) {
    auto w = read_words(dev.reg_by_key(key).address, 2);
    return uint32_t(w[1]) << 16 | w[0];
  }
  uint32_t pulse_count() {
    auto w = read_words(dev.reg_by_key("pulse_count_low").address, 2);
    return uint32_t(w[1]) << 16 | w[0];
  }
  void replay(const std::string& id) {
    for (const auto& e : dev.spec().examples)
      if (e.id == id) {
        auto reply = dev.handle_rtu(*parse_hex_strict(e.request));
        ASSERT_TRUE(reply);
        EXPECT_EQ(to_hex(*reply), *e.response);
        return;
      }
    FAIL() << "no example " << id;
  }
  void wait_ms(uint64_t ms) { dev.advance(ms * 1000); }
  bool status(uint16_t bit) { return read("status") & bit; }
};

// 四 1.2.3 writes travel = 80000; command 1 (正向定长运动) then moves 80000
// pulses at the default 1600 pulse/s with 3200 pulse/s^2 ramps: 0.5 s and
// 400 pulses each ramp, 79200 pulses at speed (49.5 s), 50.5 s in all.
// Register 70 reads 6 once the command fired; bit 7 of 75 is 1 when done.
TEST_F(Hsc60, ForwardLengthMoveTravelsTheFc16Travel) {
  EXPECT_TRUE(status(kMotionComplete));  // default 1 (四 驱动器状态寄存器)
  replay("fc16-write-travel");
  write("motion_command", 1);
  EXPECT_EQ(read("motion_command"), 6);
  wait_ms(1000);
  EXPECT_FALSE(status(kMotionComplete));
  wait_ms(49000);  // t = 50 s: still braking
  EXPECT_FALSE(status(kMotionComplete));
  wait_ms(600);
  EXPECT_TRUE(status(kMotionComplete));
  EXPECT_EQ(pulse_count(), 80000u);
  EXPECT_EQ(dev.axis().position(), 80000.0);
  EXPECT_EQ(read("motion_command"), 6);
}

// Command 2 (反向定长运动) with the default travel 1600.
TEST_F(Hsc60, ReverseLengthMove) {
  write("motion_command", 2);
  wait_ms(3000);
  EXPECT_TRUE(status(kMotionComplete));
  EXPECT_EQ(pulse_count(), uint32_t(-1600));
}

// Register 72: 0 incremental, 1 absolute.
TEST_F(Hsc60, AbsoluteAndIncrementalModes) {
  write32("travel", 1000);
  write("move_mode", 1);
  write("motion_command", 1);
  wait_ms(3000);
  write("motion_command", 1);
  wait_ms(3000);
  EXPECT_EQ(pulse_count(), 1000u);  // absolute: already there
  write("move_mode", 0);
  write("motion_command", 1);
  wait_ms(3000);
  EXPECT_EQ(pulse_count(), 2000u);
}

// Commands 3 (正向连续运动) and 0 (减速停止): 400 pulses to reach 1600
// pulse/s, then 1600 pulse/s; the stop takes 0.5 s and 400 pulses.
TEST_F(Hsc60, ContinuousMoveAndDecelerationStop) {
  write("motion_command", 3);
  wait_ms(2000);
  EXPECT_EQ(pulse_count(), 400u + 2400u);
  EXPECT_FALSE(status(kMotionComplete));
  write("motion_command", 0);
  wait_ms(250);
  EXPECT_FALSE(status(kMotionComplete));
  wait_ms(260);
  EXPECT_TRUE(status(kMotionComplete));
  EXPECT_EQ(pulse_count(), 3200u);
}

// Commands 4 (反向连续运动) and 5 (立即停止).
TEST_F(Hsc60, ReverseContinuousAndImmediateStop) {
  write("motion_command", 4);
  wait_ms(1000);
  write("motion_command", 5);
  uint32_t at = pulse_count();
  EXPECT_EQ(at, uint32_t(-(400 + 800)));
  EXPECT_TRUE(status(kMotionComplete));
  wait_ms(1000);
  EXPECT_EQ(pulse_count(), at);
}

// Status bits 4/5 show the limit signals; travel stops at a limit switch.
TEST_F(Hsc60, LimitsStopTravelAndShowInTheStatus) {
  dev.axis().inputs.positive_limit = 1000;
  dev.axis().inputs.negative_limit = -500;
  EXPECT_FALSE(status(kPositiveLimit));
  write("motion_command", 3);
  wait_ms(5000);
  EXPECT_EQ(pulse_count(), 1000u);
  EXPECT_TRUE(status(kPositiveLimit));
  EXPECT_FALSE(status(kNegativeLimit));
  EXPECT_TRUE(status(kMotionComplete));
  write("motion_command", 4);
  wait_ms(5000);
  EXPECT_EQ(pulse_count(), uint32_t(-500));
  EXPECT_TRUE(status(kNegativeLimit));
  EXPECT_FALSE(status(kPositiveLimit));
}

// Register 73 bit 0 = 0: "光耦关断时发生正限位" - with the switch released the
// drive sees the positive limit, and refuses to travel forward.
TEST_F(Hsc60, ControlRegisterInvertsTheLimitLevel) {
  dev.axis().inputs.positive_limit = 1000;
  write("control", 3 & ~1);
  EXPECT_TRUE(status(kPositiveLimit));
  write("motion_command", 3);
  wait_ms(1000);
  EXPECT_EQ(pulse_count(), 0u);
  write("motion_command", 4);  // backwards is free
  wait_ms(1000);
  EXPECT_EQ(pulse_count(), uint32_t(-1200));
}

// Register 90: "返回1：保存未完成 返回0：保存已经完成"; the reference takes 10 ms.
TEST_F(Hsc60, SaveReadsOneUntilDoneThenZero) {
  write32("speed", 5000);
  write("save", 1);
  EXPECT_EQ(read("save"), 1);
  wait_ms(5);
  EXPECT_EQ(read("save"), 1);
  wait_ms(6);
  EXPECT_EQ(read("save"), 0);
  dev.power_cycle();
  EXPECT_EQ(read32("speed"), 5000u);
}

// Register 91: "写入1启动清除 ... 返回1：清除未完成 返回0: 清除已经完成".
TEST_F(Hsc60, FactoryResetReadsOneUntilDoneThenZero) {
  write32("speed", 5000);
  write("save", 1);
  wait_ms(20);
  write("factory_reset", 1);
  EXPECT_EQ(read("factory_reset"), 1);
  wait_ms(11);
  EXPECT_EQ(read("factory_reset"), 0);
  EXPECT_EQ(read32("speed"), 1600u);  // the table's default
  dev.power_cycle();
  EXPECT_EQ(read32("speed"), 1600u);
}

// Register 40: "写入1清除计数器"; the encoder count (41/42) is unaffected.
TEST_F(Hsc60, WritingOneTo40ClearsThePulseCounter) {
  write("motion_command", 1);
  wait_ms(3000);
  EXPECT_EQ(pulse_count(), 1600u);
  write("pulse_count_high", 1);
  EXPECT_EQ(pulse_count(), 0u);
  EXPECT_NE(read32("encoder_count"), 0u);
}

// 41/42 follow the axis: 4 counts per line (register 30: "1000表示90度" with
// the 1000-line encoder of register 29), 6000 pulses/rev (register 1), so
// 1600 pulses = 1600 * 4000 / 6000 = 1066.7 counts; backwards is negative.
TEST_F(Hsc60, EncoderCountFollowsTheAxis) {
  write("motion_command", 1);
  wait_ms(3000);
  EXPECT_EQ(read32("encoder_count"), 1067u);
  write32("travel", 3000);
  write("motion_command", 2);
  wait_ms(5000);
  EXPECT_EQ(read32("encoder_count"), uint32_t(-933));  // -1400 pulses
}

// The device takes its control facts from the spec (issue 38): the same
// spec with one fact changed, loaded as a user's file is, changes it so.
class Hsc60FromAChangedSpec : public Hsc60 {
 protected:
  void load_changed(const std::vector<std::pair<std::string, std::string>>& edits) {
    load_changed_spec(dev, "hsc60", edits);
  }
};

// The continuous runs' words swapped: (70) = 3 runs in reverse, 4 forward.
TEST_F(Hsc60FromAChangedSpec, RunsActOnTheWordsTheSpecGives) {
  load_changed({{"value: 3, trigger: write, motion: true,\n       section: \"四 MODBUS寄存器地址定义 (70)\", quote: \"3—",
                 "value: 4, trigger: write, motion: true,\n       section: \"四 MODBUS寄存器地址定义 (70)\", quote: \"3—"},
                {"value: 4, trigger: write, motion: true,\n       section: \"四 MODBUS寄存器地址定义 (70)\", quote: \"4—",
                 "value: 3, trigger: write, motion: true,\n       section: \"四 MODBUS寄存器地址定义 (70)\", quote: \"4—"}});
  write("motion_command", 3);
  wait_ms(1000);
  EXPECT_EQ(pulse_count(), uint32_t(-(400 + 800)));
  write("motion_command", 5);
  write("motion_command", 4);
  wait_ms(1000);
  EXPECT_EQ(pulse_count(), 0u);
}

// The first fault step goes to the position error: a fault sets bit 3, not bit 0.
TEST_F(Hsc60FromAChangedSpec, AFaultIsTheSpecsFirstFaultStep) {
  load_changed({{"{id: over-current, from: \"*\", event: fault, to: over_current,",
                 "{id: over-current, from: \"*\", event: fault, to: position_error,"}});
  ASSERT_TRUE(dev.trip_fault());
  EXPECT_EQ(read("status") & 0x000B, 0x0008);
}

}  // namespace
}  // namespace mbc::ref
