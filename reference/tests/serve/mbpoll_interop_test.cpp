// `mbconform serve` against mbpoll (Debian package), a third-party master, on
// Modbus TCP and on the pty. mbpoll's -r is 1-based (reference = address + 1).
#include <signal.h>
#include <sys/wait.h>

#include <cstdio>
#include <regex>

#include <fmt/core.h>
#include <gtest/gtest.h>

#include "loader.h"
#include "serve_process.h"
#include "spec_registers.h"

namespace mbc::serve_test {
namespace {

struct Result {
  int status = -1;
  std::string output;
};

// Runs a shell command (bounded by timeout(1)), capturing stdout and stderr.
Result run(const std::string& cmd) {
  Result r;
  FILE* p = popen(("timeout 10 " + cmd + " 2>&1").c_str(), "r");
  if (!p) return r;
  char buf[256];
  while (fgets(buf, sizeof buf, p)) r.output += buf;
  int st = pclose(p);
  r.status = WIFEXITED(st) ? WEXITSTATUS(st) : -1;
  return r;
}

// mbpoll prints "[REF]: \tVALUE"; holding registers show as signed 16-bit.
std::optional<uint16_t> value_of(const std::string& output, int ref) {
  std::smatch m;
  std::regex line(fmt::format(R"(\[{}\]:\s*(-?\d+))", ref));
  if (!std::regex_search(output, m, line)) return std::nullopt;
  return uint16_t(std::stol(m[1]) & 0xFFFF);
}

class Mbpoll : public ::testing::TestWithParam<std::string> {
 protected:
  void SetUp() override {
    if (std::string(MBPOLL).empty()) {
      GTEST_SKIP() << "mbpoll not installed";
    }
    spec_ = spec::load_spec_by_id("sihong-57hs-r");
    server_ = std::make_unique<ServeProcess>(
        std::vector<std::string>{"--device", "sihong-57hs-r@1", "--tcp", "0", "--pty", dir_ / "tty"});
    ASSERT_TRUE(server_->wait_listening(2)) << server_->log();
  }
  void TearDown() override {
    if (server_) {
      EXPECT_EQ(server_->stop(SIGTERM), 0) << server_->log();
    }
  }
  // mbpoll's options for this transport, up to the device or host.
  std::string target_args() const {
    if (GetParam() == "tcp") return fmt::format("-m tcp -p {} 127.0.0.1", server_->endpoint("tcp")->port());
    // 8N1 as the pty takes no notice of parity; mbpoll defaults to even.
    return fmt::format("-m rtu -b 19200 -P none {}", server_->endpoint("pty")->address);
  }
  Result mbpoll(const spec::Register& r, const std::string& write_value = "", int unit = 1) {
    const char* type = r.table == spec::Table::input ? "3" : "4";
    // -c is for reads only; a write sends as many values as given.
    std::string cmd = fmt::format("{} -a {} -t {} -r {} -1 -o 1 {} {}", MBPOLL, unit, type, r.address + 1,
                                  write_value.empty() ? "-c 1" : "", target_args());
    if (!write_value.empty()) cmd += " -- " + write_value;
    return run(cmd);
  }

  TempDir dir_;
  spec::Spec spec_;
  std::unique_ptr<ServeProcess> server_;
};

TEST_P(Mbpoll, ReadsADefaultTheSpecStates) {
  const spec::Register* r = pick_default_word(spec_);
  ASSERT_TRUE(r);
  Result res = mbpoll(*r);
  EXPECT_EQ(res.status, 0) << res.output;
  EXPECT_EQ(value_of(res.output, r->address + 1), uint16_t(int64_t(*r->default_value) & 0xFFFF)) << res.output;
}

TEST_P(Mbpoll, WritesARegisterAndReadsItBack) {
  const spec::Register* r = pick_rw(spec_);
  ASSERT_TRUE(r);
  uint16_t word = middle_word(*r);
  // mbpoll takes the value as printed; an s16 is written as its signed value.
  std::string text = r->type == spec::DataType::s16 ? std::to_string(int16_t(word)) : std::to_string(word);
  Result w = mbpoll(*r, text);
  EXPECT_EQ(w.status, 0) << w.output;
  EXPECT_NE(w.output.find("Written 1 references"), std::string::npos) << w.output;
  Result res = mbpoll(*r);
  EXPECT_EQ(value_of(res.output, r->address + 1), word) << res.output;
}

// Modbus Messaging on TCP/IP Implementation Guide V1.0b §4.4.1.2: a server
// reached directly takes unit 0xFF, "The value 0 is also accepted"; on TCP,
// serving one device, unit 0 is that device, not a broadcast.
TEST_P(Mbpoll, UnitZeroOnTcpAddressesTheServerItself) {
  if (GetParam() != "tcp") GTEST_SKIP() << "unit 0 is the broadcast address on a serial line (MB-SL v1.02 §2.1)";
  const spec::Register* r = pick_default_word(spec_);
  ASSERT_TRUE(r);
  Result res = mbpoll(*r, "", 0);
  EXPECT_EQ(res.status, 0) << res.output;
  EXPECT_EQ(value_of(res.output, r->address + 1), uint16_t(int64_t(*r->default_value) & 0xFFFF)) << res.output;
}

INSTANTIATE_TEST_SUITE_P(Serve, Mbpoll, ::testing::Values("tcp", "pty"));

}  // namespace
}  // namespace mbc::serve_test
