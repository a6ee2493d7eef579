// Device facts the properties need that the spec language does not name:
// which value of which command register saves or factory-resets, and how a
// position move is commanded and observed. Registers are named by their spec
// `key`, so the spec stays the source of addresses, types and word orders;
// every fact cites the manual section it comes from. All of them live in
// facts.cpp, one table, nowhere else.
#pragma once

#include <cstdint>
#include <optional>
#include <string>
#include <vector>

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
// raw register values; positions are in the drive's position unit (pulses).
struct MotionFacts {
  std::string section;
  // Writes that prepare a move (speeds, ramps, mode), in order, before any
  // move: the property's own profile, so that speed and decel time are known.
  std::vector<CommandFact> setup;
  // The move: write `distance` (relative, pulses) into `distance_key`, then
  // `start` (if any; empty key = the distance write starts the move).
  std::string distance_key;
  double distance_scale = 1;     // raw value = pulses * distance_scale
  std::optional<CommandFact> start;
  // Position feedback (pulses), and the maximum speed in pulses/s the setup
  // configures (speed never above it).
  std::string position_key;
  double max_speed_pulses_per_s = 0;
  double decel_seconds = 0;       // a normal stop ends within this time (+ one read interval)
  std::optional<CommandFact> stop;          // decelerating stop
  std::optional<CommandFact> emergency_stop;
  // The status word: register key and the bit meaning "running"; the bit
  // meaning "in position" (optional).
  std::string status_key;
  uint16_t running_mask = 0;
  bool running_when_set = true;  // false: the bit reads 1 when standing still (motion complete)
  std::optional<uint16_t> in_position_mask;
  // Positioning refused until homed (7TRSM5740Q §5.2): a position command
  // written before any homing leaves the axis where it is.
  bool positioning_needs_homing = false;
  std::string position_command_key;  // the absolute position command refused before homing
  // The largest move a case makes (keeps cases short in virtual time).
  int64_t max_distance = 4000;
};

struct DeviceFacts {
  std::string device_id;
  std::optional<CommandFact> save;           // stores the by: save_command registers
  std::optional<CommandFact> factory_reset;  // restores the spec's defaults
  std::optional<MotionFacts> motion;
};

// The facts for a device id; nullptr when none are recorded.
const DeviceFacts* facts_for(const std::string& device_id);

}  // namespace mbc::conf::props
