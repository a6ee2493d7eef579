#include "properties/facts.h"

#include <map>
#include <mutex>

namespace mbc::conf::props {
namespace {

CommandFact fact(const spec::RegisterWrite& w) { return CommandFact{w.key, w.value, w.settle_us, w.section}; }

std::optional<CommandFact> fact(const std::optional<spec::RegisterWrite>& w) {
  if (!w) return std::nullopt;
  return fact(*w);
}

std::vector<CommandFact> facts(const std::vector<spec::RegisterWrite>& v) {
  std::vector<CommandFact> out;
  for (const auto& w : v) out.push_back(fact(w));
  return out;
}

// The spec's `operations:` section (spec/README.md) in the shape the properties use.
std::optional<DeviceFacts> from_spec(const spec::Spec& s) {
  const spec::Operations& o = s.operations;
  if (!o.save && !o.factory_reset && !o.motion) return std::nullopt;
  DeviceFacts d;
  d.device_id = s.device.id;
  d.save = fact(o.save);
  d.factory_reset = fact(o.factory_reset);
  if (o.motion) {
    const spec::MotionOperations& m = *o.motion;
    MotionFacts f;
    f.section = m.section;
    f.assumes = facts(m.assumes);
    f.setup = facts(m.setup);
    f.distance_key = m.distance_key;
    f.reverse_distance_key = m.reverse_distance_key;
    f.signed_distance = m.signed_distance;
    f.start_forward = fact(m.start_forward);
    f.start_reverse = fact(m.start_reverse);
    f.max_distance = m.max_distance;
    f.position_key = m.position_key;
    f.position_high_key = m.position_high_key;
    f.max_speed_pulses_per_s = m.max_speed_pulses_per_s;
    f.decel_seconds = m.decel_seconds;
    f.stop = fact(m.stop);
    f.emergency_stop = fact(m.emergency_stop);
    f.status_key = m.status_key;
    f.running_mask = m.running_mask;
    f.running_when_set = m.running_when_set;
    f.in_position_mask = m.in_position_mask;
    f.positioning_needs_homing = m.positioning_needs_homing;
    f.position_command_key = m.position_command_key;
    d.motion = f;
  }
  return d;
}

}  // namespace

const DeviceFacts* facts_for(const spec::Spec& s) {
  // Sessions hold the pointer; one entry per spec file for the process's life.
  static std::mutex mu;
  static std::map<std::string, std::optional<DeviceFacts>> cache;
  std::lock_guard lock(mu);
  auto [it, fresh] = cache.try_emplace(s.path + "#" + s.device.id);
  if (fresh) it->second = from_spec(s);
  return it->second ? &*it->second : nullptr;
}

}  // namespace mbc::conf::props
