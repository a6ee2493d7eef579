// The served line's timing (serve --line with --latency-timer, --turnaround,
// --echo and the line faults): a raw master on the pty writes a request and
// times what it reads. Every figure is worked out from the line's character
// time, at low baud rates so that a loaded machine keeps the margins: the
// checks that a clean line passes are bounds that a late reader or a late
// server only makes easier to meet; the checks that catch a fault are the
// fault's own figure against the standard's limit, with a margin of whole
// character times.
#include <fcntl.h>
#include <gtest/gtest.h>
#include <poll.h>
#include <termios.h>
#include <unistd.h>

#include <chrono>
#include <cstdint>
#include <string>
#include <thread>
#include <vector>

#include "serve/uart.h"
#include "serve_process.h"

namespace mbc::serve {
namespace {

using serve_test::ServeProcess;
using serve_test::TempDir;
using Clock = std::chrono::steady_clock;
using std::chrono::microseconds;

// FC 03, slave 3, register 0, one register (CRC as MB-SL v1.02 §6.2.2 computes it).
const std::vector<uint8_t> kRead{0x03, 0x03, 0x00, 0x00, 0x00, 0x01, 0x85, 0xE8};
constexpr size_t kReplyBytes = 7;  // 03 03 02 hi lo crc crc

struct Chunk {
  Clock::time_point at;
  std::vector<uint8_t> bytes;
};

struct Heard {
  Clock::time_point sent;  // when write() returned for the request's last byte
  std::vector<Chunk> chunks;
  std::vector<uint8_t> all() const {
    std::vector<uint8_t> out;
    for (const auto& c : chunks) out.insert(out.end(), c.bytes.begin(), c.bytes.end());
    return out;
  }
};

int open_master(const std::string& path, speed_t speed) {
  int fd = ::open(path.c_str(), O_RDWR | O_NOCTTY);
  if (fd < 0) return -1;
  termios t{};
  tcgetattr(fd, &t);
  cfmakeraw(&t);
  cfsetispeed(&t, speed);
  cfsetospeed(&t, speed);
  tcsetattr(fd, TCSANOW, &t);
  return fd;
}

// Writes `parts` (pausing `pause` between them), then reads until `want`
// bytes came or the line was quiet for `quiet`.
Heard exchange(int fd, const std::vector<std::vector<uint8_t>>& parts, size_t want, std::chrono::milliseconds quiet,
               std::chrono::milliseconds pause = std::chrono::milliseconds(0)) {
  Heard h;
  for (size_t i = 0; i < parts.size(); ++i) {
    if (i) std::this_thread::sleep_for(pause);
    if (::write(fd, parts[i].data(), parts[i].size()) != ssize_t(parts[i].size())) return h;
  }
  h.sent = Clock::now();
  size_t got = 0;
  while (got < want) {
    pollfd p{fd, POLLIN, 0};
    if (::poll(&p, 1, int(quiet.count())) <= 0) break;
    uint8_t buf[256];
    ssize_t n = ::read(fd, buf, sizeof buf);
    if (n <= 0) break;
    h.chunks.push_back({Clock::now(), {buf, buf + n}});
    got += size_t(n);
  }
  return h;
}

// The longest silence inside what was heard, as a master can work it out from
// its reads: a chunk of n bytes read at t took n character times to arrive,
// so the line was silent from the previous read until t - n*c at most. A late
// read only shortens what it reports for the next chunk.
microseconds longest_silence(const Heard& h, microseconds c) {
  microseconds longest{0};
  for (size_t i = 1; i < h.chunks.size(); ++i) {
    auto s = std::chrono::duration_cast<microseconds>(h.chunks[i].at - h.chunks[i - 1].at) -
             c * int64_t(h.chunks[i].bytes.size());
    longest = std::max(longest, s);
  }
  return longest;
}

// The silence between the request's end on the wire and the first reply byte's start.
microseconds silence_before_reply(const Heard& h, size_t request_bytes, microseconds c) {
  if (h.chunks.empty()) return microseconds::max();
  auto first = h.chunks.front();
  return std::chrono::duration_cast<microseconds>(first.at - h.sent) - c * int64_t(request_bytes) -
         c * int64_t(first.bytes.size());
}

struct Line {
  TempDir dir;
  LineFormat format;
  std::unique_ptr<ServeProcess> serve;
  int fd = -1;
  Line(const std::string& line, speed_t speed, std::vector<std::string> extra) {
    format = *parse_line_format(line);
    std::vector<std::string> args{"--device", "hsc60@3", "--pty", dir / "line", "--line", line, "--trace"};
    args.insert(args.end(), extra.begin(), extra.end());
    serve = std::make_unique<ServeProcess>(args);
    if (serve->wait_listening(1)) fd = open_master(dir / "line", speed);
  }
  ~Line() {
    if (fd >= 0) ::close(fd);
  }
  microseconds c() const { return format.char_time(); }
};

TEST(LineTiming, AReplyLeavesAfterT35AndItsBytesArriveOneCharacterTimeApart) {
  Line line("1200-8E1", B1200, {});
  ASSERT_GE(line.fd, 0) << line.serve->log();
  Heard h = exchange(line.fd, {kRead}, kReplyBytes, std::chrono::milliseconds(500));
  ASSERT_EQ(h.all().size(), kReplyBytes) << line.serve->log();
  // The request took 8 characters in, then t3.5 of silence, before the first reply byte started.
  EXPECT_GE(silence_before_reply(h, kRead.size(), line.c()), line.format.t35()) << line.serve->log();
  // The reply's bytes came one character time apart: those after the first read took at least
  // half their wire time more (a late first read holds more of them, and shortens the span).
  EXPECT_GE(h.chunks.back().at - h.chunks.front().at,
            line.c() * int64_t(kReplyBytes - h.chunks.front().bytes.size()) / 2);
  EXPECT_GE(h.chunks.size(), 2u) << "a reply read at once: not paced";
  EXPECT_LT(longest_silence(h, line.c()), line.format.t15() + line.c()) << line.serve->log();
}

TEST(LineTiming, TheReplyGapFaultLeavesASilenceOverT15InsideTheReply) {
  Line line("1200-8E1", B1200, {"--fault", "reply-gap"});
  ASSERT_GE(line.fd, 0) << line.serve->log();
  Heard h = exchange(line.fd, {kRead}, kReplyBytes, std::chrono::milliseconds(500));
  ASSERT_EQ(h.all().size(), kReplyBytes) << line.serve->log();
  // The fault's silence is halfway between t1.5 and t3.5: a whole character time over t1.5 at 1200 baud.
  EXPECT_GT(longest_silence(h, line.c()), line.format.t15()) << line.serve->log();
}

TEST(LineTiming, TheEarlyReplyFaultAnswersBeforeT35) {
  Line line("1200-8E1", B1200, {"--fault", "early-reply"});
  ASSERT_GE(line.fd, 0) << line.serve->log();
  Heard h = exchange(line.fd, {kRead}, kReplyBytes, std::chrono::milliseconds(500));
  ASSERT_EQ(h.all().size(), kReplyBytes) << line.serve->log();
  // One character time planned; t3.5 is 3.5 of them.
  EXPECT_LT(silence_before_reply(h, kRead.size(), line.c()), line.format.t35()) << line.serve->log();
}

TEST(LineTiming, TheTurnaroundDelayComesAfterT35) {
  Line line("1200-8E1", B1200, {"--turnaround", "60"});
  ASSERT_GE(line.fd, 0) << line.serve->log();
  Heard h = exchange(line.fd, {kRead}, kReplyBytes, std::chrono::milliseconds(500));
  ASSERT_EQ(h.all().size(), kReplyBytes) << line.serve->log();
  EXPECT_GE(silence_before_reply(h, kRead.size(), line.c()), line.format.t35() + std::chrono::milliseconds(60));
}

TEST(LineTiming, LineNoiseComesBeforeTheReplyAndT35ApartFromIt) {
  Line line("1200-8E1", B1200, {"--fault", "line-noise"});
  ASSERT_GE(line.fd, 0) << line.serve->log();
  Heard h = exchange(line.fd, {kRead}, kReplyBytes + 3, std::chrono::milliseconds(500));
  auto all = h.all();
  ASSERT_EQ(all.size(), kReplyBytes + 3) << line.serve->log();
  EXPECT_EQ(std::vector<uint8_t>(all.begin(), all.begin() + 3), (std::vector<uint8_t>{0x00, 0xFF, 0x5A}));
  EXPECT_EQ(all[3], 0x03);
  // t3.5 on the wire; a late read of the noise's last byte shortens what the master works out.
  EXPECT_GE(longest_silence(h, line.c()), line.format.t35() / 2);
}

TEST(LineTiming, TheLatencyTimerBatchesTheReply) {
  // 9600 baud: the 7-byte reply spans 8 ms of wire; 16 ms ticks hand it over in one or two
  // reads (each byte at its own time makes up to seven). A late reader only merges reads.
  Line line("9600-8E1", B9600, {"--latency-timer", "16"});
  ASSERT_GE(line.fd, 0) << line.serve->log();
  for (int i = 0; i < 4; ++i) {
    Heard h = exchange(line.fd, {kRead}, kReplyBytes, std::chrono::milliseconds(500));
    ASSERT_EQ(h.all().size(), kReplyBytes) << line.serve->log();
    EXPECT_LE(h.chunks.size(), 2u);
  }
}

TEST(LineTiming, AnEchoingAdapterHearsTheRequestPacedThenTheReply) {
  Line line("1200-8E1", B1200, {"--echo"});
  ASSERT_GE(line.fd, 0) << line.serve->log();
  Heard h = exchange(line.fd, {kRead}, kRead.size() + kReplyBytes, std::chrono::milliseconds(500));
  auto all = h.all();
  ASSERT_EQ(all.size(), kRead.size() + kReplyBytes) << line.serve->log();
  EXPECT_EQ(std::vector<uint8_t>(all.begin(), all.begin() + 8), kRead);
  EXPECT_EQ(all[8], 0x03);
  EXPECT_GE(h.chunks.size(), 3u) << "the echo and the reply came at once: not paced";
}

// 600 baud: the pause leaves 2.5 character times (46 ms) between the halves
// on the wire, over t1.5 (27 ms) and under t3.5 (64 ms). A pty carries no
// write times: serve times its reads, so a server that reads the first half
// a character time late sees a shorter silence, and a sleep that overshoots
// one makes two frames. Up to three tries, each told apart by the trace.
TEST(LineTiming, ARequestWithASilenceOverT15InsideIsDiscardedUnlessTheFaultKeepsIt) {
  const std::vector<uint8_t> a(kRead.begin(), kRead.begin() + 4), b(kRead.begin() + 4, kRead.end());
  const auto c = LineFormat{600, 8, 'E', 1}.char_time();
  const auto pause = std::chrono::duration_cast<std::chrono::milliseconds>(c * 4 + c * 5 / 2);
  {
    Line line("600-8E1", B600, {});
    ASSERT_GE(line.fd, 0) << line.serve->log();
    bool dropped = false;
    for (int k = 0; k < 3 && !dropped; ++k) {
      Heard h = exchange(line.fd, {a, b}, kReplyBytes, std::chrono::milliseconds(800), pause);
      dropped = line.serve->log().find("a silence over t1.5") != std::string::npos;
      if (dropped) {
        EXPECT_TRUE(h.all().empty()) << line.serve->log();
      }
    }
    EXPECT_TRUE(dropped) << line.serve->log();
    Heard h = exchange(line.fd, {kRead}, kReplyBytes, std::chrono::milliseconds(800));
    EXPECT_EQ(h.all().size(), kReplyBytes) << "the whole request is answered\n" << line.serve->log();
  }
  {
    Line line("600-8E1", B600, {"--fault", "keep-gapped-request"});
    ASSERT_GE(line.fd, 0) << line.serve->log();
    bool answered = false;
    for (int k = 0; k < 3 && !answered; ++k)
      answered = exchange(line.fd, {a, b}, kReplyBytes, std::chrono::milliseconds(800), pause).all().size() == kReplyBytes;
    EXPECT_TRUE(answered) << line.serve->log();
  }
}

TEST(LineTiming, LineOptionsNeedALine) {
  TempDir dir;
  for (std::vector<std::string> extra : {std::vector<std::string>{"--latency-timer", "16"},
                                         std::vector<std::string>{"--fault", "reply-gap"}}) {
    std::vector<std::string> args{"--device", "hsc60@3", "--pty", dir / "line"};
    args.insert(args.end(), extra.begin(), extra.end());
    ServeProcess serve(args);
    EXPECT_EQ(serve.wait_exit(), 2) << serve.log();
    EXPECT_NE(serve.log().find("need --line"), std::string::npos) << serve.log();
  }
}

}  // namespace
}  // namespace mbc::serve
