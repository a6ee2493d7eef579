// Rieding DHE / DHD servo drives (manual 003_ba8529b4894691ce.txt): the
// command word at 0800H (四 (2)), the speed and position set-points 0802H /
// 0804H worked through in §五, and the status area 0810H~0824H (四 (3)).
// Registers are reached through the keys of spec/devices/rieding-dhe.yaml.
//
// Judgements where the manual is silent:
// * Pulses per revolution: PN-111 encoder lines x 4 (quadrature), for both
//   the command and the feedback counts. The electronic gear PN-01/PN-02
//   scales the external pulse input, which is not simulated.
// * Speed: the set-point 0802H in % of the rated speed PN-103 (erratum
//   setpoint-percent-unit), or PN-31~33 (r/min) when D6~D7 select an internal
//   speed (§五 速度模式运行 2); capped at PN-34 when that is set. The manual
//   prints no parameter defaults: with PN-103 or PN-111 at 0 nothing moves.
// * Ramps: PN-35 / PN-36 are the times from standstill to the rated speed,
//   in the unit the spec gives them; 0 means no ramp.
// * Position mode: a position command is taken only while enabled, in
//   position mode, free of emergency stop and fault, and with the previous
//   move finished (§五 (4)); otherwise the write is acknowledged and ignored.
// * Speed mode: D4~D5 = 00 (停车) decelerates to standstill. Leaving speed
//   mode ends a speed run the same way. Torque mode holds still: no load is
//   simulated.
// * Removing the enable (D8; the external enable input is not simulated),
//   the emergency stop (D9) and a fault stop the motor at once; nothing moves
//   until they are gone.
// * What the spec states is read from it when the drive powers on: the
//   command word's fields by key (run_mode, direction, internal_speed,
//   enable), the emergency stop and reset bits (control commands
//   emergency_stop, reset), which faults D10 clears (the reset transitions),
//   the fault code LU reads. The field values (0 position, 1 speed, 2
//   torque; 0 stop, 1 FWD, 2 REV) are the enums' by their printed text, kept
//   here as constants.
// * Faults: the simulation raises none. A test (or serve) injects one with
//   Device::set_value_of("fault_code", ...); D10 clears it when 附表二 says
//   it is recoverable (可以恢复).
// * Status: speeds in r/min, negative (two's complement) in reverse. The
//   command pulses count the drive's own position command (motion in
//   position mode), the feedback pulses every motion of the motor; the
//   simulated servo follows its command exactly, so the deviation reads 0.
//   The run status word (0810H) has no printed bit layout and is left at 0.
#include <algorithm>
#include <cmath>
#include <cstdint>
#include <optional>
#include <stdexcept>
#include <string>

#include "engine/control_facts.h"
#include "engine/device.h"

namespace mbc::ref {
namespace {

// 四 (2) command word: the values of its run-mode and run-direction fields.
enum Mode { kPositionMode = 0, kSpeedMode = 1, kTorqueMode = 2 };
enum Direction { kStop = 0, kForward = 1, kReverse = 2 };
constexpr int kCountsPerLine = 4;  // quadrature decoding of PN-111

// A field of the command word: its lowest bit and its width's mask.
struct Field {
  int lo = 0;
  uint16_t mask = 0;
  int of(uint16_t word) const { return (word >> lo) & mask; }
};

// What the spec states (bitfields:, control:), read at the first power-on.
struct Facts {
  Field run_mode, direction, internal_speed;
  uint16_t enable = 0, emergency_stop = 0, reset = 0;
  uint16_t fault_lu = 0;  // 附表二 LU, the fault caused out of band

  explicit Facts(const spec::Spec& s)
      : emergency_stop(facts::command(s, "emergency_stop").mask),
        reset(facts::command(s, "reset").mask),
        fault_lu(facts::reading(s, "fault_lu", "fault_code").value) {
    const spec::Register* r = s.find_by_key("command_word");
    const spec::Bitfield* b = r ? s.find_bitfield(r->bitfield_id) : nullptr;
    auto field = [&](const char* key) {
      const spec::BitField* f = b ? b->field(key) : nullptr;
      if (!f) throw std::invalid_argument(s.device.id + ": the command_word bitfield has no field '" + key + "'");
      return Field{f->lo, uint16_t((1u << (f->hi - f->lo + 1)) - 1)};
    };
    run_mode = field("run_mode");
    direction = field("direction");
    internal_speed = field("internal_speed");
    const Field e = field("enable");
    enable = uint16_t(e.mask << e.lo);
  }
};

class RiedingDhe : public Behaviour {
 public:
  void power_on(Device& d) override {
    if (!f_) f_.emplace(d.spec());
    d.axis().emergency_stop();
    command_pulses_ = 0;
    publish(d);
  }

  void on_write(Device& d, uint16_t address, uint16_t count) override {
    auto wrote = [&](const char* key) {
      const auto& r = d.reg_by_key(key);
      return r.address >= address && r.last_address() < uint32_t(address) + count;
    };
    if (wrote("command_word")) {
      if (word(d) & f_->reset) clear_recoverable_fault(d);
      apply_command(d);
    }
    if (wrote("speed_setpoint")) change_speed(d);
    if (wrote("position_setpoint")) position_command(d);
    publish(d);
  }

  void advance(Device& d, uint64_t dt_us) override {
    if (!may_run(d)) d.axis().emergency_stop();  // e.g. a fault injected meanwhile
    double before = d.axis().position();
    d.axis().advance(double(dt_us) * 1e-6);
    if (mode(d) == kPositionMode) command_pulses_ += d.axis().position() - before;
    publish(d);
  }

  // Out of band (Device::trip_fault): LU 欠压 (附表二 code 0x0A, 可以恢复); the
  // motor stops at once, as with every fault.
  bool trip_fault(Device& d) override {
    d.set_value_of("fault_code", f_->fault_lu);
    d.axis().emergency_stop();
    publish(d);
    return true;
  }

 private:
  // Brings the motor in line with the command word.
  void apply_command(Device& d) {
    Axis& axis = d.axis();
    if (!may_run(d)) return axis.emergency_stop();
    if (mode(d) == kSpeedMode) {
      int dir = direction(d);
      if (dir == 0) return axis.stop(decel(d));
      return axis.run_at(dir * speed(d), 0, accel(d));
    }
    // A speed run ends when the mode changes; a position move goes on in
    // position mode (its D4~D5 read 00 in every §五 frame).
    bool position_move = axis.target().has_value();
    if (mode(d) != kPositionMode || !position_move) axis.stop(decel(d));
  }

  // §五 位置模式运行 (3): value * 0.1 rev, positive forward, relative.
  void position_command(Device& d) {
    Axis& axis = d.axis();
    if (!may_run(d) || mode(d) != kPositionMode || axis.moving()) return;
    const auto& r = d.reg_by_key("position_setpoint");
    double revs = double(d.value(r)) * r.scale;
    axis.move_to(std::round(axis.position()) + revs * pulses_per_rev(d), 0, speed(d), accel(d), decel(d));
  }

  void change_speed(Device& d) {
    Axis& axis = d.axis();
    if (mode(d) == kSpeedMode) return apply_command(d);
    if (mode(d) == kPositionMode && axis.moving() && axis.target())
      axis.move_to(*axis.target(), 0, speed(d), accel(d), decel(d));
  }

  // D10 clears a fault the spec's control resets (附表二 可以恢复: a reset
  // transition out of its fault state to a state with no fault).
  void clear_recoverable_fault(Device& d) {
    const auto& r = d.reg_by_key("fault_code");
    const uint16_t code = uint16_t(d.value(r));
    const spec::Control& c = *d.spec().control;
    for (const auto& st : c.states) {
      if (!st.fault || !names(st, code)) continue;
      for (const auto* t : c.transitions_on(st.id, "reset"))
        if (const spec::ControlState* to = c.state(t->to); to && !to->fault) d.set_value(r, 0);
    }
  }

  // ---- what the spec's control states (四 (2), 附表二)

  // Whether fault code `code` is what state `st` reads.
  static bool names(const spec::ControlState& st, uint16_t code) {
    return !st.status.empty() && std::all_of(st.status.begin(), st.status.end(), [&](const spec::StatusMatch& m) {
      return m.register_key == "fault_code" && m.matches(code);
    });
  }
  // ---- the command word (四 (2))

  static uint16_t word(const Device& d) { return uint16_t(d.value_of("command_word")); }
  int mode(const Device& d) const { return f_->run_mode.of(word(d)); }
  int direction(const Device& d) const {
    int dir = f_->direction.of(word(d));
    return dir == kForward ? 1 : dir == kReverse ? -1 : 0;
  }
  bool may_run(const Device& d) const {
    uint16_t w = word(d);
    return (w & f_->enable) && !(w & f_->emergency_stop) && d.value_of("fault_code") == 0;
  }

  // ---- speeds, in pulses and seconds

  static double pulses_per_rev(const Device& d) { return double(kCountsPerLine * d.value_of("encoder_lines")); }
  static double rated_rpm(const Device& d) { return double(d.value_of("rated_speed")); }
  double speed_rpm(const Device& d) const {
    int internal = f_->internal_speed.of(word(d));
    double rpm;
    if (internal != 0) {
      rpm = double(d.value_of("internal_speed_" + std::to_string(internal)));
    } else {
      const auto& r = d.reg_by_key("speed_setpoint");
      rpm = rated_rpm(d) * double(d.value(r)) * r.scale / 100;  // 额定转速 * 0.01 * 写入的数值
    }
    double max = double(d.value_of("max_speed"));
    return max > 0 ? std::min(rpm, max) : rpm;
  }
  double speed(const Device& d) const { return speed_rpm(d) * pulses_per_rev(d) / 60; }
  static double ramp(const Device& d, const char* time_key) {
    const auto& r = d.reg_by_key(time_key);
    double seconds = double(d.value(r)) * r.scale;
    double rated = rated_rpm(d) * pulses_per_rev(d) / 60;
    return seconds > 0 ? rated / seconds : 0;
  }
  static double accel(const Device& d) { return ramp(d, "accel_time"); }
  static double decel(const Device& d) { return ramp(d, "decel_time"); }

  // What the drive is told to do: a speed run, or a position move under way.
  int commanded_direction(const Device& d) const {
    if (!may_run(d)) return 0;
    if (mode(d) == kSpeedMode) return direction(d);
    return mode(d) == kPositionMode && d.axis().target() ? d.axis().direction() : 0;
  }

  void publish(Device& d) {
    const Axis& axis = d.axis();
    double ppr = pulses_per_rev(d);
    d.set_value_of("current_speed", ppr > 0 ? std::llround(axis.speed() * 60 / ppr) : 0);
    d.set_value_of("commanded_speed", std::llround(commanded_direction(d) * speed_rpm(d)));
    d.set_value_of("command_pulses", std::llround(command_pulses_));
    d.set_value_of("feedback_pulses", std::llround(axis.position()));
    d.set_value_of("position_deviation", 0);
  }

  double command_pulses_ = 0;
  std::optional<Facts> f_;  // read from the spec at the first power-on
};

}  // namespace

std::unique_ptr<Behaviour> make_rieding_dhe_behaviour() { return std::make_unique<RiedingDhe>(); }

}  // namespace mbc::ref
