// RTU framing: the frame around a PDU, where a frame ends, the line timing.
#include <gtest/gtest.h>

#include "modbus/framing.h"
#include "modbus/rtu.h"
#include "test_util.h"

namespace mbc {
namespace {

using std::chrono::microseconds;
using test::hex;

// SIHONG 57HS-R manual §6.2.1: "01 03 00 23 00 01 75 C0" / "01 03 02 00 3C B8 55".
TEST(Rtu, FrameAndUnframeTheManualsPrintedFrames) {
  EXPECT_EQ(rtu_frame(1, hex("03 00 23 00 01")), hex("01 03 00 23 00 01 75 C0"));
  Unframed u = rtu_unframe(hex("01 03 02 00 3C B8 55"));
  EXPECT_TRUE(u.ok()) << u.error;
  EXPECT_EQ(u.unit, 1);
  EXPECT_EQ(u.pdu, hex("03 02 00 3C"));
  // MB-SL v1.02 Appendix B: 02 07 -> 41 12.
  EXPECT_EQ(kRtu.frame(2, hex("07"), 0), hex("02 07 41 12"));
}

TEST(Rtu, UnframeNamesWhatIsWrong) {
  EXPECT_EQ(rtu_unframe(hex("01 03 02 00 3C 55 B8")).error, "CRC 55 B8, expected B8 55");
  EXPECT_EQ(rtu_unframe(hex("01 03 00")).error, "3 bytes: too short for an RTU frame (address, function code, CRC)");
  Bytes big = rtu_frame(1, Bytes(254, 0x41));
  EXPECT_EQ(rtu_unframe(big).error, "257 bytes: over the 256 of an RTU frame (MB-SL v1.02 §2.5.1)");
  EXPECT_FALSE(kRtu.unframe(hex("01 03 02 00 3C 55 B8")).ok());
}

// MB-SL v1.02 §2.5.1.1: t3.5 = 3.5 characters of 11 bits, t1.5 = 1.5; fixed above 19200 baud.
TEST(Rtu, CharacterTimesFromTheBaudRate) {
  EXPECT_EQ(frame_gap(9600), microseconds(4010));   // 38.5 bits / 9600
  EXPECT_EQ(frame_gap(19200), microseconds(2005));  // 38.5 bits / 19200
  EXPECT_EQ(frame_gap(38400), microseconds(1750));
  EXPECT_EQ(frame_gap(115200), microseconds(1750));
  EXPECT_EQ(char_gap(9600), microseconds(1719));  // 16.5 bits / 9600
  EXPECT_EQ(char_gap(115200), microseconds(750));
  EXPECT_EQ(wire_time(8, 9600), microseconds(9167));  // 88 bits
}

// Each of MBAP v1.1b3 §6's example PDUs, framed for slave 1: the length is
// known from the first bytes that carry it, and is the frame's size.
struct Sized {
  const char* pdu;
  size_t known_after;  // bytes of the ADU needed to know the length
};

void expect_lengths(Direction dir, std::initializer_list<Sized> cases) {
  for (const Sized& c : cases) {
    Bytes adu = rtu_frame(1, hex(c.pdu));
    for (size_t n = 0; n <= adu.size(); ++n) {
      auto got = rtu_adu_length(std::span(adu).first(n), dir);
      if (n < c.known_after) EXPECT_EQ(got, std::nullopt) << c.pdu << " after " << n;
      else EXPECT_EQ(got, adu.size()) << c.pdu << " after " << n;
    }
  }
}

TEST(Rtu, RequestLengthFollowsTheFunctionCode) {
  expect_lengths(Direction::request, {
                                         {"01 00 13 00 13", 2},
                                         {"03 00 6B 00 03", 2},
                                         {"05 00 AC FF 00", 2},
                                         {"06 00 01 00 03", 2},
                                         {"07", 2},
                                         {"08 00 00 A5 37", 2},
                                         {"0B", 2},
                                         {"0C", 2},
                                         {"0F 00 13 00 0A 02 CD 01", 7},
                                         {"10 00 01 00 02 04 00 0A 01 02", 7},
                                         {"11", 2},
                                         {"14 0E 06 00 04 00 01 00 02 06 00 03 00 09 00 02", 3},
                                         {"15 0D 06 00 04 00 07 00 03 06 AF 04 BE 10 0D", 3},
                                         {"16 00 04 00 F2 00 25", 2},
                                         {"17 00 03 00 06 00 0E 00 03 06 00 FF 00 FF 00 FF", 11},
                                         {"18 04 DE", 2},
                                         {"2B 0E 01 00", 3},
                                     });
  EXPECT_EQ(rtu_adu_length(hex("01 2B 0D"), Direction::request), std::nullopt);  // CANopen: unknowable
  EXPECT_EQ(rtu_adu_length(hex("01 41"), Direction::request), std::nullopt);     // user-defined
  EXPECT_EQ(rtu_adu_length(hex("01 83"), Direction::request), std::nullopt);
}

TEST(Rtu, ReplyLengthFollowsTheFunctionCode) {
  expect_lengths(Direction::reply, {
                                       {"01 03 CD 6B 05", 3},
                                       {"03 06 02 2B 00 00 00 64", 3},
                                       {"04 02 00 0A", 3},
                                       {"05 00 AC FF 00", 2},
                                       {"06 00 01 00 03", 2},
                                       {"07 6D", 2},
                                       {"08 00 00 A5 37", 2},
                                       {"0B FF FF 01 08", 2},
                                       {"0C 08 00 00 01 08 01 21 20 00", 3},
                                       {"0F 00 13 00 0A", 2},
                                       {"10 00 01 00 02", 2},
                                       {"11 0B 4D FF 6D 62 63 6F 6E 66 6F 72 6D", 3},
                                       {"14 0C 05 06 0D FE 00 20 05 06 33 CD 00 40", 3},
                                       {"15 0D 06 00 04 00 07 00 03 06 AF 04 BE 10 0D", 3},
                                       {"16 00 04 00 F2 00 25", 2},
                                       {"17 0C 00 FE 0A CD 00 01 00 03 00 0D 00 FF", 3},
                                       {"18 00 06 00 02 01 B8 12 84", 4},
                                       {"81 02", 2},
                                   });
  EXPECT_EQ(rtu_adu_length(hex("01 2B 0E 01"), Direction::reply), std::nullopt);  // silence ends it
}

TEST(Framing, DescriptorsStateTheStandardsSizes) {
  EXPECT_EQ(kRtu.max_pdu(), 253u);  // MBAP v1.1b3 §4.1
  EXPECT_EQ(kTcp.max_pdu(), 253u);
  EXPECT_EQ(kRtu.adu_size(5), 8u);   // address, 5-byte PDU, CRC
  EXPECT_EQ(kTcp.adu_size(5), 12u);  // MBAP header, 5-byte PDU
  EXPECT_EQ(kRtu.name, "rtu");
  EXPECT_EQ(kTcp.name, "tcp");
}

// A trace shows the PDU a broken frame carries, whatever its CRC says.
TEST(Framing, PduBytesIgnoreTheChecksum) {
  Bytes bad_crc = hex("01 03 00 23 00 01 00 00");  // 57HS-R §6.2.1's request, CRC zeroed
  auto pdu = kRtu.pdu_bytes(bad_crc);
  EXPECT_EQ(Bytes(pdu.begin(), pdu.end()), hex("03 00 23 00 01"));
  EXPECT_FALSE(kRtu.unframe(bad_crc).ok());
  EXPECT_TRUE(kRtu.pdu_bytes(hex("01 83 00")).empty());  // address and CRC only: no PDU
  Bytes mbap = hex("00 07 00 00 00 06 01 03 00 23 00 01");
  auto p2 = kTcp.pdu_bytes(mbap);
  EXPECT_EQ(Bytes(p2.begin(), p2.end()), hex("03 00 23 00 01"));
}

}  // namespace
}  // namespace mbc
