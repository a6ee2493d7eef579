#include "session/signals.h"

#include <unistd.h>

#include <csignal>
#include <cstring>
#include <vector>

namespace mbc::conf {
namespace {

std::atomic<bool> g_stop{false};
std::atomic<int> g_signal{0};
// The journals of the sessions open now (a fleet run has one per line): a
// slot is written while `state` is kWriting and read by a second signal only
// once it is kReady.
constexpr int kFree = 0, kWriting = 1, kReady = 2;
struct Slot {
  std::atomic<int> state{kFree};
  char line[1024] = "";
};
Slot g_slots[16];

void on_session_stop_signal(int sig) {
  if (g_stop.exchange(true) && (sig == SIGINT || sig == SIGTERM)) {
    bool named = false;
    for (auto& s : g_slots)
      if (s.state.load() == kReady) {
        (void)!::write(STDERR_FILENO, s.line, std::strlen(s.line));
        named = true;
      }
    if (!named) {
      const char* msg = "mbconform: stopped at once\n";
      (void)!::write(STDERR_FILENO, msg, std::strlen(msg));
    }
    ::_exit(2);
  }
  g_signal.store(sig);
}

std::string restore_line(const std::string& path) {
  return "mbconform: stopped at once; the drive is NOT restored: mbconform restore " + path + "\n";
}

}  // namespace

void install_stop_signals() {
  struct sigaction sa {};
  sa.sa_handler = on_session_stop_signal;
  sigemptyset(&sa.sa_mask);
  sa.sa_flags = SA_RESTART;  // the exchange in flight ends as usual; the command sees the stop after it
  for (int s : {SIGINT, SIGTERM, SIGHUP}) sigaction(s, &sa, nullptr);
}

bool stop_requested() { return g_stop.load(); }
int stop_signal() { return g_signal.load(); }
const std::atomic<bool>& stop_flag() { return g_stop; }

void set_stop_journal(const std::string& path) {
  const std::string line = restore_line(path);
  if (line.size() >= sizeof g_slots[0].line) return;
  for (auto& s : g_slots) {
    int free = kFree;
    if (!s.state.compare_exchange_strong(free, kWriting)) continue;
    std::memcpy(s.line, line.c_str(), line.size() + 1);
    s.state.store(kReady);
    return;
  }
}

void forget_stop_journal(const std::string& path) {
  const std::string line = restore_line(path);
  for (auto& s : g_slots) {
    int ready = kReady;
    if (s.line == line && s.state.compare_exchange_strong(ready, kWriting)) {
      s.line[0] = 0;
      s.state.store(kFree);
    }
  }
}

std::vector<std::string> stop_journals() {
  std::vector<std::string> out;
  const std::string head = restore_line("");
  for (auto& s : g_slots)
    if (s.state.load() == kReady) out.emplace_back(std::string(s.line + head.size() - 1, std::strlen(s.line) - head.size()));
  return out;
}

std::string signal_name(int sig) {
  switch (sig) {
    case SIGINT: return "SIGINT";
    case SIGTERM: return "SIGTERM";
    case SIGHUP: return "SIGHUP";
    default: return sig ? "signal " + std::to_string(sig) : "a stop";
  }
}

}  // namespace mbc::conf
