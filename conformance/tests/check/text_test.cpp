// The text form of checks, the frame script (conformance/check/README.md): reading, writing,
// the errors a malformed file gets, where a script can run, and replaying it
// on reference devices, correct and deliberately broken.
#include <gtest/gtest.h>

#include "loader.h"
#include "check/text.h"
#include "runner/runner.h"
#include "session/link.h"
#include "targets/target.h"

namespace mbc::conf::check {
using conf::replay;
using conf::ReplayResult;
using conf::unsupported;
namespace {

std::string error_of(const std::string& text) {
  try {
    parse(text, "t.txt");
  } catch (const ParseError& e) {
    return e.what();
  }
  return "";
}

TEST(ScriptFormat, ReadsEveryKindOfLine) {
  Script s = parse(
      "mbconform-script 1\n"
      "# found by hand\n"
      "device hsc60\n"
      "fault lost-write\n"
      "rtu 01 06 00 00 00 01 48 0A  -> reply 06 00 00 00 01   # write\n"
      "mbap * 00 00 00 06 01 03 00 00 00 01 -> normal\n"
      "mbap 00 07 00 00 00 06 02 03 00 00 00 01 -> exception 02\n"
      "raw-rtu 01 03 00 | 00 00 01 84 0A -> silence\n"
      "raw-mbap 00 01 00 00 00 09 01 03 00 00 00 01 -> any\n"
      "wait 20\n"
      "advance 100000\n"
      "power-cycle\n",
      "t.txt");
  EXPECT_EQ(s.device, "hsc60");
  EXPECT_EQ(s.fault, "lost-write");
  EXPECT_EQ(s.comment, "found by hand\n");
  ASSERT_EQ(s.steps.size(), 8u);
  EXPECT_EQ(s.steps[0].unit, 1);
  EXPECT_EQ(s.steps[0].pdu, (Bytes{0x06, 0x00, 0x00, 0x00, 0x01}));
  EXPECT_EQ(s.steps[0].expect.kind, Expect::Kind::reply);
  EXPECT_EQ(s.steps[0].note, "write");
  EXPECT_EQ(s.steps[1].framing, &mbc::kTcp);
  EXPECT_FALSE(s.steps[1].tid);
  EXPECT_EQ(s.steps[1].pdu, (Bytes{0x03, 0x00, 0x00, 0x00, 0x01}));
  EXPECT_EQ(s.steps[2].unit, 2);
  EXPECT_EQ(s.steps[2].tid, 7);
  EXPECT_EQ(s.steps[2].expect.code, 2);
  EXPECT_EQ(s.steps[3].kind, Step::Kind::raw);
  EXPECT_EQ(s.steps[3].gap, 3u);
  EXPECT_EQ(s.steps[3].bytes.size(), 8u);
  EXPECT_EQ(s.steps[4].framing, &mbc::kTcp);
  EXPECT_EQ(s.steps[5].us, 20000u);
  EXPECT_EQ(s.steps[6].us, 100000u);
  EXPECT_EQ(s.steps[7].kind, Step::Kind::power_cycle);
  EXPECT_EQ(s.steps[7].line, 12);
  // Written back, it reads the same.
  Script again = parse(format(s), "again");
  ASSERT_EQ(again.steps.size(), s.steps.size());
  for (size_t i = 0; i < s.steps.size(); ++i) EXPECT_EQ(line(again.steps[i]), line(s.steps[i]));
  EXPECT_EQ(format(again), format(s));
}

TEST(ScriptFormat, MalformedLinesNameFileLineColumnAndRule) {
  EXPECT_EQ(error_of("mbconform-script 3\n").rfind("t.txt:1:1: error: header:", 0), 0u);
  EXPECT_EQ(error_of("").rfind("t.txt:1:1: error: header:", 0), 0u);
  // The CRC of 01 03 00 00 00 01 is 84 0A (MB-SL v1.02 Appendix B).
  EXPECT_EQ(error_of("mbconform-script 1\n\nrtu 01 03 00 00 00 01 84 0B\n").rfind("t.txt:3:1: error: crc:", 0), 0u);
  EXPECT_EQ(error_of("mbconform-script 1\nrtu 01 03 0G\n").rfind("t.txt:2:11: error: hex:", 0), 0u);
  EXPECT_EQ(error_of("mbconform-script 1\nmbap * 00 00 00 07 01 03 00 00 00 01\n").rfind("t.txt:2:1: error: mbap:", 0), 0u);
  EXPECT_EQ(error_of("mbconform-script 1\nmbap * 00 01 00 06 01 03 00 00 00 01\n").rfind("t.txt:2:1: error: mbap:", 0), 0u);
  EXPECT_EQ(error_of("mbconform-script 1\nrtu 01 03 00 00 00 01 84 0A -> maybe\n").rfind("t.txt:2:32: error: expect:", 0), 0u);
  EXPECT_EQ(error_of("mbconform-script 1\nadvance 10 -> silence\n").rfind("t.txt:2:12: error: expect:", 0), 0u);
  EXPECT_EQ(error_of("mbconform-script 1\nadvance soon\n").rfind("t.txt:2:9: error: number:", 0), 0u);
  EXPECT_EQ(error_of("mbconform-script 1\nsend 01\n").rfind("t.txt:2:1: error: step:", 0), 0u);
  EXPECT_EQ(error_of("mbconform-script 1\nraw-rtu 01 | 03 | 00\n").rfind("t.txt:2:17: error: gap:", 0), 0u);
}

TEST(ScriptFormat, FramesPrintInTheFramingSent) {
  Bytes pdu{0x03, 0x00, 0x20, 0x00, 0x01};
  EXPECT_EQ(line(frame(&mbc::kRtu, 1, pdu)), "rtu 01 03 00 20 00 01 85 C0");
  EXPECT_EQ(line(frame(&mbc::kTcp, 1, pdu, Expect{.kind = Expect::Kind::silence})), "mbap * 00 00 00 06 01 03 00 20 00 01  -> silence");
  Step known = frame(&mbc::kTcp, 1, pdu);
  known.tid = 0x0102;
  EXPECT_EQ(line(known), "mbap 01 02 00 00 00 06 01 03 00 20 00 01");
}

TEST(ScriptReplay, RawBytesOfAnotherFramingAndInProcessStepsCannotRunLive) {
  Script s = parse("mbconform-script 1\nrtu 01 03 00 00 00 01 84 0A -> normal\nraw-rtu 01 03 00 00 00 01 84 0B -> silence\n"
                   "advance 10\n", "t.txt");
  TargetInfo tcp;
  tcp.uri = "tcp://127.0.0.1:1502";
  tcp.framing = &mbc::kTcp;
  tcp.raw = true;
  tcp.live = true;
  auto u = unsupported(s, tcp);
  ASSERT_TRUE(u);
  EXPECT_EQ(u->first, 3);
  TargetInfo rtu = tcp;
  rtu.framing = &mbc::kRtu;
  u = unsupported(s, rtu);
  ASSERT_TRUE(u);
  EXPECT_EQ(u->first, 4);  // a live drive has no virtual clock
  auto ref = open_target("ref:hsc60");
  EXPECT_FALSE(unsupported(s, ref->info()));
}

// MBAP v1.1b3 §6.6: FC 06 echoes the request; §6.3: FC 03 returns the
// register written. A device that drops writes fails the read, on its line.
TEST(ScriptReplay, MetOnTheCorrectDeviceNotOnTheBrokenOne) {
  Script s = parse(
      "mbconform-script 1\n"
      "device hsc60\n"
      "rtu 01 06 00 00 00 01 48 0A  -> reply 06 00 00 00 01\n"
      "rtu 01 03 00 00 00 01 84 0A  -> reply 03 02 00 01\n"
      "raw-rtu 01 03 00 00 00 01 84 0B  -> silence\n",
      "t.txt");
  spec::Spec spec = spec::load_spec_by_id("hsc60");
  auto good = open_target("ref:hsc60");
  DirectLink good_link(*good);
  auto r = replay(good_link, s, &spec);
  EXPECT_EQ(r.outcome, ReplayResult::Outcome::met) << r.line << ": " << r.message;
  auto broken = open_target("ref:hsc60?fault=lost-write");
  DirectLink broken_link(*broken);
  r = replay(broken_link, s, &spec);
  EXPECT_EQ(r.outcome, ReplayResult::Outcome::failed);
  EXPECT_EQ(r.line, 4);
  auto crc = open_target("ref:hsc60?fault=accept-bad-crc");
  DirectLink crc_link(*crc);
  r = replay(crc_link, s, &spec);
  EXPECT_EQ(r.outcome, ReplayResult::Outcome::failed);
  EXPECT_EQ(r.line, 5);
}

}  // namespace
}  // namespace mbc::conf::check
