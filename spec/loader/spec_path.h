// Where device specs are found (spec/README.md, "Where specs are found").
//
// Lookup order, first match wins for nothing: every directory is read, and
// an id found in two of them is an error naming both files.
//   1. each `--spec-dir DIR`, in the order given (add_spec_dir());
//   2. each directory in $MBCONFORM_SPEC_DIR (colon-separated);
//   3. the specs that come with mbconform: <dir of the executable>/../share/mbconform
//      when installed, else the source tree's spec/ (compiled in), else ./spec.
// A directory holds its specs in DIR/devices/*.yaml, or, when it has no
// devices/ folder, in DIR/*.yaml.
#pragma once

#include <string>
#include <vector>

namespace mbc::spec {

struct SpecFile {
  std::string id;      // the file name without .yaml
  std::string path;    // the file
  std::string origin;  // "--spec-dir", "MBCONFORM_SPEC_DIR", "installed", "source tree", "working directory"
};

// Adds a user's spec directory ahead of everything else (`--spec-dir`).
void add_spec_dir(const std::string& dir);

// The directory of the specs that come with mbconform (step 3 above) and
// where it was found ("installed", "source tree", "working directory").
std::pair<std::string, std::string> builtin_spec_dir();

// Every spec in every directory, sorted by id. Throws std::runtime_error
// naming both files when two directories hold the same id.
std::vector<SpecFile> spec_files();
std::vector<std::string> spec_ids();  // the ids of spec_files()
// The file of spec `id`; throws std::runtime_error when there is none.
std::string spec_path(const std::string& id);

// The file of library profile `id` (spec/README.md, "Control") for the spec
// in `spec_file`: <its folder>/../profiles/<id>.yaml, <its folder>/profiles/,
// then DIR/profiles/ of every directory above, in the same order. Empty when
// there is none.
std::string profile_path(const std::string& id, const std::string& spec_file);

}  // namespace mbc::spec
