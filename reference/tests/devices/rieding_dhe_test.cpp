// The Rieding DHE / DHD reference servo driven over RTU with the frames of
// its manual (003_ba8529b4894691ce.txt, §五): position mode, speed mode by
// set-point and by internal speed, the emergency stop and reset bits of the
// command word (四 (2)), and the status area (四 (3)). Printed frames come
// from the spec's examples; expected values from the manual's rules.
#include <gtest/gtest.h>

#include "changed_spec.h"
#include "engine/device.h"
#include "loader.h"
#include "modbus/crc16.h"
#include "modbus/hex.h"

namespace mbc::ref {
namespace {

// 四 (2) command word: D8 enable, D9 emergency stop, D10 reset; D0~D3 = 1 speed; D4~D5 = 01 FWD.
constexpr uint16_t kEnable = 1 << 8, kEmergencyStop = 1 << 9, kReset = 1 << 10, kSpeedForward = 0x0011;

// The motor the §五 note implies: "发送 1%，电机转速 ON-01=24rpm" = 1 % of 2400 r/min.
constexpr uint16_t kRatedRpm = 2400;
// PN-111 = 2500 lines, counted x4 (see rieding_dhe.cpp): 10000 pulses per revolution.
constexpr uint16_t kEncoderLines = 2500;
constexpr int32_t kPulsesPerRev = 10000;

class Rieding : public ::testing::Test {
 protected:
  Device dev{spec::load_spec_by_id("rieding-dhe"), 1};

  void SetUp() override {
    write("rated_speed", kRatedRpm);
    write("encoder_lines", kEncoderLines);
  }

  std::optional<Bytes> send(Bytes frame) {
    uint16_t c = crc16(frame);
    frame.push_back(uint8_t(c & 0xFF));
    frame.push_back(uint8_t(c >> 8));
    return dev.handle_rtu(frame);
  }
  // FC 06 (三 (2)); the manual prints no reply, the standard's is the echo.
  void write(const char* key, uint16_t value) {
    uint16_t a = dev.reg_by_key(key).address;
    Bytes req{1, 6, uint8_t(a >> 8), uint8_t(a), uint8_t(value >> 8), uint8_t(value)};
    auto reply = send(req);
    ASSERT_TRUE(reply);
    EXPECT_EQ(Bytes(reply->begin(), reply->end() - 2), req);
  }
  std::vector<uint16_t> read_words(uint16_t a, uint16_t count) {
    auto reply = send({1, 3, uint8_t(a >> 8), uint8_t(a), 0, uint8_t(count)});
    EXPECT_TRUE(reply && reply->size() == size_t(5 + 2 * count)) << (reply ? to_hex(*reply) : "silence");
    if (!reply || reply->size() != size_t(5 + 2 * count)) return std::vector<uint16_t>(count, 0xDEAD);
    std::vector<uint16_t> words;
    for (int i = 0; i < count; ++i) words.push_back(uint16_t((*reply)[3 + 2 * i] << 8 | (*reply)[4 + 2 * i]));
    return words;
  }
  int16_t read(const char* key) { return int16_t(read_words(dev.reg_by_key(key).address, 1)[0]); }
  int32_t read32(const char* key) {  // 四 (3): (Lo) at the lower address
    auto w = read_words(dev.reg_by_key(key).address, 2);
    return int32_t(uint32_t(w[1]) << 16 | w[0]);
  }
  int32_t feedback() { return read32("feedback_pulses"); }
  // Sends a printed frame (the resolved one where the print is an erratum);
  // the manual prints no replies: an FC 06 is echoed (MBAP v1.1b3 §6.6).
  void replay(const std::string& id) {
    for (const auto& e : dev.spec().examples)
      if (e.id == id) {
        Bytes req = *parse_hex_strict(e.resolved_request.value_or(e.request));
        auto reply = dev.handle_rtu(req);
        ASSERT_TRUE(reply) << id;
        EXPECT_EQ(to_hex(*reply), to_hex(req)) << id;
        return;
      }
    FAIL() << "no example " << id;
  }
  void wait_s(double s) { dev.advance(uint64_t(s * 1e6)); }
};

// §五 位置模式运行: enable, 1 % speed (24 r/min = 0.4 rev/s), +4 rev (0x0028 =
// 40 x 0.1 rev) takes 10 s; (4) a second position command while the first
// is under way is not taken; -4 rev (0xFFD8) then brings the motor back.
TEST_F(Rieding, PositionModeFourRevolutionsForwardAndBack) {
  replay("pos-enable");
  replay("pos-speed-1pct");
  replay("pos-move-fwd-4rev");
  wait_s(5);
  EXPECT_EQ(feedback(), 2 * kPulsesPerRev);
  EXPECT_EQ(read("current_speed"), 24);  // "ON-01=24rpm"
  replay("pos-move-rev-4rev");           // not taken: the move is not finished
  wait_s(6);
  EXPECT_EQ(feedback(), 4 * kPulsesPerRev);
  EXPECT_EQ(read32("command_pulses"), 4 * kPulsesPerRev);
  EXPECT_EQ(read32("position_deviation"), 0);
  EXPECT_EQ(read("current_speed"), 0);
  replay("pos-move-rev-4rev");
  wait_s(11);
  EXPECT_EQ(feedback(), 0);
  EXPECT_EQ(read32("command_pulses"), 0);
}

// §五 位置模式运行 (1): position commands act only enabled and in position mode.
TEST_F(Rieding, PositionCommandNeedsEnable) {
  replay("pos-speed-1pct");
  replay("pos-move-fwd-4rev");
  wait_s(11);
  EXPECT_EQ(feedback(), 0);
  write("command_word", kEnable | 0x0001);  // enabled, but speed mode (D4~D5 = 00: 停车)
  replay("pos-move-fwd-4rev");
  wait_s(11);
  EXPECT_EQ(feedback(), 0);
}

// §五 速度模式运行 1: enable + FWD, 10 % of rated = 240 r/min = 4 rev/s;
// enable + REV turns it round; 1 % slows it to 24 r/min.
TEST_F(Rieding, SpeedModeForwardAndReverse) {
  replay("spd1-enable-fwd");
  replay("spd1-speed-10pct");
  wait_s(1);
  EXPECT_EQ(feedback(), 4 * kPulsesPerRev);
  EXPECT_EQ(read("current_speed"), 240);
  EXPECT_EQ(read("commanded_speed"), 240);
  replay("spd1-enable-rev");
  wait_s(1);
  EXPECT_EQ(feedback(), 0);
  EXPECT_EQ(read("current_speed"), -240);
  replay("spd1-speed-1pct");
  wait_s(1);
  EXPECT_EQ(feedback(), -int32_t(0.4 * kPulsesPerRev));
  EXPECT_EQ(read("current_speed"), -24);
  write("command_word", kEnable | 0x0001);  // D4~D5 = 00: 停车
  wait_s(0.1);
  EXPECT_EQ(read("current_speed"), 0);
}

// §五 速度模式运行 2: internal speed 1 (PN-31) + FWD / REV + enable. The
// printed frames carry a bad CRC (errata crc-spd2-fwd/-rev): the drive does
// not act on them; the resolved frames run at PN-31.
TEST_F(Rieding, InternalSpeedOne) {
  write("internal_speed_1", 60);  // 1 rev/s
  for (const auto& e : dev.spec().examples)
    if (e.id == "spd2-int1-fwd") {
      EXPECT_FALSE(dev.handle_rtu(*parse_hex_strict(e.request)));
    }
  wait_s(1);
  EXPECT_EQ(feedback(), 0);
  replay("spd2-int1-fwd");
  wait_s(1);
  EXPECT_EQ(feedback(), kPulsesPerRev);
  EXPECT_EQ(read("current_speed"), 60);
  replay("spd2-int1-rev");
  wait_s(2);
  EXPECT_EQ(feedback(), -kPulsesPerRev);
}

// 四 (2) D9 SCI 急停: the motor stops at once and stays stopped while D9 is set.
TEST_F(Rieding, EmergencyStop) {
  replay("spd1-enable-fwd");
  replay("spd1-speed-10pct");
  wait_s(0.5);
  write("command_word", kEnable | kEmergencyStop | kSpeedForward);
  EXPECT_EQ(read("current_speed"), 0);
  int32_t stopped = feedback();
  EXPECT_EQ(stopped, 2 * kPulsesPerRev);
  wait_s(1);
  EXPECT_EQ(feedback(), stopped);
  replay("spd1-enable-fwd");
  wait_s(0.5);
  EXPECT_EQ(feedback(), stopped + 2 * kPulsesPerRev);
}

// 四 (2) D8 SCI 使能: without it (and no external enable) the motor stops.
TEST_F(Rieding, RemovingTheEnableStops) {
  replay("spd1-enable-fwd");
  replay("spd1-speed-10pct");
  wait_s(0.5);
  write("command_word", kSpeedForward);
  wait_s(1);
  EXPECT_EQ(feedback(), 2 * kPulsesPerRev);
}

// 四 (2) D10 SCI 复位 and 附表二: a recoverable fault (LU, 0x0A) is cleared and
// the motor runs again; a non-recoverable one (EC, 0x07) stays.
TEST_F(Rieding, ResetClearsRecoverableFaultsOnly) {
  replay("spd1-enable-fwd");
  replay("spd1-speed-10pct");
  dev.set_value_of("fault_code", 0x0A);
  wait_s(1);
  EXPECT_EQ(feedback(), 0);
  EXPECT_EQ(read("fault_code"), 0x0A);
  write("command_word", kReset | kEnable | kSpeedForward);
  EXPECT_EQ(read("fault_code"), 0);
  wait_s(1);
  EXPECT_EQ(feedback(), 4 * kPulsesPerRev);

  dev.set_value_of("fault_code", 0x07);
  write("command_word", kReset | kEnable | kSpeedForward);
  EXPECT_EQ(read("fault_code"), 0x07);
  wait_s(1);
  EXPECT_EQ(feedback(), 4 * kPulsesPerRev);
}

// PN-35 加速时间一 (s): standstill to rated speed (2400 r/min) in 1 s, so
// 240 r/min after 0.1 s and 120 r/min half-way there.
TEST_F(Rieding, AccelerationTimeFromPn35) {
  write("accel_time", 1);
  replay("spd1-enable-fwd");
  replay("spd1-speed-10pct");
  wait_s(0.05);
  EXPECT_EQ(read("current_speed"), 120);
  wait_s(0.1);
  EXPECT_EQ(read("current_speed"), 240);
}

// The device takes the command word's fields and its control facts from the
// spec (issue 38): the same spec with one changed, loaded as a user's file
// is, changes the device so.
class RiedingFromAChangedSpec : public Rieding {
 protected:
  void load_changed(const std::vector<std::pair<std::string, std::string>>& edits) {
    load_changed_spec(dev, "rieding-dhe", edits);
    SetUp();
  }
};

// The enable field keyed on D10 instead of D8: 0x0111 runs nothing, 0x0411 runs.
TEST_F(RiedingFromAChangedSpec, TheEnableIsTheKeyedField) {
  load_changed({{"{bit: 8, key: enable,", "{bit: 8, key: sci_enable_printed,"},
                {"{bit: 10, key: reset,", "{bit: 10, key: enable,"}});
  replay("spd1-enable-fwd");
  replay("spd1-speed-10pct");
  wait_s(1);
  EXPECT_EQ(feedback(), 0);
  write("command_word", kReset | kSpeedForward);
  wait_s(1);
  EXPECT_EQ(feedback(), 4 * kPulsesPerRev);
}

// The emergency stop command on D11: D9 no longer stops the motor.
TEST_F(RiedingFromAChangedSpec, TheEmergencyStopIsTheCommandsBit) {
  load_changed({{"      mask: 0x0200\n      value: 0x0200\n      write: 0x0200", "      mask: 0x0800\n      value: 0x0800\n      write: 0x0800"}});
  replay("spd1-enable-fwd");
  replay("spd1-speed-10pct");
  wait_s(0.5);
  write("command_word", kEnable | kEmergencyStop | kSpeedForward);
  wait_s(0.5);
  EXPECT_EQ(feedback(), 4 * kPulsesPerRev);
  write("command_word", kEnable | 0x0800 | kSpeedForward);
  EXPECT_EQ(read("current_speed"), 0);
}

// The LU fault read as code 0x0D: a fault caused out of band shows 0x0D.
TEST_F(RiedingFromAChangedSpec, AFaultShowsTheCodeItsStateReads) {
  load_changed({{"status: [{register: fault_code, mask: 0xFFFF, value: 0x000A}]",
                 "status: [{register: fault_code, mask: 0xFFFF, value: 0x000D}]"}});
  ASSERT_TRUE(dev.trip_fault());
  EXPECT_EQ(read("fault_code"), 0x0D);
}

}  // namespace
}  // namespace mbc::ref
