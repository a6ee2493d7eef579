// The reply judge: the standard's example replies pass against their
// requests; each departure from MBAP v1.1b3 is named.
#include <gtest/gtest.h>

#include "modbus/judge.h"
#include "test_util.h"

namespace mbc {
namespace {

using test::hex;

TEST(Judge, StandardExamplesAreWellFormed) {
  struct Pair {
    const char* request;
    const char* reply;
  };
  for (const Pair& p : {
           Pair{"01 00 13 00 13", "01 03 CD 6B 05"},  // §6.1 (19 coils: 3 padding bits of 05 are zero)
           Pair{"03 00 6B 00 03", "03 06 02 2B 00 00 00 64"},
           Pair{"05 00 AC FF 00", "05 00 AC FF 00"},
           Pair{"10 00 01 00 02 04 00 0A 01 02", "10 00 01 00 02"},
           Pair{"16 00 04 00 F2 00 25", "16 00 04 00 F2 00 25"},
           Pair{"17 00 03 00 06 00 0E 00 03 06 00 FF 00 FF 00 FF", "17 0C 00 FE 0A CD 00 01 00 03 00 0D 00 FF"},
           Pair{"08 00 00 A5 37", "08 00 00 A5 37"},
       }) {
    Judged j = judge_reply(hex(p.request), hex(p.reply));
    EXPECT_TRUE(j.ok()) << p.reply << ": " << (j.problems.empty() ? "" : j.problems[0]);
    EXPECT_EQ(j.kind, Judged::Kind::normal);
  }
  Judged j = judge_reply(hex("03 00 6B 00 03"), hex("03 06 02 2B 00 00 00 64"));
  EXPECT_EQ(j.registers, (std::vector<uint16_t>{555, 0, 100}));
  j = judge_reply(hex("01 00 13 00 13"), hex("01 03 CD 6B 05"));
  EXPECT_EQ(j.bits.size(), 19u);
}

TEST(Judge, ExceptionReplies) {
  Judged j = judge_reply(hex("01 04 A1 00 01"), hex("81 02"));  // §7's example
  EXPECT_TRUE(j.ok());
  EXPECT_EQ(j.kind, Judged::Kind::exception);
  EXPECT_EQ(j.exception_code, 2);
  j = judge_reply(hex("01 04 A1 00 01"), hex("81 02 00"));
  EXPECT_EQ(j.problems, std::vector<std::string>{"exception reply is 3 bytes, MBAP v1.1b3 §7 says 2"});
  j = judge_reply(hex("01 04 A1 00 01"), hex("81"));
  EXPECT_EQ(j.kind, Judged::Kind::malformed);
}

TEST(Judge, DeparturesAreNamed) {
  auto first = [](const char* req, const char* rep) {
    Judged j = judge_reply(hex(req), hex(rep));
    EXPECT_FALSE(j.ok()) << rep;
    return j.problems.empty() ? std::string() : j.problems[0];
  };
  EXPECT_EQ(first("03 00 6B 00 03", "04 06 02 2B 00 00 00 64"), "reply function code 0x04, request was 0x03");
  EXPECT_EQ(first("03 00 6B 00 03", "03 04 02 2B 00 00"), "byte count 4 for 3 registers, expected 6");
  EXPECT_EQ(first("03 00 6B 00 03", "03 06 02 2B 00 00"), "reply is 6 bytes, expected 8");
  EXPECT_EQ(first("01 00 13 00 13", "01 03 CD 6B 0D"), "padding bits of the last byte are not zero (MBAP v1.1b3 §6.1)");
  EXPECT_EQ(first("01 00 13 00 13", "01 02 CD 6B"), "byte count 2 for 19 bits, expected 3");
  EXPECT_EQ(first("06 00 01 00 03", "06 00 01 00 04"), "reply does not echo the request (MBAP v1.1b3 §6)");
  EXPECT_EQ(first("08 00 00 A5 37", "08 00"), "diagnostics reply too short");
  EXPECT_EQ(first("03 00 6B 00 03", ""), "empty reply PDU");
  Bytes big{0x03, 0xFC};
  big.resize(254, 0);
  EXPECT_EQ(first("03 00 00 00 7E", to_hex(big).c_str()), "reply PDU is 254 bytes, over the 253 of MBAP v1.1b3 §4.1");
}

TEST(Judge, DescribeForPeople) {
  EXPECT_EQ(describe_pdu(hex("03 00 6B 00 03"), true), "FC03 read holding registers address 107 (0x006B) quantity 3");
  EXPECT_EQ(describe_pdu(hex("06 00 01 00 03"), true), "FC06 write single register address 1 (0x0001) value 3");
  EXPECT_EQ(describe_pdu(hex("03 06 02 2B 00 00 00 64"), false), "FC03 read holding registers: 6 bytes 022B 0000 0064");
  EXPECT_EQ(describe_pdu(hex("10 00 01 00 02"), false), "FC16 write multiple registers address 1 (0x0001) 0002");
  EXPECT_EQ(describe_pdu(hex("81 02"), false), "FC01 read coils exception 02");
  EXPECT_EQ(describe_pdu(hex("81"), false), "FC01 read coils exception (missing code)");
  EXPECT_EQ(describe_pdu(hex("18 04 DE"), true), "FC24 read FIFO queue");
  EXPECT_EQ(describe_pdu({}, true), "(empty)");
}

}  // namespace
}  // namespace mbc
