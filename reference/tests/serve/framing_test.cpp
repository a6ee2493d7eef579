// The transport-side framing rules of `serve`, against the standards' numbers.
#include <gtest/gtest.h>

#include "serve/mbap.h"
#include "serve/rtu_framing.h"
#include "serve/server.h"
#include "serve/trace.h"

namespace mbc::serve {
namespace {

using std::chrono::microseconds;

// MB-SL v1.02 §2.5.1.1: t3.5 = 3.5 characters of 11 bits; 1.75 ms above 19200 baud.
TEST(RtuFraming, FrameGapIsThreeAndAHalfCharacters) {
  EXPECT_EQ(frame_gap(9600), microseconds(4010));   // 38.5 bits / 9600
  EXPECT_EQ(frame_gap(19200), microseconds(2005));  // 38.5 bits / 19200
  EXPECT_EQ(frame_gap(38400), microseconds(1750));
  EXPECT_EQ(frame_gap(115200), microseconds(1750));
  EXPECT_EQ(wire_time(8, 9600), microseconds(9167));  // 88 bits
}

Bytes b(std::initializer_list<uint8_t> v) { return Bytes(v); }

// MBAP v1.1b3 §6: request layouts.
TEST(RtuFraming, RequestLengthFollowsTheFunctionCode) {
  EXPECT_EQ(rtu_request_length(b({1, 0x03})), 8u);
  EXPECT_EQ(rtu_request_length(b({1, 0x06})), 8u);
  EXPECT_EQ(rtu_request_length(b({1, 0x08})), 8u);
  EXPECT_EQ(rtu_request_length(b({1, 0x07})), 4u);
  EXPECT_EQ(rtu_request_length(b({1, 0x11})), 4u);
  EXPECT_EQ(rtu_request_length(b({1, 0x16})), 10u);
  // FC 16: slave FC addr(2) qty(2) count values CRC.
  EXPECT_EQ(rtu_request_length(b({1, 0x10, 0, 0, 0, 2})), std::nullopt);  // count not seen yet
  EXPECT_EQ(rtu_request_length(b({1, 0x10, 0, 0, 0, 2, 4})), 13u);
  EXPECT_EQ(rtu_request_length(b({1, 0x0F, 0, 0, 0, 9, 2})), 11u);
  EXPECT_EQ(rtu_request_length(b({1, 0x17, 0, 0, 0, 1, 0, 5, 0, 1, 2})), 15u);
  EXPECT_EQ(rtu_request_length(b({1, 0x2B, 0x0E})), 7u);
  EXPECT_EQ(rtu_request_length(b({1, 0x2B, 0x0D})), std::nullopt);
  EXPECT_EQ(rtu_request_length(b({1, 0x41})), std::nullopt);
  EXPECT_EQ(rtu_request_length(b({1})), std::nullopt);
}

// MB TCP v1.0b §3.1.3: the reply repeats transaction, protocol and unit.
TEST(Mbap, ReplyKeepsTheRequestHeader) {
  Bytes req = b({0x12, 0x34, 0, 0, 0, 6, 0x11, 0x03, 0, 0x6B, 0, 3});
  auto h = parse_mbap(req);
  ASSERT_TRUE(h);
  EXPECT_EQ(h->transaction, 0x1234);
  EXPECT_EQ(h->length, 6);
  EXPECT_EQ(h->unit, 0x11);
  EXPECT_EQ(h->adu_size(), req.size());
  EXPECT_TRUE(h->length_ok());
  EXPECT_EQ(mbap_reply(*h, b({0x03, 2, 0, 7})), b({0x12, 0x34, 0, 0, 0, 5, 0x11, 0x03, 2, 0, 7}));
  EXPECT_FALSE(parse_mbap(b({0, 1, 0, 0, 0, 6})));
  EXPECT_FALSE((Mbap{0, 0, 1, 0}.length_ok()));    // no function code
  EXPECT_FALSE((Mbap{0, 0, 255, 0}.length_ok()));  // PDU over 253 bytes
}

TEST(ServeArgs, EndpointsAndDevices) {
  auto e = parse_endpoint(Transport::tcp, "5020");
  EXPECT_EQ(e.host, "127.0.0.1");
  EXPECT_EQ(e.port, 5020);
  e = parse_endpoint(Transport::rtu_tcp, "0.0.0.0:0");
  EXPECT_EQ(e.host, "0.0.0.0");
  EXPECT_EQ(e.port, 0);
  e = parse_endpoint(Transport::tcp, "[::1]:502");
  EXPECT_EQ(e.host, "::1");
  EXPECT_EQ(e.port, 502);
  EXPECT_THROW(parse_endpoint(Transport::tcp, "host:"), std::invalid_argument);
  EXPECT_THROW(parse_endpoint(Transport::tcp, "65536"), std::invalid_argument);
  auto d = parse_device_arg("hsc60@2");
  EXPECT_EQ(d.id, "hsc60");
  EXPECT_EQ(d.slave, 2);
  EXPECT_EQ(parse_device_arg("hsc60").slave, 1);
  EXPECT_THROW(parse_device_arg("hsc60@0"), std::invalid_argument);
  EXPECT_THROW(parse_device_arg("hsc60@248"), std::invalid_argument);
  EXPECT_THROW(parse_device_arg("@3"), std::invalid_argument);
}

TEST(Trace, DecodesRequestsRepliesAndExceptions) {
  Bytes read = b({0x01, 0x03, 0x00, 0x23, 0x00, 0x01, 0x75, 0xC0});  // sihong-57hs-r §6.2.1
  EXPECT_EQ(describe_rtu(read, Direction::request), "slave 1 FC 03 read holding registers addr 0x0023 qty 1 CRC ok");
  EXPECT_EQ(describe_pdu(b({0x03, 0x02, 0x00, 0x3C}), Direction::reply), "FC 03 read holding registers 2 bytes: 60");
  EXPECT_EQ(describe_pdu(b({0x86, 0x02}), Direction::reply), "FC 86 exception 02 (illegal data address)");
}

}  // namespace
}  // namespace mbc::serve
