// The semantic rules of the spec language (the table at the end of
// spec/README.md). The schema has already vouched for shapes and types.
#pragma once

#include <string>

#include "diagnostic.h"
#include "spec.h"
#include "yaml_json.h"

namespace mbc::spec {

// `expected_id` is the file's stem, or empty when the text has no file name.
void check_semantics(const Spec& spec, const JsonDocument& doc, const std::string& expected_id, Diagnostics& out);

}  // namespace mbc::spec
