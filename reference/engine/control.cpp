#include "engine/control.h"

#include <algorithm>
#include <cmath>

namespace mbc::ref {

namespace {

constexpr double kDefaultSpeed = 1000;    // units/s, when the model states no top_speed
constexpr double kRampSeconds = 0.1;      // start and stop ramps of a started motion
constexpr double kDefaultStopSeconds = 0.1;  // a stop with no stated time
constexpr int kMaxAutomaticSteps = 16;    // a model's automatic steps never loop forever

bool contains(const std::vector<std::string>& v, const std::string& s) {
  return std::find(v.begin(), v.end(), s) != v.end();
}

void add_unique(std::vector<std::string>& v, const std::string& s) {
  if (!s.empty() && !contains(v, s)) v.push_back(s);
}

}  // namespace

ControlExecutor::ControlExecutor(const spec::Control& control, std::unique_ptr<Behaviour> inner,
                                 std::shared_ptr<const ControlTweak> tweak)
    : control_(control), inner_(std::move(inner)), tweak_(std::move(tweak)) {
  for (const auto& c : control_.commands) add_unique(command_keys_, c.register_key);
  for (const auto& s : control_.states)
    for (const auto& m : s.status) add_unique(status_keys_, m.register_key);
  for (const auto& t : control_.transitions)
    if (const spec::ControlCommand* c = control_.command(t.command); c && c->stops) add_unique(stopping_states_, t.to);
}

bool ControlExecutor::covers(const Device& d, const std::string& key, uint16_t address, uint32_t count) {
  const spec::Register* r = d.find_by_key(key);
  return r && r->address >= address && r->address < uint32_t(address) + count;
}

bool ControlExecutor::conditions_hold(const Device& d, const spec::ControlTransition& t) const {
  for (const auto& c : t.when) {
    const spec::Register* r = d.find_by_key(c.register_key);
    if (!r || !std::count(c.values.begin(), c.values.end(), d.value(*r))) return false;
  }
  return true;
}

bool ControlExecutor::start_allowed() const {
  const spec::ControlState* s = control_.state(state_);
  return s && s->motion && !s->fault && !contains(stopping_states_, state_);
}

ControlExecutor::Decision ControlExecutor::decide(const Device& d, const std::string& key, uint16_t last,
                                                  uint16_t word) const {
  Decision out;
  // The commands the word gives, each with the model's transition out of the
  // current state (nullptr: not defined there).
  struct Selected {
    const spec::ControlCommand* command;
    const spec::ControlTransition* model;
  };
  std::vector<Selected> selected;
  for (const auto& c : control_.commands) {
    if (c.register_key != key) continue;
    bool gives = c.selected_by(word);
    if (gives && c.trigger == spec::Trigger::edge) {
      uint16_t bits = c.edge_mask ? c.edge_mask : c.mask;
      gives = (uint16_t(~last) & word & bits) == bits;
    }
    if (tweak_) {
      const bool model = gives;
      gives = tweak_->selected(*this, c, last, word, model);
      if (gives != model) out.bent = true;
    }
    if (!gives) continue;
    if (tweak_ && tweak_->ignores(*this, c)) out.ignored = true;
    const spec::ControlTransition* model = nullptr;
    for (const spec::ControlTransition* t : control_.transitions_on(state_, c.id))
      if (conditions_hold(d, *t)) {
        model = t;
        break;
      }
    selected.push_back({&c, model});
  }
  // A defined command wins over an undefined one the same word gives.
  for (bool defined : {true, false})
    for (const Selected& s : selected) {
      if ((s.model != nullptr) != defined) continue;
      const spec::ControlTransition* t = tweak_ ? tweak_->take(*this, *s.command, s.model) : s.model;
      if (t != s.model) out.bent = true;
      if (t) {
        out.command = s.command;
        out.transition = t;
        return out;
      }
    }
  for (const Selected& s : selected) {
    // A mode's start command is the mode's, never an undefined one.
    const std::string& id = s.command->id;
    if (std::none_of(control_.modes.begin(), control_.modes.end(),
                     [&](const spec::ControlMode& m) { return m.start_command == id; }))
      out.undefined = true;
    else if (!out.starts_mode && mode_ && mode_->start_command == id && start_allowed()) {
      out.command = s.command;
      out.starts_mode = true;
    }
  }
  if (out.starts_mode) out.undefined = false;
  return out;
}

std::optional<uint16_t> ControlExecutor::mode_value_written(const Device& d, const spec::ControlMode& m,
                                                            uint16_t address, std::span<const uint16_t> values) const {
  if (!m.select) return std::nullopt;
  const spec::Register* r = d.find_by_key(m.select->key);
  if (!r || r->words != 1 || r->address < address || r->address >= uint32_t(address) + values.size())
    return std::nullopt;
  return values[r->address - address];
}

std::optional<uint8_t> ControlExecutor::check_write(const Device& d, uint16_t address, std::span<const uint16_t> values) {
  if (inner_)
    if (auto code = inner_->check_write(d, address, values)) return code;
  moving_ = d.axis().moving();
  if (control_.undefined.kind != spec::UndefinedCommand::Kind::exception) return std::nullopt;
  const auto code = uint8_t(control_.undefined.code);
  for (const auto& m : control_.modes)
    if (auto v = mode_value_written(d, m, address, values);
        v && int16_t(*v) == m.select->value && !m.select_in.empty() && !contains(m.select_in, state_))
      return code;
  for (const auto& key : command_keys_) {
    const spec::Register* r = d.find_by_key(key);
    if (!r || r->address < address || r->address >= uint32_t(address) + values.size()) continue;
    auto last = last_word_.find(key);
    if (decide(d, key, last == last_word_.end() ? 0 : last->second, values[r->address - address]).undefined)
      return code;
  }
  return std::nullopt;
}

void ControlExecutor::on_write(Device& d, uint16_t address, uint16_t count) {
  // Decided before the behaviour acts (moving_ is as check_write saw it).
  bool ignored = false;
  if (inner_ && tweak_)
    for (const auto& key : command_keys_)
      if (covers(d, key, address, count)) {
        auto it = last_word_.find(key);
        ignored |= decide(d, key, it == last_word_.end() ? 0 : it->second, d.word(d.reg_by_key(key).address)).ignored;
      }
  if (inner_ && !ignored) inner_->on_write(d, address, count);
  moving_ = d.axis().moving();
  // Modes first, so that one write of the mode and the command word starts
  // the mode it selects.
  for (const auto& m : control_.modes) {
    if (!m.select || !covers(d, m.select->key, address, count)) continue;
    if (d.value_of(m.select->key) != m.select->value) continue;
    if (m.select_in.empty() || contains(m.select_in, state_)) select_mode(d, m);
  }
  for (const auto& key : command_keys_) {
    if (!covers(d, key, address, count)) continue;
    const uint16_t word = d.word(d.reg_by_key(key).address);
    auto it = last_word_.find(key);
    const uint16_t last = it == last_word_.end() ? 0 : it->second;
    last_word_[key] = word;
    Decision dec = decide(d, key, last, word);
    if (dec.bent) imposed_ = true;
    else if (dec.transition) imposed_ = false;
    if (dec.transition) enter(d, *dec.transition, dec.command);
    else if (dec.starts_mode) start_mode(d);
  }
  run_automatic(d, 0);
  follow_speed(d);
  follow(d);
  publish(d);
}

void ControlExecutor::before_read(Device& d, uint16_t address, uint16_t count) {
  if (inner_) inner_->before_read(d, address, count);
  follow(d);
  publish(d);
}

void ControlExecutor::advance(Device& d, uint64_t dt_us) {
  const double dt = double(dt_us) * 1e-6;
  if (inner_) inner_->advance(d, dt_us);
  else advance_axis(d, dt);
  in_state_s_ += dt;
  run_automatic(d, dt);
  follow_speed(d);
  follow(d);
  publish(d);
}

void ControlExecutor::power_on(Device& d) {
  if (inner_) inner_->power_on(d);
  state_ = control_.initial;
  if (state_.empty())
    for (const auto& t : control_.transitions)
      if (t.automatic() && t.event == "power_on") {
        state_ = t.to;
        break;
      }
  if (state_.empty() && !control_.states.empty()) state_ = control_.states.front().id;
  in_state_s_ = 0;
  last_word_.clear();
  for (const auto& key : command_keys_)
    if (const spec::Register* r = d.find_by_key(key)) last_word_[key] = d.word(r->address);
  mode_ = nullptr;
  move_started_ = done_ = homing_ = false;
  speed_commanded_ = 0;
  imposed_ = false;
  for (const auto& m : control_.modes)
    if (m.select && d.find_by_key(m.select->key) && d.value_of(m.select->key) == m.select->value) {
      select_mode(d, m);
      break;
    }
  follow(d);
  publish(d);
}

bool ControlExecutor::trip_fault(Device& d) {
  // The drive's own detection: it shows the fault as its manual prints it.
  if (inner_ && inner_->trip_fault(d)) {
    imposed_ = false;
    follow(d);
    publish(d);
    return true;
  }
  const spec::ControlTransition* step = nullptr;
  for (const auto& t : control_.transitions)
    if (t.automatic() && t.event == "fault" && (t.from == state_ || (t.from == "*" && !step)) && conditions_hold(d, t))
      step = &t;
  if (!step) return false;
  enter(d, *step, nullptr);
  if (inner_) {
    // No detection of its own: the model's fault state, its readings written once.
    imposed_ = true;
    publish(d);
    imposed_ = false;
    inner_->advance(d, 0);
    follow(d);
  }
  publish(d);
  return true;
}

bool ControlExecutor::names(const Device& d, const spec::ControlState& s) const {
  if (s.status.empty()) return false;
  for (const auto& m : s.status) {
    const spec::Register* r = d.find_by_key(m.register_key);
    if (!r || !m.matches(d.word(r->address))) return false;
  }
  return true;
}

void ControlExecutor::follow(Device& d) {
  if (!inner_ || imposed_) return;
  if (const spec::ControlState* now = control_.state(state_); now && names(d, *now)) return;
  for (const auto& s : control_.states)
    if (names(d, s)) {
      if (s.id != state_) in_state_s_ = 0;
      state_ = s.id;
      return;
    }
}

void ControlExecutor::enter(Device& d, const spec::ControlTransition& t, const spec::ControlCommand* command) {
  state_ = t.to;
  in_state_s_ = 0;
  if (inner_) return;  // the device's behaviour moves and stops its axis
  const spec::ControlState* to = control_.state(state_);
  if (!to || !to->motion) {
    // No torque: the axis stands still at once.
    d.axis().emergency_stop();
    move_started_ = homing_ = false;
    speed_commanded_ = 0;
  } else if (!start_allowed()) {
    double within = command && command->stops && command->stop_within_ms ? *command->stop_within_ms / 2000
                                                                          : kDefaultStopSeconds;
    stop_axis(d, within);
  }
}

void ControlExecutor::run_automatic(Device& d, double dt) {
  if (inner_ && !imposed_) return;  // the behaviour takes its own steps; follow() reads them
  for (int i = 0; i < kMaxAutomaticSteps; ++i) {
    const spec::ControlTransition* step = nullptr;
    for (const auto& t : control_.transitions) {
      if (!t.automatic() || !(t.from == state_ || t.from == "*") || !conditions_hold(d, t)) continue;
      bool due = false;
      if (t.event == "time") due = !t.within_ms || (dt > 0 && in_state_s_ * 1000 >= *t.within_ms / 2);
      else if (t.event == "motion_done" || t.event == "reaction_done") due = dt > 0 && !d.axis().moving();
      if (due) {
        step = &t;
        break;
      }
    }
    if (!step || step->to == state_) return;
    enter(d, *step, nullptr);
  }
}

void ControlExecutor::select_mode(Device& d, const spec::ControlMode& m) {
  if (mode_ != &m) {
    if (!inner_ && d.axis().moving()) stop_axis(d, kDefaultStopSeconds);
    mode_ = &m;
    move_started_ = done_ = homing_ = false;
    speed_commanded_ = 0;
  }
  if (!m.display_key.empty() && d.find_by_key(m.display_key)) d.set_value_of(m.display_key, m.select->value);
}

void ControlExecutor::start_mode(Device& d) {
  if (inner_ || !mode_) return;
  const double speed = control_.top_speed.value_or(kDefaultSpeed);
  const double accel = speed / kRampSeconds;
  auto setpoint = [&]() -> std::optional<double> {
    if (mode_->setpoint_keys.empty() || !d.find_by_key(mode_->setpoint_keys.front())) return std::nullopt;
    return double(d.value_of(mode_->setpoint_keys.front()));
  };
  done_ = false;
  if (mode_->id == "position") {
    if (auto target = setpoint()) {
      d.axis().move_to(*target, 0, speed, accel, accel);
      move_started_ = true;
    }
  } else if (mode_->id == "speed") {
    move_started_ = true;
    speed_commanded_ = std::nan("");  // follow_speed runs it at the set-point
    follow_speed(d);
  } else if (mode_->id == "homing") {
    if (auto home = d.axis().inputs.home_position) {
      // The switch is fixed to the machine; the drive's positions have their own origin.
      double target = double(*home) - (d.axis().machine_position() - d.axis().position());
      d.axis().move_to(target, 0, speed, accel, accel);
      homing_ = true;
    } else {
      d.axis().set_position(0);
      done_ = true;
    }
  }
}

void ControlExecutor::follow_speed(Device& d) {
  if (inner_ || !mode_ || mode_->id != "speed" || !start_allowed()) return;
  if (!mode_->start_command.empty() && !move_started_) return;
  if (mode_->setpoint_keys.empty() || !d.find_by_key(mode_->setpoint_keys.front())) return;
  const double v = double(d.value_of(mode_->setpoint_keys.front()));
  if (v == speed_commanded_) return;
  const double accel = std::max(std::abs(v), control_.top_speed.value_or(kDefaultSpeed)) / kRampSeconds;
  if (v == 0) d.axis().stop(accel);
  else d.axis().run_at(v, 0, accel);
  speed_commanded_ = v;
}

void ControlExecutor::stop_axis(Device& d, double within_s) {
  move_started_ = homing_ = false;
  speed_commanded_ = 0;
  const double v = std::abs(d.axis().speed());
  if (!d.axis().moving()) return;
  if (v == 0 || within_s <= 0) d.axis().emergency_stop();
  else d.axis().stop(v / within_s);
}

void ControlExecutor::advance_axis(Device& d, double dt_s) {
  d.axis().advance(dt_s);
  if (d.axis().moving()) return;
  if (homing_) {
    homing_ = false;
    d.axis().set_position(0);
    done_ = true;
  } else if (move_started_ && mode_ && mode_->id == "position") {
    move_started_ = false;
    done_ = d.axis().in_position();
  }
}

void ControlExecutor::publish(Device& d) {
  const spec::ControlState* s = control_.state(state_);
  auto put = [&](const std::string& key, auto&& change) {
    const spec::Register* r = d.find_by_key(key);
    if (!r) return;
    uint16_t w = d.word(r->address);
    change(w);
    d.set_word(r->address, w);
  };
  // What proves each mode: the axis position (position, homing) or speed.
  if (!inner_)
    for (const auto& m : control_.modes) {
      const spec::Register* r = m.actual_key.empty() ? nullptr : d.find_by_key(m.actual_key);
      if (!r) continue;
      if (m.id == "position" || m.id == "homing") d.set_value(*r, std::llround(d.axis().position()));
      else if (m.id == "speed") d.set_value(*r, std::llround(d.axis().speed()));
    }
  // The modes' done readings: every mode's bits cleared, then the active
  // mode's set when it holds (two modes may share a bit: CiA 402 bit 10).
  if (!inner_) {
    for (const auto& m : control_.modes)
      if (m.done) put(m.done->register_key, [&](uint16_t& w) { w = uint16_t(w & ~m.done->mask); });
    if (mode_ && mode_->done) {
      bool holds = done_;
      if (mode_->id == "speed")
        holds = start_allowed() && !std::isnan(speed_commanded_) && std::abs(d.axis().speed() - speed_commanded_) < 0.5;
      const spec::StatusMatch& m = *mode_->done;
      if (holds) put(m.register_key, [&](uint16_t& w) { w = uint16_t(w | (m.value & m.mask)); });
    }
  }
  const bool readings = !inner_ || imposed_;
  for (const auto& key : status_keys_)
    put(key, [&](uint16_t& w) {
      if (s && readings)
        for (const auto& match : s->status)
          if (match.register_key == key) w = uint16_t((w & ~match.mask) | (match.value & match.mask));
      if (tweak_) w = tweak_->status(*this, key, w);
    });
}

}  // namespace mbc::ref
