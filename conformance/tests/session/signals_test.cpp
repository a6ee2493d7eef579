// The journals a second stop signal names (session/signals.h): every session
// open names its own, a fleet run's parallel lines all of theirs, and a
// restored drive's journal is not named.
#include <gtest/gtest.h>

#include <sys/wait.h>
#include <unistd.h>

#include <csignal>
#include <functional>
#include <string>
#include <utility>

#include "session/signals.h"

namespace mbc::conf {
namespace {

// Runs `child` in a forked process whose stderr is read here: its exit code
// (-1 when it did not exit) and what it wrote.
std::pair<int, std::string> in_child(const std::function<void()>& child) {
  int err[2];
  if (pipe(err) != 0) return {-1, "pipe failed"};
  pid_t pid = fork();
  if (pid == 0) {
    dup2(err[1], STDERR_FILENO);
    close(err[0]);
    child();
    _exit(12);
  }
  close(err[1]);
  std::string text;
  char buf[4096];
  for (ssize_t n; (n = read(err[0], buf, sizeof buf)) > 0;) text.append(buf, size_t(n));
  close(err[0]);
  int status = 0;
  waitpid(pid, &status, 0);
  return {WIFEXITED(status) ? WEXITSTATUS(status) : -1, text};
}

TEST(StopSignals, ASecondSignalNamesEveryOpenJournalButARestoredOne) {
  auto [code, text] = in_child([] {
    install_stop_signals();
    set_stop_journal("/tmp/line-a/journal.txt");
    set_stop_journal("/tmp/line-b/journal.txt");
    set_stop_journal("/tmp/line-c/journal.txt");
    forget_stop_journal("/tmp/line-b/journal.txt");  // restored
    if (stop_journals().size() != 2) _exit(10);
    raise(SIGINT);  // asks to stop
    if (!stop_requested()) _exit(11);
    raise(SIGINT);  // ends at once, naming the journals
  });
  EXPECT_EQ(code, 2) << text;
  EXPECT_NE(text.find("NOT restored: mbconform restore /tmp/line-a/journal.txt\n"), std::string::npos) << text;
  EXPECT_NE(text.find("NOT restored: mbconform restore /tmp/line-c/journal.txt\n"), std::string::npos) << text;
  EXPECT_EQ(text.find("line-b"), std::string::npos) << text;
}

TEST(StopSignals, NoJournalIsStoppedAtOnce) {
  auto [code, text] = in_child([] {
    install_stop_signals();
    raise(SIGTERM);
    raise(SIGTERM);
  });
  EXPECT_EQ(code, 2) << text;
  EXPECT_EQ(text, "mbconform: stopped at once\n");
}

}  // namespace
}  // namespace mbc::conf
