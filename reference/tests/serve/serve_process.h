// Runs `mbconform serve` as a child process for the interoperability tests:
// waits (bounded) for its "listening" lines, stops it with a signal and
// reports how it exited, so a hang fails fast instead of stalling ctest.
#pragma once

#include <sys/types.h>

#include <chrono>
#include <optional>
#include <string>
#include <vector>

namespace mbc::serve_test {

// The mbconform binary: $MBCONFORM_BIN, else the one this build made.
std::string mbconform_bin();

// A fresh directory under $TMPDIR, removed by the destructor.
class TempDir {
 public:
  TempDir();
  ~TempDir();
  const std::string& path() const { return path_; }
  std::string operator/(const std::string& name) const { return path_ + "/" + name; }

 private:
  std::string path_;
};

struct Listening {
  std::string transport;  // tcp | rtu-tcp | pty
  std::string address;    // 127.0.0.1:PORT or the pty path
  int port() const;       // for tcp and rtu-tcp
};

class ServeProcess {
 public:
  // Starts `mbconform serve <args>` (stderr goes to a log file read by log()).
  // `max_files` > 0: the child's RLIMIT_NOFILE, soft and hard (EMFILE tests).
  explicit ServeProcess(std::vector<std::string> args, int max_files = 0);
  ~ServeProcess();  // SIGKILL if still running
  ServeProcess(const ServeProcess&) = delete;
  ServeProcess& operator=(const ServeProcess&) = delete;

  // Reads stdout until `count` listening lines came; false on timeout or exit.
  bool wait_listening(size_t count, std::chrono::milliseconds timeout = std::chrono::seconds(10));
  const std::vector<Listening>& endpoints() const { return endpoints_; }
  const Listening* endpoint(const std::string& transport) const;

  // Sends `signal`, waits for the exit; the exit code, 128+signal when killed
  // by one, nullopt on timeout (then the child is killed).
  std::optional<int> stop(int signal, std::chrono::milliseconds timeout = std::chrono::seconds(5));
  // Waits for an exit without signalling (for argument errors).
  std::optional<int> wait_exit(std::chrono::milliseconds timeout = std::chrono::seconds(10));
  std::string log() const;  // stderr so far
  pid_t pid() const { return pid_; }

 private:
  pid_t pid_ = -1;
  int stdout_fd_ = -1;
  std::string stdout_buf_;
  std::string log_path_;
  TempDir log_dir_;
  std::vector<Listening> endpoints_;
};

}  // namespace mbc::serve_test
