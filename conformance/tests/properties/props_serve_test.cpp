// The properties against real transports: `mbconform serve` over Modbus TCP
// and RTU over TCP (libmodbus as the master), clean and with a fault; and the
// `mbconform props` command line (exit codes, reports, counterexamples).
#include <gtest/gtest.h>
#include <fmt/core.h>
#include <nlohmann/json.hpp>

#include <cstdio>
#include <filesystem>
#include <fstream>

#include "properties/properties.h"
#include "loader.h"
#include "serve_process.h"

namespace mbc::conf::props {
namespace {

using serve_test::ServeProcess;
using serve_test::TempDir;

Options live_options() {
  Options o;
  o.cases = 30;
  o.seed = 20261130;
  o.max_size = 30;
  return o;
}

CaseResult run_live(const std::string& uri, const std::string& device, const std::string& invariant,
                    Options options = live_options()) {
  static std::map<std::string, spec::Spec> specs;
  if (!specs.count(device)) specs.emplace(device, spec::load_spec_by_id(device));
  TargetSource src = source_for(uri, &specs.at(device));
  return run_invariant(*find_invariant(invariant), src, options);
}

// --allow-motion: the stop property moves the axis.
Options moving_options() {
  Options o = live_options();
  o.cases = 5;
  o.policy.allow_motion = true;
  return o;
}

TEST(PropsOverServe, CleanDeviceHoldsOverTcpAndRtuOverTcp) {
  ServeProcess server({"--device", "hsc60@1", "--tcp", "127.0.0.1:0", "--rtu-tcp", "127.0.0.1:0"});
  ASSERT_TRUE(server.wait_listening(2)) << server.log();
  std::string tcp = fmt::format("tcp://127.0.0.1:{}?unit=1", server.endpoint("tcp")->port());
  std::string rtu = fmt::format("rtu-tcp://127.0.0.1:{}?unit=1", server.endpoint("rtu-tcp")->port());
  for (const auto& uri : {tcp, rtu})
    for (const char* inv : {"read-after-write", "rejection-changes-nothing", "responses-well-formed"}) {
      CaseResult c = run_live(uri, "hsc60", inv);
      EXPECT_EQ(c.outcome, Outcome::pass) << uri << " " << c.id << ": " << c.message;
    }
  CaseResult c = run_live(rtu, "hsc60", "foreign-or-corrupt-ignored");
  EXPECT_EQ(c.outcome, Outcome::pass) << c.message;
}

TEST(PropsOverServe, ServedFaultIsCaught) {
  ServeProcess server({"--fault", "lost-write", "--device", "hsc60@1", "--rtu-tcp", "127.0.0.1:0"});
  ASSERT_TRUE(server.wait_listening(1)) << server.log();
  std::string rtu = fmt::format("rtu-tcp://127.0.0.1:{}?unit=1", server.endpoint("rtu-tcp")->port());
  CaseResult c = run_live(rtu, "hsc60", "read-after-write");
  EXPECT_EQ(c.outcome, Outcome::fail) << c.message;
}

// The control properties (issue 38) against a served CiA 402 drive over RTU
// (RTU over TCP), as well as in-process (properties_test): the state machine
// holds, and a state-machine fault served the same way is caught. On a live
// target the stop is not sampled in real time and no fault can be tripped out
// of band: that one skips. The stop from motion moves the axis: it skips
// without --allow-motion, and with it samples the axis on the wall clock.
TEST(PropsOverServe, ControlPropertiesOnCia402OverRtu) {
  ServeProcess server({"--device", "cia402-modbus@1", "--rtu-tcp", "127.0.0.1:0"});
  ASSERT_TRUE(server.wait_listening(1)) << server.log();
  std::string rtu = fmt::format("rtu-tcp://127.0.0.1:{}?unit=1", server.endpoint("rtu-tcp")->port());
  for (const char* inv : {"control-status-names-state", "control-undefined-command", "control-mode-switch"}) {
    CaseResult c = run_live(rtu, "cia402-modbus", inv);
    EXPECT_EQ(c.outcome, Outcome::pass) << inv << ": " << c.message;
  }
  CaseResult stop = run_live(rtu, "cia402-modbus", "control-stop-from-motion");
  EXPECT_EQ(stop.outcome, Outcome::skip) << stop.message;
  EXPECT_NE(stop.message.find("--allow-motion"), std::string::npos) << stop.message;
  stop = run_live(rtu, "cia402-modbus", "control-stop-from-motion", moving_options());
  EXPECT_EQ(stop.outcome, Outcome::pass) << stop.message;
  CaseResult reset = run_live(rtu, "cia402-modbus", "control-fault-reset");
  EXPECT_EQ(reset.outcome, Outcome::skip) << reset.message;
  EXPECT_NE(reset.message.find("trip"), std::string::npos) << reset.message;
}

// A drive that ignores a quick stop while it moves, served over TCP: caught
// in real time (the speed holds steady after the stop), as in-process.
TEST(PropsOverServe, AStopIgnoredWhileMovingIsCaughtLive) {
  ServeProcess server({"--fault", "stop-ignored", "--device", "cia402-modbus@1", "--tcp", "127.0.0.1:0"});
  ASSERT_TRUE(server.wait_listening(1)) << server.log();
  std::string tcp = fmt::format("tcp://127.0.0.1:{}?unit=1", server.endpoint("tcp")->port());
  CaseResult c = run_live(tcp, "cia402-modbus", "control-stop-from-motion", moving_options());
  EXPECT_EQ(c.outcome, Outcome::fail) << c.message;
  EXPECT_NE(c.message.find("quick_stop"), std::string::npos) << c.message;
}

TEST(PropsOverServe, ControlFaultServedOverRtuIsCaught) {
  for (const char* fault : {"status-bit-wrong", "transition-missing", "undefined-command-accepted"}) {
    ServeProcess server({"--fault", fault, "--device", "cia402-modbus@1", "--rtu-tcp", "127.0.0.1:0"});
    ASSERT_TRUE(server.wait_listening(1)) << server.log();
    std::string rtu = fmt::format("rtu-tcp://127.0.0.1:{}?unit=1", server.endpoint("rtu-tcp")->port());
    CaseResult c = run_live(rtu, "cia402-modbus", "control-status-names-state");
    EXPECT_EQ(c.outcome, Outcome::fail) << fault << " went unnoticed over RTU: " << c.message;
  }
}

// ---- the command line ------------------------------------------------------

// `mbconform COMMAND ARGS`: its exit code, its output in *out.
int run_tool(const std::string& command, const std::string& args, std::string* out = nullptr) {
  std::string cmd = serve_test::mbconform_bin() + " " + command + " " + args + " 2>&1";
  FILE* p = popen(cmd.c_str(), "r");
  std::string text;
  char buf[4096];
  while (size_t n = fread(buf, 1, sizeof buf, p)) text.append(buf, n);
  int status = pclose(p);
  if (out) *out = text;
  return WIFEXITED(status) ? WEXITSTATUS(status) : -1;
}
int run_cli(const std::string& args, std::string* out = nullptr) { return run_tool("props", args, out); }

TEST(PropsCli, ExitCodesReportsAndCounterexamples) {
  TempDir dir;
  std::string out;
  EXPECT_EQ(run_cli(fmt::format("--target ref:hsc60 --only read-after-write --cases 20 --seed 1 --out {}", dir / "clean"), &out), 0)
      << out;
  EXPECT_TRUE(std::filesystem::exists(dir / "clean/report.json")) << out;
  EXPECT_TRUE(std::filesystem::exists(dir / "clean/junit.xml")) << out;

  EXPECT_EQ(run_cli(fmt::format("--target 'ref:hsc60?fault=lost-write' --only stateful-model --seed 1 --out {}", dir / "bad"), &out), 1)
      << out;
  EXPECT_NE(out.find("shrunk counterexample"), std::string::npos) << out;
  auto regression = dir / "bad/regressions/hsc60-stateful-model.txt";
  ASSERT_TRUE(std::filesystem::exists(regression)) << out;
  // The written counterexample replays: the clean device agrees, the broken one does not.
  EXPECT_EQ(run_cli("--replay " + regression, &out), 0) << out;
  EXPECT_EQ(run_cli("--target 'ref:hsc60?fault=lost-write' --replay " + regression, &out), 1) << out;
  // It is written with every expectation the model had: `mbconform replay`,
  // which reads only the file, gives the same verdicts.
  EXPECT_EQ(run_tool("replay", regression + " --target 'ref:hsc60?fault=lost-write'", &out), 1) << out;
  EXPECT_NE(out.find("not met on"), std::string::npos) << out;
  EXPECT_EQ(run_tool("replay", regression + " --target ref:hsc60", &out), 0) << out;

  EXPECT_EQ(run_cli("--target ref:no-such-device", &out), 2) << out;
  EXPECT_EQ(run_cli("--target ref:hsc60 --only no-such-invariant", &out), 2) << out;
  EXPECT_EQ(run_cli("--target 'ref:hsc60?fault=no-such-fault'", &out), 2) << out;
  EXPECT_EQ(run_cli("--target tcp://127.0.0.1:1?unit=1", &out), 2) << out;  // no spec named
}

// A clean drive served on a live transport, `props` with no opt-in: the
// frame policy holds back the generated frames it does not allow (FC 05 is
// not in hsc60's profile, writes to command registers, ...). A case with such
// a frame is discarded, never a counterexample: no property fails the good
// drive, and what was held back is said. The same run against the drive
// with a lost write still fails.
TEST(PropsCli, ALiveCleanDriveWithoutOptInsFailsNoProperty) {
  TempDir dir;
  std::string out;
  {
    ServeProcess server({"--device", "hsc60@1", "--tcp", "127.0.0.1:0"});
    ASSERT_TRUE(server.wait_listening(1)) << server.log();
    std::string uri = fmt::format("tcp://127.0.0.1:{}?unit=1", server.endpoint("tcp")->port());
    int rc = run_cli(fmt::format("--target '{}' --device hsc60 --cases 30 --seed 7 --out {}", uri, dir / "clean"), &out);
    EXPECT_NE(rc, 1) << out;
    auto report = nlohmann::json::parse(std::ifstream(dir / "clean/report.json"));
    int held = 0;
    for (const auto& c : report["devices"][0]["cases"]) {
      EXPECT_NE(c["outcome"], "fail") << c["id"] << ": " << c["message"];
      if (c.contains("held_back")) held += c["held_back"].get<int>();
      if (c.contains("extra") && c["extra"].contains("held_back")) held += c["extra"]["held_back"].get<int>();
    }
    EXPECT_GT(held, 0) << "no generated frame was held back: the test no longer tests the policy's refusals\n" << out;
  }
  ServeProcess bad({"--fault", "lost-write", "--device", "hsc60@1", "--tcp", "127.0.0.1:0"});
  ASSERT_TRUE(bad.wait_listening(1)) << bad.log();
  std::string uri = fmt::format("tcp://127.0.0.1:{}?unit=1", bad.endpoint("tcp")->port());
  EXPECT_EQ(run_cli(fmt::format("--target '{}' --device hsc60 --only read-after-write --cases 30 --seed 7 --out {}", uri,
                                dir / "bad"), &out), 1) << out;
}

// A live drive whose control commands may move it (sihong-57hs-r's): without
// --allow-motion the frame policy refuses every command the control
// properties would give, so they run no case. That is no PASS: the run is
// PARTIAL, names --allow-motion in the summary, report.json and junit.xml,
// and exits 0, or 3 under --require-complete; with the flag the same
// properties run and pass. A property the flag alone would not enable (the
// fault reset: no fault can be caused on a live drive) names no opt-in.
TEST(PropsCli, APropertySkippedForWantOfAnOptInMakesThePropsRunPartial) {
  TempDir dir;
  ServeProcess server({"--device", "sihong-57hs-r@1", "--tcp", "127.0.0.1:0"});
  ASSERT_TRUE(server.wait_listening(1)) << server.log();
  const std::string base = fmt::format("--target 'tcp://127.0.0.1:{}?unit=1' --device sihong-57hs-r --cases 10 --seed 1 -q "
                                       "--only control-undefined-command --only control-fault-reset",
                                       server.endpoint("tcp")->port());
  std::string out;
  EXPECT_EQ(run_cli(base + " --out " + (dir / "partial"), &out), 0) << out;
  EXPECT_NE(out.find("\nPARTIAL: "), std::string::npos) << out;
  EXPECT_NE(out.find("--allow-motion would enable 1"), std::string::npos) << out;
  auto j = nlohmann::json::parse(std::ifstream(dir / "partial/report.json"));
  EXPECT_EQ(j["verdict"], "PARTIAL") << out;
  ASSERT_EQ(j["missing_opt_ins"].size(), 1u) << j["missing_opt_ins"].dump();
  EXPECT_EQ(j["missing_opt_ins"][0]["flag"], "--allow-motion");
  EXPECT_EQ(j["missing_opt_ins"][0]["must_cases"], 1);
  for (const auto& c : j["devices"][0]["cases"]) {
    EXPECT_EQ(c["outcome"], "skip") << c.dump();
    if (c["id"] == "prop.control-undefined-command.sihong-57hs-r") EXPECT_EQ(c.value("opt_in", ""), "--allow-motion") << c.dump();
    else EXPECT_FALSE(c.contains("opt_in")) << c.dump();
  }
  std::ifstream junit_file(dir / "partial/junit.xml");
  std::string junit((std::istreambuf_iterator<char>(junit_file)), std::istreambuf_iterator<char>());
  EXPECT_NE(junit.find("<property name=\"verdict\" value=\"PARTIAL\"/>"), std::string::npos) << junit;
  EXPECT_NE(junit.find("<property name=\"opt-in\" value=\"--allow-motion: would enable 1"), std::string::npos) << junit;

  EXPECT_EQ(run_cli(base + " --require-complete --out " + (dir / "gate"), &out), 3) << out;

  EXPECT_EQ(run_cli(base + " --allow-motion --require-complete --out " + (dir / "motion"), &out), 0) << out;
  auto m = nlohmann::json::parse(std::ifstream(dir / "motion/report.json"));
  EXPECT_EQ(m["verdict"], "PASS") << out;
  EXPECT_EQ(m["devices"][0]["cases"][0]["outcome"], "pass") << m["devices"][0]["cases"][0].dump();
}

// A spec from a register sheet (source: csv): its facts are inferred, so a
// live target takes no write of it without --allow-writes. A control
// property whose walk needs such a write is skipped for that opt-in; the
// drive is never failed for a frame that was not sent.
TEST(PropsCli, AControlWalkTheFramePolicyHoldsBackIsSkippedNotFailed) {
  TempDir dir;
  std::string text;
  {
    std::ifstream f(spec::load_spec_by_id("hsc60").path);
    text.assign(std::istreambuf_iterator<char>(f), std::istreambuf_iterator<char>());
  }
  const std::string manual = "\n  manual:\n";
  auto at = text.find(manual);
  ASSERT_NE(at, std::string::npos);
  text.insert(at + manual.size(), "    source: csv\n");
  const std::string spec_file = dir / "hsc60.yaml";
  std::ofstream(spec_file) << text;
  ServeProcess server({"--device", "hsc60@1", "--tcp", "127.0.0.1:0"});
  ASSERT_TRUE(server.wait_listening(1)) << server.log();
  const std::string base = fmt::format("--target 'tcp://127.0.0.1:{}?unit=1' --spec {} --cases 10 --seed 1 -q "
                                       "--only control-status-names-state --only control-undefined-command",
                                       server.endpoint("tcp")->port(), spec_file);
  std::string out;
  EXPECT_EQ(run_cli(base + " --out " + (dir / "held"), &out), 0) << out;
  auto j = nlohmann::json::parse(std::ifstream(dir / "held/report.json"));
  EXPECT_EQ(j["verdict"], "PARTIAL") << out;
  bool writes_named = false;
  for (const auto& c : j["devices"][0]["cases"]) {
    EXPECT_NE(c["outcome"], "fail") << c.dump();
    writes_named |= c.value("opt_in", "") == "--allow-writes";
  }
  EXPECT_TRUE(writes_named) << j["devices"][0]["cases"].dump();
}

}  // namespace
}  // namespace mbc::conf::props
