// Where the four vendor manuals are: $MBCONFORM_MANUALS_DIR, else
// shared/manuals beside the checkout. Completeness tests scan them.
#pragma once

#include <cstdlib>
#include <filesystem>
#include <optional>

inline std::optional<std::filesystem::path> manuals_dir() {
  namespace fs = std::filesystem;
  if (const char* env = std::getenv("MBCONFORM_MANUALS_DIR")) return fs::path(env);
  for (fs::path p : {fs::path(MBCONFORM_SOURCE_DIR) / ".." / "shared" / "manuals", fs::path("/work/shared/manuals")})
    if (fs::is_directory(p)) return p;
  return std::nullopt;
}
