#include "session/progress.h"

#include <fmt/core.h>
#include <unistd.h>

#include <cstdio>

namespace mbc::conf {

using Clock = std::chrono::steady_clock;

std::string format_duration(std::chrono::seconds s) {
  long t = long(s.count());
  if (t < 0) t = 0;
  if (t >= 3600) return fmt::format("{}:{:02}:{:02}", t / 3600, t / 60 % 60, t % 60);
  return fmt::format("{}:{:02}", t / 60, t % 60);
}

Progress::Progress(std::string what, bool forced, bool quiet) : what_(std::move(what)) {
  tty_ = isatty(STDERR_FILENO);
  enabled_ = !quiet && (tty_ || forced);
  start_ = Clock::now();
  last_ = start_;
}

bool Progress::due() {
  if (!enabled_) return false;
  auto now = Clock::now();
  if (now - last_ < std::chrono::seconds(1)) return false;
  last_ = now;
  return true;
}

void Progress::emit(const std::string& text) {
  if (tty_) fmt::print(stderr, "\r\033[K{}", text);
  else fmt::print(stderr, "{}\n", text);
  std::fflush(stderr);
  shown_ = true;
}

void Progress::update(uint64_t done, uint64_t total, const char* unit) {
  if (!due()) return;
  double secs = std::chrono::duration<double>(Clock::now() - start_).count();
  double rate = secs > 0 ? double(done) / secs : 0;
  std::string text = fmt::format("{}: {}{}{} {}, {:.1f}/s, {} elapsed", what_, done, total ? "/" : "",
                                 total ? std::to_string(total) : "", unit, rate,
                                 format_duration(std::chrono::seconds(long(secs))));
  if (total && rate > 0 && done <= total)
    text += ", ETA " + format_duration(std::chrono::seconds(long(double(total - done) / rate)));
  emit(text);
}

void Progress::update_timed(uint64_t done, const char* unit, std::chrono::milliseconds budget) {
  if (!due()) return;
  auto elapsed = std::chrono::duration_cast<std::chrono::seconds>(Clock::now() - start_);
  double secs = std::chrono::duration<double>(Clock::now() - start_).count();
  emit(fmt::format("{}: {} {}, {:.1f}/s, {} elapsed, ETA {}", what_, done, unit, secs > 0 ? double(done) / secs : 0,
                   format_duration(elapsed),
                   format_duration(std::chrono::duration_cast<std::chrono::seconds>(budget) - elapsed)));
}

void Progress::clear() {
  if (shown_ && tty_) {
    fmt::print(stderr, "\r\033[K");
    std::fflush(stderr);
  }
  shown_ = false;
}

}  // namespace mbc::conf
