#include "serve_process.h"

#include <sys/resource.h>

#include <fcntl.h>
#include <poll.h>
#include <signal.h>
#include <sys/wait.h>
#include <unistd.h>

#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <sstream>
#include <stdexcept>
#include <thread>

namespace mbc::serve_test {

using Clock = std::chrono::steady_clock;
namespace fs = std::filesystem;

std::string mbconform_bin() {
  if (const char* env = std::getenv("MBCONFORM_BIN")) return env;
  return MBCONFORM_BIN;  // compile definition: $<TARGET_FILE:mbconform>
}

TempDir::TempDir() {
  std::string tmpl = (fs::temp_directory_path() / "mbc-serve-XXXXXX").string();
  if (!mkdtemp(tmpl.data())) throw std::runtime_error("mkdtemp failed");
  path_ = tmpl;
}
TempDir::~TempDir() {
  std::error_code ec;
  fs::remove_all(path_, ec);
}

int Listening::port() const { return std::stoi(address.substr(address.rfind(':') + 1)); }

ServeProcess::ServeProcess(std::vector<std::string> args, int max_files) {
  log_path_ = log_dir_ / "stderr.log";
  int out[2];
  if (pipe(out) != 0) throw std::runtime_error("pipe failed");
  args.insert(args.begin(), {mbconform_bin(), "serve"});
  pid_ = fork();
  if (pid_ == 0) {
    dup2(out[1], STDOUT_FILENO);
    int err = open(log_path_.c_str(), O_WRONLY | O_CREAT | O_TRUNC, 0644);
    dup2(err, STDERR_FILENO);
    close(out[0]);
    close(out[1]);
    if (max_files > 0) {
      rlimit lim{rlim_t(max_files), rlim_t(max_files)};
      setrlimit(RLIMIT_NOFILE, &lim);
    }
    std::vector<char*> argv;
    for (auto& a : args) argv.push_back(a.data());
    argv.push_back(nullptr);
    execv(argv[0], argv.data());
    _exit(127);
  }
  close(out[1]);
  stdout_fd_ = out[0];
}

ServeProcess::~ServeProcess() {
  if (pid_ > 0) {
    kill(pid_, SIGKILL);
    waitpid(pid_, nullptr, 0);
  }
  if (stdout_fd_ >= 0) close(stdout_fd_);
}

bool ServeProcess::wait_listening(size_t count, std::chrono::milliseconds timeout) {
  auto deadline = Clock::now() + timeout;
  while (endpoints_.size() < count) {
    size_t nl;
    while ((nl = stdout_buf_.find('\n')) != std::string::npos) {
      std::istringstream line(stdout_buf_.substr(0, nl));
      stdout_buf_.erase(0, nl + 1);
      std::string word;
      Listening l;
      if (line >> word >> l.transport >> l.address && word == "listening") endpoints_.push_back(l);
    }
    if (endpoints_.size() >= count) break;
    auto left = std::chrono::duration_cast<std::chrono::milliseconds>(deadline - Clock::now()).count();
    if (left <= 0) return false;
    pollfd p{stdout_fd_, POLLIN, 0};
    if (poll(&p, 1, int(left)) <= 0) return false;
    char buf[512];
    ssize_t n = read(stdout_fd_, buf, sizeof buf);
    if (n <= 0) return false;  // the server exited
    stdout_buf_.append(buf, size_t(n));
  }
  return true;
}

const Listening* ServeProcess::endpoint(const std::string& transport) const {
  for (const auto& e : endpoints_)
    if (e.transport == transport) return &e;
  return nullptr;
}

std::optional<int> ServeProcess::wait_exit(std::chrono::milliseconds timeout) {
  auto deadline = Clock::now() + timeout;
  while (pid_ > 0) {
    int status = 0;
    pid_t r = waitpid(pid_, &status, WNOHANG);
    if (r == pid_) {
      pid_ = -1;
      return WIFEXITED(status) ? WEXITSTATUS(status) : 128 + WTERMSIG(status);
    }
    if (Clock::now() > deadline) {
      kill(pid_, SIGKILL);
      waitpid(pid_, nullptr, 0);
      pid_ = -1;
      return std::nullopt;
    }
    std::this_thread::sleep_for(std::chrono::milliseconds(5));
  }
  return std::nullopt;
}

std::optional<int> ServeProcess::stop(int signal, std::chrono::milliseconds timeout) {
  if (pid_ <= 0) return std::nullopt;
  kill(pid_, signal);
  return wait_exit(timeout);
}

std::string ServeProcess::log() const {
  std::ifstream in(log_path_);
  std::stringstream s;
  s << in.rdbuf();
  return s.str();
}

}  // namespace mbc::serve_test
