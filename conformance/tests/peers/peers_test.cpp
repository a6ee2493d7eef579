// Third-party Modbus servers under `mbconform run --map auto --device
// modbus-standard --allow-writes`, as a driver library's CI would run it.
// No failure may come from the map: the failing cases must be exactly the
// deviations conformance/README.md documents for that library, both ways
// (a documented deviation that no longer fails is as wrong as a new one).
#include <fcntl.h>
#include <gtest/gtest.h>
#include <netinet/in.h>
#include <poll.h>
#include <signal.h>
#include <sys/socket.h>
#include <sys/wait.h>
#include <unistd.h>

#include <array>
#include <atomic>
#include <map>
#include <thread>
#include <chrono>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <set>
#include <sstream>
#include <string>
#include <vector>

#include <nlohmann/json.hpp>

#include "serve_process.h"

namespace {

using mbc::serve_test::ServeProcess;
using mbc::serve_test::TempDir;

std::string slurp(const std::string& path) {
  std::ifstream in(path);
  std::stringstream ss;
  ss << in.rdbuf();
  return ss.str();
}

// A port nothing listens on right now (bound, read, closed).
int free_port() {
  int fd = socket(AF_INET, SOCK_STREAM, 0);
  sockaddr_in a{};
  a.sin_family = AF_INET;
  a.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
  bind(fd, reinterpret_cast<sockaddr*>(&a), sizeof a);
  socklen_t len = sizeof a;
  getsockname(fd, reinterpret_cast<sockaddr*>(&a), &len);
  close(fd);
  return ntohs(a.sin_port);
}

// A peer server as a child process: started with `argv`, ready when it
// prints "listening"; killed (its process group) at the end.
class Peer {
 public:
  Peer(const std::vector<std::string>& argv, const std::vector<std::string>& env) {
    int out[2];
    if (pipe2(out, O_CLOEXEC) != 0) return;
    pid_ = fork();
    if (pid_ == 0) {
      setpgid(0, 0);
      dup2(out[1], STDOUT_FILENO);
      for (const auto& e : env) putenv(const_cast<char*>(e.c_str()));
      std::vector<char*> args;
      for (const auto& a : argv) args.push_back(const_cast<char*>(a.c_str()));
      args.push_back(nullptr);
      execv(args[0], args.data());
      _exit(127);
    }
    close(out[1]);
    out_ = out[0];
  }
  ~Peer() {
    if (pid_ > 0) {
      kill(-pid_, SIGKILL);
      kill(pid_, SIGKILL);
      waitpid(pid_, nullptr, 0);
    }
    if (out_ >= 0) close(out_);
  }
  bool wait_listening(std::chrono::seconds timeout) {
    auto until = std::chrono::steady_clock::now() + timeout;
    std::string got;
    while (std::chrono::steady_clock::now() < until) {
      pollfd p{out_, POLLIN, 0};
      if (poll(&p, 1, 100) <= 0) continue;
      char buf[256];
      ssize_t n = read(out_, buf, sizeof buf);
      if (n <= 0) return false;
      got.append(buf, size_t(n));
      if (got.find("listening") != std::string::npos) return true;
    }
    return false;
  }

 private:
  pid_t pid_ = -1;
  int out_ = -1;
};

struct Out {
  int rc = -1;
  std::string text;
};

Out run_mbconform(const std::vector<std::string>& args) {
  std::string cmd = MBCONFORM_BIN;
  for (const auto& a : args) cmd += " '" + a + "'";
  cmd += " 2>&1";
  Out o;
  FILE* p = popen(cmd.c_str(), "r");
  std::array<char, 4096> buf;
  size_t n;
  while ((n = fread(buf.data(), 1, buf.size(), p)) > 0) o.text.append(buf.data(), n);
  int st = pclose(p);
  o.rc = WIFEXITED(st) ? WEXITSTATUS(st) : -1;
  return o;
}

// The case ids conformance/README.md lists for `library` under "What
// mbconform finds in real libraries": the first `code` of each table row of
// the library's subsection ("### <library> ...").
std::set<std::string> documented(const std::string& library) {
  std::istringstream in(slurp(CONFORMANCE_README));
  std::set<std::string> ids;
  std::string line;
  bool section = false, mine = false;
  while (std::getline(in, line)) {
    if (line.rfind("## ", 0) == 0) section = line.find("What mbconform finds in real libraries") != std::string::npos;
    if (!section) continue;
    if (line.rfind("### ", 0) == 0) mine = line.find(library) != std::string::npos;
    if (!mine || line.rfind("| `", 0) != 0) continue;
    auto a = line.find('`') + 1;
    ids.insert(line.substr(a, line.find('`', a) - a));
  }
  return ids;
}

std::set<std::string> failing(const nlohmann::json& report) {
  std::set<std::string> ids;
  for (const auto& d : report["devices"])
    for (const auto& c : d["cases"])
      if (c["outcome"] == "fail") ids.insert(c["id"].get<std::string>());
  return ids;
}

std::string listed(const std::set<std::string>& s) {
  std::string out;
  for (const auto& x : s) out += "\n  " + x;
  return out.empty() ? " (none)" : out;
}

struct PeerSpec {
  std::string name;     // the gtest parameter
  std::string library;  // as the README's subsection names it
};

class PeerRun : public ::testing::TestWithParam<PeerSpec> {};

TEST_P(PeerRun, FailingCasesAreTheDocumentedDeviations) {
  const PeerSpec& ps = GetParam();
  int port = free_port();
  std::vector<std::string> argv, env;
  if (ps.name == "libmodbus") {
    argv = {LIBMODBUS_SERVER, std::to_string(port)};
  } else if (ps.name == "pymodbus") {
    argv = {PYTHON3, std::string(PEERS_SOURCE_DIR) + "/pymodbus_server.py", std::to_string(port)};
  } else {
#ifdef NODE
    argv = {NODE, std::string(PEERS_SOURCE_DIR) + "/modbus_serial_server.js", std::to_string(port)};
    env = {std::string("NODE_PATH=") + NODE_PATH};
#endif
  }
  ASSERT_FALSE(argv.empty());
  Peer peer(argv, env);
  ASSERT_TRUE(peer.wait_listening(std::chrono::seconds(30))) << ps.name << " did not start";

  TempDir dir;
  Out o = run_mbconform({"run", "--quiet", "--target", "tcp://127.0.0.1:" + std::to_string(port) + "?unit=1", "--map", "auto",
                         "--device", "modbus-standard", "--allow-writes", "--allow-disruptive", "--out", dir / "r"});
  std::printf("%s\n", o.text.c_str());
  ASSERT_TRUE(o.rc == 0 || o.rc == 1) << o.text;
  auto report = nlohmann::json::parse(slurp(dir / "r/report.json"));
  EXPECT_EQ(report["incomplete"], "") << "the run against " << ps.name << " did not finish";

  std::set<std::string> want = documented(ps.library), got = failing(report), extra, missing;
  for (const auto& id : got)
    if (!want.count(id)) extra.insert(id);
  for (const auto& id : want)
    if (!got.count(id)) missing.insert(id);
  EXPECT_TRUE(extra.empty()) << ps.name << ": failing, not documented in conformance/README.md:" << listed(extra);
  EXPECT_TRUE(missing.empty()) << ps.name << ": documented, but did not fail:" << listed(missing);
  EXPECT_EQ(o.rc, want.empty() ? 0 : 1) << o.text;
}

INSTANTIATE_TEST_SUITE_P(Peers, PeerRun,
                         ::testing::Values(PeerSpec{"libmodbus", "libmodbus"}, PeerSpec{"pymodbus", "pymodbus"},
                                           PeerSpec{"modbus_serial", "modbus-serial"}),
                         [](const auto& p) { return p.param.name; });

// Control: a server that follows the standard but maps something else than
// modbus-standard.yaml (a copy of it with another register map, served by
// `mbconform serve`) passes `run --map auto`: no failure comes from the map.
TEST(PeersControl, ServeWithAnotherMapPasses) {
  TempDir dir;
  std::string standard = slurp(std::string(SPEC_DIR) + "/devices/modbus-standard.yaml");
  auto regs = standard.find("\nregisters:"), examples = standard.find("\nexamples:"), errata = standard.find("\nerrata:");
  ASSERT_NE(regs, std::string::npos);
  ASSERT_NE(errata, std::string::npos);
  std::string other = standard.substr(0, regs) + R"(
registers:
  - {address: 0x0000, count: 100, table: holding, name: {en: "holding block"}, access: rw, type: u16, range: {min: 0, max: 65535}, default: 0, section: "MBAP 4.3"}
  - {address: 0x0400, count: 40, table: holding, name: {en: "second holding block"}, access: rw, type: u16, range: {min: 0, max: 65535}, default: 0, section: "MBAP 4.3"}
  - {address: 0x0000, count: 64, table: coil, name: {en: "coil block"}, access: rw, type: bit, default: 0, section: "MBAP 4.3"}
  - {address: 0x0010, count: 30, table: input, name: {en: "input block"}, access: ro, type: u16, default: 0, section: "MBAP 4.3"}
  - {address: 0x0000, count: 16, table: discrete_input, name: {en: "discrete block"}, access: ro, type: bit, default: 0, section: "MBAP 4.3"}
examples: []
)" + standard.substr(errata);
  (void)examples;
  // Spec ids are unique across spec directories: the copy gets an id of its own.
  auto id = other.find("  id: modbus-standard\n");
  ASSERT_NE(id, std::string::npos);
  other.replace(id, 21, "  id: standard-other-map\n");
  std::filesystem::create_directories(dir / "spec/devices");
  std::ofstream(dir / "spec/devices/standard-other-map.yaml") << other;
  setenv("MBCONFORM_SPEC_DIR", (dir / "spec").c_str(), 1);
  ServeProcess serve({"--device", "standard-other-map@1", "--tcp", "127.0.0.1:0"});
  unsetenv("MBCONFORM_SPEC_DIR");
  ASSERT_TRUE(serve.wait_listening(1)) << serve.log();
  int port = serve.endpoint("tcp")->port();
  Out o = run_mbconform({"run", "--quiet", "--target", "tcp://127.0.0.1:" + std::to_string(port) + "?unit=1", "--map", "auto",
                         "--allow-writes", "--out", dir / "r"});
  EXPECT_EQ(o.rc, 0) << o.text;
  EXPECT_NE(o.text.find("holding 0x0400-0x0427"), std::string::npos) << o.text;

  // The same probe as a spec skeleton: it passes spec check, its facts say they were observed.
  std::string tcp = "tcp://127.0.0.1:" + std::to_string(port) + "?unit=1";
  Out d = run_mbconform({"spec", "discover", "--target", tcp, "--out", dir / "served.yaml"});
  ASSERT_EQ(d.rc, 0) << d.text;
  Out check = run_mbconform({"spec", "check", dir / "served.yaml"});
  EXPECT_EQ(check.rc, 0) << check.text << slurp(dir / "served.yaml");
  std::string skeleton = slurp(dir / "served.yaml");
  EXPECT_NE(skeleton.find("address: 0x0400, count: 40, table: holding"), std::string::npos) << skeleton;
  EXPECT_NE(skeleton.find("OBSERVED"), std::string::npos) << skeleton;
  EXPECT_EQ(run_mbconform({"spec", "discover", "--target", "tcp://127.0.0.1:1?unit=1&timeout=200", "--out", dir / "x.yaml"}).rc, 2);
}

}  // namespace

namespace {

// A target that goes away during a run (README: exit codes). The libmodbus
// server is told to die on, or to stop reading after, FC 100 (a user-defined
// code every run sends as "unsupported", MBAP v1.1b3 §5).
struct Lost {
  Out out;
  nlohmann::json report;
};
Lost run_against(const std::string& mode, TempDir& dir) {
  int port = free_port();
  Peer peer({LIBMODBUS_SERVER, std::to_string(port), mode, "100"}, {});
  EXPECT_TRUE(peer.wait_listening(std::chrono::seconds(30)));
  Lost l;
  l.out = run_mbconform({"run", "--quiet", "--target", "tcp://127.0.0.1:" + std::to_string(port) + "?unit=1", "--map",
                         "holding=0-199,coils=0-199,input=0-199,discrete=0-199", "--allow-writes", "--allow-disruptive", "--filter", "function-codes",
                         "--out", dir / "r"});
  l.report = nlohmann::json::parse(slurp(dir / "r/report.json"), nullptr, false);
  return l;
}

const nlohmann::json* case_named(const nlohmann::json& report, const std::string& suffix) {
  for (const auto& c : report["devices"][0]["cases"])
    if (c["id"].get<std::string>().ends_with(suffix)) return &c;
  return nullptr;
}

// Lost for good: one FAIL naming the last request, the rest not run
// (errors, not failures), the first line of the report says incomplete, exit 2
// (a lost target is INCOMPLETE in every command: the run was not done).
TEST(TargetLoss, DeadTargetIsOneFailAndTheRestNotRun) {
  TempDir dir;
  Lost l = run_against("--die-on", dir);
  EXPECT_EQ(l.out.rc, 2) << l.out.text;
  ASSERT_TRUE(l.report.is_object()) << l.out.text;
  const auto* c = case_named(l.report, "fc100/unsupported");
  ASSERT_TRUE(c) << l.out.text;
  EXPECT_EQ((*c)["outcome"], "fail");
  EXPECT_NE((*c)["message"].get<std::string>().find("the target was lost after the request"), std::string::npos) << (*c)["message"];
  EXPECT_NE((*c)["message"].get<std::string>().find(" 64 00 00 00 01"), std::string::npos) << (*c)["message"];  // FC 100, address 0, quantity 1
  // The summary's first line (after the line that announces the run).
  auto inc = l.out.text.find("\nINCOMPLETE: ");
  EXPECT_NE(inc, std::string::npos) << l.out.text;
  EXPECT_LT(inc, l.out.text.find("\ndevice ")) << l.out.text;
  EXPECT_NE(l.report["incomplete"].get<std::string>(), "");
  size_t failed = 0;
  for (const auto& k : l.report["devices"][0]["cases"]) failed += k["outcome"] == "fail";
  EXPECT_EQ(failed, 1u) << "only the case the target was lost in fails";
}

// A wedged connection (answers again only on a new one): one FAIL naming the
// request, not a "silence" failure for every case after it; the run goes on.
TEST(TargetLoss, WedgedConnectionIsOneFail) {
  TempDir dir;
  Lost l = run_against("--wedge-on", dir);
  ASSERT_TRUE(l.report.is_object()) << l.out.text;
  const auto* c = case_named(l.report, "fc100/unsupported");
  ASSERT_TRUE(c) << l.out.text;
  EXPECT_EQ((*c)["outcome"], "fail");
  EXPECT_NE((*c)["message"].get<std::string>().find("stopped answering"), std::string::npos) << (*c)["message"];
  EXPECT_EQ(l.report["incomplete"], "") << l.out.text;
  for (const auto& k : l.report["devices"][0]["cases"]) {
    if (k["outcome"] == "fail") {
      EXPECT_TRUE(k["id"].get<std::string>().ends_with("fc100/unsupported")) << k["id"] << ": " << k["message"];
    }
  }
}

// A server that accepts the connection but never answers cannot be tested: exit 2.
TEST(TargetLoss, UnansweringTargetExits2) {
  int port = free_port();
  Peer peer({LIBMODBUS_SERVER, std::to_string(port), "--wedge-on", "3"}, {});
  ASSERT_TRUE(peer.wait_listening(std::chrono::seconds(30)));
  TempDir dir;
  Out o = run_mbconform({"run", "--quiet", "--target", "tcp://127.0.0.1:" + std::to_string(port) + "?unit=1&timeout=200", "--device",
                         "modbus-standard", "--out", dir / "r"});
  EXPECT_EQ(o.rc, 2) << o.text;
  EXPECT_NE(o.text.find("does not answer"), std::string::npos) << o.text;
}

}  // namespace

namespace {

// Verdicts must not depend on how busy the machine is (README: no verdict
// from a race). The same `run` and `props` against a served device, once as
// the machine is and once with two bounded CPU burners on top (one per core
// of the CI machine), give the same case outcomes.
class Burners {
 public:
  explicit Burners(int n) {
    for (int i = 0; i < n; ++i)
      threads_.emplace_back([this] {
        auto until = std::chrono::steady_clock::now() + std::chrono::minutes(5);  // bounded even if never stopped
        volatile uint64_t x = 0;
        while (!stop_.load() && std::chrono::steady_clock::now() < until) x = x + 1;
      });
  }
  ~Burners() {
    stop_ = true;
    for (auto& t : threads_) t.join();
  }

 private:
  std::atomic<bool> stop_{false};
  std::vector<std::thread> threads_;
};

std::map<std::string, std::string> outcomes(const std::string& report_json) {
  std::map<std::string, std::string> out;
  auto j = nlohmann::json::parse(slurp(report_json));
  for (const auto& d : j["devices"])
    for (const auto& c : d["cases"]) out[c["id"].get<std::string>()] = c["outcome"].get<std::string>();
  return out;
}

TEST(UnderLoad, RunPropsAndFuzzGiveTheSameVerdicts) {
  ServeProcess serve({"--device", "hsc60@1", "--tcp", "127.0.0.1:0"});
  ASSERT_TRUE(serve.wait_listening(1)) << serve.log();
  std::string uri = "tcp://127.0.0.1:" + std::to_string(serve.endpoint("tcp")->port()) + "?unit=1";
  TempDir dir;
  auto both = [&](const std::string& tag) {
    Out r = run_mbconform({"run", "--quiet", "--target", uri, "--device", "hsc60", "--out", dir / (tag + "-run")});
    Out p = run_mbconform({"props", "--target", uri, "--device", "hsc60", "--cases", "40", "--seed", "7", "--out", dir / (tag + "-props")});
    // fuzz: the served device follows its spec, so no finding, busy or not.
    Out f = run_mbconform({"fuzz", "--target", uri, "--device", "hsc60", "--duration", "2s", "--seed", "7", "--out", dir / (tag + "-fuzz")});
    EXPECT_EQ(f.rc, 0) << tag << ": fuzz found something in a correct device\n" << f.text;
    return std::make_pair(r, p);
  };
  auto idle = both("idle");
  std::pair<Out, Out> busy;
  {
    Burners burn(2);
    busy = both("busy");
  }
  EXPECT_EQ(idle.first.rc, busy.first.rc) << idle.first.text << "\n---\n" << busy.first.text;
  EXPECT_EQ(idle.second.rc, busy.second.rc) << idle.second.text << "\n---\n" << busy.second.text;
  for (const char* what : {"run", "props"}) {
    auto a = outcomes(dir / (std::string("idle-") + what + "/report.json"));
    auto b = outcomes(dir / (std::string("busy-") + what + "/report.json"));
    EXPECT_FALSE(a.empty()) << what;
    for (const auto& [id, outcome] : a) EXPECT_EQ(outcome, b[id]) << what << " " << id;
    EXPECT_EQ(a.size(), b.size()) << what;
  }
}

}  // namespace
