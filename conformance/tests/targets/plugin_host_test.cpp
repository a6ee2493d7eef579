// A vendor plugin runs in mbconform-plugin-host, a child process: a segfault,
// an abort, an endless loop or a broken contract fails that request with a
// message naming the signal or the violation, the host is restarted, and the
// next request is served. The plugins are broken on purpose
// (broken_plugin.c, on FC 0x41); nothing here is timed except the watchdog
// the URI sets.
#include <gtest/gtest.h>

#include <cstdlib>
#include <filesystem>
#include <fstream>

#include <nlohmann/json.hpp>

#include "modbus/pdu.h"
#include "serve_process.h"
#include "targets/target.h"

#ifdef BROKEN_PLUGIN_1

namespace mbc::conf {
namespace {

struct Broken {
  const char* name;
  const char* library;
  const char* says;  // in the failure message
};

void PrintTo(const Broken& b, std::ostream* os) { *os << b.name; }

class BrokenPlugin : public ::testing::TestWithParam<Broken> {};

TEST_P(BrokenPlugin, FailsTheRequestAndTheHostComesBack) {
  const Broken& b = GetParam();
  auto t = open_target(std::string("plugin:") + b.library + "?timeout=500");
  Bytes read = read_request(3, 0, 2);
  Reply before = t->transact(read);
  ASSERT_TRUE(before.pdu);
  try {
    t->transact(Bytes{0x41});
    ADD_FAILURE() << b.name << ": the broken request went through";
  } catch (const std::runtime_error& e) {
    EXPECT_NE(std::string(e.what()).find(b.says), std::string::npos) << e.what();
  }
  Reply after = t->transact(read);
  ASSERT_TRUE(after.pdu) << "the host did not come back after " << b.name;
  EXPECT_EQ(*after.pdu, *before.pdu);
}

INSTANTIATE_TEST_SUITE_P(Host, BrokenPlugin,
                         ::testing::Values(Broken{"segfault", BROKEN_PLUGIN_1, "SIGSEGV"},
                                           Broken{"abort", BROKEN_PLUGIN_2, "SIGABRT"},
                                           Broken{"hang", BROKEN_PLUGIN_3, "hung"},
                                           Broken{"overcapacity", BROKEN_PLUGIN_4, "over the 512-byte response capacity"},
                                           Broken{"negative", BROKEN_PLUGIN_5, "without an error message"}),
                         [](const auto& info) { return std::string(info.param.name); });

// A whole run against a crashing plugin: the case that crashes it fails,
// naming the signal, the run goes on and writes its reports (exit 1).
TEST(BrokenPluginRun, RunGoesOnAndWritesReports) {
  serve_test::TempDir dir;
  std::string cmd = serve_test::mbconform_bin() + " run --quiet --target 'plugin:" + BROKEN_PLUGIN_1 +
                    "?timeout=2000' --device modbus-standard --filter 'function-codes' --out " + (dir / "r") +
                    " > " + (dir / "out.txt") + " 2>&1";
  int st = std::system(cmd.c_str());
  ASSERT_TRUE(WIFEXITED(st)) << "mbconform itself died";
  EXPECT_EQ(WEXITSTATUS(st), 1);
  std::ifstream in(dir / "r/report.json");
  ASSERT_TRUE(in) << "no report written";
  auto j = nlohmann::json::parse(in);
  size_t crashed = 0, ran = 0;
  for (const auto& c : j["devices"][0]["cases"]) {
    ++ran;
    crashed += c["message"].get<std::string>().find("SIGSEGV") != std::string::npos;
  }
  EXPECT_GT(ran, 1u);
  EXPECT_GE(crashed, 1u) << j.dump().substr(0, 2000);
}

}  // namespace
}  // namespace mbc::conf

#endif  // BROKEN_PLUGIN_1
