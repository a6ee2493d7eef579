// The manual errata report (`mbconform spec errata`): every printed frame
// with its CRC checked, every recorded contradiction with its resolution,
// and every way the device deviates from the modbus-standard baseline.
#pragma once

#include <string>

#include <nlohmann/json.hpp>

#include "spec.h"

namespace mbc::spec {

// `standard` is the modbus-standard spec; deviations are computed against it.
nlohmann::json errata_report(const Spec& device, const Spec& standard);
std::string errata_markdown(const nlohmann::json& report);

}  // namespace mbc::spec
