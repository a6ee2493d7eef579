// The one judge and the version-2 text form (conformance/check/README.md):
// the messages a person reads for a reply that is too short or a connection
// that closed; raw MBAP requests read as MBAP (TCP IG v1.0b §3.1.3), not as
// RTU; a case written as text and read back is the same case; and a replayed
// plan records an OBSERVED miss as such and goes on.
#include <gtest/gtest.h>

#include "check/judge.h"
#include "check/text.h"
#include "loader.h"
#include "modbus/mbap.h"
#include "modbus/pdu.h"
#include "modbus/rtu.h"
#include "runner/runner.h"
#include "session/link.h"

namespace mbc::conf::check {
namespace {

Reply reply_of(Bytes pdu) {
  Reply r;
  r.request = {0x01};
  r.frame = rtu_frame(1, pdu);
  r.pdu = std::move(pdu);
  return r;
}

Expect expect(Expect::Kind k, uint8_t code = 0) {
  Expect e;
  e.kind = k;
  e.code = code;
  return e;
}

// MBAP v1.1b3 §7: an exception reply is the function code | 0x80 and one code.
TEST(Judge, AOneByteExceptionReplyIsTooShortNotTooLong) {
  Step s = frame(&mbc::kRtu, 1, {0x0C}, expect(Expect::Kind::answered));
  auto m = judge(s, reply_of({0x8C}), JudgeContext{});
  ASSERT_TRUE(m);
  EXPECT_NE(m->why.find("exception reply of 1 byte"), std::string::npos) << m->why;
  EXPECT_EQ(m->why.find("longer"), std::string::npos) << m->why;
  s.expect = expect(Expect::Kind::exception, 1);
  m = judge(s, reply_of({0x8C}), JudgeContext{});
  ASSERT_TRUE(m);
  EXPECT_NE(m->why.find("exception reply of 1 byte"), std::string::npos) << m->why;
  // Three bytes are too long.
  m = judge(s, reply_of({0x8C, 0x01, 0x00}), JudgeContext{});
  ASSERT_TRUE(m);
  EXPECT_EQ(m->why, "exception reply longer than 2 bytes");
  EXPECT_FALSE(judge(s, reply_of({0x8C, 0x01}), JudgeContext{}));
}

TEST(Judge, AClosedConnectionIsNamedNotCalledSilence) {
  Step s = frame(&mbc::kTcp, 1, read_request(3, 0, 1), expect(Expect::Kind::normal));
  Reply closed;
  closed.closed = true;
  auto m = judge(s, closed, JudgeContext{});
  ASSERT_TRUE(m);
  EXPECT_EQ(m->kind, Mismatch::Kind::silent);
  EXPECT_EQ(m->why, "the server closed the connection");
  m = judge(s, Reply{}, JudgeContext{});
  ASSERT_TRUE(m);
  EXPECT_EQ(m->why, "no reply");
}

// standard/mbap/short-pdu: FC 03 without its quantity, MBAP length right.
// Read as RTU its "PDU" would start at the transaction id's low byte.
TEST(Judge, RawMbapRequestsAreReadAsMbap) {
  Bytes shorter{0x03, 0x00, 0x00};
  Step s = raw_mbap(mbap_frame(0x5301, 1, shorter), expect(Expect::Kind::exception, 3));
  auto req = request_pdu(s, 1);
  ASSERT_TRUE(req);
  EXPECT_EQ(*req, shorter);
  EXPECT_FALSE(request_pdu(s, 2));  // another unit
  JudgeContext ctx;
  ctx.framing = &mbc::kTcp;
  Reply r;
  r.frame = mbap_frame(0x5301, 1, Bytes{0x83, 0x03});
  r.pdu = Bytes{0x83, 0x03};
  EXPECT_FALSE(judge(s, r, ctx));
  r.pdu = Bytes{0x83, 0x02};
  auto m = judge(s, r, ctx);
  ASSERT_TRUE(m);
  EXPECT_EQ(m->why, "exception 02 instead of 03");
  // No whole MBAP header, or a length that counts no PDU: no request at all.
  EXPECT_FALSE(request_pdu(raw_mbap(mbap_frame(1, 1, Bytes{})), 1));
}

TEST(Text, ACaseReadsBackAsTheSameCase) {
  Case c;
  c.id = "hsc60/standard/x/y+1";
  c.family = "standard";
  c.level = Level::observed;
  c.clause = "MBAP v1.1b3 §6.17; #7";
  c.title = "a title # with a hash";
  c.touches = {{0x0020, 2}};
  c.functions_optional = true;
  Step w = frame(&mbc::kRtu, 1, write_multiple_registers(0x0020, std::vector<uint16_t>{0, 0}), expect(Expect::Kind::reply));
  w.expect.pdu = {0x10, 0x00, 0x20, 0x00, 0x02};
  w.expect.adu = rtu_frame(1, w.expect.pdu);
  w.expect.text = "FC, address and quantity";
  w.note = "write 0x0020 x2";
  w.setup = true;
  Step r = frame(&mbc::kRtu, 1, read_request(3, 0x0020, 2), expect(Expect::Kind::registers));
  r.expect.words = {0x0001, 0xFFFF};
  r.may_go_unanswered = true;
  Step same = frame(&mbc::kRtu, 0, write_multiple_registers(0x0020, std::vector<uint16_t>{0, 0}), expect(Expect::Kind::same));
  same.expect.memo = 1;
  same.words_from = 1;
  same.expect.either = {expect(Expect::Kind::silence), expect(Expect::Kind::none)};
  c.steps = {w, r, same, advance(1000)};
  std::string text = std::string(kHeader) + "\n";
  for (const auto& l : case_lines(c, &mbc::kTcp)) text += l + "\n";
  Script sc = parse(text, "t.txt");
  ASSERT_EQ(sc.cases.size(), 1u) << text;
  const Case& b = sc.cases[0];
  EXPECT_EQ(b.id, c.id);
  EXPECT_EQ(b.family, "standard");
  EXPECT_EQ(b.level, Level::observed);
  EXPECT_EQ(b.clause, c.clause);
  EXPECT_EQ(b.title, c.title);
  EXPECT_EQ(b.touches, c.touches);
  EXPECT_TRUE(b.functions_optional);
  ASSERT_EQ(b.steps.size(), 4u);
  EXPECT_EQ(b.steps[0].expect.kind, Expect::Kind::reply);
  EXPECT_EQ(b.steps[0].expect.pdu, w.expect.pdu);
  EXPECT_EQ(b.steps[0].expect.adu, w.expect.adu);
  EXPECT_EQ(b.steps[0].expect.text, w.expect.text);
  EXPECT_EQ(b.steps[0].note, w.note);
  EXPECT_TRUE(b.steps[0].setup);
  EXPECT_EQ(b.steps[0].pdu, w.pdu);
  EXPECT_EQ(b.steps[1].expect.words, r.expect.words);
  EXPECT_TRUE(b.steps[1].may_go_unanswered);
  EXPECT_EQ(b.steps[2].unit, 0);
  EXPECT_EQ(b.steps[2].expect.kind, Expect::Kind::same);
  EXPECT_EQ(b.steps[2].expect.memo, 1);
  EXPECT_EQ(b.steps[2].words_from, 1);
  ASSERT_EQ(b.steps[2].expect.either.size(), 2u);
  EXPECT_EQ(b.steps[2].expect.either[0].kind, Expect::Kind::silence);
  EXPECT_EQ(b.steps[2].expect.either[1].kind, Expect::Kind::none);
  EXPECT_EQ(b.steps[3].kind, Step::Kind::advance);
  // Written again, it is the same text.
  std::string again = std::string(kHeader) + "\n";
  for (const auto& l : case_lines(b, &mbc::kTcp)) again += l + "\n";
  EXPECT_EQ(again, text);
  // A skipped case keeps its reason; its steps are commented out.
  c.skip_reason = "the target cannot send raw frames";
  text = std::string(kHeader) + "\n";
  for (const auto& l : case_lines(c, &mbc::kRtu)) text += l + "\n";
  sc = parse(text, "t.txt");
  ASSERT_EQ(sc.cases.size(), 1u);
  EXPECT_EQ(sc.cases[0].skip_reason, c.skip_reason);
  EXPECT_TRUE(sc.cases[0].steps.empty());
}

TEST(Text, CaseLinesAndFlagsNameTheirErrors) {
  auto error_of = [](const std::string& t) {
    try {
      parse(t, "t.txt");
    } catch (const ParseError& e) {
      return std::string(e.what());
    }
    return std::string();
  };
  EXPECT_EQ(error_of("mbconform-script 2\ncase a/b MAYBE x\n").rfind("t.txt:2:10: error: case:", 0), 0u);
  EXPECT_EQ(error_of("mbconform-script 2\ntouches 0x0020 1\n").rfind("t.txt:2:1: error: touches:", 0), 0u);
  EXPECT_EQ(error_of("mbconform-script 2\nrtu 01 03 00 00 00 01 84 0A +soon\n").rfind("t.txt:2:29: error: flag:", 0), 0u);
  EXPECT_EQ(error_of("mbconform-script 2\ncase a/b MUST x\nrtu 01 03 00 00 00 01 84 0A -> same-as 1\n").rfind("t.txt:3:1: error: step:", 0), 0u);
  EXPECT_EQ(error_of("mbconform-script 1\nrtu 01 03 00 00 00 01 84 0A +setup\n").rfind("t.txt:2:29: error: flag:", 0), 0u);
}

// A plan's OBSERVED miss is recorded as OBSERVED and the replay goes on; a
// MUST miss fails the replay, and the next case still runs.
TEST(Replay, CasesAreRecordedAsTheirLevelAndTheReplayGoesOn) {
  Script s = parse(
      "mbconform-script 2\n"
      "device hsc60\n"
      "case hsc60/x/observed OBSERVED §1\n"
      "rtu 01 03 00 00 00 01 84 0A  -> reply 03 02 12 34\n"
      "case hsc60/x/must MUST §2\n"
      "rtu 01 03 00 00 00 01 84 0A  -> normal\n"
      "case hsc60/x/skipped MUST §3\n"
      "skip not here\n"
      "# rtu 01 03 00 00 00 01 84 0A  -> normal\n"
      "case hsc60/x/fails MUST §4\n"
      "rtu 01 03 00 00 00 01 84 0A  -> silence\n"
      "case hsc60/x/after MUST §5\n"
      "rtu 01 03 00 00 00 01 84 0A  -> normal\n",
      "t.txt");
  spec::Spec spec = spec::load_spec_by_id("hsc60");
  auto t = open_target("ref:hsc60");
  DirectLink link(*t);
  auto r = conf::replay(link, s, &spec);
  EXPECT_EQ(r.outcome, conf::ReplayResult::Outcome::failed);
  ASSERT_EQ(r.run.cases.size(), 5u);
  EXPECT_EQ(r.run.cases[0].outcome, Outcome::observed);
  EXPECT_NE(r.run.cases[0].message.find("differs from the expectation"), std::string::npos) << r.run.cases[0].message;
  EXPECT_EQ(r.run.cases[1].outcome, Outcome::pass);
  EXPECT_EQ(r.run.cases[2].outcome, Outcome::skip);
  EXPECT_EQ(r.run.cases[2].message, "not here");
  EXPECT_EQ(r.run.cases[3].outcome, Outcome::fail);
  EXPECT_EQ(r.run.cases[4].outcome, Outcome::pass);
  EXPECT_EQ(r.run.cases[3].family, "x");
}

}  // namespace
}  // namespace mbc::conf::check
