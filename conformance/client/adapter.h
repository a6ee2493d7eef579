// The adapter process: the library under test, driven through JSON lines on
// its stdin and stdout (protocol 1, conformance/client/README.md). Its stderr
// is kept for the report. Waiting for a line also serves the scenario server,
// so one thread runs both ends.
#pragma once

#include <chrono>
#include <optional>
#include <string>
#include <string_view>
#include <utility>

#include <nlohmann/json.hpp>
#include <sys/types.h>

#include "client/server.h"

namespace mbc::client {

class Adapter {
 public:
  // `command` runs under /bin/sh -c.
  explicit Adapter(std::string command);
  ~Adapter();
  Adapter(const Adapter&) = delete;
  Adapter& operator=(const Adapter&) = delete;

  // Starts the process. Throws std::runtime_error when it cannot be started.
  void start();
  // Sends one line. False when the adapter is gone.
  bool send(const nlohmann::json& message);
  // The next JSON line from stdout, serving `server` (may be null) while
  // waiting; nullopt at the deadline or when the adapter exited. A line that
  // is not a JSON object is logged and skipped.
  std::optional<nlohmann::json> next(Clock::time_point deadline, ScenarioServer* server);
  // Kills the process (SIGKILL) and reaps it.
  void kill();
  // After next() gave nothing: when the adapter has exited on its own, how
  // ("exited with status 3", "killed by SIGSEGV"), reaped; else empty.
  std::string exited(std::chrono::milliseconds grace);
  // Waits up to `grace` for it to exit on its own; kills it after that. Returns its exit status (-1: killed).
  int finish(std::chrono::milliseconds grace);
  bool running() const { return pid_ > 0; }

  // Everything it wrote on stderr since the last call, with mbconform's
  // notes on the protocol ("not a JSON object on stdout: ...").
  // The log is capped (kMaxLog bytes for the whole run, then one line
  // saying how much was dropped): an adapter flooding stderr once grew
  // mbconform to 2 GB and its report.json to 671 MB.
  std::string take_log();
  void log_note(const std::string& note) { append_log("[mbconform] " + note + "\n"); }

  // What the adapter may write: its log (stderr and mbconform's notes) in
  // all, one line of stdout, and how deep a reply's JSON may nest.
  static constexpr size_t kMaxLog = 1u << 20;
  static constexpr size_t kMaxLine = 1u << 20;
  static constexpr size_t kMaxDepth = 64;

 private:
  void drain_stderr();
  void append_log(std::string_view text);
  std::string command_;
  pid_t pid_ = -1;
  int in_ = -1, out_ = -1, err_ = -1;
  std::string out_buf_, log_;
  size_t logged_ = 0;          // log bytes kept since start
  uint64_t log_dropped_ = 0;   // log bytes past kMaxLog, not kept
  bool skipping_line_ = false; // the current stdout line is past kMaxLine: dropped up to its newline
};

// True when `text` (a JSON text) nests arrays and objects at most `max` deep;
// parsing a deeper one recursed until the stack ran out (150k levels: SIGSEGV).
bool json_depth_ok(std::string_view text, size_t max);

}  // namespace mbc::client
