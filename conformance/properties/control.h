// Properties of a drive's control state machine (the spec's `control:`,
// spec::Control), with RapidCheck: after every command the status reading
// names the state the spec says comes next; a command not defined in a state
// does what `undefined` says; a command that stops (quick stop, emergency
// stop) stops the axis from every moving state within the stated time; the
// fault and reset path; a mode switch accepted only where `select_in`
// allows it. The model is the spec alone: states, commands, transitions,
// automatic steps and their stated times, never the reference code. A
// transition whose basis is not stated, or an automatic step with no stated
// time, is OBSERVED: the model accepts either state.
//
// The motion-free walk (`control_walk`) is the path a live drive takes
// without --allow-motion: set-points 0 first, then enable and disable,
// mode selection and fault reset, every frame through the frame policy.
#pragma once

#include <optional>
#include <set>
#include <string>
#include <vector>

#include "properties/properties.h"

namespace mbc::conf::props {

std::vector<Invariant> control_invariants();

// A control counterexample (every step a write of a command register, a
// status read or time passing) replayed through the control model; "" when
// every reply agrees. nullopt when the steps are not a control sequence (the
// register model replays them).
std::optional<std::string> control_replay(Session& session, const std::vector<Step>& steps);

// The motion-free walk: writes 0 to every set-point of the spec's modes,
// then walks the states the spec reaches without motion (enable, disable,
// every mode selected where select_in allows it, fault reset when in a
// fault), checking the status after each step. Every frame goes through the
// session's target, whose gate is the frame policy. Returns "" when every
// reading agreed with the spec, else the first disagreement. `skipped`
// lists the steps the policy or the spec kept out, one line each.
std::string control_walk(Session& session, std::vector<std::string>& skipped);

}  // namespace mbc::conf::props
