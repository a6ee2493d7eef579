// A vendor stack that crashes, hangs, leaks, forks or signals its parent:
// `mbconform run` against it completes (every case has a result, none is
// "not run: the target was lost"), and only the cases that met the fault fail.
#include <gtest/gtest.h>
#include <fmt/core.h>
#include <nlohmann/json.hpp>
#include <signal.h>
#include <sys/wait.h>

#include <chrono>
#include <cstdio>
#include <fstream>
#include <sstream>
#include <thread>

#include "serve_process.h"

namespace mbc::conf {
namespace {

using serve_test::TempDir;

struct Out {
  int rc = -1;
  std::string text;
};

Out run_cli(const std::string& args) {
  std::string cmd = serve_test::mbconform_bin() + " " + args + " 2>&1";
  FILE* p = popen(cmd.c_str(), "r");
  Out o;
  char buf[4096];
  while (size_t n = fread(buf, 1, sizeof buf, p)) o.text.append(buf, n);
  int status = pclose(p);
  o.rc = WIFEXITED(status) ? WEXITSTATUS(status) : 128 + (WIFSIGNALED(status) ? WTERMSIG(status) : 0);
  return o;
}

nlohmann::json report(const std::string& dir) {
  std::ifstream in(dir + "/report.json");
  nlohmann::json j = nlohmann::json::object();
  if (in) in >> j;
  return j;
}

// Counts the cases of a run's report: total, failed, and those never run because the target was lost.
struct Tally {
  size_t total = 0, failed = 0, lost = 0, fault_failed = 0;
};
Tally tally(const nlohmann::json& j, const std::string& fault_words) {
  Tally t;
  for (const auto& d : j.value("devices", nlohmann::json::array()))
    for (const auto& c : d.value("cases", nlohmann::json::array())) {
      ++t.total;
      std::string outcome = c.value("outcome", ""), msg = c.value("message", "");
      if (outcome == "fail") ++t.failed;
      if (msg.find("the target was lost") != std::string::npos) ++t.lost;
      if (outcome == "fail" && msg.find(fault_words) != std::string::npos) ++t.fault_failed;
    }
  return t;
}

#if defined(BROKEN_PLUGIN_6) && defined(BROKEN_PLUGIN_10)
TEST(PluginFaults, ARunAgainstAPluginThatCrashesOnEveryWriteCompletes) {
  TempDir dir;
  Out o = run_cli(fmt::format("run --quiet --filter /registers/0x000 --target 'plugin:{}?device=hsc60' --device hsc60 --out {}", BROKEN_PLUGIN_6, dir / "r"));
  EXPECT_EQ(o.rc, 1) << o.text;
  Tally t = tally(report(dir / "r"), "the plugin crashed");
  EXPECT_GT(t.total, 10u) << o.text;
  EXPECT_EQ(t.lost, 0u) << "plugin faults never count toward a lost target\n" << o.text;
  EXPECT_GT(t.fault_failed, 3u) << "the cases that met the crash fail, more than three of them in a row";
  EXPECT_LT(t.fault_failed, t.total);
}

TEST(PluginFaults, ARunAgainstAPluginThatHangsOnEveryWriteCompletes) {
  TempDir dir;
  Out o = run_cli(fmt::format("run --quiet --filter /registers/0x000 --target 'plugin:{}?device=hsc60&timeout=100' --device hsc60 --out {}", BROKEN_PLUGIN_10, dir / "r"));
  EXPECT_EQ(o.rc, 1) << o.text;
  Tally t = tally(report(dir / "r"), "the plugin hung");
  EXPECT_EQ(t.lost, 0u) << o.text;
  EXPECT_GT(t.fault_failed, 3u) << o.text;
}

TEST(PluginFaults, ADeadlineEndsTheRunAndNamesTheCasesNotRun) {
  TempDir dir;
  Out o = run_cli(fmt::format("run --quiet --target 'plugin:{}?device=hsc60&timeout=300' --device hsc60 --deadline 3s --out {}", BROKEN_PLUGIN_10,
                              dir / "r"));
  EXPECT_EQ(o.rc, 2) << o.text;
  size_t not_run = 0;
  for (const auto& d : report(dir / "r").value("devices", nlohmann::json::array()))
    for (const auto& c : d.value("cases", nlohmann::json::array())) not_run += c.value("message", "").find("--deadline 3s ran out") != std::string::npos;
  EXPECT_GT(not_run, 0u) << o.text;
}
#endif

#ifdef BROKEN_PLUGIN_7
TEST(PluginFaults, APluginThatKillsItsParentDoesNotEndTheRun) {
  TempDir dir;
  Out o = run_cli(fmt::format("run --quiet --filter function-codes --target 'plugin:{}?device=hsc60' --device hsc60 --out {}", BROKEN_PLUGIN_7, dir / "r"));
  EXPECT_TRUE(o.rc == 0 || o.rc == 1) << o.text;
  EXPECT_TRUE(report(dir / "r").contains("devices")) << o.text;
}
#endif

#ifdef BROKEN_PLUGIN_8
bool gone(int pid) {
  for (int i = 0; i < 100; ++i) {
    std::ifstream stat(fmt::format("/proc/{}/stat", pid));
    std::string line;
    if (!std::getline(stat, line)) return true;
    auto close = line.rfind(')');
    if (close != std::string::npos && close + 2 < line.size() && line[close + 2] == 'Z') return true;
    std::this_thread::sleep_for(std::chrono::milliseconds(20));
  }
  return false;
}

TEST(PluginFaults, AChildThePluginForksDoesNotOutliveTheRun) {
  TempDir dir;
  std::string pids = dir / "pids";
  Out o = run_cli(fmt::format("run --quiet --filter /registers/0x000 --target 'plugin:{}?device=hsc60&config={}' --device hsc60 --out {}", BROKEN_PLUGIN_8,
                              pids, dir / "r"));
  EXPECT_TRUE(o.rc == 0 || o.rc == 1) << o.text;
  std::ifstream in(pids);
  int pid = 0, seen = 0;
  while (in >> pid) {
    ++seen;
    EXPECT_TRUE(gone(pid)) << "the plugin's child " << pid << " outlived the run";
  }
  EXPECT_GT(seen, 0) << o.text;
}
#endif

#ifdef BROKEN_PLUGIN_9
TEST(PluginFaults, APluginOverItsMemoryLimitFailsThatCaseOnly) {
  TempDir dir;
  Out o = run_cli(fmt::format("run --quiet --filter function-codes --target 'plugin:{}?device=hsc60' --device hsc60 --plugin-mem 256 --out {}", BROKEN_PLUGIN_9, dir / "r"));
  EXPECT_TRUE(o.rc == 0 || o.rc == 1) << o.text;
  Tally t = tally(report(dir / "r"), "the plugin crashed");
  EXPECT_EQ(t.lost, 0u) << o.text;
  EXPECT_GT(t.total, 10u) << o.text;
}
#endif

}  // namespace
}  // namespace mbc::conf
