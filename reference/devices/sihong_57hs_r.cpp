// SIHONG 57HS-R (manual 000_6950555f7a269f5a.txt): position and speed moves
// (§7.1, §7.2), start/stop commands (§7.6), homing (§7.5), the save/reset
// command (§6.1 0x002B) and the status words 0x0002~0x000C. Registers are
// reached through the keys of spec/devices/sihong-57hs-r.yaml.
//
// Judgements where the manual is silent:
// * Ramps: 0x0021/0x0022 are the times from the start speed (0x0020) to the
//   max speed (0x0023) and back; a time of 0 means no ramp.
// * Homing (§7.5) ramps from standstill to 0x0032/0x0033 in 0x0034 ms; "后退一段
//   距离" (back off a distance) is 1/10 revolution past the switch edge; the
//   origin offsets 0x0035 (CCW, +) / 0x0036 (CW, -) are travelled after the
//   switch is found and that point becomes position 0. In modes 2/3 the
//   limit itself stops the axis at once (the Axis stops at limit switches).
// * The Axis inputs stand for switches wired to X inputs configured for
//   them (0x0043~0x0046); 0x0008 shows them on the inputs so configured, but
//   motion does not require the configuration. Limits always stop at once
//   (0x0017's coast/disable choices are not modelled).
// * A released motor (0x0029 = 0) stops and ignores start and homing commands.
// * The alarm Device::trip_fault causes is the first one 0x002A clears (the
//   spec's alarm-clear transition to a state without fault: Err2). Err1/Err5
//   stay until a power cycle (§8 掉电恢复/掉电复位: the first reading of
//   erratum alarm-clear-power-cycle, as the spec's control writes it).
// * What the spec states is read from it at power-on, never restated here:
//   the 0x0027/0x0028/0x0029/0x002A/0x0030 command patterns (control
//   commands), the 0x0007 bits and the 0x0003 work modes (the readings of the
//   states released, moving, homing and alarm, the modes' done), which alarms
//   0x002A clears (the alarm-clear transitions), the 0x002B save and reset
//   values (operations).
#include <algorithm>
#include <cmath>
#include <cstdlib>
#include <optional>
#include <stdexcept>
#include <string>

#include "engine/control_facts.h"
#include "engine/device.h"

namespace mbc::ref {
namespace {

// Left as constants: the spec states these only as an enum's labels (no
// control: entry can say "the home switch input"), and keying on a label
// would restate it as a string.
// §6.1 0x0043~0x0046 input functions and 0x004C/0x004D output functions
// (output 2, "驱动器状态信号", is not explained and is left inactive).
constexpr int kHomeInput = 1, kPositiveLimitInput = 2, kNegativeLimitInput = 3;
constexpr int kAlarmOutput = 1, kHomedOutput = 3, kInPositionOutput = 4;
// §6.1 0x0005: 0 = counter-clockwise (positive), 1 = clockwise (negative).
constexpr int kNegativeDirection = 1;
constexpr int kInputs = 4, kOutputs = 2;  // X0~X3, Y0~Y1 (§4.2.2)

// What the spec's control: and operations: state (§6.1, §7.6, §8).
struct Facts {
  explicit Facts(const spec::Spec& s)
      : start_relative(facts::command(s, "start_relative")),
        start_absolute(facts::command(s, "start_absolute")),
        start_speed(facts::command(s, "start_speed")),
        stop(facts::command(s, "stop")),
        emergency_stop(facts::command(s, "emergency_stop")),
        enable(facts::command(s, "enable")),
        release(facts::command(s, "release")),
        start_homing(facts::command(s, "start_homing")),
        alarm_clear(facts::command(s, "alarm_clear")),
        alarm_state(facts::fault_step(s).to),
        in_position(facts::done(s, "position").value),
        homed(facts::done(s, "homing").value),
        running(facts::reading(s, "moving", "motion_status").value),
        alarm(facts::reading(s, alarm_state, "motion_status").value),
        released(facts::reading(s, "released", "motion_status").value),
        work_moving(facts::reading(s, "moving", "work_mode").value),
        work_homing(facts::reading(s, "homing", "work_mode").value),
        save(facts::save(s)),
        factory_reset(facts::factory_reset(s)) {
    // The alarm a fault raises: the first alarm_code the clear recovers from.
    const spec::Control& c = facts::control(s);
    for (const auto* t : c.transitions_on(alarm_state, alarm_clear.id))
      if (const spec::ControlState* to = c.state(t->to); to && !to->fault)
        for (const auto& when : t->when)
          if (when.register_key == "alarm_code" && !when.values.empty()) {
            tripped_alarm = int(when.values.front());
            return;
          }
    throw std::invalid_argument(s.device.id + ": control: no alarm_clear transition names an alarm_code it clears");
  }
  // 0x0027 (§7.6.1), 0x0028 (§7.6.2), 0x0029, 0x002A (§6.1), 0x0030 (§7.6.3).
  spec::ControlCommand start_relative, start_absolute, start_speed, stop, emergency_stop, enable, release,
      start_homing, alarm_clear;
  std::string alarm_state;  // the state a fault enters
  // 0x0007: in position, homing done, running, alarm, released (§6.1).
  uint16_t in_position, homed, running, alarm, released;
  int64_t work_moving, work_homing;  // 0x0003 (§6.1)
  spec::RegisterWrite save, factory_reset;  // 0x002B (§6.1)
  int tripped_alarm = 0;                    // 0x0006 (§8)
};

class Sihong57hsR : public Behaviour {
 public:
  void power_on(Device& d) override {
    f_.emplace(d.spec());
    enabled_ = true;
    homed_ = false;
    alarm_ = 0;
    homing_ = Homing::off;
    stop_decel_ = ramp(d, "decel_time");
    publish(d);
  }

  void on_write(Device& d, uint16_t address, uint16_t count) override {
    auto wrote = [&](const char* key) {
      const auto& r = d.reg_by_key(key);
      return r.address < address + count && r.last_address() >= address;
    };
    const Facts& f = *f_;
    auto gives = [&](const spec::ControlCommand& c) {
      return wrote(c.register_key.c_str()) && c.selected_by(uint16_t(d.value_of(c.register_key)));
    };
    if (gives(f.start_relative) || gives(f.start_absolute)) start_position(d, gives(f.start_absolute));
    if (gives(f.start_speed)) start_speed(d);
    if (gives(f.emergency_stop)) {
      homing_ = Homing::off;
      d.axis().emergency_stop();
    } else if (gives(f.stop)) {
      homing_ = Homing::off;
      d.axis().stop(stop_decel_);  // §7.6.2 注意: the decel time set before the move
    }
    if (!alarm_) {  // §8 锁机: an alarm holds the motor released until cleared
      if (gives(f.enable)) enabled_ = true;
      if (gives(f.release)) {
        enabled_ = false;
        homing_ = Homing::off;
        d.axis().emergency_stop();
      }
    }
    if (gives(f.alarm_clear)) clear_alarm(d);
    // 0x002C: not a control command (it changes no state); its register's
    // command prints "1 clears" in words only.
    if (wrote("position_clear") && d.value_of("position_clear") == 1) d.axis().set_position(0);
    if (gives(f.start_homing)) start_homing(d);
    // The EEPROM-sync switch 0x0016 is the engine's (persistence.unless).
    if (wrote(f.factory_reset.key.c_str()) && d.value_of(f.factory_reset.key) == f.factory_reset.value)
      d.factory_reset();
    if (wrote(f.save.key.c_str()) && d.value_of(f.save.key) == f.save.value) d.save_persistent();
    publish(d);
  }

  void before_read(Device& d, uint16_t, uint16_t) override { publish(d); }

  // Out of band (Device::trip_fault): Err2 电源电压过高 (§8, 锁机/自动恢复). The
  // drive cuts the motor current on the alarm (our reading: §8 says 锁机), so
  // it reads released; 0x002A = 1 clears the code and leaves it released.
  bool trip_fault(Device& d) override {
    alarm_ = f_->tripped_alarm;
    enabled_ = false;
    homing_ = Homing::off;
    d.axis().emergency_stop();
    publish(d);
    return true;
  }

  void advance(Device& d, uint64_t dt_us) override {
    double left = double(dt_us) * 1e-6;
    for (int events = 0; left > 0 && events < 10000; ++events) {
      Axis::Step step = d.axis().advance_until(left);
      left -= step.elapsed;
      if (step.event == Axis::Event::none) break;
      if (homing_ != Homing::off) on_homing_event(d, step.event);
    }
    publish(d);
  }

 private:
  // §7.6.1: a position move of 0x0024 pulses (relative, or to 0x0024 when
  // absolute), or a speed move at 0x0023 (its sign the direction, §7.2).
  void start_position(Device& d, bool absolute) {
    if (!enabled_) return;
    homing_ = Homing::off;
    stop_decel_ = ramp(d, "decel_time");
    double pulses = double(d.value_of("total_pulses"));
    double from = absolute ? 0 : std::round(d.axis().position());
    d.axis().move_to(from + pulses, start_speed_of(d), max_speed_of(d), ramp(d, "accel_time"), stop_decel_);
  }
  void start_speed(Device& d) {
    if (!enabled_) return;
    homing_ = Homing::off;
    stop_decel_ = ramp(d, "decel_time");
    double max = max_speed_of(d);
    d.axis().run_at(d.value_of("max_speed") < 0 ? -max : max, start_speed_of(d), ramp(d, "accel_time"));
  }
  static double start_speed_of(const Device& d) { return pulses_per_s(d, double(d.value_of("start_speed"))); }
  static double max_speed_of(const Device& d) { return pulses_per_s(d, std::abs(double(d.value_of("max_speed")))); }

  // 0x002A clears the alarm where the spec's control leads out of the alarm
  // to a state with no fault (its `when` holding for the alarm code).
  void clear_alarm(Device& d) {
    const spec::Control& c = facts::control(d.spec());
    for (const auto* t : c.transitions_on(f_->alarm_state, f_->alarm_clear.id)) {
      bool holds = true;
      for (const auto& when : t->when) {
        int64_t v = d.value_of(when.register_key);
        holds = holds && std::find(when.values.begin(), when.values.end(), v) != when.values.end();
      }
      if (!holds) continue;
      if (const spec::ControlState* to = c.state(t->to); to && !to->fault) alarm_ = 0;
      return;
    }
  }

  // §7.5. The final approach is always slow and positive in modes 0/1 ("以慢速
  // 正向查找原点"), towards the limit in modes 2/3; the switch ("sensor") is
  // the home switch in modes 0/1 and that limit in modes 2/3.
  enum class Homing { off, search, brake, leave, back_off, approach, offset };

  void start_homing(Device& d) {
    if (!enabled_) return;
    int mode = int(d.value_of("homing_mode"));
    on_limits_ = mode >= 2;
    approach_dir_ = mode == 3 ? -1 : 1;
    search_dir_ = (mode == 0 || mode == 2) ? 1 : -1;
    reversed_ = false;
    homed_ = false;
    bool on_sensor = on_limits_
                         ? (approach_dir_ > 0 ? d.axis().positive_limit_active() : d.axis().negative_limit_active())
                         : d.axis().home_active();
    if (on_sensor) {
      leave(d);
    } else {
      homing_ = Homing::search;
      d.axis().run_at(search_dir_ * fast(d), 0, fast(d) / ramp_s(d));
    }
  }

  void on_homing_event(Device& d, Axis::Event e) {
    Axis& axis = d.axis();
    bool sensor_found = on_limits_ ? e == Axis::Event::limit : e == Axis::Event::home_on;
    switch (homing_) {
      case Homing::search:
        if (sensor_found && on_limits_) {
          leave(d);  // the limit already stopped the axis
        } else if (sensor_found) {
          homing_ = Homing::brake;  // "遇到原点后，减速停止"
          axis.stop(fast(d) / ramp_s(d));
        } else if (e == Axis::Event::limit && !reversed_) {
          // Modes 0/1: "碰到正限位后，反向运动继续查找原点".
          reversed_ = true;
          search_dir_ = -search_dir_;
          axis.run_at(search_dir_ * fast(d), 0, fast(d) / ramp_s(d));
        } else if (e == Axis::Event::limit) {
          homing_ = Homing::off;  // no home switch between the limits
        }
        return;
      case Homing::brake:
        if (e == Axis::Event::finished) {
          // Overshot past the switch towards the approach side: approach now.
          if (!axis.home_active() && search_dir_ != approach_dir_)
            approach(d);
          else
            leave(d);
        }
        break;
      case Homing::leave:
        if (e == Axis::Event::home_off) back_off(d);
        break;
      case Homing::back_off:
        if (e == Axis::Event::finished) approach(d);
        break;
      case Homing::approach:
        if (sensor_found) {
          axis.emergency_stop();  // "找到后停止": at the switch edge
          int offset = int(d.value_of("home_offset_ccw") - d.value_of("home_offset_cw"));
          if (offset == 0) return homed(d);
          homing_ = Homing::offset;
          axis.move_to(axis.position() + offset, 0, slow(d), slow(d) / ramp_s(d), slow(d) / ramp_s(d));
          return;
        }
        break;
      case Homing::offset:
        if (e == Axis::Event::finished) return homed(d);
        break;
      case Homing::off:
        return;
    }
    if (e == Axis::Event::limit) homing_ = Homing::off;  // an unexpected limit aborts
  }

  // Off the sensor, onto the side the slow approach starts from.
  void leave(Device& d) {
    if (on_limits_) return back_off(d);
    homing_ = Homing::leave;
    d.axis().run_at(-approach_dir_ * slow(d), 0, slow(d) / ramp_s(d));
  }
  void back_off(Device& d) {
    homing_ = Homing::back_off;
    double margin = pulses_per_rev(d) / 10;
    d.axis().move_to(std::round(d.axis().position()) - approach_dir_ * margin, 0, slow(d), slow(d) / ramp_s(d),
                     slow(d) / ramp_s(d));
  }
  void approach(Device& d) {
    homing_ = Homing::approach;
    d.axis().run_at(approach_dir_ * slow(d), 0, slow(d) / ramp_s(d));
  }
  void homed(Device& d) {
    homing_ = Homing::off;
    homed_ = true;
    d.axis().set_position(0);
    d.axis().move_to(0, 0, 1, 0, 0);  // standing on the origin: in position
  }

  // Status words §6.1 0x0002~0x000C.
  void publish(Device& d) {
    const Axis& axis = d.axis();
    d.set_value_of("current_slave_id", d.slave_id());
    const Facts& f = *f_;
    d.set_value_of("work_mode", homing_ != Homing::off ? f.work_homing : f.work_moving);
    d.set_value_of("motion_state", axis.moving() ? 1 : 0);
    if (axis.direction() != 0) direction_ = axis.direction();
    d.set_value_of("motion_direction", direction_ < 0 ? kNegativeDirection : 0);
    d.set_value_of("alarm_code", alarm_);
    uint16_t status = (axis.in_position() ? f.in_position : 0) | (homed_ ? f.homed : 0) |
                      (axis.moving() ? f.running : 0) | (alarm_ ? f.alarm : 0) | (enabled_ ? 0 : f.released);
    d.set_value_of("motion_status", status);
    uint16_t inputs = 0;
    for (int x = 0; x < kInputs; ++x) {
      int64_t function = d.value_of("input_function.x" + std::to_string(x));
      bool active = (function == kHomeInput && axis.home_active()) ||
                    (function == kPositiveLimitInput && axis.positive_limit_active()) ||
                    (function == kNegativeLimitInput && axis.negative_limit_active());
      if (active) inputs |= uint16_t(1u << x);
    }
    d.set_value_of("input_state", inputs);
    uint16_t outputs = 0;
    for (int y = 0; y < kOutputs; ++y) {
      int64_t function = d.value_of("output_function.y" + std::to_string(y));
      bool active = (function == kAlarmOutput && alarm_) || (function == kHomedOutput && homed_) ||
                    (function == kInPositionOutput && axis.in_position());
      if (active) outputs |= uint16_t(1u << y);
    }
    d.set_value_of("output_state", outputs);
    d.set_value_of("current_position", std::llround(axis.position()));
    d.set_value_of("current_speed", std::llround(std::abs(axis.speed()) * 60 / pulses_per_rev(d)));
  }

  // §6.1 0x0011: the microstep enum names its pulses per revolution
  // ("1000 pulses/rev"), so the number comes from the spec.
  // A code the enum does not list (only an injected fault or a corrupted
  // EEPROM image can store one: the engine refuses it on the wire) runs at
  // the default code's resolution rather than stopping the device.
  static double pulses_per_rev(const Device& d) {
    const auto& r = d.reg_by_key("microstep");
    const auto& values = d.spec().find_enum(r.enum_id)->values;
    for (int64_t code : {d.value(r), int64_t(r.default_value.value_or(0))})
      for (const auto& v : values)
        if (v.value == code) return std::stod(v.name.en);
    return std::stod(values.front().name.en);
  }
  static double pulses_per_s(const Device& d, double rpm) { return rpm * pulses_per_rev(d) / 60; }
  // Acceleration (pulses/s^2) from the start speed to the max speed in the
  // time held by `time_key` (ms); 0 = no ramp.
  static double ramp(const Device& d, const char* time_key) {
    double ms = double(d.value_of(time_key));
    double span = pulses_per_s(d, std::abs(double(d.value_of("max_speed"))) - double(d.value_of("start_speed")));
    return ms > 0 && span > 0 ? span / (ms / 1000) : 0;
  }
  static double fast(const Device& d) { return pulses_per_s(d, double(d.value_of("homing_speed"))); }
  static double slow(const Device& d) { return pulses_per_s(d, double(d.value_of("homing_slow_speed"))); }
  static double ramp_s(const Device& d) { return double(d.value_of("homing_ramp_time")) / 1000; }

  bool enabled_ = true, homed_ = false, on_limits_ = false, reversed_ = false;
  int alarm_ = 0, direction_ = 1, search_dir_ = 1, approach_dir_ = 1;
  Homing homing_ = Homing::off;
  double stop_decel_ = 0;
  std::optional<Facts> f_;  // read from the spec at power-on
};

}  // namespace

std::unique_ptr<Behaviour> make_sihong_57hs_r_behaviour() { return std::make_unique<Sihong57hsR>(); }

}  // namespace mbc::ref
