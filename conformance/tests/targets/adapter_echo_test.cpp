// The RTU target on a 2-wire adapter that echoes the request (serve --echo
// plays that adapter on a pty), and the USB latency timer's note.
#include <gtest/gtest.h>

#include <filesystem>
#include <fstream>

#include "modbus/pdu.h"
#include "serve_process.h"
#include "targets/kinds.h"
#include "targets/target.h"

namespace mbc::conf {
namespace {

using serve_test::ServeProcess;
using serve_test::TempDir;

Reply read_zero(const std::string& uri, uint8_t fc = 3) {
  auto t = open_target(uri);
  t->set_wait(Target::Wait::reply);
  return t->transact(read_request(fc, 0, 1));
}

TEST(AdapterEcho, EchoOneStripsTheRequestAndTheReplyIsJudgedAlone) {
  TempDir dir;
  ServeProcess serve({"--device", "hsc60@1", "--pty", dir / "line", "--echo"});
  ASSERT_TRUE(serve.wait_listening(1)) << serve.log();
  Reply r = read_zero("rtu://" + (dir / "line") + "?baud=19200&unit=1&echo=1");
  ASSERT_TRUE(r.pdu) << r.framing_error;
  EXPECT_EQ((*r.pdu)[0], 0x03);  // a normal reply, not the echoed request
  EXPECT_EQ(r.pdu->size(), 4u);  // FC, byte count 2, one register
}

TEST(AdapterEcho, FoundByItselfOnASerialLine) {
  TempDir dir;
  ServeProcess serve({"--device", "hsc60@1", "--pty", dir / "line", "--echo"});
  ASSERT_TRUE(serve.wait_listening(1)) << serve.log();
  const std::string uri = "rtu://" + (dir / "line") + "?baud=19200&unit=1";
  auto t = open_target(uri);
  t->set_wait(Target::Wait::reply);
  for (int k = 0; k < 3; ++k) {
    Reply r = t->transact(read_request(3, 0, 1));
    ASSERT_TRUE(r.pdu) << k << ": " << r.framing_error;
    EXPECT_EQ(r.pdu->size(), 4u);
  }
  // FC 06's reply is its request: echo and reply come back to back, the second copy is the reply.
  Reply w = t->transact(write_single_register(0x0000, 5000));
  ASSERT_TRUE(w.pdu) << w.framing_error;
  EXPECT_EQ((*w.pdu)[0] & 0x80, 0);
  EXPECT_EQ(t->late_replies(), 0u) << "the echo must not be taken for a reply that came late";
}

TEST(AdapterEcho, WithEchoOffTheEchoSpoilsTheReply) {
  TempDir dir;
  ServeProcess serve({"--device", "hsc60@1", "--pty", dir / "line", "--echo"});
  ASSERT_TRUE(serve.wait_listening(1)) << serve.log();
  Reply r = read_zero("rtu://" + (dir / "line") + "?baud=19200&unit=1&echo=0");
  EXPECT_FALSE(r.pdu && r.pdu->size() == 4 && (*r.pdu)[0] == 0x03) << "echo=0 takes the echo as the reply's start";
}

TEST(AdapterEcho, NoEchoOnALineWithoutOne) {
  TempDir dir;
  ServeProcess serve({"--device", "hsc60@1", "--pty", dir / "line"});
  ASSERT_TRUE(serve.wait_listening(1)) << serve.log();
  Reply r = read_zero("rtu://" + (dir / "line") + "?baud=19200&unit=1");
  ASSERT_TRUE(r.pdu) << r.framing_error;
  EXPECT_EQ(r.pdu->size(), 4u);
}

TEST(AdapterEcho, BadEchoAndDirectionParametersAreOneLine) {
  EXPECT_THROW(open_target("rtu:///dev/null?echo=2"), std::invalid_argument);
  EXPECT_THROW(open_target("rtu:///dev/null?rts=sideways"), std::invalid_argument);
  EXPECT_THROW(open_target("rtu-tcp://127.0.0.1:1?rs485=kernel"), std::invalid_argument);
}

TEST(UsbLatency, SixteenMillisecondsIsNamedWithTheCommandThatLowersIt) {
  TempDir dir;
  namespace fs = std::filesystem;
  fs::create_directories(dir / "sys/bus/usb-serial/devices/ttyUSB7");
  std::ofstream(dir / "sys/bus/usb-serial/devices/ttyUSB7/latency_timer") << "16\n";
  fs::create_directories(dir / "dev");
  std::ofstream(dir / "dev/ttyUSB7") << "";
  fs::create_symlink(dir / "dev/ttyUSB7", dir / "by-id");
  auto notes = usb_latency_notes(dir / "by-id", dir / "sys");
  ASSERT_EQ(notes.size(), 1u);
  EXPECT_NE(notes[0].find("16 ms"), std::string::npos) << notes[0];
  EXPECT_NE(notes[0].find("echo 1 >"), std::string::npos) << notes[0];
  EXPECT_TRUE(usb_latency_notes(dir / "dev/ttyUSB7", dir / "nosys").empty());
}

}  // namespace
}  // namespace mbc::conf
