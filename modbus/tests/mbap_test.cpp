// MBAP framing (MB Messaging on TCP/IP v1.0b §3.1.3).
#include <gtest/gtest.h>

#include "modbus/mbap.h"
#include "test_util.h"

namespace mbc {
namespace {

using test::hex;

// MB TCP v1.0b §3.1.3: the reply repeats transaction, protocol and unit.
TEST(Mbap, ReplyKeepsTheRequestHeader) {
  Bytes req = hex("12 34 00 00 00 06 11 03 00 6B 00 03");
  auto h = parse_mbap(req);
  ASSERT_TRUE(h);
  EXPECT_EQ(h->transaction, 0x1234);
  EXPECT_EQ(h->length, 6);
  EXPECT_EQ(h->unit, 0x11);
  EXPECT_EQ(h->adu_size(), req.size());
  EXPECT_TRUE(h->length_ok());
  EXPECT_EQ(mbap_reply(*h, hex("03 02 00 07")), hex("12 34 00 00 00 05 11 03 02 00 07"));
  EXPECT_FALSE(parse_mbap(hex("00 01 00 00 00 06")));
  EXPECT_FALSE((Mbap{0, 0, 1, 0}.length_ok()));    // no function code
  EXPECT_FALSE((Mbap{0, 0, 255, 0}.length_ok()));  // PDU over 253 bytes
}

// A server's replies to a batch of requests, side by side in one output.
TEST(Mbap, RepliesAppendSideBySide) {
  Bytes out = hex("AA");
  append_mbap_reply(out, Mbap{0x1234, 0, 6, 0x11}, hex("03 02 00 07"));
  append_mbap_reply(out, Mbap{0x1235, 0, 6, 0x11}, hex("83 02"));
  EXPECT_EQ(out, hex("AA 12 34 00 00 00 05 11 03 02 00 07 12 35 00 00 00 03 11 83 02"));
}

TEST(Mbap, FrameAndUnframe) {
  Bytes adu = mbap_frame(0x0001, 0xFF, hex("03 00 6B 00 03"));
  EXPECT_EQ(adu, hex("00 01 00 00 00 06 FF 03 00 6B 00 03"));
  EXPECT_EQ(kTcp.frame(0xFF, hex("03 00 6B 00 03"), 1), adu);
  Unframed u = mbap_unframe(adu);
  EXPECT_TRUE(u.ok()) << u.error;
  EXPECT_EQ(u.transaction, 1);
  EXPECT_EQ(u.unit, 0xFF);
  EXPECT_EQ(u.pdu, hex("03 00 6B 00 03"));
}

TEST(Mbap, UnframeNamesWhatIsWrong) {
  EXPECT_EQ(mbap_unframe(hex("00 01 00 00 00")).error, "5 bytes: shorter than the 7-byte MBAP header");
  EXPECT_EQ(mbap_unframe(hex("00 01 00 01 00 06 FF 03 00 6B 00 03")).error, "MBAP protocol id 1, not 0 (Modbus)");
  EXPECT_EQ(mbap_unframe(hex("00 01 00 00 00 07 FF 03 00 6B 00 03")).error,
            "MBAP length 7 (unit id + 6 PDU bytes) but 6 bytes follow the length field");
  EXPECT_EQ(mbap_unframe(hex("00 01 00 00 00 01 FF")).error,
            "MBAP length 1: a PDU of 1..253 bytes needs 2..254 (MBAP v1.1b3 §4.1)");
}

}  // namespace
}  // namespace mbc
