// Progress of a long command on stderr (run, props, fuzz, replay): done and
// total, the rate, the time elapsed and the time left, at most once a
// second. On when stderr is a terminal or with --progress; off with -q. On
// a terminal it is one line rewritten in place; otherwise a line a second.
#pragma once

#include <chrono>
#include <cstdint>
#include <optional>
#include <string>

namespace mbc::conf {

class Progress {
 public:
  // `forced`: --progress; `quiet`: -q.
  Progress(std::string what, bool forced, bool quiet);
  ~Progress() { clear(); }
  bool enabled() const { return enabled_; }
  // `done` of `total` (0: unknown) `unit`s ("cases", "frames").
  void update(uint64_t done, uint64_t total, const char* unit);
  // `done` `unit`s within a time budget: the ETA is the budget's end.
  void update_timed(uint64_t done, const char* unit, std::chrono::milliseconds budget);
  // Erases the line (terminal) before other output.
  void clear();

 private:
  bool due();
  void emit(const std::string& text);
  std::string what_;
  bool enabled_ = false, tty_ = false, shown_ = false;
  std::chrono::steady_clock::time_point start_, last_;
};

std::string format_duration(std::chrono::seconds s);  // "1:05:09", "4:07"

}  // namespace mbc::conf
