// CRC-16 and hex against the standard's worked example and the manuals' printed frames.
#include <gtest/gtest.h>

#include "modbus/bytes.h"
#include "modbus/crc16.h"
#include "modbus/hex.h"
#include "test_util.h"

namespace mbc {
namespace {

using test::hex;

// MB over Serial Line v1.02 Appendix B worked example: 02 07 -> CRC 0x1241, sent 41 12.
TEST(Crc16, StandardAppendixExample) {
  EXPECT_EQ(crc16(hex("02 07")), 0x1241);
  Bytes b = hex("02 07");
  append_crc(b);
  EXPECT_EQ(b, hex("02 07 41 12"));
  EXPECT_TRUE(crc_ok(b));
}

// SIHONG 57HS-R manual §6.2.1, printed request and reply.
TEST(Crc16, ManualPrintedFrames) {
  EXPECT_TRUE(crc_ok(hex("01 03 00 23 00 01 75 C0")));
  EXPECT_TRUE(crc_ok(hex("01 03 02 00 3C B8 55")));
  EXPECT_FALSE(crc_ok(hex("01 03 00 23 00 01 C0 75")));  // CRC bytes swapped
  EXPECT_FALSE(crc_ok(hex("01 03")));                    // too short to carry a CRC
}

TEST(Hex, StrictFormatIsUppercasePairsWithSingleSpaces) {
  EXPECT_EQ(parse_hex_strict("01 03 00 23"), hex("01 03 00 23"));
  EXPECT_FALSE(parse_hex_strict("01 03 0023"));
  EXPECT_FALSE(parse_hex_strict("01  03"));
  EXPECT_FALSE(parse_hex_strict("01 03 "));
  EXPECT_FALSE(parse_hex_strict("0a 03"));
  EXPECT_FALSE(parse_hex_strict(""));
}

TEST(Hex, LenientAcceptsRunTogetherPairsAndAnyCase) {
  EXPECT_EQ(parse_hex("01 06 FF 00 0B 580B"), (Bytes{0x01, 0x06, 0xFF, 0x00, 0x0B, 0x58, 0x0B}));  // 57HS-R §6.2.4
  EXPECT_EQ(parse_hex("0a\tff\n"), (Bytes{0x0A, 0xFF}));
  EXPECT_FALSE(parse_hex("0"));
  EXPECT_FALSE(parse_hex("0G"));
  EXPECT_EQ(to_hex(Bytes{0x01, 0xAB, 0x0F}), "01 AB 0F");
  EXPECT_EQ(to_hex(Bytes{}), "");
}

TEST(Bytes, BigEndianWords) {
  Bytes b{0x12};
  put_be16(b, 0xABCD);
  EXPECT_EQ(b, (Bytes{0x12, 0xAB, 0xCD}));
  EXPECT_EQ(be16(b, 1), 0xABCD);
  set_be16(b, 0, 0x0102);
  EXPECT_EQ(b, (Bytes{0x01, 0x02, 0xCD}));
}

}  // namespace
}  // namespace mbc
