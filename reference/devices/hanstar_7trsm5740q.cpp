// Hanstar 7TRSM5740Q (manual 002_20d5da5312f4fe5b.txt): homing and
// positioning (§5.2), forward/reverse and speed mode (§5.3, §5.4), 到位 mode
// (§5.5), speed changes (表 16), the status word (表 M01), the hardware
// configuration (表 M02) and saving to flash (4002). Registers are reached
// through the keys of spec/devices/hanstar-7trsm5740q.yaml.
//
// Judgements where the manual is silent:
// * Profile: §5.7 prints an S-curve shaped by AccCof. The Axis runs a
//   trapezoid instead, with the same start speed (3008), running speed and
//   acceleration time, (PlusStartTime + PlusConstantTime) * AccSteps * 0.5 us;
//   AccCof is not used. Homing runs at the homing speed without ramps
//   ("除找零时"). A pulse period of 0 means "no speed": the motor does not
//   move. The manual prints no default for any parameter, so a master sets
//   them first (§5.6).
// * Refused commands: positioning (2002) before a correct homing, and after a
//   limit stopped a positioning move (§5.2 "步进一体机不响应定位指令"), and the
//   到位 commands without a correct homing (表 17) are acknowledged like any
//   write (the manual prints no exception reply; §5.3 likewise "虽执行指令 ...
//   不会动作") but do not move the motor; the status and 1002 are unchanged.
// * A 32-bit command acts when one write covers both its words (§6.1: such
//   variables are written with FC 16 as 32 bits); half of one is only stored.
// * The Axis is the machine and its limit inputs are the switches at its
//   ends. UP is the switch forward travel runs into (positive_limit, or
//   negative_limit when M02 bit 7 reverses the motor), DW the other one. The
//   drive counts steps from its own origin: position = ±(axis - origin).
// * A limit stops the Axis at the switch at once where the manual says
//   "减速停止"; the alarm is the same. In 到位 mode the switch turning active
//   is the edge that counts (碰到, "meets"); it is looked for every 50 us (one
//   step at the 20 kHz maximum of 表一), and the motor decelerates from there.
//   A 到位 forward/reverse of 0 steps runs until the edge.
// * 表 M01: bits 2:0 read 1 while running (1-7 all mean "running": the
//   lowest bit of control.motion's running_mask). The alarm nibble is cleared
//   by the next command that starts motion. The status is written when the
//   state changes, so it reads the initial state's 0xFF until the first
//   motion command (homing, 2004/2006).
// * 表 M02: each logic bit's default (0) is the level §5.7 says the sensor
//   gives when active; the other value inverts what the drive sees. Bit 7 at
//   its default is the motor's own direction.
// * What the spec states is read from it at the first power-on: the status
//   values of the control's states (表 M01), the register and word of each
//   command (home, stop, position, forward, reverse), whether positioning
//   waits for homing (control.motion.positioning_needs_homing, §5.2), and the
//   表 M02 bits (hw-config's field keys). The 到位 commands (表 17) are not in
//   the spec's control: they are reached by their registers' keys.
#include <cmath>
#include <cstdint>
#include <limits>
#include <optional>
#include <stdexcept>
#include <string>

#include "engine/device.h"

namespace mbc::ref {
namespace {

// §5.7: rpm = 300000 / (period * 细分).
constexpr double kRpmPeriodProduct = 300000;
constexpr double kArrivalSlice = 50e-6;  // s: one step at 20 kHz (表一 步进频率)

[[noreturn]] void missing(const std::string& what) {
  throw std::runtime_error("hanstar-7trsm5740q reference device: the spec states no " + what);
}

// A control command (6.2 表 13, 表 15): its register, and the words that give it.
struct Command {
  std::string key;
  uint16_t mask = 0, value = 0;
};

// A 表 M02 bit; `normal` its default value.
struct Bit {
  int bit = 0;
  bool normal = false;
  // The bit is away from its default.
  bool flipped(int64_t word) const { return bool((word >> bit) & 1) != normal; }
};

// What the spec states (control:, bitfields:), read once.
struct Facts {
  uint16_t undefined = 0;  // 表 M01 0xff: the initial state's reading
  uint16_t running = 0;    // Bit[2:0] while running: the lowest bit of control.motion's running_mask
  uint16_t homing = 0;     // Bit[3]: state homing's reading
  uint16_t homing_failed = 0, up_alarm = 0, down_alarm = 0;  // Bit[7:4]: the alarm states' readings
  Command home, stop, position, forward, reverse;
  bool positioning_needs_homing = false;  // §5.2
  Bit up_logic, down_logic, home_logic, reverse_direction;

  static Facts of(const spec::Spec& s) {
    if (!s.control) missing("control: section");
    const spec::Control& c = *s.control;
    auto reading = [&](const std::string& id) -> uint16_t {
      const spec::ControlState* st = c.state(id);
      if (!st || st->status.size() != 1) missing("state '" + id + "' with one status reading");
      return uint16_t(st->status.front().value & st->status.front().mask);
    };
    auto command = [&](const char* id) {
      const spec::ControlCommand* cmd = c.command(id);
      if (!cmd) missing(std::string("command '") + id + "'");
      return Command{cmd->register_key, cmd->mask, cmd->value};
    };
    const spec::Register* hw = s.find_by_key("hw_config");
    const spec::Bitfield* m02 = hw ? s.find_bitfield(hw->bitfield_id) : nullptr;
    auto bit = [&](const char* key) {
      const spec::BitField* f = m02 ? m02->field(key) : nullptr;
      if (!f) missing(std::string("hw_config field '") + key + "'");
      return Bit{f->lo, f->default_value.value_or(0) != 0};
    };
    Facts f;
    f.undefined = reading(c.initial);
    if (!c.motion || !c.motion->running_mask) missing("control.motion.status running_mask");
    f.running = uint16_t(c.motion->running_mask & -c.motion->running_mask);
    f.homing = reading("homing");
    f.homing_failed = reading("homing_failed");
    f.up_alarm = reading("up_limit");
    f.down_alarm = reading("down_limit");
    f.home = command("home");
    f.stop = command("stop");
    f.position = command("position");
    f.forward = command("forward");
    f.reverse = command("reverse");
    f.positioning_needs_homing = c.motion->positioning_needs_homing;
    f.up_logic = bit("up_logic");
    f.down_logic = bit("down_logic");
    f.home_logic = bit("home_logic");
    f.reverse_direction = bit("reverse_direction");
    return f;
  }
};

class Hanstar7trsm5740q : public Behaviour {
 public:
  void power_on(Device& d) override {
    if (!facts_) facts_ = Facts::of(d.spec());
    // §5.2 "每次重新上电后，都需要一次复位操作": not homed, status undefined.
    d.axis().emergency_stop();
    sign_ = facts_->reverse_direction.flipped(d.value_of("hw_config")) ? -1 : 1;
    origin_ = d.axis().position();
    target_ = 0;
    undefined_ = true;
    homed_ = false;
    alarm_ = 0;
    homing_ = Homing::off;
    arrival_ = Arrival::off;
    move_ = Move::none;
    run_speed_ = speed_of(double(d.value_of("run_period")));
    publish(d);
  }

  void on_write(Device& d, uint16_t address, uint16_t count) override {
    // Whole register written (see "A 32-bit command acts ..." above).
    auto wrote = [&](const char* key) {
      const auto& r = d.reg_by_key(key);
      return r.address >= address && r.last_address() < uint32_t(address) + count;
    };
    // A command acts when its register is written whole with a word that gives it.
    auto gives = [&](const Command& c) {
      return wrote(c.key.c_str()) && (d.word(uint16_t(d.reg_by_key(c.key).address)) & c.mask) == c.value;
    };
    const Facts& f = *facts_;
    if (wrote("hw_config")) set_direction(d);
    if (gives(f.home)) start_homing(d);
    if (gives(f.stop)) stop(d);
    if (gives(f.position) && (homed_ || !f.positioning_needs_homing))
      go_to_coordinate(d, d.value_of(f.position.key), Arrival::off);
    if (gives(f.forward)) relative(d, +1, d.value_of(f.forward.key), Arrival::off);
    if (gives(f.reverse)) relative(d, -1, d.value_of(f.reverse.key), Arrival::off);
    // 表 17: "到位功能均在步进一体机正确复位情况下" (the spec says so in these
    // registers' effect only).
    if (homed_) {
      if (wrote("arrival_position_up")) go_to_coordinate(d, d.value_of("arrival_position_up"), Arrival::up);
      if (wrote("arrival_forward_up")) relative(d, +1, d.value_of("arrival_forward_up"), Arrival::up);
      if (wrote("arrival_reverse_up")) relative(d, -1, d.value_of("arrival_reverse_up"), Arrival::up);
      if (wrote("arrival_position_dw")) go_to_coordinate(d, d.value_of("arrival_position_dw"), Arrival::down);
      if (wrote("arrival_forward_dw")) relative(d, +1, d.value_of("arrival_forward_dw"), Arrival::down);
      if (wrote("arrival_reverse_dw")) relative(d, -1, d.value_of("arrival_reverse_dw"), Arrival::down);
    }
    if (wrote("speed_period_command")) change_speed(d, speed_of(double(d.value_of("speed_period_command"))));
    if (wrote("speed_rpm_command")) {
      // 2010: rpm as a float; steps/s = 1e6 / period = rpm * 细分 * 1e6 / 300000 (§5.7).
      double rpm = d.float_value(d.reg_by_key("speed_rpm_command"));
      if (std::isfinite(rpm) && rpm > 0)
        change_speed(d, rpm * double(d.value_of("microstep")) * 1e6 / kRpmPeriodProduct);
    }
    if (wrote("save_command")) d.save_persistent();  // 4002: 参数存储到内部 flash
    refuse_seen_limit(d);
    publish(d);
  }

  void advance(Device& d, uint64_t dt_us) override {
    Axis& axis = d.axis();
    double left = double(dt_us) * 1e-6;
    while (left > 0 && axis.moving()) {
      if (refuse_seen_limit(d)) break;
      int dir = sign_ * axis.direction();
      bool signal_was = arrival_signal(d);
      Axis::Step step = step_axis(d, arrival_ != Arrival::off ? std::min(left, kArrivalSlice) : left);
      left -= step.elapsed;
      // §5.5 / 表 17: in 到位 mode meeting the chosen switch ("碰到 ... 边沿触发开关")
      // decelerates the motor to a stop, with no alarm.
      if (arrival_ != Arrival::off && !arrival_edge_seen_ && arrival_signal(d) && !signal_was) {
        arrival_edge_seen_ = true;
        axis.stop(decel(d));
      }
      on_event(d, step.event, dir);
    }
    if (!axis.moving()) {
      move_ = Move::none;
      arrival_ = Arrival::off;
    }
    publish(d);
  }

  // Out of band (Device::trip_fault): while homing, the search ends without
  // the zero signal (表 M01 0x1, §5.2); otherwise, once a command defined the
  // status, the UP switch is met running forward (表 M01 0x6, §5.3: 减速停止并给出
  // 报警信号). Before the first command (0xFF) the manual gives no alarm.
  bool trip_fault(Device& d) override {
    if (undefined_) return true;  // nothing the status can show
    if (homing_ != Homing::off) homing_over(d, false);
    else limit_stop(d, +1);
    publish(d);
    return true;
  }

 private:
  enum class Homing { off, release, search };
  enum class Arrival { off, up, down };
  enum class Move { none, position, velocity, stopping };

  // ---- commands

  // §5.2, figures 5/6: with the home signal active, first run forward the
  // release steps (3014) and look again; then run in reverse at most the
  // maximum search steps (3010) until the signal turns active.
  void start_homing(Device& d) {
    begin_command();
    homed_ = false;
    if (home_seen(d)) {
      homing_ = Homing::release;
      homing_move(d, double(d.value_of("release_steps")));
    } else {
      search_home(d);
    }
  }
  void search_home(Device& d) {
    homing_ = Homing::search;
    homing_move(d, -double(d.value_of("homing_max_steps")));
  }
  void homing_move(Device& d, double steps) {
    double v = speed_of(double(d.value_of("homing_period")));
    if (steps == 0 || v <= 0) return homing_over(d, false);
    go_to(d, drive_position(d) + steps, v, v, 0, 0);
  }
  void homing_over(Device& d, bool found) {
    homing_ = Homing::off;
    d.axis().emergency_stop();
    move_ = Move::none;
    if (!found) {
      alarm_ = facts_->homing_failed;  // "给出找零错误的报警信号"
      return;
    }
    homed_ = true;
    origin_ = d.axis().position();  // the mechanical zero (§5.2)
    target_ = 0;
    run_speed_ = speed_of(double(d.value_of("run_period")));  // 3009: "找零之后的速度恢复到这个速度"
  }

  void stop(Device& d) {
    homing_ = Homing::off;  // an interrupted homing leaves the drive not homed
    if (d.axis().moving()) {
      move_ = Move::stopping;
      d.axis().stop(decel(d));  // §6.3.2: 减速停止
    }
  }

  // 2002 / 2202 / 2402: to a step coordinate; a new target replaces an
  // unfinished one (§5.2).
  void go_to_coordinate(Device& d, int64_t target, Arrival arrival) {
    begin_command();
    arrival_ = arrival;
    move_ = Move::position;
    positioning_ = arrival == Arrival::off;
    go_to(d, double(target), start_speed(d), run_speed_, accel(d), decel(d));
  }

  // 2004/2006 (and the 到位 variants): `steps` from where the motor is; 0 runs
  // on in speed mode (§5.4). 2004/2006 force "correctly homed" (表 15).
  void relative(Device& d, int dir, int64_t steps, Arrival arrival) {
    begin_command();
    arrival_ = arrival;
    if (arrival == Arrival::off) homed_ = true;
    if (steps == 0) {
      move_ = Move::velocity;
      d.axis().run_at(sign_ * dir * run_speed_, start_speed(d), accel(d));
    } else {
      move_ = Move::position;
      go_to(d, std::round(drive_position(d)) + dir * double(steps), start_speed(d), run_speed_, accel(d), decel(d));
    }
  }

  // §5.2: a speed change during a move ramps to the new speed; otherwise
  // the next move uses it.
  void change_speed(Device& d, double speed) {
    if (speed <= 0) return;
    run_speed_ = speed;
    if (homing_ != Homing::off) return;
    Axis& axis = d.axis();
    if (move_ == Move::position && axis.target())
      axis.move_to(*axis.target(), start_speed(d), run_speed_, accel(d), decel(d));
    if (move_ == Move::velocity) axis.run_at(axis.direction() * run_speed_, start_speed(d), accel(d));
  }

  void begin_command() {
    undefined_ = false;
    positioning_ = false;
    alarm_ = 0;
    homing_ = Homing::off;
    arrival_edge_seen_ = false;
  }

  void go_to(Device& d, double drive_target, double start, double max, double acc, double dec) {
    target_ = std::llround(drive_target);
    d.axis().move_to(origin_ + sign_ * drive_target, start, max, acc, dec);
  }

  // M02 bit 7 reverses the motor: the drive's count keeps its value, its
  // directions swap on the machine.
  void set_direction(Device& d) {
    int sign = facts_->reverse_direction.flipped(d.value_of("hw_config")) ? -1 : 1;
    if (sign == sign_) return;
    double p = drive_position(d);
    sign_ = sign;
    origin_ = d.axis().position() - sign_ * p;
  }

  // ---- motion events

  void on_event(Device& d, Axis::Event e, int dir) {
    if (homing_ != Homing::off) {
      // The signal turns active on the sensor's edge, or on its far edge when active low.
      bool signal_on = e == (home_active_low(d) ? Axis::Event::home_off : Axis::Event::home_on);
      if (homing_ == Homing::search && signal_on) return homing_over(d, true);
      if (e == Axis::Event::finished && homing_ == Homing::search) return homing_over(d, false);
      if (e == Axis::Event::finished && homing_ == Homing::release) {
        // Figure 6: still on the switch after the release steps is an error.
        if (home_seen(d)) return homing_over(d, false);
        return search_home(d);
      }
    }
    if (e == Axis::Event::limit) limit_stop(d, dir);
    if (e == Axis::Event::finished) move_ = Move::none;
  }

  // 表 M01 alarms 6/7; after a positioning move the drive takes no more
  // positioning commands (§5.2), a forward/reverse move may go on (§5.3).
  void limit_stop(Device& d, int dir) {
    d.axis().emergency_stop();
    alarm_ = dir > 0 ? facts_->up_alarm : facts_->down_alarm;
    if (homing_ != Homing::off || positioning_) homed_ = false;
    homing_ = Homing::off;
    move_ = Move::none;
  }

  // A limit the drive sees that the Axis does not stop at (inverted
  // polarity, M02 bits 0/1): travel towards it ends where it starts.
  bool refuse_seen_limit(Device& d) {
    if (arrival_ != Arrival::off || !d.axis().moving()) return false;
    int dir = sign_ * d.axis().direction();
    if ((dir > 0 && up_seen(d)) || (dir < 0 && down_seen(d))) {
      limit_stop(d, dir);
      return true;
    }
    return false;
  }

  // Advances the Axis with the limits the drive does not treat as limits
  // taken out: both in 到位 mode (§5.5 "不做限位信号用"), an inverted one always
  // (the drive sees it everywhere but on the switch; refuse_seen_limit acts).
  Axis::Step step_axis(Device& d, double dt) {
    Axis& axis = d.axis();
    AxisInputs machine = axis.inputs;
    auto& up = sign_ > 0 ? axis.inputs.positive_limit : axis.inputs.negative_limit;
    auto& down = sign_ > 0 ? axis.inputs.negative_limit : axis.inputs.positive_limit;
    const int64_t hw = d.value_of("hw_config");
    if (arrival_ != Arrival::off || facts_->up_logic.flipped(hw)) up.reset();
    if (arrival_ != Arrival::off || facts_->down_logic.flipped(hw)) down.reset();
    Axis::Step step = axis.advance_until(dt);
    axis.inputs = machine;
    return step;
  }

  // ---- signals as the drive sees them (表 M02)

  bool up_switch(const Device& d) const {
    return sign_ > 0 ? d.axis().positive_limit_active() : d.axis().negative_limit_active();
  }
  bool down_switch(const Device& d) const {
    return sign_ > 0 ? d.axis().negative_limit_active() : d.axis().positive_limit_active();
  }
  // §5.7: an active limit sensor pulls the line low, an active home sensor
  // drives it high; a logic bit away from its default inverts the level.
  bool up_seen(const Device& d) const { return up_switch(d) != facts_->up_logic.flipped(d.value_of("hw_config")); }
  bool down_seen(const Device& d) const { return down_switch(d) != facts_->down_logic.flipped(d.value_of("hw_config")); }
  bool home_active_low(const Device& d) const { return facts_->home_logic.flipped(d.value_of("hw_config")); }
  bool home_seen(const Device& d) const { return d.axis().home_active() != home_active_low(d); }
  bool arrival_signal(const Device& d) const {
    return arrival_ == Arrival::up ? up_switch(d) : arrival_ == Arrival::down ? down_switch(d) : false;
  }

  // ---- speeds (§5.7)

  static double speed_of(double period_us) { return period_us > 0 ? 1e6 / period_us : 0; }
  double start_speed(const Device& d) const { return speed_of(double(d.value_of("homing_period"))); }
  // Trapezoid over the S-curve's acceleration time (§5.7 加速时间).
  double accel(const Device& d) const {
    double start_period = double(d.value_of("homing_period"));
    double run_period = run_speed_ > 0 ? 1e6 / run_speed_ : 0;
    double t = (start_period + run_period) * double(d.value_of("accel_steps")) * 0.5e-6;
    double span = run_speed_ - start_speed(d);
    return t > 0 && span > 0 ? span / t : 0;
  }
  double decel(const Device& d) const { return accel(d); }  // §5.7: the same S-curve stops the motor

  double drive_position(const Device& d) const { return sign_ * (d.axis().position() - origin_); }

  void publish(Device& d) {
    const Axis& axis = d.axis();
    const Facts& f = *facts_;
    uint16_t status = f.undefined;
    if (!undefined_)
      status = uint16_t((axis.moving() ? f.running : 0) | (homing_ != Homing::off ? f.homing : 0) | alarm_);
    d.set_value_of("motor_status", status);
    d.set_value_of("current_position", std::llround(drive_position(d)));
    d.set_value_of("target_position", target_);
    double v = std::abs(axis.speed());
    d.set_value_of("current_period", v > 0 ? std::min<int64_t>(std::llround(1e6 / v), 0xFFFF) : 0);
  }

  int sign_ = 1;
  double origin_ = 0, run_speed_ = 0;
  int64_t target_ = 0;
  bool undefined_ = true, homed_ = false, positioning_ = false, arrival_edge_seen_ = false;
  uint16_t alarm_ = 0;  // the Bit[7:4] of an alarm state's reading
  std::optional<Facts> facts_;
  Homing homing_ = Homing::off;
  Arrival arrival_ = Arrival::off;
  Move move_ = Move::none;
};

}  // namespace

std::unique_ptr<Behaviour> make_hanstar_7trsm5740q_behaviour() { return std::make_unique<Hanstar7trsm5740q>(); }

}  // namespace mbc::ref
