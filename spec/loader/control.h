// The `control:` section (spec/README.md, "Control"): building spec::Control
// from a device's YAML, with the library profile it names
// (spec/profiles/<id>.yaml) resolved onto the device's register keys, and
// the rules `spec check` applies to the result.
#pragma once

#include <optional>
#include <string>

#include "diagnostic.h"
#include "spec.h"
#include "yaml_json.h"

namespace mbc::spec {

// Builds s.control from doc.root["control"] (absent: s.control stays empty)
// and checks it. Needs s.registers and s.errata built. Diagnostics about a
// profile's own entries name the profile's file.
void build_control(Spec& s, const JsonDocument& doc, const std::string& file, Diagnostics& out);

// A library profile file, parsed and matched against the profile schema
// (device.schema.json, definitions/control_profile); nullopt with a
// diagnostic when it does not load.
std::optional<JsonDocument> load_profile_document(const std::string& path, Diagnostics& out);

}  // namespace mbc::spec
