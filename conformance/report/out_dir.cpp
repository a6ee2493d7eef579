// The output directory, checked before the first frame: a run that cannot
// write its reports is lost (a 20-second run at 9600 baud found out only at
// the end). Created here, then a probe file is created and removed. A
// default directory is claimed new (claim_new_dir), never shared.
#include <fcntl.h>
#include <sys/stat.h>
#include <unistd.h>

#include <cerrno>
#include <cstring>
#include <filesystem>

#include <fmt/core.h>

#include "report/report.h"

namespace mbc::conf {

std::string out_dir_problem(const std::string& dir) {
  if (dir.empty()) return "";
  std::error_code ec;
  std::filesystem::create_directories(dir, ec);
  if (ec) return fmt::format("cannot create {}: {}", dir, ec.message());
  if (!std::filesystem::is_directory(dir, ec)) return fmt::format("{} is not a directory", dir);
  std::string probe = (std::filesystem::path(dir) / ".mbconform-write-check").string();
  int fd = ::open(probe.c_str(), O_WRONLY | O_CREAT | O_TRUNC | O_CLOEXEC, 0644);
  if (fd < 0) return fmt::format("cannot write into {}: {}", dir, std::strerror(errno));
  ::close(fd);
  ::unlink(probe.c_str());
  return "";
}

std::string claim_new_dir(const std::string& parent, const std::string& stem) {
  std::error_code ec;
  std::filesystem::create_directories(parent, ec);
  const std::string first = (std::filesystem::path(parent) / stem).string();
  // 10000 runs in one second is more than any machine starts; past it the
  // name is left to out_dir_problem (it exists: written into, as before).
  for (int n = 1; n < 10000; ++n) {
    std::string candidate = n == 1 ? first : fmt::format("{}-{}", first, n);
    if (::mkdir(candidate.c_str(), 0777) == 0) return candidate;
    if (errno != EEXIST) break;
  }
  return first;
}

bool out_dir_ok(const std::string& dir, const char* command) {
  std::string why = out_dir_problem(dir);
  if (why.empty()) return true;
  fmt::print(stderr, "{}: error: --out: {}\n", command, why);
  return false;
}

}  // namespace mbc::conf
