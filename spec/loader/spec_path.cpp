#include "spec_path.h"

#include <algorithm>
#include <cstdlib>
#include <filesystem>
#include <map>
#include <stdexcept>
#include <system_error>

#ifndef MBCONFORM_SOURCE_SPEC_DIR
#define MBCONFORM_SOURCE_SPEC_DIR "spec"
#endif

namespace mbc::spec {
namespace {

namespace fs = std::filesystem;

std::vector<std::string>& user_dirs() {
  static std::vector<std::string> dirs;
  return dirs;
}

bool has_devices(const fs::path& dir) {
  std::error_code ec;
  return fs::is_directory(dir / "devices", ec);
}

// The specs of one directory (DIR/devices/*.yaml, else DIR/*.yaml).
void scan(const std::string& dir, const std::string& origin, std::vector<SpecFile>& out) {
  std::error_code ec;
  if (!fs::is_directory(dir, ec))
    throw std::runtime_error(dir + ": " + origin + " names no directory");
  fs::path from = has_devices(dir) ? fs::path(dir) / "devices" : fs::path(dir);
  std::vector<SpecFile> here;
  for (const auto& e : fs::directory_iterator(from, ec))
    if (e.path().extension() == ".yaml" && !fs::is_directory(e.path(), ec))
      here.push_back({e.path().stem().string(), e.path().string(), origin});
  std::sort(here.begin(), here.end(), [](const auto& a, const auto& b) { return a.id < b.id; });
  out.insert(out.end(), here.begin(), here.end());
}

}  // namespace

void add_spec_dir(const std::string& dir) { user_dirs().push_back(dir); }

std::pair<std::string, std::string> builtin_spec_dir() {
  std::error_code ec;
  fs::path exe = fs::read_symlink("/proc/self/exe", ec);
  if (!ec) {
    fs::path installed = exe.parent_path().parent_path() / "share" / "mbconform";
    if (has_devices(installed)) return {installed.lexically_normal().string(), "installed"};
  }
  if (has_devices(MBCONFORM_SOURCE_SPEC_DIR)) return {MBCONFORM_SOURCE_SPEC_DIR, "source tree"};
  return {"spec", "working directory"};
}

std::vector<SpecFile> spec_files() {
  std::vector<std::pair<std::string, std::string>> dirs;  // (dir, origin) in lookup order
  for (const auto& d : user_dirs()) dirs.emplace_back(d, "--spec-dir");
  if (const char* env = std::getenv("MBCONFORM_SPEC_DIR"); env && *env) {
    std::string list = env;
    for (size_t pos = 0; pos <= list.size();) {
      size_t end = std::min(list.find(':', pos), list.size());
      if (end > pos) dirs.emplace_back(list.substr(pos, end - pos), "MBCONFORM_SPEC_DIR");
      pos = end + 1;
    }
  }
  auto builtin = builtin_spec_dir();
  std::error_code ec;
  if (fs::is_directory(builtin.first, ec)) dirs.push_back(builtin);

  // A directory named twice (say $MBCONFORM_SPEC_DIR pointing at the
  // built-in one) is read once, under its first name.
  std::vector<std::string> seen;
  std::vector<SpecFile> files;
  for (const auto& [dir, origin] : dirs) {
    std::string canon = fs::weakly_canonical(dir, ec).string();
    if (std::find(seen.begin(), seen.end(), canon) != seen.end()) continue;
    seen.push_back(canon);
    scan(dir, origin, files);
  }
  std::map<std::string, const SpecFile*> by_id;
  for (const auto& f : files) {
    auto [it, fresh] = by_id.emplace(f.id, &f);
    if (!fresh)
      throw std::runtime_error("spec id '" + f.id + "' is defined twice: " + it->second->path + " (" +
                               it->second->origin + ") and " + f.path + " (" + f.origin +
                               "); spec ids are unique across all spec directories, rename one of them");
  }
  std::stable_sort(files.begin(), files.end(), [](const auto& a, const auto& b) { return a.id < b.id; });
  return files;
}

std::vector<std::string> spec_ids() {
  std::vector<std::string> ids;
  for (const auto& f : spec_files()) ids.push_back(f.id);
  return ids;
}

std::string spec_path(const std::string& id) {
  for (const auto& f : spec_files())
    if (f.id == id) return f.path;
  std::string known;
  for (const auto& f : spec_files()) known += (known.empty() ? "" : ", ") + f.id;
  throw std::runtime_error("no spec with id '" + id + "' (known: " + known +
                           "; add a directory with --spec-dir or $MBCONFORM_SPEC_DIR)");
}

std::string profile_path(const std::string& id, const std::string& spec_file) {
  std::error_code ec;
  const std::string name = id + ".yaml";
  std::vector<fs::path> dirs;
  if (!spec_file.empty()) {
    fs::path here = fs::path(spec_file).parent_path();
    if (here.empty()) here = ".";
    dirs.push_back(here / ".." / "profiles");
    dirs.push_back(here / "profiles");
  }
  for (const auto& d : user_dirs()) dirs.push_back(fs::path(d) / "profiles");
  if (const char* env = std::getenv("MBCONFORM_SPEC_DIR"); env && *env) {
    std::string list = env;
    for (size_t pos = 0; pos <= list.size();) {
      size_t end = std::min(list.find(':', pos), list.size());
      if (end > pos) dirs.push_back(fs::path(list.substr(pos, end - pos)) / "profiles");
      pos = end + 1;
    }
  }
  dirs.push_back(fs::path(builtin_spec_dir().first) / "profiles");
  for (const auto& d : dirs)
    if (fs::is_regular_file(d / name, ec)) return (d / name).lexically_normal().string();
  return "";
}

}  // namespace mbc::spec
