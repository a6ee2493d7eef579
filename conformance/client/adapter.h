// The adapter process: the library under test, driven through JSON lines on
// its stdin and stdout (protocol 1, conformance/client/README.md). Its stderr
// is kept for the report. Waiting for a line also serves the scenario server,
// so one thread runs both ends.
#pragma once

#include <chrono>
#include <optional>
#include <string>
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
  // Waits up to `grace` for it to exit on its own; kills it after that. Returns its exit status (-1: killed).
  int finish(std::chrono::milliseconds grace);
  bool running() const { return pid_ > 0; }

  // Everything it wrote on stderr since the last call, with mbconform's
  // notes on the protocol ("not a JSON object on stdout: ...").
  std::string take_log() {
    drain_stderr();
    return std::exchange(log_, std::string());
  }
  void log_note(const std::string& note) { log_ += "[mbconform] " + note + "\n"; }

 private:
  void drain_stderr();
  std::string command_;
  pid_t pid_ = -1;
  int in_ = -1, out_ = -1, err_ = -1;
  std::string out_buf_, log_;
};

}  // namespace mbc::client
