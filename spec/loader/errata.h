// The manual errata report (`mbconform spec errata`): every printed frame
// with its CRC checked, every recorded contradiction with its resolution,
// and every way the device deviates from the modbus-standard baseline.
#pragma once

#include <string>

#include <nlohmann/json.hpp>

#include "spec.h"

namespace mbc::spec {

// `standard` is the modbus-standard spec; deviations are computed against it.
// `demoted` lists the cases OBSERVED because a fact they rely on is inferred
// (the conformance generators know them; the spec floor does not): each
// {"case", "level_if_stated", "facts": [{"fact", "basis", "why", "searched", "section"}]}.
nlohmann::json errata_report(const Spec& device, const Spec& standard,
                             const nlohmann::json& demoted = nlohmann::json::array());
std::string errata_markdown(const nlohmann::json& report);

}  // namespace mbc::spec
