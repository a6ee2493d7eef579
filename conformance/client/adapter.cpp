#include "client/adapter.h"

#include <fcntl.h>
#include <poll.h>
#include <signal.h>
#include <sys/wait.h>
#include <unistd.h>

#include <cerrno>
#include <cstring>
#include <algorithm>
#include <string_view>
#include <stdexcept>
#include <vector>

namespace mbc::client {
namespace {

void close_fd(int& fd) {
  if (fd >= 0) ::close(fd);
  fd = -1;
}

}  // namespace

bool json_depth_ok(std::string_view text, size_t max) {
  size_t depth = 0;
  bool in_string = false, escaped = false;
  for (char c : text) {
    if (in_string) {
      if (escaped) escaped = false;
      else if (c == '\\') escaped = true;
      else if (c == '"') in_string = false;
      continue;
    }
    if (c == '"') in_string = true;
    else if (c == '[' || c == '{') {
      if (++depth > max) return false;
    } else if ((c == ']' || c == '}') && depth) {
      --depth;
    }
  }
  return true;
}

void Adapter::append_log(std::string_view text) {
  size_t keep = std::min(text.size(), kMaxLog - std::min(kMaxLog, logged_));
  log_.append(text.substr(0, keep));
  logged_ += keep;
  log_dropped_ += text.size() - keep;
}

std::string Adapter::take_log() {
  drain_stderr();
  std::string out = std::exchange(log_, std::string());
  if (log_dropped_) {
    out += "[mbconform] the adapter's output past " + std::to_string(kMaxLog) + " bytes was dropped (" +
           std::to_string(log_dropped_) + " bytes)\n";
    log_dropped_ = 0;
  }
  return out;
}

Adapter::Adapter(std::string command) : command_(std::move(command)) {}

Adapter::~Adapter() { kill(); }

void Adapter::start() {
  int in[2], out[2], err[2];
  if (pipe2(in, O_CLOEXEC) != 0 || pipe2(out, O_CLOEXEC) != 0 || pipe2(err, O_CLOEXEC) != 0)
    throw std::runtime_error(std::string("pipe: ") + std::strerror(errno));
  pid_t pid = fork();
  if (pid < 0) throw std::runtime_error(std::string("fork: ") + std::strerror(errno));
  if (pid == 0) {
    dup2(in[0], 0);
    dup2(out[1], 1);
    dup2(err[1], 2);
    setpgid(0, 0);  // its own group: a kill reaches the interpreter and what it started
    execl("/bin/sh", "sh", "-c", command_.c_str(), static_cast<char*>(nullptr));
    _exit(127);
  }
  ::close(in[0]);
  ::close(out[1]);
  ::close(err[1]);
  pid_ = pid;
  in_ = in[1];
  out_ = out[0];
  err_ = err[0];
  fcntl(out_, F_SETFL, O_NONBLOCK);
  fcntl(err_, F_SETFL, O_NONBLOCK);
  out_buf_.clear();
  signal(SIGPIPE, SIG_IGN);  // an adapter that died must not take mbconform with it
}

bool Adapter::send(const nlohmann::json& message) {
  if (in_ < 0) return false;
  std::string line = message.dump() + "\n";
  size_t off = 0;
  while (off < line.size()) {
    ssize_t n = ::write(in_, line.data() + off, line.size() - off);
    if (n < 0 && errno == EINTR) continue;
    if (n <= 0) return false;
    off += size_t(n);
  }
  return true;
}

// Bounded: an adapter that writes stderr without end does not keep this
// loop (and the scenario server waiting on it) from the rest.
void Adapter::drain_stderr() {
  char buf[4096];
  ssize_t n;
  for (int i = 0; i < 64 && err_ >= 0 && (n = ::read(err_, buf, sizeof buf)) > 0; ++i)
    append_log(std::string_view(buf, size_t(n)));
}

std::optional<nlohmann::json> Adapter::next(Clock::time_point deadline, ScenarioServer* server) {
  std::vector<pollfd> fds;
  for (;;) {
    for (size_t nl; (nl = out_buf_.find('\n')) != std::string::npos;) {
      std::string line = out_buf_.substr(0, nl);
      out_buf_.erase(0, nl + 1);
      if (std::exchange(skipping_line_, false)) continue;  // the end of a line too long to keep
      if (!json_depth_ok(line, kMaxDepth)) {
        log_note("a JSON line on stdout nested deeper than " + std::to_string(kMaxDepth) + " levels: ignored (" +
                 std::to_string(line.size()) + " bytes)");
        continue;
      }
      auto j = nlohmann::json::parse(line, nullptr, false);
      if (!j.is_discarded() && j.is_object()) return j;
      if (!line.empty()) log_note("not a JSON object on stdout: " + line.substr(0, 200) + (line.size() > 200 ? "..." : ""));
    }
    if (out_buf_.size() > kMaxLine) {
      if (!skipping_line_)
        log_note("a line on stdout longer than " + std::to_string(kMaxLine) + " bytes: ignored");
      skipping_line_ = true;
      out_buf_.clear();
    }
    if (out_ < 0) return std::nullopt;
    auto now = Clock::now();
    if (now >= deadline) return std::nullopt;
    auto until = deadline;
    if (server)
      if (auto due = server->next_due()) until = std::min(until, *due);
    fds.clear();
    fds.push_back({out_, POLLIN, 0});
    fds.push_back({err_, POLLIN, 0});
    if (server) server->fill_poll(fds);
    auto wait = std::chrono::duration_cast<std::chrono::microseconds>(until - now);
    timespec ts{time_t(std::max<int64_t>(0, wait.count()) / 1000000), long(std::max<int64_t>(0, wait.count()) % 1000000) * 1000};
    int rc = ppoll(fds.data(), fds.size(), &ts, nullptr);
    if (rc < 0 && errno != EINTR) throw std::runtime_error(std::string("poll: ") + std::strerror(errno));
    if (rc > 0) {
      if (fds[1].revents) drain_stderr();
      if (fds[0].revents) {
        char buf[4096];
        ssize_t n = ::read(out_, buf, sizeof buf);
        if (n > 0) out_buf_.append(buf, size_t(n));
        else if (n == 0) close_fd(out_);  // the adapter closed stdout: it exited
      }
      if (server) server->on_poll(fds);
    }
    if (server) server->on_time();
  }
}

void Adapter::kill() {
  if (pid_ > 0) {
    ::kill(-pid_, SIGKILL);
    ::kill(pid_, SIGKILL);
    waitpid(pid_, nullptr, 0);
    pid_ = -1;
  }
  drain_stderr();
  close_fd(in_);
  close_fd(out_);
  close_fd(err_);
}

std::string Adapter::exited(std::chrono::milliseconds grace) {
  if (pid_ <= 0 || out_ >= 0) return "";  // stdout still open: it did not end
  auto deadline = Clock::now() + grace;
  for (;;) {
    int status = 0;
    pid_t r = waitpid(pid_, &status, WNOHANG);
    if (r == pid_) {
      pid_ = -1;
      drain_stderr();
      close_fd(in_);
      close_fd(out_);
      close_fd(err_);
      if (WIFSIGNALED(status)) {
        const char* abbrev = sigabbrev_np(WTERMSIG(status));
        return "killed by SIG" + std::string(abbrev ? abbrev : std::to_string(WTERMSIG(status)));
      }
      return "exited with status " + std::to_string(WIFEXITED(status) ? WEXITSTATUS(status) : -1);
    }
    if (r < 0 || Clock::now() >= deadline) return "";
    usleep(2000);
  }
}

int Adapter::finish(std::chrono::milliseconds grace) {
  if (pid_ <= 0) return -1;
  close_fd(in_);  // end of input: every adapter stops reading
  auto deadline = Clock::now() + grace;
  int status = 0;
  while (Clock::now() < deadline) {
    drain_stderr();
    pid_t r = waitpid(pid_, &status, WNOHANG);
    if (r == pid_) {
      pid_ = -1;
      drain_stderr();
      close_fd(out_);
      close_fd(err_);
      return WIFEXITED(status) ? WEXITSTATUS(status) : -1;
    }
    usleep(5000);
  }
  kill();
  return -1;
}

}  // namespace mbc::client
