// The control executor: a device's `control:` section (spec::Control) run as
// a state machine. Any device whose spec has one runs it; nothing of a
// profile (CiA 402 or another) is written here, it all comes from the spec:
//
// * State: the power-on state is `initial`. A write of a command register is
//   read as commands (level: the word's bits; edge: the `edge_mask` bits rose
//   since the last word written there; write: every matching write), and the
//   first one with a transition out of the current state whose `when` holds
//   is taken. A command with none there does what `undefined` says: ignored
//   (the word is stored, the state stays) or refused with its exception code.
// * Automatic steps (no command): `power_on` at power-up, `motion_done` once
//   the axis stands still, `reaction_done` once a fault reaction stopped it,
//   `time` after half its stated `within_ms` (at once when none is stated),
//   `fault` when a fault trips (Device::trip_fault(): the out-of-band cause
//   for a layout that gives none on the bus).
// * Status: after every step the current state's readings are published:
//   the bits of each StatusMatch's mask are set to its value, the other bits
//   stay as they are (the modes' `done` bits are set by the active mode).
// * Modes: a write of a mode's `select` value selects it where `select_in`
//   allows (else the write is handled as `undefined` says) and shows it in its
//   `display` register. In a state that allows motion and that no stopping
//   command leads to, the mode's start command starts its motion on the
//   virtual Axis with its set-points: position, an absolute move to the first
//   set-point; speed, a run at the first set-point (continuously, following
//   writes, when the mode has no start command); homing, a move to the home
//   switch (Axis::inputs.home_position) that becomes position 0, or position 0
//   at once when the axis has no home switch. Its `done` reading holds once
//   the move reached its target, the speed its set-point, or the homing ended.
//   Its `actual` register shows the axis position (position, homing) or speed.
// * Stops: a command with `stops` decelerates the axis to standstill within
//   half its `stop_within_ms` (100 ms when none is stated); entering a state
//   without motion stops it at once (no torque); a fault decelerates it.
//
// Judgements where a model states no figure: moves run at `top_speed`
// (1000 units/s when none is stated) with 100 ms ramps; units are pulses.
//
// With a device behaviour of its own (reference/devices/), the behaviour is
// the drive as its manual prints it: it moves the axis and writes its status
// registers. The executor then follows it: after every step its state is the
// one the status names (the current one while it still does), and it writes
// no status of its own, so the drive's reading is never bent to the model.
// A fault (Device::trip_fault) is the behaviour's own when it has one (the
// drive detects it and shows it), else the model's step with its readings.
// A ControlTweak (reference/faults) that departs from the model imposes its
// state: its readings are written over the behaviour's until the next step.
// A write giving a command the tweak ignores is not passed to the behaviour:
// the drive does not act on it (a stop ignored while moving).
#pragma once

#include <cstdint>
#include <memory>
#include <optional>
#include <span>
#include <string>
#include <unordered_map>
#include <vector>

#include "engine/device.h"

namespace mbc::ref {

class ControlExecutor;

// A deliberate deviation from the model (reference/faults): by default every
// hook returns the model's answer.
class ControlTweak {
 public:
  virtual ~ControlTweak() = default;
  // The transition command `c` takes out of the current state; `model` is the
  // model's (nullptr: the command is not defined there).
  virtual const spec::ControlTransition* take(const ControlExecutor&, const spec::ControlCommand&,
                                              const spec::ControlTransition* model) const {
    return model;
  }
  // Whether `word`, written after `last`, gives command `c`; `model` is the model's answer.
  virtual bool selected(const ControlExecutor&, const spec::ControlCommand&, uint16_t last, uint16_t word,
                        bool model) const {
    return model;
  }
  // Whether the drive does not act on a write that gives command `c` (its
  // own behaviour, if any, never sees the write).
  virtual bool ignores(const ControlExecutor&, const spec::ControlCommand&) const { return false; }
  // The word published into status register `key`; `word` is the model's.
  virtual uint16_t status(const ControlExecutor&, const std::string& key, uint16_t word) const { return word; }
};

class ControlExecutor final : public Behaviour {
 public:
  // `inner`: the device's own behaviour, or null (the executor moves the axis).
  ControlExecutor(const spec::Control& control, std::unique_ptr<Behaviour> inner,
                  std::shared_ptr<const ControlTweak> tweak = nullptr);

  std::optional<uint8_t> check_write(const Device&, uint16_t address, std::span<const uint16_t> values) override;
  void on_write(Device&, uint16_t address, uint16_t count) override;
  void before_read(Device&, uint16_t address, uint16_t count) override;
  void advance(Device&, uint64_t dt_us) override;
  void power_on(Device&) override;
  bool trip_fault(Device&) override;

  const spec::Control& control() const { return control_; }
  const std::string& state() const { return state_; }
  // Whether the axis moved when the write being decided came in.
  bool axis_moving() const { return moving_; }
  const spec::ControlMode* active_mode() const { return mode_; }

 private:
  // What a write of command register `key` gives: the transition to take, or
  // none; `undefined` when some command was selected and none is defined.
  struct Decision {
    const spec::ControlCommand* command = nullptr;
    const spec::ControlTransition* transition = nullptr;
    bool starts_mode = false;
    bool undefined = false;
    bool bent = false;  // a tweak changed the model's answer
    bool ignored = false;  // the word gives a command the tweak ignores: the drive does not act on the write
  };
  Decision decide(const Device&, const std::string& key, uint16_t last, uint16_t word) const;
  bool conditions_hold(const Device&, const spec::ControlTransition&) const;
  bool start_allowed() const;
  void enter(Device&, const spec::ControlTransition&, const spec::ControlCommand*);
  void run_automatic(Device&, double dt_s);
  void select_mode(Device&, const spec::ControlMode&);
  void start_mode(Device&);
  void follow_speed(Device&);
  void stop_axis(Device&, double within_s);
  void advance_axis(Device&, double dt_s);
  void publish(Device&);
  // With a behaviour: the state its status names (kept while it still does).
  void follow(Device&);
  bool names(const Device&, const spec::ControlState&) const;
  // Where in `[address, address+count)` register `key` lies, if it does.
  static bool covers(const Device&, const std::string& key, uint16_t address, uint32_t count);
  std::optional<uint16_t> mode_value_written(const Device&, const spec::ControlMode&, uint16_t address,
                                             std::span<const uint16_t> values) const;

  spec::Control control_;  // a copy: the device's spec moves with the device
  std::unique_ptr<Behaviour> inner_;
  std::shared_ptr<const ControlTweak> tweak_;
  std::string state_;
  std::vector<std::string> stopping_states_;  // entered by a command that stops
  std::unordered_map<std::string, uint16_t> last_word_;  // per command register key
  std::vector<std::string> command_keys_, status_keys_;
  const spec::ControlMode* mode_ = nullptr;
  double in_state_s_ = 0;
  bool moving_ = false;        // the axis moved when the last write came in
  bool move_started_ = false;  // the active mode's motion started and not yet done
  bool done_ = false;          // the active mode's done reading holds
  bool homing_ = false;
  double speed_commanded_ = 0;
  bool imposed_ = false;  // a tweak departed from the model: its state's readings are written
};

}  // namespace mbc::ref
