// Which Behaviour each device id gets. A device whose spec states everything
// needs no entry (modbus-standard has none; cia402-modbus's control: section
// is run by the control executor, engine/control.h).
#include <functional>
#include <map>

#include "engine/control.h"
#include "engine/device.h"

namespace mbc::ref {

std::unique_ptr<Behaviour> make_sihong_57hs_r_behaviour();       // sihong_57hs_r.cpp
std::unique_ptr<Behaviour> make_hsc60_behaviour();               // hsc60.cpp
std::unique_ptr<Behaviour> make_hanstar_7trsm5740q_behaviour();  // hanstar_7trsm5740q.cpp
std::unique_ptr<Behaviour> make_rieding_dhe_behaviour();         // rieding_dhe.cpp

std::unique_ptr<Behaviour> make_behaviour(const spec::Spec& spec, std::shared_ptr<const ControlTweak> tweak) {
  static const std::map<std::string, std::function<std::unique_ptr<Behaviour>()>> registry = {
      {"sihong-57hs-r", make_sihong_57hs_r_behaviour},
      {"hsc60", make_hsc60_behaviour},
      {"hanstar-7trsm5740q", make_hanstar_7trsm5740q_behaviour},
      {"rieding-dhe", make_rieding_dhe_behaviour},
  };
  auto it = registry.find(spec.device.id);
  std::unique_ptr<Behaviour> own = it == registry.end() ? nullptr : it->second();
  if (spec.control) return std::make_unique<ControlExecutor>(*spec.control, std::move(own), std::move(tweak));
  return own ? std::move(own) : std::make_unique<Behaviour>();
}

}  // namespace mbc::ref
