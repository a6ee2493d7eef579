// Device facts the properties need beyond the register table: which value of
// which command register saves or factory-resets, and how a position move is
// commanded and observed. They come from the spec's `operations:` section
// (spec/README.md), registers named by key, each fact citing its section; so
// a fifth drive gets the persistence and motion properties from its spec alone.
#pragma once

#include <cstdint>
#include <optional>
#include <string>
#include <vector>

#include "spec.h"

namespace mbc::conf::props {

// A write of `value` to the register with spec key `key`, done after
// `settle_us` of (virtual) time.
struct CommandFact {
  std::string key;
  int64_t value = 0;
  uint64_t settle_us = 0;
  std::string section;
};

// How a position move is set up, started, stopped and watched. Values are
// raw register values; positions and distances are in pulses.
struct MotionFacts {
  std::string section;
  // Register values the facts below assume (e.g. the microstep they convert
  // speeds with); a device holding others skips the speed checks.
  std::vector<CommandFact> assumes;
  // Writes that set the profile before a move (speeds, ramps, mode), in order.
  std::vector<CommandFact> setup;
  // A move of d pulses: |d| (or d, when signed) into distance_key (or
  // reverse_distance_key for d < 0, when given), then the start command for
  // its direction, if any (none: the distance write starts the move).
  std::string distance_key, reverse_distance_key;
  bool signed_distance = false;
  std::optional<CommandFact> start_forward, start_reverse;
  int64_t max_distance = 4000;
  // Position feedback: one register, or a low and a high word in two
  // (read as one two's-complement 32-bit count).
  std::string position_key, position_high_key;
  // What the setup configures: the top speed (pulses/s) and the time a
  // normal stop takes from it.
  double max_speed_pulses_per_s = 0;
  double decel_seconds = 0;
  std::optional<CommandFact> stop, emergency_stop;
  // Status word: running (bits of running_mask non-zero, or zero when
  // running_when_set is false: a "motion complete" bit), in position.
  std::string status_key;
  uint16_t running_mask = 0;
  bool running_when_set = true;
  uint16_t in_position_mask = 0;
  // Positioning refused until homed: a write of position_command_key before
  // any homing leaves the axis where it is.
  bool positioning_needs_homing = false;
  std::string position_command_key;
};

struct DeviceFacts {
  std::string device_id;
  std::optional<CommandFact> save;           // stores the by: save_command registers
  std::optional<CommandFact> factory_reset;  // restores the spec's defaults
  std::optional<MotionFacts> motion;
};

// The facts of a spec's `operations:`; nullptr when it has none.
const DeviceFacts* facts_for(const spec::Spec& spec);

}  // namespace mbc::conf::props
