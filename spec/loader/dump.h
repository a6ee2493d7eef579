// The resolved spec as JSON (`mbconform spec dump ID --json`). Other tools
// read this; its fields are documented in spec/README.md ("The dump format")
// and only ever grow.
#pragma once

#include <nlohmann/json.hpp>

#include "spec.h"

namespace mbc::spec {

nlohmann::json to_json(const Spec& spec);

}  // namespace mbc::spec
