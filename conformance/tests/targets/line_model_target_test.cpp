// The RTU target reading a served line that behaves like a bench
// (serve --line, reference/serve/README.md): replies paced one character
// time a byte, batched by a USB latency timer, behind the adapter's echo, and
// split by a silence under t3.5. Each read must give the device's reply, as
// the served reference device's FC 03 layout says: FC, byte count 2, one register.
#include <gtest/gtest.h>

#include "modbus/pdu.h"
#include "serve_process.h"
#include "targets/target.h"

namespace mbc::conf {
namespace {

using serve_test::ServeProcess;
using serve_test::TempDir;

void reads_three(const std::string& uri, const ServeProcess& serve) {
  auto t = open_target(uri);
  t->set_wait(Target::Wait::reply);
  for (int k = 0; k < 3; ++k) {
    Reply r = t->transact(read_request(3, 0, 1));
    ASSERT_TRUE(r.pdu) << k << ": " << r.framing_error << "\n" << serve.log();
    EXPECT_EQ((*r.pdu)[0], 0x03);
    EXPECT_EQ(r.pdu->size(), 4u);
  }
  EXPECT_EQ(t->late_replies(), 0u);
}

struct Served {
  TempDir dir;
  ServeProcess serve;
  explicit Served(std::vector<std::string> extra)
      : serve([&] {
          std::vector<std::string> a{"--device", "hsc60@1", "--pty", dir / "line", "--trace"};
          a.insert(a.end(), extra.begin(), extra.end());
          return a;
        }()) {}
  std::string uri(const std::string& rest) { return "rtu://" + (dir / "line") + "?unit=1&" + rest; }
};

TEST(LineModelTarget, ReadsPacedRepliesAt9600And115200) {
  for (const char* line : {"9600-8E1", "115200-8E1"}) {
    Served s({"--line", line});
    ASSERT_TRUE(s.serve.wait_listening(1)) << s.serve.log();
    reads_three(s.uri(std::string("baud=") + std::string(line).substr(0, std::string(line).find('-')) + "&parity=E"), s.serve);
  }
}

TEST(LineModelTarget, ReadsRepliesBatchedBySixteenMillisecondLatency) {
  Served s({"--line", "9600-8E1", "--latency-timer", "16"});
  ASSERT_TRUE(s.serve.wait_listening(1)) << s.serve.log();
  reads_three(s.uri("baud=9600&parity=E"), s.serve);
}

TEST(LineModelTarget, StripsAPacedEchoGivenOrFound) {
  Served s({"--line", "9600-8E1", "--echo"});
  ASSERT_TRUE(s.serve.wait_listening(1)) << s.serve.log();
  reads_three(s.uri("baud=9600&parity=E&echo=1"), s.serve);
  reads_three(s.uri("baud=9600&parity=E"), s.serve);
}

TEST(LineModelTarget, ReadsAReplyWithASilenceUnderT35InsideAsOneFrame) {
  Served s({"--line", "9600-8E1", "--fault", "reply-gap"});
  ASSERT_TRUE(s.serve.wait_listening(1)) << s.serve.log();
  reads_three(s.uri("baud=9600&parity=E"), s.serve);
}

}  // namespace
}  // namespace mbc::conf
