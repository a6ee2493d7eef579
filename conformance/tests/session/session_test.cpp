// The session (conformance/session/): the gate, the journal, restore, and
// the commands that reach a drive through it, against `mbconform serve` on a
// pty read by libmodbus (a master nobody here wrote):
//   - two drives on one RTU line (hsc60@1, sihong-57hs-r@2): run, props,
//     fuzz and replay interrupted by SIGINT at three moments, and by SIGKILL
//     at three moments followed by `mbconform restore`; every readable point
//     of both units equals its value before the command;
//   - an 8-drive line: props and fuzz against unit 1 leave units 2-8 unchanged;
//   - a new user's `run --target rtu:///dev/PTY --device hsc60` (no line
//     parameters) against a line served at 9600 8N1 passes.
#include <fcntl.h>
#include <gtest/gtest.h>
#include <fmt/core.h>
#include <modbus/modbus.h>
#include <signal.h>
#include <sys/wait.h>
#include <unistd.h>

#include <chrono>
#include <filesystem>
#include <fstream>
#include <map>
#include <sstream>
#include <thread>

#include "loader.h"
#include "modbus/crc16.h"
#include "modbus/pdu.h"
#include "safety/safety.h"
#include "serve_process.h"
#include "policy/policy.h"
#include "session/journal.h"
#include "session/session.h"
#include "properties/control.h"
#include "modbus/bytes.h"
#include "modbus/rtu.h"
#include "targets/target.h"

namespace mbc::conf {
namespace {

using serve_test::ServeProcess;
using serve_test::TempDir;
using namespace std::chrono_literals;

TargetInfo live_rtu(uint8_t unit) {
  TargetInfo i;
  i.kind = conf::TargetKind::rtu;
  i.live = true;
  i.raw = true;
  i.unit = unit;
  return i;
}

// The frame policy's own tests are conformance/tests/policy/.

// ---- the line --------------------------------------------------------------

TEST(LineSettings, UriThenSpecThenTheStandard) {
  spec::Spec hsc = spec::load_spec_by_id("hsc60");
  ASSERT_TRUE(hsc.serial.baud_default);
  LineSettings l = line_settings("rtu:///dev/ttyUSB0", &hsc);
  EXPECT_NE(l.uri.find(fmt::format("baud={}", *hsc.serial.baud_default)), std::string::npos) << l.uri;
  EXPECT_NE(l.origin.find("from the spec hsc60"), std::string::npos) << l.origin;
  l = line_settings("rtu:///dev/ttyUSB0?baud=38400&parity=E", &hsc);
  EXPECT_NE(l.tried.find("38400 8E"), std::string::npos) << l.tried;
  l = line_settings("rtu:///dev/ttyUSB0", nullptr);
  EXPECT_NE(l.tried.find("19200 8E1"), std::string::npos) << l.tried;
  EXPECT_NE(l.origin.find("standard"), std::string::npos) << l.origin;
}

TEST(Uri, RepeatedParameterAndAPathWithoutItsSlashAreErrors) {
  EXPECT_THROW(parse_uri("tcp://127.0.0.1:502?unit=1&unit=2"), std::invalid_argument);
  EXPECT_THROW(parse_uri("rtu://dev/ttyUSB0"), std::invalid_argument);
  EXPECT_NO_THROW(parse_uri("rtu:///dev/ttyUSB0?unit=1"));
}

// ---- two drives on one served line ---------------------------------------------

// Every readable point of `unit` (each register of the spec in its table, as
// libmodbus reads it; an exception is a value too).
using Points = std::map<std::string, std::string>;

Points read_points(const std::string& pty, int unit, const spec::Spec& s) {
  Points out;
  modbus_t* ctx = modbus_new_rtu(pty.c_str(), 115200, 'N', 8, 1);
  EXPECT_NE(ctx, nullptr);
  if (!ctx) return out;
  modbus_set_slave(ctx, unit);
  modbus_set_response_timeout(ctx, 1, 0);
  EXPECT_EQ(modbus_connect(ctx), 0) << modbus_strerror(errno);
  for (const auto& r : s.registers) {
    if (r.access == spec::Access::wo || r.access == spec::Access::command) continue;
    std::string key = fmt::format("{}:{}:{:04X}", unit, spec::to_string(r.table), r.address);
    uint16_t regs[2] = {0, 0};
    uint8_t bits[1] = {0};
    int rc = -1;
    for (int attempt = 0; attempt < 3 && rc < 0; ++attempt) {
      switch (r.table) {
        case spec::Table::holding: rc = modbus_read_registers(ctx, r.address, r.words, regs); break;
        case spec::Table::input: rc = modbus_read_input_registers(ctx, r.address, r.words, regs); break;
        case spec::Table::coil: rc = modbus_read_bits(ctx, r.address, 1, bits); break;
        case spec::Table::discrete_input: rc = modbus_read_input_bits(ctx, r.address, 1, bits); break;
      }
      // An exception reply (codes 01-0B: EMBXILFUN..EMBXGTAR) is a value too.
      // Anything else, such as a reply from the other unit ("Response not
      // from requested slave": a late answer to the killed command's last
      // request), is read again once the line is flushed.
      if (rc < 0 && errno >= EMBXILFUN && errno <= EMBXGTAR) break;
      if (rc < 0) {
        std::this_thread::sleep_for(std::chrono::milliseconds(50));
        modbus_flush(ctx);
      }
    }
    out[key] = rc < 0 ? fmt::format("error {}", modbus_strerror(errno)) : fmt::format("{:04X} {:04X} {}", regs[0], regs[1], bits[0]);
  }
  modbus_close(ctx);
  modbus_free(ctx);
  return out;
}

struct Child {
  pid_t pid = -1;
  std::string out_path, err_path;
};

Child spawn(const std::vector<std::string>& args, const std::string& dir) {
  Child c;
  c.out_path = dir + "/stdout.txt";
  c.err_path = dir + "/stderr.txt";
  c.pid = fork();
  if (c.pid == 0) {
    int o = ::open(c.out_path.c_str(), O_WRONLY | O_CREAT | O_TRUNC, 0644);
    int e = ::open(c.err_path.c_str(), O_WRONLY | O_CREAT | O_TRUNC, 0644);
    dup2(o, 1);
    dup2(e, 2);
    std::vector<char*> argv;
    std::string bin = serve_test::mbconform_bin();
    argv.push_back(bin.data());
    for (const auto& a : args) argv.push_back(const_cast<char*>(a.c_str()));
    argv.push_back(nullptr);
    execv(bin.c_str(), argv.data());
    _exit(127);
  }
  return c;
}

std::string slurp(const std::string& path) {
  std::ifstream in(path);
  std::stringstream ss;
  ss << in.rdbuf();
  return ss.str();
}

// The exit code, 128+signal, or -1 after `limit` (then the child is killed).
int wait_exit(pid_t pid, std::chrono::seconds limit) {
  auto until = std::chrono::steady_clock::now() + limit;
  int status = 0;
  while (std::chrono::steady_clock::now() < until) {
    pid_t r = waitpid(pid, &status, WNOHANG);
    if (r == pid) return WIFEXITED(status) ? WEXITSTATUS(status) : 128 + WTERMSIG(status);
    std::this_thread::sleep_for(20ms);
  }
  kill(pid, SIGKILL);
  waitpid(pid, &status, 0);
  return -1;
}

int run_mbconform(const std::vector<std::string>& args, std::string* out = nullptr) {
  TempDir d;
  Child c = spawn(args, d.path());
  int rc = wait_exit(c.pid, 120s);
  if (out) *out = slurp(c.out_path) + slurp(c.err_path);
  return rc;
}

// The journal path the command printed on stderr, once it did.
std::optional<std::string> journal_of(const Child& c, std::chrono::seconds limit) {
  auto until = std::chrono::steady_clock::now() + limit;
  while (std::chrono::steady_clock::now() < until) {
    std::string err = slurp(c.err_path);
    if (auto at = err.find("journal: "); at != std::string::npos) {
      auto end = err.find(' ', at + 9);
      if (end != std::string::npos) return err.substr(at + 9, end - at - 9);
    }
    int status = 0;
    if (waitpid(c.pid, &status, WNOHANG) == c.pid) return std::nullopt;
    std::this_thread::sleep_for(10ms);
  }
  return std::nullopt;
}

// A frame script writing every plain register of `unit` in turn, with pauses
// (replay's frames are otherwise over too soon to interrupt).
std::string write_script(const spec::Spec& s, int unit) {
  std::string text = "mbconform-script 1\n";
  for (int round = 0; round < 20; ++round)
    for (const auto& r : s.registers) {
      if (r.table != spec::Table::holding || r.access != spec::Access::rw || r.words != 1 || !r.range || r.command) continue;
      if (!allowed_write(PolicyFacts{&s, live_rtu(uint8_t(unit)), {}}, r)) continue;
      Bytes f{uint8_t(unit)};
      // A signed register's minimum (-3000) as its two's-complement word, by way of an integer.
      Bytes pdu = write_single_register(r.address, uint16_t(int64_t(round % 2 ? r.range->min : r.range->max)));
      f.insert(f.end(), pdu.begin(), pdu.end());
      append_crc(f);
      text += "rtu " + to_hex(f) + "\nwait 20\n";
    }
  return text;
}

class TwoDrives : public ::testing::Test {
 protected:
  void SetUp() override {
    pty_ = dir_ / "ttyMB";
    server_ = std::make_unique<ServeProcess>(
        std::vector<std::string>{"--device", "hsc60@1", "--device", "sihong-57hs-r@2", "--pty", pty_});
    ASSERT_TRUE(server_->wait_listening(1)) << server_->log();
    specs_[1] = spec::load_spec_by_id("hsc60");
    specs_[2] = spec::load_spec_by_id("sihong-57hs-r");
    std::ofstream(dir_ / "script-1.txt") << write_script(specs_[1], 1);
    std::ofstream(dir_ / "script-2.txt") << write_script(specs_[2], 2);
  }
  // Whether `point` ("UNIT:TABLE:ADDR" read as hex words) is a status register
  // of that drive's control and `read` holds the safe state's reading there.
  bool names_safe_state(const std::string& point, const std::string& read) {
    int unit = point[0] - '0';
    const spec::Spec& s = specs_[unit];
    if (!s.control || s.control->states.empty() || read.size() < 4) return false;
    const spec::ControlState* safe = s.control->state(s.control->safe);
    if (!safe) return false;
    bool named = false;
    for (const auto& m : safe->status) {
      const spec::Register* r = s.find_by_key(m.register_key);
      if (!r || point != fmt::format("{}:{}:{:04X}", unit, spec::to_string(r->table), r->address)) continue;
      if (!m.matches(uint16_t(std::stoul(read.substr(0, 4), nullptr, 16)))) return false;
      named = true;
    }
    return named;
  }
  Points both() {
    Points p = read_points(pty_, 1, specs_[1]);
    for (auto& kv : read_points(pty_, 2, specs_[2])) p.insert(kv);
    return p;
  }
  std::vector<std::string> command(const std::string& name, int unit, const std::string& out) {
    std::string uri = fmt::format("rtu://{}?unit={}", pty_, unit);
    std::string device = unit == 1 ? "hsc60" : "sihong-57hs-r";
    if (name == "run") return {"run", "--target", uri, "--device", device, "--out", out};
    if (name == "props") return {"props", "--target", uri, "--device", device, "--out", out, "--cases", "40", "--seed", "3"};
    if (name == "fuzz") return {"fuzz", "--target", uri, "--device", device, "--out", out, "--duration", "20s", "--seed", "3"};
    return {"replay", dir_ / fmt::format("script-{}.txt", unit), "--target", uri, "--device", device, "--out", out};
  }
  // Interrupts `name` at three moments by `sig` (SIGKILL: then `mbconform
  // restore JOURNAL`); both drives read the same after each.
  void interrupt(const std::string& name, int sig) {
    const Points before = both();
    ASSERT_GT(before.size(), 100u);
    const std::chrono::milliseconds moments[] = {200ms, 1200ms, 3000ms};
    for (int k = 0; k < 3; ++k) {
      int unit = k % 2 ? 1 : 2;
      std::string out = dir_ / fmt::format("{}-{}-{}", name, sig, k);
      // Its own log files: a journal line left by the previous command must not be read as this one's.
      std::string logs = dir_ / fmt::format("log-{}-{}-{}", name, sig, k);
      std::filesystem::create_directories(logs);
      Child c = spawn(command(name, unit, out), logs);
      auto journal = journal_of(c, 30s);
      ASSERT_TRUE(journal) << name << ": no journal line\n" << slurp(c.err_path) << slurp(c.out_path);
      std::this_thread::sleep_for(moments[k]);
      int status = 0;
      bool ended_before = waitpid(c.pid, &status, WNOHANG) == c.pid;
      if (!ended_before) kill(c.pid, sig);
      int rc = ended_before ? (WIFEXITED(status) ? WEXITSTATUS(status) : -1) : wait_exit(c.pid, 30s);
      std::string log = slurp(c.err_path) + slurp(c.out_path);
      if (sig == SIGKILL) {
        if (!ended_before) {
          EXPECT_EQ(rc, 128 + SIGKILL) << log;
          std::string restore_out;
          EXPECT_EQ(run_mbconform({"restore", *journal}, &restore_out), 0) << restore_out;
        }
      } else if (!ended_before) {
        EXPECT_EQ(rc, 2) << name << " at " << moments[k].count() << " ms\n" << log;
      }
      Points after = both();
      for (const auto& [key, value] : before) {
        // A control the run commanded is restored to its safe state first
        // (spec control.safe, issue 38): its status reads as before, or that state.
        if (after[key] != value && names_safe_state(key, after[key])) continue;
        EXPECT_EQ(after[key], value) << name << " unit " << unit << ", " << (sig == SIGKILL ? "SIGKILL" : "SIGINT") << " at "
                                     << moments[k].count() << " ms: point " << key << "\n" << log;
      }
    }
  }
  TempDir dir_;
  std::string pty_;
  std::unique_ptr<ServeProcess> server_;
  std::map<int, spec::Spec> specs_;
};

TEST_F(TwoDrives, RunInterruptedBySigint) { interrupt("run", SIGINT); }
TEST_F(TwoDrives, RunKilledThenRestored) { interrupt("run", SIGKILL); }
TEST_F(TwoDrives, PropsInterruptedBySigint) { interrupt("props", SIGINT); }
TEST_F(TwoDrives, PropsKilledThenRestored) { interrupt("props", SIGKILL); }
TEST_F(TwoDrives, FuzzInterruptedBySigint) { interrupt("fuzz", SIGINT); }
TEST_F(TwoDrives, FuzzKilledThenRestored) { interrupt("fuzz", SIGKILL); }
TEST_F(TwoDrives, ReplayInterruptedBySigint) { interrupt("replay", SIGINT); }
TEST_F(TwoDrives, ReplayKilledThenRestored) { interrupt("replay", SIGKILL); }

TEST_F(TwoDrives, ReplayOfAWriteToAnotherUnitIsRefused) {
  Bytes f{2};
  Bytes pdu = write_single_register(0x0020, 1);
  f.insert(f.end(), pdu.begin(), pdu.end());
  append_crc(f);
  std::ofstream(dir_ / "foreign.txt") << "mbconform-script 1\nrtu " << to_hex(f) << "\n";
  const Points before = both();
  std::string out;
  EXPECT_EQ(run_mbconform({"replay", dir_ / "foreign.txt", "--target", fmt::format("rtu://{}?unit=1", pty_), "--device", "hsc60",
                           "--out", dir_ / "foreign"}, &out), 2) << out;
  EXPECT_NE(out.find("unit 2"), std::string::npos) << out;
  EXPECT_EQ(both(), before);
}

// ---- eight drives on one line -------------------------------------------------

TEST(EightDrives, PropsAndFuzzAgainstUnitOneLeaveTheOthersUnchanged) {
  TempDir dir;
  std::string pty = dir / "ttyMB";
  std::vector<std::string> args;
  for (int u = 1; u <= 8; ++u) args.insert(args.end(), {"--device", fmt::format("hsc60@{}", u)});
  args.insert(args.end(), {"--pty", pty});
  ServeProcess server(args);
  ASSERT_TRUE(server.wait_listening(1)) << server.log();
  spec::Spec s = spec::load_spec_by_id("hsc60");
  auto all = [&] {
    Points p;
    for (int u = 1; u <= 8; ++u)
      for (auto& kv : read_points(pty, u, s)) p.insert(kv);
    return p;
  };
  const Points before = all();
  std::string uri = fmt::format("rtu://{}?unit=1", pty);
  std::string out;
  int rc = run_mbconform({"props", "--target", uri, "--device", "hsc60", "--cases", "30", "--seed", "5", "--out", dir / "props"}, &out);
  EXPECT_TRUE(rc == 0 || rc == 1) << out;
  rc = run_mbconform({"fuzz", "--target", uri, "--device", "hsc60", "--duration", "5s", "--seed", "5", "--out", dir / "fuzz"}, &out);
  EXPECT_TRUE(rc == 0 || rc == 1) << out;
  const Points after = all();
  for (const auto& [key, value] : before) {
    if (key.rfind("1:", 0) == 0) continue;  // unit 1 is checked by the restore tests
    auto it = after.find(key);
    ASSERT_NE(it, after.end()) << key;
    EXPECT_EQ(it->second, value) << "point " << key << " of a drive that was not the target";
  }
}

// ---- time bounds -------------------------------------------------------------------

// The bound is the command's promise (--duration + 10 s), not a performance
// figure: a fuzzer that outlives it against a dead target is a hang.
TEST(TimeBounds, FuzzAgainstATargetThatDiesEndsWithinDurationPlusTenSeconds) {
  TempDir dir;
  auto server = std::make_unique<ServeProcess>(std::vector<std::string>{"--device", "hsc60@1", "--rtu-tcp", "127.0.0.1:0"});
  ASSERT_TRUE(server->wait_listening(1)) << server->log();
  std::string uri = fmt::format("rtu-tcp://127.0.0.1:{}?unit=1", server->endpoint("rtu-tcp")->port());
  Child c = spawn({"fuzz", "--target", uri, "--device", "hsc60", "--duration", "4s", "--seed", "9", "--out", dir / "f"}, dir.path());
  ASSERT_TRUE(journal_of(c, 30s)) << slurp(c.err_path);
  std::this_thread::sleep_for(1s);
  server->stop(SIGKILL);
  int rc = wait_exit(c.pid, 14s);
  EXPECT_NE(rc, -1) << "still running 14 s after a 4 s --duration\n" << slurp(c.err_path) << slurp(c.out_path);
  EXPECT_NE(slurp(c.err_path).find("journal"), std::string::npos);
}

TEST(TimeBounds, ADurationOutOfRangeOrThatSendsNothingExitsTwo) {
  std::string out;
  for (const char* d : {"9999999h", "0s", "-5s", "10 parsecs"}) {
    EXPECT_EQ(run_mbconform({"fuzz", "--target", "ref:hsc60", "--duration", d, "--out", "/tmp/mbc-unused-out"}, &out), 2) << d << ": " << out;
  }
}

// ---- bounded input ----------------------------------------------------------------

TEST(BoundedInput, PathologicalFiltersAndEndlessFilesGetOneLine) {
  std::string out;
  // Both give a result or one line: RE2 is linear in the id.
  EXPECT_EQ(run_mbconform({"run", "--target", "ref:hsc60", "--list", "--filter", "(.*.*.*.*.*)*X$"}, &out), 2) << out;
  EXPECT_NE(out.find("matches none"), std::string::npos) << out;
  // 20 000 nested groups: a result (the ids with an x) or one line, never a crash.
  int rc = run_mbconform({"run", "--target", "ref:hsc60", "--list", "--filter", std::string(20000, '(') + "x" + std::string(20000, ')')}, &out);
  EXPECT_TRUE(rc == 0 || (rc == 2 && out.find("--filter") != std::string::npos)) << rc << ": " << out.substr(0, 300);
  // Plain text is a literal substring.
  EXPECT_EQ(run_mbconform({"run", "--target", "ref:hsc60", "--list", "--filter", "0x0000/above-max"}, &out), 0) << out;
  EXPECT_NE(out.find("hsc60/registers/0x0000/above-max"), std::string::npos) << out;
  EXPECT_EQ(run_mbconform({"run", "--target", "ref:hsc60", "--quirks", "/dev/zero", "--out", "/tmp/mbc-unused-out"}, &out), 2) << out;
  EXPECT_NE(out.find("not a regular file"), std::string::npos) << out;
  EXPECT_EQ(run_mbconform({"replay", "/dev/zero", "--target", "ref:hsc60"}, &out), 2) << out;
  EXPECT_EQ(run_mbconform({"props", "--replay", "/dev/zero"}, &out), 2) << out;
  EXPECT_EQ(run_mbconform({"spec", "import", "--csv", "/dev/zero", "--id", "x"}, &out), 2) << out;
}

TEST(BoundedInput, AWaitOverSixtySecondsNeedsAnOptIn) {
  TempDir dir;
  std::ofstream(dir / "long.txt") << "mbconform-script 1\ndevice hsc60\nwait 2000000000\n";
  std::string out;
  EXPECT_EQ(run_mbconform({"replay", dir / "long.txt", "--target", "tcp://127.0.0.1:1?unit=1", "--device", "hsc60"}, &out), 2) << out;
  EXPECT_NE(out.find("--allow-long-waits"), std::string::npos) << out;
}

TEST(BoundedInput, AnUnwritableSummaryIsFoundBeforeTheFirstFrame) {
  TempDir dir;
  std::ofstream(dir / "file") << "x";
  std::string out;
  EXPECT_EQ(run_mbconform({"run", "--target", "ref:hsc60", "--out", dir / "r", "--summary", dir / "file/sub"}, &out), 2) << out;
  EXPECT_NE(out.find("--summary"), std::string::npos) << out;
  EXPECT_FALSE(std::filesystem::exists(dir / "r/report.json")) << "nothing ran";
}

// ---- a new user's first run -----------------------------------------------------

TEST(NewUser, RunWithoutLineParametersTakesTheSpecsSettings) {
  TempDir dir;
  std::string pty = dir / "ttyMB";
  ServeProcess server({"--device", "hsc60@1", "--pty", pty, "--line-rate", "9600"});
  ASSERT_TRUE(server.wait_listening(1)) << server.log();
  std::string out;
  int rc = run_mbconform({"run", "--target", "rtu://" + pty, "--device", "hsc60", "--out", dir / "run"}, &out);
  EXPECT_EQ(rc, 0) << out;
  // Nobody at unit 5: one line, naming what was tried and what the spec says.
  rc = run_mbconform({"run", "--target", fmt::format("rtu://{}?unit=5&timeout=200", pty), "--device", "hsc60", "--out", dir / "none"}, &out);
  EXPECT_EQ(rc, 2) << out;
  EXPECT_NE(out.find("does not answer at 9600 8N1, unit 5"), std::string::npos) << out;
  EXPECT_NE(out.find("the spec hsc60 says"), std::string::npos) << out;
}

// ---- a drive's control in Operation enabled (issue 38) ------------------------

// A served CiA 402 drive (cia402-modbus over Modbus TCP) brought into
// Operation enabled with a set-point by another master (libmodbus); `props`
// on it interrupted by SIGINT, and by SIGKILL then `mbconform restore`: the
// journal records the control state, and the restore leaves the drive in its
// safe state (Switch on disabled) first, then every register of the journal
// other than the controlword holds its value from before the command.
class Cia402 : public ::testing::Test {
 protected:
  void SetUp() override {
    spec_ = spec::load_spec_by_id("cia402-modbus");
    server_ = std::make_unique<ServeProcess>(std::vector<std::string>{"--device", "cia402-modbus@1", "--tcp", "127.0.0.1:0"});
    ASSERT_TRUE(server_->wait_listening(1)) << server_->log();
    port_ = server_->endpoint("tcp")->port();
    uri_ = fmt::format("tcp://127.0.0.1:{}?unit=1", port_);
  }
  // Modbus TCP, or the RTU line at pty_ when a fixture serves one.
  modbus_t* connect() {
    modbus_t* ctx = pty_.empty() ? modbus_new_tcp("127.0.0.1", port_) : modbus_new_rtu(pty_.c_str(), 115200, 'N', 8, 1);
    EXPECT_NE(ctx, nullptr);
    modbus_set_slave(ctx, 1);
    modbus_set_response_timeout(ctx, 1, 0);
    EXPECT_EQ(modbus_connect(ctx), 0) << modbus_strerror(errno);
    return ctx;
  }
  std::vector<uint16_t> regs() {
    modbus_t* ctx = connect();
    std::vector<uint16_t> v(14, 0);
    EXPECT_EQ(modbus_read_registers(ctx, 0, 14, v.data()), 14) << modbus_strerror(errno);
    modbus_close(ctx);
    modbus_free(ctx);
    return v;
  }
  // Shutdown, then Switch on + Enable operation, with a target velocity: Operation enabled, moving.
  void enable() {
    modbus_t* ctx = connect();
    EXPECT_EQ(modbus_write_register(ctx, 2, 3), 1);  // profile velocity
    const uint16_t velocity[2] = {0, 200};
    EXPECT_EQ(modbus_write_registers(ctx, 4, 2, velocity), 2);
    EXPECT_EQ(modbus_write_register(ctx, 0, 0x06), 1);
    EXPECT_EQ(modbus_write_register(ctx, 0, 0x0F), 1);
    modbus_close(ctx);
    modbus_free(ctx);
    std::this_thread::sleep_for(100ms);
    ASSERT_EQ(regs()[1] & 0x6F, 0x27) << "not in Operation enabled";
  }
  // What the other drive on the line reads (none: no other drive).
  virtual Points neighbour() { return {}; }
  void interrupt(int sig) {
    const Points others = neighbour();
    for (int k = 0; k < 2; ++k) {
      enable();
      const std::vector<uint16_t> before = regs();
      std::string out = dir_ / fmt::format("props-{}-{}", sig, k), logs = dir_ / fmt::format("log-{}-{}", sig, k);
      std::filesystem::create_directories(logs);
      std::vector<std::string> args{"props", "--target", uri_, "--device", "cia402-modbus", "--out", out, "--cases", "200",
                                    "--seed", "5", "--only", "control-status-names-state"};
      if (k == 1) args.push_back("--allow-motion");
      Child c = spawn(args, logs);
      auto journal = journal_of(c, 30s);
      ASSERT_TRUE(journal) << "no journal line\n" << slurp(c.err_path) << slurp(c.out_path);
      std::this_thread::sleep_for(k ? 1500ms : 700ms);
      int status = 0;
      bool ended_before = waitpid(c.pid, &status, WNOHANG) == c.pid;
      if (!ended_before) kill(c.pid, sig);
      int rc = ended_before ? (WIFEXITED(status) ? WEXITSTATUS(status) : -1) : wait_exit(c.pid, 30s);
      std::string log = slurp(c.err_path) + slurp(c.out_path);
      if (sig == SIGKILL && !ended_before) {
        EXPECT_EQ(rc, 128 + SIGKILL) << log;
        std::string restore_out;
        EXPECT_EQ(run_mbconform({"restore", *journal}, &restore_out), 0) << restore_out;
        log += restore_out;
      }
      // The journal recorded the control state before the command's first command write.
      JournalContents j = read_journal(*journal);
      EXPECT_EQ(j.control_state, "operation_enabled") << log;
      const std::vector<uint16_t> after = regs();
      EXPECT_EQ(after[1] & 0x4F, 0x40) << "statusword " << after[1] << ": not in Switch on disabled, the safe state\n" << log;
      EXPECT_EQ(after[6] | after[7], 0) << "the axis still moves (velocity actual)\n" << log;
      // Every register the journal kept, but the controlword (a command), holds its value from before.
      for (const auto& e : j.originals) {
        if (e.address == 0) continue;
        for (size_t w = 0; w < e.value.size(); ++w)
          EXPECT_EQ(after[e.address + w], before[e.address + w]) << "register " << e.address + w << "\n" << log;
      }
      // The other drive on the line: every readable point as before.
      const Points now = neighbour();
      for (const auto& [key, value] : others) {
        auto it = now.find(key);
        ASSERT_NE(it, now.end()) << key;
        EXPECT_EQ(it->second, value) << (sig == SIGKILL ? "SIGKILL" : "SIGINT") << ", moment " << k << ": point " << key
                                     << " of the drive that was not the target\n" << log;
      }
    }
  }
  TempDir dir_;
  spec::Spec spec_;
  std::unique_ptr<ServeProcess> server_;
  int port_ = 0;
  std::string uri_, pty_;
};

TEST_F(Cia402, PropsInOperationEnabledInterruptedBySigint) { interrupt(SIGINT); }
TEST_F(Cia402, PropsInOperationEnabledKilledThenRestored) { interrupt(SIGKILL); }

// Two drives on one RTU line (cia402-modbus@1, hsc60@2), unit 1 in Operation
// enabled and moving: `props` on unit 1 interrupted by SIGINT, and by SIGKILL
// then `mbconform restore`. Unit 1 ends in its safe state with the axis
// stopped and its registers as before; unit 2, which no command addressed,
// reads exactly as before at every readable point.
class TwoDrivesInOperationEnabled : public Cia402 {
 protected:
  void SetUp() override {
    spec_ = spec::load_spec_by_id("cia402-modbus");
    other_ = spec::load_spec_by_id("hsc60");
    pty_ = dir_ / "ttyMB";
    server_ = std::make_unique<ServeProcess>(
        std::vector<std::string>{"--device", "cia402-modbus@1", "--device", "hsc60@2", "--pty", pty_});
    ASSERT_TRUE(server_->wait_listening(1)) << server_->log();
    // 8N1 as the other drive's line: a pty served here reopened at 8E1 (the
    // spec's default) after a SIGKILL fails with EINVAL (the pty drops PARENB;
    // left to the transport, see the issue 38 report).
    uri_ = fmt::format("rtu://{}?unit=1&baud=115200&parity=N", pty_);
  }
  Points neighbour() override {
    Points p = read_points(pty_, 2, other_);
    EXPECT_GT(p.size(), 50u);
    return p;
  }
  spec::Spec other_;
};

TEST_F(TwoDrivesInOperationEnabled, PropsInterruptedBySigint) { interrupt(SIGINT); }
TEST_F(TwoDrivesInOperationEnabled, PropsKilledThenRestored) { interrupt(SIGKILL); }

// The motion-free walk on a served drive without --allow-motion: it enables
// and disables, selects every mode and ends in the safe state, and no frame it
// sent is one the frame policy counts as motion (set-points written 0 first).
TEST_F(Cia402, TheMotionFreeWalkSendsNoMotion) {
  TempDir out;
  SessionOptions o;
  o.command = "test";
  o.out_dir = out.path();
  Session session(uri_, &spec_, o);
  session.keep();
  props::SpecView view(spec_, session.info(), {});
  props::Session walker(session, view, nullptr);
  std::vector<std::string> skipped;
  EXPECT_EQ(props::control_walk(walker, skipped), "");
  for (const auto& line : skipped) std::cout << "walk: skipped " << line << "\n";
  // The frames sent, judged again by the policy with what they themselves wrote before.
  PolicyFacts f{&spec_, session.info(), {}};
  int writes = 0, enables = 0;
  for (const auto& st : walker.steps()) {
    if (st.kind != props::Step::Kind::frame) continue;
    auto body = mbc::kRtu.pdu_bytes(st.frame);
    Bytes pdu(body.begin(), body.end());
    EXPECT_EQ(control_motion(f, pdu), "") << st.note;
    if (pdu[0] == 0x06 || pdu[0] == 0x10) ++writes;
    if (pdu[0] == 0x06 && be16(pdu, 1) == 0 && (be16(pdu, 3) & 0x8F) == 0x0F) ++enables;
    // What the drive echoed: a set-point written 0 (as the policy learns it).
    if (st.reply_pdu && pdu[0] == 0x10 && be16(pdu, 1) >= 4 && be16(pdu, 1) <= 8)
      for (uint16_t k = 0; k < be16(pdu, 3); ++k)
        if (be16(pdu, 6 + 2 * k) == 0) f.zeroed.insert(uint16_t(be16(pdu, 1) + k));
  }
  EXPECT_GT(enables, 0) << "the walk never enabled the drive";
  EXPECT_GT(writes, 5);
  EXPECT_EQ(regs()[1] & 0x4F, 0x40) << "the walk ends in the safe state";
  // Without the set-points written 0 first, the same enable is motion.
  PolicyFacts cold{&spec_, session.info(), {}};
  EXPECT_NE(control_motion(cold, write_single_register(0, 0x0F)), "");
  session.restore();
}

}  // namespace
}  // namespace mbc::conf
