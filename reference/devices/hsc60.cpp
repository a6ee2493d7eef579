// HSC60 (manual 001_f56de7e2fd70f1f6.txt, 四 MODBUS寄存器地址定义): the motion
// command (70) with fixed-length and continuous moves, the status (75) and
// control (73) words, the counters (39~42) and the save (90) / factory reset
// (91) commands. Registers are reached through the keys of spec/devices/hsc60.yaml.
//
// Judgements where the manual is silent:
// * Moves start from standstill (the manual has no start speed); an
//   acceleration or deceleration of 0 means no ramp.
// * Absolute mode (72 = 1): command 1 moves to +travel, command 2 to -travel.
// * Save and reset take kCommandTime of virtual time: 90/91 read 1 until
//   then, and the effect (Device::save_persistent / factory_reset) happens
//   when they complete.
// * The simulation has no pulse input, so the "external" pulse counter 39/40
//   counts the drive's own pulses (axis position since the last clear).
// * Limits: the Axis inputs are the physical switches, and the optocoupler
//   conducts while one is active. Register 73 says which state is "limit"
//   (bit = 1: conducting). The drive refuses to travel towards a limit it
//   sees; with bit = 1 the Axis stops exactly at the switch.
// * What the spec states is read from it at power-on, never restated here:
//   the (70) command values (control commands), the (75) motion-complete bit
//   (the readings of the states idle and running), the alarm bit a fault
//   sets (the state the model's first fault step enters: 过流), the (90)/(91)
//   values (operations) and the (40) clear value (its register's command).
#include <cmath>
#include <cstdint>
#include <optional>
#include <stdexcept>
#include <string>

#include "engine/control_facts.h"
#include "engine/device.h"

namespace mbc::ref {
namespace {

// Left as constants: the spec states these only as a bitfield's or an enum's
// labels (the limits are inputs, not states of its control:), and keying on
// a label would restate it as a string.
// 四 驱动器状态寄存器 (75): the limit bits.
constexpr uint16_t kPositiveLimitBit = 1u << 4, kNegativeLimitBit = 1u << 5;
// 四 驱动器控制寄存器 (73): limit signal levels.
constexpr uint16_t kPositiveLevelBit = 1u << 0, kNegativeLevelBit = 1u << 1;
constexpr int kAbsoluteMode = 1;  // register 72 (enum move-mode: 1 绝对模式)
// Register 30's note "1000表示90度" with the 1000-line default of register 29:
// the encoder is read in quadrature, 4 counts per line.
constexpr int kCountsPerLine = 4;
constexpr uint64_t kCommandTime = 10'000;  // us: how long a save or reset reads "in progress"

// What the spec's control:, operations: and registers state (四).
struct Facts {
  explicit Facts(const spec::Spec& s)
      : stop(facts::command(s, "stop")),
        move_forward(facts::command(s, "move_forward")),
        move_reverse(facts::command(s, "move_reverse")),
        run_forward(facts::command(s, "run_forward")),
        run_reverse(facts::command(s, "run_reverse")),
        emergency_stop(facts::command(s, "emergency_stop")),
        idle(facts::reading(s, "idle", "status")),
        running(facts::reading(s, "running", "status")),
        tripped(facts::reading(s, facts::fault_step(s).to, "status")),
        save(facts::save(s)),
        factory_reset(facts::factory_reset(s)) {
    const spec::Register& r = *s.find_by_key("pulse_count_high");
    if (!r.command || r.command->values.size() != 1)
      throw std::invalid_argument(s.device.id + ": pulse_count_high: its command names no one clear value");
    clear_count = r.command->values.front();
  }
  // (70) 运动指令.
  spec::ControlCommand stop, move_forward, move_reverse, run_forward, run_reverse, emergency_stop;
  // (75): the readings of idle (运动完成) and running, and of the fault a
  // trip enters (its alarm bit).
  spec::StatusMatch idle, running, tripped;
  spec::RegisterWrite save, factory_reset;  // (90), (91)
  int64_t clear_count = 0;                  // (40) "写入1清除计数器"
};

class Hsc60 : public Behaviour {
 public:
  void power_on(Device& d) override {
    f_.emplace(d.spec());
    alarm_ = 0;  // the manual prints no alarm reset: a power cycle clears it
    pulse_origin_ = 0;
    save_left_ = reset_left_ = 0;
    publish(d);
  }

  void on_write(Device& d, uint16_t address, uint16_t count) override {
    auto wrote = [&](const char* key) {
      const auto& r = d.reg_by_key(key);
      return r.address < address + count && r.last_address() >= address;
    };
    const Facts& f = *f_;
    if (wrote(f.stop.register_key.c_str())) command(d, uint16_t(d.value_of(f.stop.register_key)));
    if (wrote("pulse_count_high") && d.value_of("pulse_count_high") == f.clear_count)
      pulse_origin_ = std::llround(d.axis().position());  // "写入1清除计数器"
    if (wrote(f.save.key.c_str()) && d.value_of(f.save.key) == f.save.value) save_left_ = kCommandTime;
    if (wrote(f.factory_reset.key.c_str()) && d.value_of(f.factory_reset.key) == f.factory_reset.value)
      reset_left_ = kCommandTime;
    publish(d);
  }

  void before_read(Device& d, uint16_t, uint16_t) override { publish(d); }

  // Out of band (Device::trip_fault): the fault the model's first fault step
  // enters (over-current, 75 bit 0); the motor
  // stops at once. The manual prints what the drive does on an alarm nowhere
  // else, and no reset: the bit stays until power is cycled.
  bool trip_fault(Device& d) override {
    alarm_ = uint16_t((alarm_ & ~f_->tripped.mask) | f_->tripped.value);
    d.axis().emergency_stop();
    publish(d);
    return true;
  }

  void advance(Device& d, uint64_t dt_us) override {
    refuse_limited_travel(d);
    d.axis().advance(double(dt_us) * 1e-6);
    refuse_limited_travel(d);
    auto completes = [&](uint64_t& left) {
      if (left == 0) return false;
      left = left > dt_us ? left - dt_us : 0;
      return left == 0;
    };
    if (completes(save_left_)) d.save_persistent();
    if (completes(reset_left_)) d.factory_reset();
    publish(d);
  }

 private:
  // (70): each value as the spec's control command gives it.
  void command(Device& d, uint16_t word) {
    const Facts& f = *f_;
    Axis& axis = d.axis();
    double speed = double(d.value_of("speed")), accel = double(d.value_of("accel"));
    double decel = double(d.value_of("decel"));
    if (f.stop.selected_by(word)) axis.stop(decel);
    if (f.move_forward.selected_by(word) || f.move_reverse.selected_by(word)) {
      double travel = double(d.value_of("travel")) * (f.move_forward.selected_by(word) ? 1 : -1);
      double from = d.value_of("move_mode") == kAbsoluteMode ? 0 : std::round(axis.position());
      axis.move_to(from + travel, 0, speed, accel, decel);
    }
    if (f.run_forward.selected_by(word) || f.run_reverse.selected_by(word))
      axis.run_at(f.run_forward.selected_by(word) ? speed : -speed, 0, accel);
    if (f.emergency_stop.selected_by(word)) axis.emergency_stop();
    refuse_limited_travel(d);
  }

  // The limit signals as the drive sees them through the levels of 73.
  bool positive_limit(const Device& d) const {
    bool conducting = d.axis().positive_limit_active();
    return (d.value_of("control") & kPositiveLevelBit) ? conducting : !conducting;
  }
  bool negative_limit(const Device& d) const {
    bool conducting = d.axis().negative_limit_active();
    return (d.value_of("control") & kNegativeLevelBit) ? conducting : !conducting;
  }
  void refuse_limited_travel(Device& d) {
    int dir = d.axis().direction();
    if ((dir > 0 && positive_limit(d)) || (dir < 0 && negative_limit(d))) d.axis().emergency_stop();
  }

  void publish(Device& d) {
    const Axis& axis = d.axis();
    const Facts& f = *f_;
    // Running or idle as the control's states read, the alarm bits over them.
    uint16_t status = uint16_t((axis.moving() ? f.running.value : f.idle.value) | alarm_) |
                      (positive_limit(d) ? kPositiveLimitBit : 0) | (negative_limit(d) ? kNegativeLimitBit : 0);
    d.set_value_of("status", status);
    // 32-bit counters, two's complement when the axis is below its origin.
    auto pulses = uint32_t(std::llround(axis.position()) - pulse_origin_);
    d.set_value_of("pulse_count_low", pulses & 0xFFFF);
    d.set_value_of("pulse_count_high", pulses >> 16);
    double counts_per_pulse = double(kCountsPerLine * d.value_of("encoder_lines")) / double(d.value_of("microstep"));
    d.set_value_of("encoder_count", uint32_t(std::llround(axis.position() * counts_per_pulse)));
    d.set_value_of("save", save_left_ ? 1 : 0);
    d.set_value_of("factory_reset", reset_left_ ? 1 : 0);
  }

  uint16_t alarm_ = 0;  // 75 bits 0, 1, 3
  int64_t pulse_origin_ = 0;
  uint64_t save_left_ = 0, reset_left_ = 0;
  std::optional<Facts> f_;  // read from the spec at power-on
};

}  // namespace

std::unique_ptr<Behaviour> make_hsc60_behaviour() { return std::make_unique<Hsc60>(); }

}  // namespace mbc::ref
