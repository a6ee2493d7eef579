// What a device behaviour (reference/devices/) reads of its spec's `control:`
// (and `operations:`) instead of restating it as a constant: a command's word
// pattern, the reading that names a state, a mode's `done` reading. A
// behaviour reads them when the device powers on; a spec that lacks one gets
// one line naming the device and the entry (std::invalid_argument), never a
// silent 0.
#pragma once

#include <stdexcept>
#include <string>

#include "spec.h"

namespace mbc::ref::facts {

inline const spec::Control& control(const spec::Spec& s) {
  if (!s.control) throw std::invalid_argument(s.device.id + ": the spec has no control: section");
  return *s.control;
}

inline const spec::ControlCommand& command(const spec::Spec& s, const std::string& id) {
  if (const spec::ControlCommand* c = control(s).command(id)) return *c;
  throw std::invalid_argument(s.device.id + ": control: has no command '" + id + "'");
}

inline const spec::ControlState& state(const spec::Spec& s, const std::string& id) {
  if (const spec::ControlState* st = control(s).state(id)) return *st;
  throw std::invalid_argument(s.device.id + ": control: has no state '" + id + "'");
}

// The reading of register `key` that names state `id`.
inline spec::StatusMatch reading(const spec::Spec& s, const std::string& id, const std::string& key) {
  for (const auto& m : state(s, id).status)
    if (m.register_key == key) return m;
  throw std::invalid_argument(s.device.id + ": control: state '" + id + "' reads no '" + key + "'");
}

// The `done` reading of mode `id` (in position, homing attained).
inline spec::StatusMatch done(const spec::Spec& s, const std::string& id) {
  const spec::ControlMode* m = control(s).mode(id);
  if (!m || !m->done) throw std::invalid_argument(s.device.id + ": control: mode '" + id + "' has no done: reading");
  return *m->done;
}

// The first `event: fault` step of the model from every state ("*"): the
// fault a drive detects when one is caused out of band (Device::trip_fault),
// as the control executor picks it.
inline const spec::ControlTransition& fault_step(const spec::Spec& s) {
  for (const auto& t : control(s).transitions)
    if (t.automatic() && t.event == "fault" && t.from == "*") return t;
  throw std::invalid_argument(s.device.id + ": control: has no fault step from \"*\"");
}

// operations.save / operations.factory_reset.
inline spec::RegisterWrite save(const spec::Spec& s) {
  if (!s.operations.save) throw std::invalid_argument(s.device.id + ": operations: has no save");
  return *s.operations.save;
}
inline spec::RegisterWrite factory_reset(const spec::Spec& s) {
  if (!s.operations.factory_reset) throw std::invalid_argument(s.device.id + ": operations: has no factory_reset");
  return *s.operations.factory_reset;
}

}  // namespace mbc::ref::facts
