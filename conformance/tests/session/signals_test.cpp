// The journals a second stop signal names (session/signals.h): every session
// open names its own, a fleet run's parallel lines all of theirs, and a
// restored drive's journal is not named.
#include <gtest/gtest.h>

#include <sys/wait.h>
#include <unistd.h>

#include <csignal>
#include <string>

#include "session/signals.h"

namespace mbc::conf {
namespace {

TEST(StopSignals, ASecondSignalNamesEveryOpenJournalButARestoredOne) {
  int err[2];
  ASSERT_EQ(pipe(err), 0);
  pid_t pid = fork();
  ASSERT_GE(pid, 0);
  if (pid == 0) {
    dup2(err[1], STDERR_FILENO);
    close(err[0]);
    install_stop_signals();
    set_stop_journal("/tmp/line-a/journal.txt");
    set_stop_journal("/tmp/line-b/journal.txt");
    set_stop_journal("/tmp/line-c/journal.txt");
    forget_stop_journal("/tmp/line-b/journal.txt");  // restored
    if (stop_journals().size() != 2) _exit(10);
    raise(SIGINT);  // asks to stop
    if (!stop_requested()) _exit(11);
    raise(SIGINT);  // ends at once, naming the journals
    _exit(12);
  }
  close(err[1]);
  std::string text;
  char buf[4096];
  for (ssize_t n; (n = read(err[0], buf, sizeof buf)) > 0;) text.append(buf, size_t(n));
  close(err[0]);
  int status = 0;
  waitpid(pid, &status, 0);
  ASSERT_TRUE(WIFEXITED(status)) << text;
  EXPECT_EQ(WEXITSTATUS(status), 2) << text;
  EXPECT_NE(text.find("NOT restored: mbconform restore /tmp/line-a/journal.txt\n"), std::string::npos) << text;
  EXPECT_NE(text.find("NOT restored: mbconform restore /tmp/line-c/journal.txt\n"), std::string::npos) << text;
  EXPECT_EQ(text.find("line-b"), std::string::npos) << text;
}

TEST(StopSignals, NoJournalIsStoppedAtOnce) {
  int err[2];
  ASSERT_EQ(pipe(err), 0);
  pid_t pid = fork();
  ASSERT_GE(pid, 0);
  if (pid == 0) {
    dup2(err[1], STDERR_FILENO);
    close(err[0]);
    install_stop_signals();
    raise(SIGTERM);
    raise(SIGTERM);
    _exit(12);
  }
  close(err[1]);
  std::string text;
  char buf[4096];
  for (ssize_t n; (n = read(err[0], buf, sizeof buf)) > 0;) text.append(buf, size_t(n));
  close(err[0]);
  int status = 0;
  waitpid(pid, &status, 0);
  ASSERT_TRUE(WIFEXITED(status)) << text;
  EXPECT_EQ(WEXITSTATUS(status), 2) << text;
  EXPECT_EQ(text, "mbconform: stopped at once\n");
}

}  // namespace
}  // namespace mbc::conf
