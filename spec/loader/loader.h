// Loading and checking device specs (spec/README.md describes the language).
#pragma once

#include <optional>
#include <string>
#include <string_view>
#include <vector>

#include "diagnostic.h"
#include "spec.h"
#include "spec_path.h"

namespace mbc::spec {

struct LoadResult {
  std::optional<Spec> spec;  // set when the file parsed and matched the schema
  Diagnostics diagnostics;   // schema and semantic errors, sorted by location

  bool ok() const { return spec.has_value() && diagnostics.empty(); }
};

// Loads and checks spec text. `file` names it in diagnostics; the
// id-matches-file rule applies only when file ends in ".yaml".
LoadResult load_spec_text(std::string_view text, const std::string& file);
LoadResult load_spec_file(const std::string& path);

// spec_ids(), spec_path(id): where specs are found (spec_path.h).

// Loads spec `id` (spec_path()); throws std::runtime_error with every
// diagnostic when it does not load cleanly.
Spec load_spec_by_id(const std::string& id);

// The embedded JSON Schema (spec/schema/device.schema.json).
std::string_view device_schema_text();

}  // namespace mbc::spec
