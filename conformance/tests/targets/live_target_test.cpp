// The live targets (tcp://, rtu-tcp://, rtu:// on a pty) against a real
// `mbconform serve` child process serving modbus-standard. What a reply must
// hold comes from the spec (defaults, exception policy) and the standard
// (silence for a foreign slave, a CRC error, a frame split by a gap).
#include <fmt/core.h>
#include <gtest/gtest.h>

#include <algorithm>
#include <chrono>
#include <csignal>
#include <cstdio>
#include <vector>

#include "loader.h"
#include "modbus/crc16.h"
#include "modbus/judge.h"
#include "modbus/pdu.h"
#include "modbus/rtu.h"
#include "serve_process.h"
#include "spec_registers.h"
#include "targets/target.h"

namespace mbc::conf {
namespace {

using namespace std::chrono_literals;
using serve_test::ServeProcess;
using serve_test::TempDir;

constexpr const char* kDevice = "modbus-standard";

struct Served {
  spec::Spec spec = spec::load_spec_by_id(kDevice);
  uint8_t slave = uint8_t(spec.serial.slave_default.value_or(1));
  TempDir dir;
  std::unique_ptr<ServeProcess> serve;

  Served() {
    serve = std::make_unique<ServeProcess>(std::vector<std::string>{
        "--device", fmt::format("{}@{}", kDevice, slave), "--tcp", "127.0.0.1:0", "--rtu-tcp", "127.0.0.1:0", "--pty",
        dir / "tty"});
    if (!serve->wait_listening(3)) throw std::runtime_error("serve did not start: " + serve->log());
  }
  std::string uri(const std::string& kind) const {
    // parity=N: a pty has no parity bit, and glibc's tcsetattr fails with
    // EINVAL when nothing it was asked to change could be changed (a second
    // open of a pty already set to the same line).
    if (kind == "pty") return fmt::format("rtu://{}?baud={}&parity=N&unit={}", serve->endpoint("pty")->address,
                                          spec.serial.baud_default.value_or(19200), slave);
    return fmt::format("{}://{}?unit={}", kind, serve->endpoint(kind)->address, slave);
  }
  // A word whose default the spec states, and a writable word.
  const spec::Register& default_word() const { return *serve_test::pick_default_word(spec); }
  const spec::Register& rw_word() const {
    auto* r = serve_test::pick_rw(spec);
    return r ? *r : *serve_test::pick_rw_word(spec);
  }
  uint8_t read_fc(const spec::Register& r) const { return r.table == spec::Table::input ? 4 : 3; }
  // A slave id inside the allowed range that nobody on this bus has.
  uint8_t foreign_slave() const { return uint8_t(slave == spec.serial.slave_max ? slave - 1 : slave + 1); }
};

class LiveTarget : public ::testing::TestWithParam<std::string> {
 protected:
  Served served;
  std::unique_ptr<Target> target = open_target(served.uri(GetParam()));
  bool rtu() const { return target->info().framing == &mbc::kRtu; }
};

TEST_P(LiveTarget, InfoDescribesTheLink) {
  const TargetInfo& i = target->info();
  EXPECT_TRUE(i.live);
  EXPECT_TRUE(i.raw);
  EXPECT_FALSE(i.power_cycle);
  EXPECT_FALSE(i.virtual_clock);
  EXPECT_EQ(i.unit, served.slave);
  EXPECT_EQ(i.framing, GetParam() == "tcp" ? &mbc::kTcp : &mbc::kRtu);
  EXPECT_EQ(i.baud.has_value(), GetParam() == "pty");
  // What `run --plan` takes for this kind before opening it is what the
  // opened target says.
  EXPECT_EQ(framing_of(i.kind), i.framing);
  EXPECT_EQ(is_live(i.kind), i.live);
  EXPECT_EQ(kind_of_uri(parse_uri(i.uri), i.uri), i.kind);
  EXPECT_THROW(target->power_cycle(), std::logic_error);
  EXPECT_THROW(target->advance(1ms), std::logic_error);
  // Reopening the normalised URI gives the same link.
  EXPECT_EQ(open_target(i.uri)->info().uri, i.uri);
}

TEST_P(LiveTarget, ReadsTheDefaultTheSpecStates) {
  const auto& r = served.default_word();
  Bytes req = read_request(served.read_fc(r), r.address, 1);
  Reply reply = target->transact(req);
  ASSERT_TRUE(reply.pdu) << reply.framing_error << " frame " << to_hex(reply.frame);
  Judged j = judge_reply(req, *reply.pdu);
  ASSERT_TRUE(j.ok()) << describe_pdu(*reply.pdu, false);
  ASSERT_EQ(j.registers.size(), 1u);
  EXPECT_EQ(j.registers[0], uint16_t(int64_t(*r.default_value) & 0xFFFF));
  // The frame is kept as received, the request as sent on the wire.
  if (rtu()) {
    EXPECT_EQ(reply.request, rtu_frame(served.slave, req));
    EXPECT_TRUE(crc_ok(reply.frame));
    EXPECT_EQ(reply.frame[0], served.slave);
  } else {
    ASSERT_GE(reply.request.size(), 7u + req.size());
    EXPECT_EQ(Bytes(reply.frame.begin(), reply.frame.begin() + 2), Bytes(reply.request.begin(), reply.request.begin() + 2));
  }
  EXPECT_GT(reply.latency.count(), 0);
}

TEST_P(LiveTarget, WritesAndReadsBack) {
  const auto& r = served.rw_word();
  uint16_t value = r.range ? serve_test::word_other_than_default(r) : uint16_t(int64_t(r.default_value.value_or(0)) + 1);
  Bytes write = write_single_register(r.address, value);
  Reply w = target->transact(write);
  ASSERT_TRUE(w.pdu) << w.framing_error;
  EXPECT_EQ(*w.pdu, write);  // FC 06 echoes the request (MBAP v1.1b3 §6.6)
  Bytes read = read_request(3, r.address, 1);
  Reply back = target->transact(read);
  ASSERT_TRUE(back.pdu) << back.framing_error;
  Judged j = judge_reply(read, *back.pdu);
  ASSERT_EQ(j.registers.size(), 1u);
  EXPECT_EQ(j.registers[0], value);
}

// MB-SL v1.02 §2.2 / MB TCP §4.4.1.1: a request for another slave id gets no
// reply, and the link stays usable.
TEST_P(LiveTarget, ForeignSlaveIsSilentAndTheNextExchangeWorks) {
  const auto& r = served.default_word();
  Bytes req = read_request(served.read_fc(r), r.address, 1);
  Reply foreign = target->transact(served.foreign_slave(), req);
  EXPECT_TRUE(foreign.silent()) << to_hex(foreign.frame);
  EXPECT_FALSE(foreign.pdu);
  Reply ok = target->transact(req);
  EXPECT_TRUE(ok.pdu) << ok.framing_error;
}

// Target::transact_all: on Modbus TCP the requests go out together and each
// reply is paired with its request by transaction id; elsewhere one after
// another. Either way a request nobody answers (a slave id nobody on the bus
// has, MB-SL v1.02 §2.1) is silent and the ones after it get their own replies.
TEST_P(LiveTarget, TransactAllPairsEachReplyWithItsRequest) {
  EXPECT_EQ(target->pipelines(), GetParam() == "tcp");
  const auto& r = served.default_word();
  Bytes read = read_request(served.read_fc(r), r.address, 1);
  const Bytes unlisted{0x41};  // a function code modbus-standard does not list: its policy's exception
  auto policy = served.spec.profile.policy(spec::Violation::unsupported_function);
  ASSERT_EQ(policy.kind, spec::PolicyEntry::Kind::exception);
  target->set_wait(Target::Wait::window);
  std::vector<Target::Request> requests{
      {served.slave, read}, {served.foreign_slave(), read}, {served.slave, unlisted}, {served.slave, read}};
  std::vector<Reply> replies = target->transact_all(requests, 4);
  ASSERT_EQ(replies.size(), 4u);
  for (size_t i : {size_t(0), size_t(3)}) {
    ASSERT_TRUE(replies[i].pdu) << i << ": " << replies[i].framing_error << " " << to_hex(replies[i].frame);
    Judged j = judge_reply(read, *replies[i].pdu);
    ASSERT_TRUE(j.ok() && j.registers.size() == 1) << i << ": " << describe_pdu(*replies[i].pdu, false);
    EXPECT_EQ(j.registers[0], uint16_t(int64_t(*r.default_value) & 0xFFFF)) << i;
  }
  EXPECT_TRUE(replies[1].silent()) << to_hex(replies[1].frame);
  ASSERT_TRUE(replies[2].pdu) << replies[2].framing_error;
  EXPECT_EQ(*replies[2].pdu, (Bytes{0xC1, uint8_t(policy.code)}));
  for (const auto& rep : replies) EXPECT_FALSE(rep.request.empty());
}

// MB-SL v1.02 §2.5.1.2: a frame with a wrong CRC is discarded; what the spec
// says the device does decides what the test expects.
TEST_P(LiveTarget, RawFrameWithBadCrcFollowsThePolicy) {
  if (!rtu()) GTEST_SKIP() << "Modbus TCP has no CRC";
  const auto& r = served.default_word();
  Bytes adu = rtu_frame(served.slave, read_request(served.read_fc(r), r.address, 1));
  adu.back() ^= 0xFF;
  Reply reply = target->send_raw(adu);
  EXPECT_EQ(reply.request, adu);
  auto policy = served.spec.profile.policy(spec::Violation::crc_error);
  ASSERT_EQ(policy.kind, spec::PolicyEntry::Kind::silent) << "the test assumes the spec's crc_error policy";
  EXPECT_TRUE(reply.silent()) << to_hex(reply.frame);
}

// MB-SL v1.02 §2.5.1.1: a silence of more than t1.5 inside a frame makes it
// incomplete: the receiver discards both parts, so no reply; the next
// well-formed request still gets one.
TEST_P(LiveTarget, FrameSplitByAGapIsNotAnswered) {
  const auto& r = served.default_word();
  Bytes pdu = read_request(served.read_fc(r), r.address, 1);
  if (!rtu()) {
    // MB TCP frames by the MBAP length, never by timing: the split frame is answered.
    Bytes adu{0x12, 0x34, 0, 0, 0, uint8_t(1 + pdu.size()), served.slave};
    adu.insert(adu.end(), pdu.begin(), pdu.end());
    Reply reply = target->send_raw(adu, 3);
    ASSERT_TRUE(reply.pdu) << reply.framing_error << " " << to_hex(reply.frame);
    EXPECT_EQ(reply.frame[0], 0x12);  // the transaction id echoed (MB TCP §3.1.3)
    EXPECT_EQ(reply.frame[1], 0x34);
    return;
  }
  Bytes adu = rtu_frame(served.slave, pdu);
  Reply reply = target->send_raw(adu, 3);
  EXPECT_TRUE(reply.silent()) << to_hex(reply.frame);
  Reply whole = target->send_raw(adu);
  EXPECT_TRUE(whole.pdu) << whole.framing_error;
}

// A truncated frame fails its CRC (RTU, MB-SL v1.02 §2.5.1.2) or never
// completes its MBAP length (TCP): no reply either way; then the link works.
TEST_P(LiveTarget, TruncatedFrameIsNotAnswered) {
  const auto& r = served.default_word();
  Bytes pdu = read_request(served.read_fc(r), r.address, 1);
  Reply ok = target->transact(pdu);
  ASSERT_TRUE(ok.pdu);
  Bytes adu = ok.request;
  adu.pop_back();
  EXPECT_TRUE(target->send_raw(adu).silent());
  if (!rtu()) return;  // the server still waits for the missing byte: the next request completes garbage
  Reply again = target->transact(pdu);
  EXPECT_TRUE(again.pdu) << again.framing_error;
}

// MB TCP: a server drops a connection whose MBAP length cannot be right
// (serve does); the target reconnects for the next exchange.
TEST_P(LiveTarget, ReconnectsAfterTheServerClosedTheConnection) {
  if (rtu()) GTEST_SKIP() << "MBAP only";
  Bytes bogus{0x00, 0x07, 0x00, 0x00, 0x00, 0x00, served.slave};  // length 0: not even a unit id
  Reply dropped = target->send_raw(bogus);
  EXPECT_TRUE(dropped.silent()) << to_hex(dropped.frame);
  const auto& r = served.default_word();
  Reply ok = target->transact(read_request(served.read_fc(r), r.address, 1));
  EXPECT_TRUE(ok.pdu) << ok.framing_error;
}

// A fresh target on a live link (the fuzzer's reductions and its rounds
// after a finding: Session::restart) is the link opened again: a new
// socket, or the serial line (here a pty) opened again.
TEST_P(LiveTarget, OpensAgainForAFreshStart) {
  const auto& r = served.default_word();
  Bytes pdu = read_request(served.read_fc(r), r.address, 1);
  ASSERT_TRUE(target->transact(pdu).pdu);
  ASSERT_TRUE(target->reconnect());
  Reply again = target->transact(pdu);
  EXPECT_TRUE(again.pdu) << again.framing_error << " " << to_hex(again.frame);
}

TEST_P(LiveTarget, RawWellFormedFrameIsAnsweredLikeTransact) {
  const auto& r = served.default_word();
  Bytes pdu = read_request(served.read_fc(r), r.address, 1);
  Reply a = target->transact(pdu);
  Bytes adu = rtu() ? rtu_frame(served.slave, pdu) : a.request;
  Reply b = target->send_raw(adu);
  ASSERT_TRUE(a.pdu && b.pdu) << a.framing_error << b.framing_error;
  EXPECT_EQ(*a.pdu, *b.pdu);
}

// MB-SL v1.02 §2.1 / spec broadcast: a broadcast write gets no reply, and it
// is applied when the spec says so. On Modbus TCP a server reached directly
// (one device served) takes unit 0 as addressed to itself and answers
// (Implementation Guide V1.0b §4.4.1.2).
TEST_P(LiveTarget, BroadcastWriteIsSilent) {
  if (!served.spec.serial.broadcast_address) GTEST_SKIP();
  const auto& r = served.rw_word();
  uint16_t value = r.range ? serve_test::word_other_than_default(r) : uint16_t(int64_t(r.default_value.value_or(0)) + 2);
  Bytes write = write_single_register(r.address, value);
  Reply b = target->transact(uint8_t(*served.spec.serial.broadcast_address), write);
  if (!rtu()) {
    ASSERT_TRUE(b.pdu) << "unit 0 on Modbus TCP got no answer";
    EXPECT_EQ(*b.pdu, write) << "FC 06 echo";
    return;
  }
  EXPECT_TRUE(b.silent()) << to_hex(b.frame);
  if (served.spec.serial.broadcast_writes != "applied" || !rtu()) return;
  Bytes read = read_request(3, r.address, 1);
  Reply back = target->transact(read);
  ASSERT_TRUE(back.pdu);
  EXPECT_EQ(judge_reply(read, *back.pdu).registers, std::vector<uint16_t>{value});
}

// The silence window starts at the configured timeout and, once replies were
// timed, shrinks to a margin over their latency (never asserted as a
// duration: only its relation to the timeout and to the latencies seen). On
// the pty the margin is over the excess above each exchange's line time.
TEST_P(LiveTarget, SilenceWindowAdaptsToMeasuredLatency) {
  auto before = target->silence_window();
  EXPECT_EQ(before, 1000ms);
  const auto& r = served.default_word();
  Bytes req = read_request(served.read_fc(r), r.address, 1);
  constexpr int kExchanges = 200;
  std::vector<int64_t> lat;
  auto wall0 = std::chrono::steady_clock::now();
  for (int i = 0; i < kExchanges; ++i) {
    Reply reply = target->transact(req);
    ASSERT_TRUE(reply.pdu) << i << ": " << reply.framing_error;
    lat.push_back(reply.latency.count());
  }
  auto wall = std::chrono::duration_cast<std::chrono::microseconds>(std::chrono::steady_clock::now() - wall0);
  std::sort(lat.begin(), lat.end());
  auto after = target->silence_window();
  EXPECT_LE(after, before);
  int64_t p99 = lat[lat.size() * 99 / 100 - 1];
  if (rtu() && target->info().baud)
    EXPECT_GT(after.count(), p99);  // the line time plus a margin, not below p99
  else
    EXPECT_GE(after.count(), 4 * p99 / 2);  // a multiple of p99, not below it
  std::printf("[latency] %s: %d exchanges: median %lld us, p99 %lld us, max %lld us; wall %lld us per exchange; silence window %lld us\n",
              GetParam().c_str(), kExchanges, (long long)lat[lat.size() / 2], (long long)lat[lat.size() * 99 / 100],
              (long long)lat.back(), (long long)(wall.count() / kExchanges), (long long)after.count());
}

INSTANTIATE_TEST_SUITE_P(Serve, LiveTarget, ::testing::Values("tcp", "rtu-tcp", "pty"),
                         [](const auto& p) { return p.param == "rtu-tcp" ? std::string("rtu_tcp") : p.param; });

TEST(LiveTargetUri, RejectsBadUris) {
  for (const char* bad : {"tcp://", "tcp://127.0.0.1:1502?unit=0", "tcp://127.0.0.1:1502?unit=256",
                          "tcp://127.0.0.1:1502?colour=red", "tcp://127.0.0.1:99999", "rtu-tcp://127.0.0.1",
                          "rtu://", "rtu:///dev/null?parity=X", "rtu:///dev/null?baud=fast", "rtu:///dev/null?data=9",
                          "rtu:///dev/null?stop=3", "rtu:///dev/null?unit=248", "rtu:///dev/null?timeout=0"}) {
    EXPECT_THROW(open_target(bad), std::invalid_argument) << bad;
  }
}

TEST(LiveTargetUri, CannotConnectNamesTheUri) {
  // A port nothing listens on: bind one, read its number, close it.
  ServeProcess probe({"--device", std::string(kDevice) + "@1", "--tcp", "127.0.0.1:0"});
  ASSERT_TRUE(probe.wait_listening(1));
  int port = probe.endpoint("tcp")->port();
  probe.stop(SIGTERM);
  for (std::string uri : {fmt::format("tcp://127.0.0.1:{}?timeout=500", port),
                          fmt::format("rtu-tcp://127.0.0.1:{}?timeout=500", port), std::string("rtu:///nonexistent/tty0")}) {
    try {
      open_target(uri);
      ADD_FAILURE() << uri << " opened";
    } catch (const std::runtime_error& e) {
      EXPECT_NE(std::string(e.what()).find(uri.substr(0, uri.find('?'))), std::string::npos) << e.what();
    }
  }
}

}  // namespace
}  // namespace mbc::conf
