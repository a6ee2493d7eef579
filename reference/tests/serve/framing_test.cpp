// `serve`'s arguments and its trace (the framing rules themselves: modbus/tests/).
#include <gtest/gtest.h>

#include "serve/server.h"
#include "serve/trace.h"

namespace mbc::serve {
namespace {

Bytes b(std::initializer_list<uint8_t> v) { return Bytes(v); }

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
