// Which Behaviour each device id gets. A device whose spec states everything
// needs no entry (modbus-standard has none).
#include <functional>
#include <map>

#include "engine/device.h"

namespace mbc::ref {

std::unique_ptr<Behaviour> make_sihong_57hs_r_behaviour();       // sihong_57hs_r.cpp
std::unique_ptr<Behaviour> make_hsc60_behaviour();               // hsc60.cpp
std::unique_ptr<Behaviour> make_hanstar_7trsm5740q_behaviour();  // hanstar_7trsm5740q.cpp
std::unique_ptr<Behaviour> make_rieding_dhe_behaviour();         // rieding_dhe.cpp

std::unique_ptr<Behaviour> make_behaviour(const std::string& device_id) {
  static const std::map<std::string, std::function<std::unique_ptr<Behaviour>()>> registry = {
      {"sihong-57hs-r", make_sihong_57hs_r_behaviour},
      {"hsc60", make_hsc60_behaviour},
      {"hanstar-7trsm5740q", make_hanstar_7trsm5740q_behaviour},
      {"rieding-dhe", make_rieding_dhe_behaviour},
  };
  auto it = registry.find(device_id);
  return it == registry.end() ? std::make_unique<Behaviour>() : it->second();
}

}  // namespace mbc::ref
