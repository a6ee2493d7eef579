// check-capture's reader, pairing and judge on captures built here frame by
// frame (modbus/pcapng.h), with expectations from the standard and the
// modbus-standard spec: MBAP v1.1b3 §6 layouts, §7 exception codes, the
// spec's exception policy (02 for an unmapped address, 01 for an
// unsupported function).
#include <gtest/gtest.h>

#include <cstdio>
#include <filesystem>
#include <fstream>

#include "capture/check.h"
#include "capture/pcap_tap.h"
#include "capture/serial_log.h"
#include "loader.h"
#include "modbus/crc16.h"
#include "modbus/mbap.h"
#include "modbus/pcapng.h"
#include "modbus/pdu.h"
#include "modbus/rtu.h"
#include "report/report.h"

namespace mbc::conf::capture {
namespace {

const spec::Spec& standard() {
  static spec::Spec s = spec::load_spec_by_id("modbus-standard");
  return s;
}

// A pcapng being built in memory: Ethernet, one TCP conversation per `conv()`.
struct Builder {
  Bytes file = pcapng::section_header("test");
  uint64_t t = 1'700'000'000'000'000;
  Builder() {
    auto idb = pcapng::interface_description(pcapng::kLinkEthernet, "eth0", "");
    file.insert(file.end(), idb.begin(), idb.end());
  }
  void put(const Bytes& frame, uint64_t dt = 1000) {
    t += dt;
    auto epb = pcapng::enhanced_packet(0, t, frame);
    file.insert(file.end(), epb.begin(), epb.end());
  }
  pcapng::TcpConversation conv(uint16_t client_port, uint16_t server_port = 502) {
    pcapng::TcpConversation c(0x0A000001, client_port, 0x0A000002, server_port);
    for (int i = 0; i < 3; ++i) put(c.handshake(i));
    return c;
  }
};

const CaseResult* find_case(const Result& r, const std::string& suffix) {
  for (const auto& c : r.run.cases)
    if (c.id.size() >= suffix.size() && c.id.compare(c.id.size() - suffix.size(), suffix.size(), suffix) == 0) return &c;
  return nullptr;
}

Result check(const Bytes& file, Options o = {}) { return check_capture_bytes(file, standard(), o); }

TEST(CaptureRead, PairsByTransactionAndJudgesTheStandardsReplies) {
  Builder b;
  auto c = b.conv(40000);
  // FC 03 of 2 registers at 0 (mapped), answered with 4 bytes (MBAP v1.1b3 §6.3).
  b.put(c.data(true, mbap_frame(7, 1, read_request(3, 0, 2))));
  // FC 03 at 0x0100, in the standard's gap: exception 02 (policy unmapped_address).
  b.put(c.data(true, mbap_frame(8, 1, read_request(3, 0x0100, 1))));
  // Replies out of order: paired by transaction id, not by order.
  b.put(c.data(false, mbap_frame(8, 1, exception_reply(3, 2))));
  const uint16_t regs[] = {1, 2};
  b.put(c.data(false, mbap_frame(7, 1, read_registers_reply(3, regs))));
  Result r = check(b.file);
  EXPECT_EQ(r.stats.error, "");
  EXPECT_EQ(r.coverage.requests, 2u);
  EXPECT_EQ(r.coverage.exchanges, 2u);
  EXPECT_EQ(r.coverage.exceptions, 1u);
  EXPECT_EQ(r.coverage.requests_by_fc.at(3), 2u);
  EXPECT_EQ(r.coverage.exceptions_by_fc.at(3), 1u);
  EXPECT_EQ(r.coverage.latency_count, 2u);
  ASSERT_TRUE(find_case(r, "/capture/function-codes/fc03/reply"));
  EXPECT_EQ(find_case(r, "/capture/function-codes/fc03/reply")->outcome, Outcome::pass);
  EXPECT_EQ(find_case(r, "/capture/policy/unmapped_address")->outcome, Outcome::pass);
  EXPECT_EQ(find_case(r, "/capture/registers/holding/0x0000/read")->outcome, Outcome::pass);
  // Never exercised: not seen, never a pass.
  EXPECT_EQ(find_case(r, "/capture/function-codes/fc10/reply")->outcome, Outcome::skip);
  EXPECT_NE(find_case(r, "/capture/function-codes/fc10/reply")->message.find("not seen"), std::string::npos);
  EXPECT_EQ(find_case(r, "/capture/registers/holding/0x0005/read")->outcome, Outcome::skip);
}

TEST(CaptureRead, WrongRepliesFailTheirCase) {
  Builder b;
  auto c = b.conv(40001);
  // Unmapped address answered normally: the policy says exception 02.
  b.put(c.data(true, mbap_frame(1, 1, read_request(3, 0x0100, 1))));
  const uint16_t one[] = {5};
  b.put(c.data(false, mbap_frame(1, 1, read_registers_reply(3, one))));
  // A valid read of 2 registers answered with a byte count of 2 (§6.3: 2 x quantity).
  b.put(c.data(true, mbap_frame(2, 1, read_request(3, 0, 2))));
  b.put(c.data(false, mbap_frame(2, 1, Bytes{0x03, 0x02, 0x00, 0x01})));
  // Unit echo broken (MBAP §4.1).
  b.put(c.data(true, mbap_frame(3, 1, read_request(3, 0, 1))));
  b.put(c.data(false, mbap_frame(3, 9, read_registers_reply(3, one))));
  Result r = check(b.file);
  EXPECT_EQ(find_case(r, "/capture/policy/unmapped_address")->outcome, Outcome::fail);
  EXPECT_EQ(find_case(r, "/capture/function-codes/fc03/byte-count")->outcome, Outcome::fail);
  EXPECT_EQ(find_case(r, "/capture/framing/unit-echo")->outcome, Outcome::fail);
  EXPECT_FALSE(find_case(r, "/capture/policy/unmapped_address")->frames.empty());
  EXPECT_GT(conf::count(r.run).must_failed, 0u);
}

TEST(CaptureRead, AReplyOfAnotherFunctionCodeIsNotPairedByGuess) {
  Builder b;
  auto c = b.conv(40006);
  // Every request with transaction id 0 (as fuzz-72.pcap's client does): the
  // exception reply to FC 20 belongs to no request this capture holds.
  b.put(c.data(true, mbap_frame(0, 1, Bytes{0x1D, 0, 0, 0, 0})));
  b.put(c.data(false, mbap_frame(0, 1, exception_reply(0x20, 1))));
  Result r = check(b.file);
  EXPECT_EQ(r.coverage.unsolicited, 1u);
  EXPECT_EQ(r.coverage.unanswered, 1u);
  EXPECT_EQ(r.coverage.exchanges, 0u);
  EXPECT_EQ(find_case(r, "/capture/pairing/unsolicited")->outcome, Outcome::observed);
  EXPECT_EQ(find_case(r, "/capture/policy/unsupported_function")->outcome, Outcome::skip);
  EXPECT_EQ(conf::count(r.run).must_failed, 0u);
}

TEST(CaptureRead, ReassemblesSplitSegmentsAndSkipsRetransmissions) {
  Builder b;
  auto c = b.conv(40002);
  Bytes rq = mbap_frame(5, 1, read_request(3, 0, 1));
  b.put(c.data(true, std::span(rq).first(4)));
  Bytes second = c.data(true, std::span(rq).subspan(4));
  b.put(second);
  b.put(second);  // the same segment again: a retransmission, not a second request
  const uint16_t one[] = {5};
  b.put(c.data(false, mbap_frame(5, 1, read_registers_reply(3, one))));
  Result r = check(b.file);
  EXPECT_EQ(r.coverage.requests, 1u);
  EXPECT_EQ(r.coverage.exchanges, 1u);
  EXPECT_EQ(r.coverage.unanswered, 0u);
}

TEST(CaptureRead, AHoleInTheStreamDropsTheIncompleteAduAndIsAFinding) {
  Builder b;
  auto c = b.conv(40003);
  Bytes rq = mbap_frame(5, 1, read_request(3, 0, 1));
  b.put(c.data(true, std::span(rq).first(4)));
  (void)c.data(true, std::span(rq).subspan(4));  // not captured
  b.put(c.data(true, mbap_frame(6, 1, read_request(3, 1, 1))));
  Result r = check(b.file);
  EXPECT_EQ(r.coverage.requests, 1u);  // only the whole one
  EXPECT_GE(r.finding_count, 1u);
  EXPECT_EQ(r.coverage.unanswered, 1u);
  EXPECT_EQ(find_case(r, "/capture/pairing/unanswered")->outcome, Outcome::observed);
}

TEST(CaptureRead, RtuOverTcpOnAnotherPortIsFoundByItsCrc) {
  Builder b;
  auto c = b.conv(40004, 1503);
  b.put(c.data(true, rtu_frame(1, read_request(3, 0, 1))));
  const uint16_t one[] = {5};
  b.put(c.data(false, rtu_frame(1, read_registers_reply(3, one))));
  Options o;
  EXPECT_EQ(check(b.file, o).coverage.requests, 0u);  // port 1503 is not a server port by default
  o.read.ports.push_back(1503);
  Result r = check(b.file, o);
  EXPECT_EQ(r.coverage.requests, 1u);
  EXPECT_EQ(r.coverage.exchanges, 1u);
  EXPECT_EQ(find_case(r, "/capture/framing/crc")->outcome, Outcome::pass);
}

// A common RTU request reads as an MBAP header too: "01 03 00 00 00 0A C5 CD"
// has bytes 2-3 = 0 (protocol 0) and 4-5 = 10 (a length). Its CRC checks:
// RTU over TCP, never MBAP (MB-SL v1.02 §2.5.1.2: the CRC is the frame's end).
TEST(CaptureRead, RtuThatLooksLikeMbapIsReadAsRtu) {
  Builder b;
  auto c = b.conv(40007, 1503);
  Bytes rq = rtu_frame(1, read_request(3, 0, 10));
  ASSERT_EQ(to_hex(rq), "01 03 00 00 00 0A C5 CD");
  const uint16_t ten[10] = {1, 2, 3, 4, 5, 6, 7, 8, 9, 10};
  b.put(c.data(true, rq));
  b.put(c.data(false, rtu_frame(1, read_registers_reply(3, ten))));
  b.put(c.data(true, rtu_frame(1, read_request(3, 0, 2))));  // "01 03 00 00 00 02 C4 0B": length 2, protocol 0
  const uint16_t two[] = {1, 2};
  b.put(c.data(false, rtu_frame(1, read_registers_reply(3, two))));
  Options o;
  o.read.ports.push_back(1503);
  Result r = check(b.file, o);
  EXPECT_EQ(r.coverage.requests, 2u);
  EXPECT_EQ(r.coverage.exchanges, 2u);
  EXPECT_EQ(find_case(r, "/capture/framing/crc")->outcome, Outcome::pass);
  EXPECT_EQ(find_case(r, "/capture/function-codes/fc03/reply")->outcome, Outcome::pass);
  EXPECT_EQ(conf::count(r.run).must_failed, 0u);
  // The same frames in a serial log: each line that is an RTU frame whose CRC checks is RTU.
  std::string log = "0.000000 line rx " + to_hex(rtu_frame(1, read_request(3, 0, 2))) + "\n" +
                    "0.020000 line tx " + to_hex(rtu_frame(1, read_registers_reply(3, two))) + "\n";
  Result l = check(Bytes(log.begin(), log.end()));
  EXPECT_EQ(l.coverage.exchanges, 1u);
  EXPECT_EQ(find_case(l, "/capture/framing/crc")->outcome, Outcome::pass);
}

// A client that reuses a transaction id while the first request waits: a
// server answers requests in turn, so the replies pair by order (MB
// Messaging on TCP/IP v1.0b §3.1.3: the id pairs a reply with its request;
// two alike are told apart only by their order).
TEST(CaptureRead, AReusedTransactionIdPairsByOrder) {
  Builder b;
  auto c = b.conv(40008);
  b.put(c.data(true, mbap_frame(9, 1, read_request(3, 0, 1))));       // mapped
  b.put(c.data(true, mbap_frame(9, 1, read_request(3, 0x0100, 1))));  // in the gap: exception 02
  b.put(c.data(true, mbap_frame(9, 1, read_request(3, 0, 2))));       // mapped, 2 registers
  const uint16_t one[] = {5}, two[] = {5, 6};
  b.put(c.data(false, mbap_frame(9, 1, read_registers_reply(3, one))));
  b.put(c.data(false, mbap_frame(9, 1, exception_reply(3, 2))));
  b.put(c.data(false, mbap_frame(9, 1, read_registers_reply(3, two))));
  Result r = check(b.file);
  EXPECT_EQ(r.coverage.exchanges, 3u);
  EXPECT_EQ(r.coverage.unsolicited, 0u);
  EXPECT_EQ(find_case(r, "/capture/policy/unmapped_address")->outcome, Outcome::pass);
  EXPECT_EQ(find_case(r, "/capture/function-codes/fc03/byte-count")->outcome, Outcome::pass);
  EXPECT_EQ(conf::count(r.run).must_failed, 0u) << conf::count(r.run).fail;
}

TEST(CaptureRead, TruncatedAndMalformedCapturesGiveOneLineNotACrash) {
  Builder b;
  auto c = b.conv(40005);
  b.put(c.data(true, mbap_frame(5, 1, read_request(3, 0, 1))));
  // A classic pcap cut in the middle of its last packet: libpcap says so.
  Bytes cut(b.file.begin(), b.file.end() - 10);
  Result r = check(cut);
  EXPECT_NE(r.stats.error, "");
  EXPECT_EQ(r.stats.error.find('\n'), std::string::npos);
  // Not a capture at all.
  Bytes junk = {0x00, 0x01, 0x02, 0x03, 0xFF, 0xFE};
  Result j = check(junk);
  EXPECT_NE(j.stats.error, "");
  // Empty.
  EXPECT_NE(check(Bytes{}).stats.error, "");
}

TEST(SerialLog, ReadsTimedFramesAndJudgesTheGaps) {
  // 19200 baud: t3.5 = 3.5 x 11 bits / 19200 = 2005 us; an 8-byte frame takes 4583 us.
  Bytes rq = rtu_frame(1, read_request(3, 0, 1));
  const uint16_t one[] = {5};
  Bytes rp = rtu_frame(1, read_registers_reply(3, one));
  std::string log = "# a sniffer's log\n";
  log += "2026-01-01T00:00:00.000000Z line rx " + to_hex(rq) + "\n";
  log += "2026-01-01T00:00:00.020000Z line tx " + to_hex(rp) + " | reply\n";   // 20 ms later: fine
  log += "2026-01-01T00:00:00.025000Z line rx " + to_hex(rq) + "\n";            // 5 ms after its end minus 4.6 ms on the wire: too close
  log += "2026-01-01T00:00:00.040000Z line -- no reply\n";
  log += "garbage line\n";
  Options o;
  o.judge.baud = 19200;
  Result r = check(Bytes(log.begin(), log.end()), o);
  EXPECT_EQ(r.stats.format, "serial log");
  EXPECT_EQ(r.coverage.requests, 2u);
  EXPECT_EQ(r.coverage.exchanges, 1u);
  EXPECT_EQ(r.finding_count, 1u);  // the garbage line
  EXPECT_EQ(find_case(r, "/capture/timing/t3.5")->outcome, Outcome::fail);
  EXPECT_EQ(find_case(r, "/capture/timing/t3.5")->level, Level::should);
  EXPECT_EQ(find_case(r, "/capture/timing/latency")->outcome, Outcome::pass);
  EXPECT_EQ(find_case(r, "/capture/timing/t1.5")->outcome, Outcome::skip);
}

TEST(SerialLog, TimeFormats) {
  EXPECT_EQ(parse_log_time("1.5"), 1500000u);
  EXPECT_EQ(parse_log_time("1970-01-01T00:00:01.000002Z"), 1000002u);
  EXPECT_FALSE(parse_log_time("1970-01-01 00:00:01"));
  EXPECT_FALSE(parse_log_time("abc"));
  EXPECT_FALSE(parse_log_time("1."));
}

TEST(PcapTap, ARunsFramesReadBack) {
  std::string path = testing::TempDir() + "/tap.pcapng";
  {
    auto t = tap_pcap(open_target("ref:modbus-standard?unit=1"), path);
    Reply a = t->transact(1, read_request(3, 0, 2));
    Reply b = t->transact(1, read_request(3, 0x0100, 1));
    ASSERT_FALSE(a.silent());
    ASSERT_FALSE(b.silent());
  }
  Result r = check_capture(path, standard(), {});
  EXPECT_EQ(r.stats.error, "");
  EXPECT_EQ(r.stats.format, "pcapng");
  EXPECT_EQ(r.coverage.requests, 2u);
  EXPECT_EQ(r.coverage.exchanges, 2u);
  EXPECT_EQ(r.coverage.exceptions, 1u);
  EXPECT_EQ(find_case(r, "/capture/policy/unmapped_address")->outcome, Outcome::pass);
  EXPECT_EQ(find_case(r, "/capture/framing/crc")->outcome, Outcome::pass);
}

}  // namespace
}  // namespace mbc::conf::capture
