#include "session/signals.h"

#include <unistd.h>

#include <csignal>
#include <cstring>

namespace mbc::conf {
namespace {

std::atomic<bool> g_stop{false};
std::atomic<int> g_signal{0};
// Written before a handler can read it; a second signal prints it as is.
char g_restore_line[4096] = "";

void on_session_stop_signal(int sig) {
  if (g_stop.exchange(true) && (sig == SIGINT || sig == SIGTERM)) {
    const char* msg = g_restore_line[0] ? g_restore_line : "mbconform: stopped at once\n";
    (void)!::write(STDERR_FILENO, msg, std::strlen(msg));
    ::_exit(2);
  }
  g_signal.store(sig);
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
  std::string line = "mbconform: stopped at once; the drive is NOT restored: mbconform restore " + path + "\n";
  if (line.size() >= sizeof g_restore_line) return;
  std::memcpy(g_restore_line, line.c_str(), line.size() + 1);
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
