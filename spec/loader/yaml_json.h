// YAML text to JSON, remembering where every value came from, with hard
// bounds so that no input can exhaust the stack or memory: the loader is
// fuzzed (fuzz/spec_loader_fuzzer.cc).
#pragma once

#include <map>
#include <optional>
#include <string>
#include <string_view>

#include <nlohmann/json.hpp>

#include "diagnostic.h"
#include "spec.h"

namespace mbc::spec {

struct YamlLimits {
  size_t max_bytes = 4u << 20;     // a spec is a few hundred KiB at most
  int max_depth = 48;              // nesting of mappings and sequences
  size_t max_nodes = 1u << 20;     // after alias expansion
  size_t max_scalar_bytes = 8192;  // one string
};

struct JsonDocument {
  nlohmann::json root;
  // JSON pointer ("/registers/3/access") -> where that value starts.
  std::map<std::string, SourceLoc> locations;

  SourceLoc where(const std::string& pointer) const;  // nearest known ancestor
};

// Parses `text`; on failure returns nullopt and appends a `yaml` diagnostic.
std::optional<JsonDocument> yaml_to_json(std::string_view text, const std::string& file,
                                         Diagnostics& out, const YamlLimits& limits = {});

}  // namespace mbc::spec
