// The served line model (serve --line, reference/serve/uart.h): what a UART
// at the wrong rate reads, worked out by hand from the bit timing, and a
// real master (libmodbus) at the line's rate and at another rate.
#include <gtest/gtest.h>
#include <modbus.h>
#include <sys/wait.h>
#include <unistd.h>

#include <csignal>
#include <cstdint>
#include <vector>

#include "serve/uart.h"
#include "serve_process.h"

namespace mbc::serve {
namespace {

using serve_test::ServeProcess;
using serve_test::TempDir;

TEST(LineFormat, ParsesTheFormsTheCommandLineTakes) {
  auto f = parse_line_format("9600-8N2");
  ASSERT_TRUE(f);
  EXPECT_EQ(f->baud, 9600);
  EXPECT_EQ(f->parity, 'N');
  EXPECT_EQ(f->stop_bits, 2);
  EXPECT_EQ(f->bits_per_char(), 11);
  auto d = parse_line_format("115200");  // MB-SL v1.02 §2.5.1: 8E1 unless said
  ASSERT_TRUE(d);
  EXPECT_EQ(d->text(), "115200-8E1");
  for (const char* bad : {"", "fast", "9600-8X1", "9600-8N3", "9600-9N1", "12-8N1", "9600-8N"})
    EXPECT_FALSE(parse_line_format(bad)) << bad;
}

TEST(Resample, TheSameRateAndFormatReadsEveryByte) {
  LineFormat f{19200, 8, 'E', 1};
  std::vector<uint8_t> frame{0x01, 0x03, 0x00, 0x00, 0x00, 0x0A, 0xC5, 0xCD};
  EXPECT_EQ(resample(frame, f, f), frame);
}

// 0xFF at 9600 8E1: start 0, eight 1s, parity 0 (eight ones: even), stop 1.
// A 19200 receiver samples at half-bit steps of the sender's bits: the first
// character reads start 0 then data 0,1,1,1,1,1,1,1 (0xFE), parity 1 (seven
// ones: even parity wants 1), stop 1: 0xFE. The sender's parity bit 0 is the
// next falling edge: 0 then 1s after it (stop, then the idle line): 0xFE again.
TEST(Resample, AByteAtHalfTheRateReadsAsWorkedOutByHand) {
  LineFormat sender{9600, 8, 'E', 1}, receiver{19200, 8, 'E', 1};
  std::vector<uint8_t> sent{0xFF};
  EXPECT_EQ(resample(sent, sender, receiver), (std::vector<uint8_t>{0xFE, 0xFE}));
}

// 0x00 at 9600 8E1 is low for ten of the sender's bits (start, data, parity): a
// 19200 receiver finds its stop bit (10.5 of its bits = 5.25 of the
// sender's) still low: a framing error, dropped. The next edge is the
// sender's stop bit rising, never falling again: nothing more.
TEST(Resample, AFramingErrorIsDropped) {
  LineFormat sender{9600, 8, 'E', 1}, receiver{19200, 8, 'E', 1};
  std::vector<uint8_t> sent{0x00};
  EXPECT_TRUE(resample(sent, sender, receiver).empty());
}

TEST(Resample, AFrameAtAnotherCommonRateNeverReadsAsItself) {
  std::vector<uint8_t> frame{0x03, 0x03, 0x00, 0x00, 0x00, 0x02, 0xC5, 0xE9};
  for (int rx : {2400, 4800, 9600, 38400, 57600, 115200}) {
    LineFormat sender{19200, 8, 'E', 1}, receiver{rx, 8, 'E', 1};
    EXPECT_NE(resample(frame, sender, receiver), frame) << rx;
  }
}

// A real master on a served 19200 line: answered at 19200, nothing usable at 9600.
int read_one(const std::string& path, int baud, uint16_t& value) {
  modbus_t* ctx = modbus_new_rtu(path.c_str(), baud, 'E', 8, 1);
  if (!ctx) return -1;
  modbus_set_slave(ctx, 3);
  modbus_set_response_timeout(ctx, 0, 300000);
  int rc = -1;
  if (modbus_connect(ctx) == 0) {
    rc = modbus_read_registers(ctx, 0, 1, &value);
    modbus_close(ctx);
  }
  modbus_free(ctx);
  return rc;
}

TEST(ServedLine, AMasterAtTheLinesRateIsAnsweredAndOneAtAnotherIsNot) {
  TempDir dir;
  ServeProcess serve({"--device", "hsc60@3", "--pty", dir / "line", "--line", "19200-8E1", "--trace"});
  ASSERT_TRUE(serve.wait_listening(1)) << serve.log();
  uint16_t v = 0;
  EXPECT_EQ(read_one(dir / "line", 19200, v), 1) << serve.log();
  EXPECT_EQ(read_one(dir / "line", 9600, v), -1) << serve.log();
  EXPECT_EQ(read_one(dir / "line", 115200, v), -1) << serve.log();
  EXPECT_EQ(read_one(dir / "line", 19200, v), 1) << "the line still answers at its rate\n" << serve.log();
  EXPECT_NE(serve.log().find("sent at 9600 baud to a 19200-8E1 line"), std::string::npos) << serve.log();
}

// A master that reopens a served 9600-8E1 line with the same settings: after
// one SIGKILLed holding it open, and after one that closed it. Linux's pty
// driver drops PARENB, so a pty left at the last client's termios took the
// same request as "nothing changed" and glibc's tcsetattr said EINVAL
// (libmodbus: modbus_connect failed). serve puts the line back as it opened
// it when its last client goes.
TEST(ServedLine, AMasterReopensTheLineAtItsParityAfterOneWasKilled) {
  TempDir dir;
  ServeProcess serve({"--device", "hsc60@3", "--pty", dir / "line", "--line", "9600-8E1"});
  ASSERT_TRUE(serve.wait_listening(1)) << serve.log();
  int ready[2];
  ASSERT_EQ(pipe(ready), 0);
  pid_t holder = fork();
  if (holder == 0) {
    close(ready[0]);
    modbus_t* ctx = modbus_new_rtu((dir / "line").c_str(), 9600, 'E', 8, 1);
    modbus_set_slave(ctx, 3);
    modbus_set_response_timeout(ctx, 0, 300000);
    uint16_t v = 0;
    char ok = modbus_connect(ctx) == 0 && modbus_read_registers(ctx, 0, 1, &v) == 1 ? 'y' : 'n';
    (void)!write(ready[1], &ok, 1);
    pause();  // holds the line open until killed
    _exit(0);
  }
  close(ready[1]);
  char ok = 0;
  ASSERT_EQ(read(ready[0], &ok, 1), 1);
  close(ready[0]);
  kill(holder, SIGKILL);
  waitpid(holder, nullptr, 0);
  EXPECT_EQ(ok, 'y') << "the first master was not answered\n" << serve.log();
  uint16_t v = 0;
  for (int k = 0; k < 3; ++k) {
    // The close reaches serve through inotify: a reopen at once may find the line not yet put back.
    int rc = -1;
    for (int tries = 0; tries < 20 && rc != 1; ++tries) {
      rc = read_one(dir / "line", 9600, v);
      if (rc != 1) usleep(50000);
    }
    EXPECT_EQ(rc, 1) << "reopen " << k << " at 9600-8E1 failed (" << modbus_strerror(errno) << ")\n" << serve.log();
  }
}

}  // namespace
}  // namespace mbc::serve
