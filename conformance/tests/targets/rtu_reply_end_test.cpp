// Where the rtu:// target ends a reply (MB-SL v1.02 §2.5.1.1): as soon as
// the bytes are one whole ADU by its function code or byte count and its CRC
// (modbus/rtu.h rtu_adu_complete), else when the line falls silent; and how
// long it waits for a reply that may not come: the line time of the request
// and of the longest reply the standard gives its function code; and a reply
// to the previous request that comes in after the next one went out. The
// slave is played by this test on a real pty.
#include <gtest/gtest.h>
#include <poll.h>
#include <unistd.h>

#include <atomic>
#include <chrono>
#include <functional>
#include <mutex>
#include <thread>

#include "modbus/crc16.h"
#include "modbus/hex.h"
#include "modbus/pdu.h"
#include "modbus/rtu.h"
#include "serve/endpoint.h"
#include "targets/target.h"

namespace mbc::conf {
namespace {

using namespace std::chrono_literals;

// Bytes as the standards print them.
Bytes hex(std::string_view s) { return parse_hex(s).value(); }

// ---- the rule itself ----

TEST(RtuReplyEnd, AReplyIsCompleteAtItsLengthWithItsCrc) {
  Bytes reply = rtu_frame(1, hex("03 04 00 0A 01 02"));  // FC 03, byte count 4 (MBAP v1.1b3 §6.3)
  for (size_t n = 0; n < reply.size(); ++n)
    EXPECT_FALSE(rtu_adu_complete(std::span(reply).first(n), Direction::reply)) << "a prefix of " << n << " bytes";
  EXPECT_TRUE(rtu_adu_complete(reply, Direction::reply));

  Bytes trailing = reply;
  trailing.push_back(0x00);
  EXPECT_FALSE(rtu_adu_complete(trailing, Direction::reply)) << "trailing bytes: the silence ends that frame";
  Bytes bad_crc = reply;
  bad_crc.back() ^= 0x01;
  EXPECT_FALSE(rtu_adu_complete(bad_crc, Direction::reply)) << "a bad CRC: not a frame that ends by length";
}

TEST(RtuReplyEnd, AnExceptionIsCompleteAtFiveBytes) {
  Bytes exception = rtu_frame(1, hex("83 02"));  // MBAP v1.1b3 §7
  ASSERT_EQ(exception.size(), 5u);
  EXPECT_FALSE(rtu_adu_complete(std::span(exception).first(4), Direction::reply));
  EXPECT_TRUE(rtu_adu_complete(exception, Direction::reply));
}

TEST(RtuReplyEnd, ALengthTheFunctionCodeDoesNotFixIsNeverCompleteByLength) {
  // A user-defined code and FC 43 / MEI 14 (its objects' lengths vary): only
  // the line's silence ends them, even when the CRC of the bytes so far checks.
  EXPECT_FALSE(rtu_adu_complete(rtu_frame(1, hex("41 AA BB")), Direction::reply));
  EXPECT_FALSE(rtu_adu_complete(rtu_frame(1, hex("2B 0E 01 01 00 00 01 00 03 41 42 43")), Direction::reply));
}

TEST(RtuReplyEnd, RequestsFollowTheirOwnLayout) {
  Bytes read = rtu_frame(1, read_request(3, 0, 2));
  EXPECT_TRUE(rtu_adu_complete(read, Direction::request));
  // The same bytes as a reply: FC 03's byte count (0x00) says 5 bytes.
  EXPECT_FALSE(rtu_adu_complete(read, Direction::reply));
}

// ---- on a pty ----

// A slave on the master side of a pty. A frame ends when the line is quiet
// for 3 ms (t3.5 at 115200 baud is 1.75 ms), or at its length when more came
// behind it; a frame for unit 1 with a good CRC and at most 256 bytes is
// answered by `answer`, part by part, each part after its pause.
struct Part {
  Bytes bytes;
  std::chrono::microseconds pause{0};
};

class ScriptedSlave {
 public:
  using Answer = std::function<std::vector<Part>(const Bytes& request)>;
  explicit ScriptedSlave(Answer answer) : answer_(std::move(answer)) {
    serve::RawPty pty = serve::open_raw_pty();  // a raw line, as the master's end is
    master_ = pty.master;
    slave_ = pty.slave;
    path_ = pty.name;
    thread_ = std::thread([this] { serve(); });
  }
  ~ScriptedSlave() {
    stop_ = true;
    thread_.join();
    close(master_);
    close(slave_);
  }
  std::string uri(const std::string& params = "") const {
    return "rtu://" + path_ + "?baud=115200&parity=N&unit=1" + params;
  }
  std::atomic<int> frames{0}, answered{0};

 private:
  void serve() {
    Bytes in;
    while (!stop_) {
      pollfd p{master_, POLLIN, 0};
      int rc = poll(&p, 1, in.empty() ? 20 : 3);
      if (rc > 0) {
        uint8_t buf[512];
        ssize_t n = read(master_, buf, sizeof buf);
        if (n > 0) in.insert(in.end(), buf, buf + n);
        continue;
      }
      while (!in.empty()) {
        // Requests that came in while it was busy answering are told apart by length.
        auto n = rtu_adu_length(in, Direction::request);
        size_t take = n && *n < in.size() && crc_ok(std::span(in).first(*n)) ? *n : in.size();
        Bytes frame(in.begin(), in.begin() + ptrdiff_t(take));
        in.erase(in.begin(), in.begin() + ptrdiff_t(take));
        if (!answer(frame)) return;
      }
    }
  }
  bool answer(const Bytes& frame) {
    ++frames;
    if (frame.size() < 4 || frame.size() > kMaxRtuAdu || frame[0] != 1 || !crc_ok(frame)) return true;
    for (const Part& part : answer_(frame)) {
      std::this_thread::sleep_for(part.pause);
      if (write(master_, part.bytes.data(), part.bytes.size()) != ssize_t(part.bytes.size())) return false;
    }
    ++answered;
    return true;
  }
  Answer answer_;
  int master_ = -1, slave_ = -1;
  std::string path_;
  std::atomic<bool> stop_{false};
  std::thread thread_;
};

const Bytes kRegisterReply = rtu_frame(1, hex("03 02 12 34"));

std::vector<Part> whole(const Bytes& b) { return {{b, {}}}; }

TEST(RtuReplyEnd, AReplySplitAcrossReadsIsReadWhole) {
  ScriptedSlave slave([](const Bytes&) {
    return std::vector<Part>{{Bytes(kRegisterReply.begin(), kRegisterReply.begin() + 3), {}},
                             {Bytes(kRegisterReply.begin() + 3, kRegisterReply.end()), 2ms}};
  });
  auto target = open_target(slave.uri());
  target->set_wait(Target::Wait::reply);
  Reply r = target->transact(1, read_request(3, 0, 1));
  EXPECT_EQ(r.frame, kRegisterReply) << to_hex(r.frame);
  ASSERT_TRUE(r.pdu) << r.framing_error;
  EXPECT_EQ(*r.pdu, hex("03 02 12 34"));
}

TEST(RtuReplyEnd, ASlowReplyIsWaitedForAndReadByteByByte) {
  ScriptedSlave slave([](const Bytes&) {
    std::vector<Part> parts;
    for (size_t i = 0; i < kRegisterReply.size(); ++i) parts.push_back({Bytes{kRegisterReply[i]}, i == 0 ? 200ms : 1ms});
    return parts;
  });
  auto target = open_target(slave.uri());
  target->set_wait(Target::Wait::reply);
  Reply r = target->transact(1, read_request(3, 0, 1));
  EXPECT_EQ(r.frame, kRegisterReply) << to_hex(r.frame);
  ASSERT_TRUE(r.pdu) << r.framing_error;
  EXPECT_EQ(*r.pdu, hex("03 02 12 34"));
}

TEST(RtuReplyEnd, TrailingBytesStayInTheFrameAndOutOfTheNextExchange) {
  std::atomic<bool> garbage{true};
  ScriptedSlave slave([&](const Bytes&) {
    Bytes b = kRegisterReply;
    if (garbage.exchange(false)) b.insert(b.end(), {0xDE, 0xAD, 0xBE});
    return whole(b);
  });
  auto target = open_target(slave.uri());
  target->set_wait(Target::Wait::reply);
  Reply r = target->transact(1, read_request(3, 0, 1));
  EXPECT_EQ(r.frame.size(), kRegisterReply.size() + 3) << "the read ended at the reply's length: " << to_hex(r.frame);
  EXPECT_FALSE(r.framing_error.empty()) << "a frame with trailing bytes is not a well-formed reply";

  Reply next = target->transact(1, read_request(3, 0, 1));
  EXPECT_EQ(next.frame, kRegisterReply) << to_hex(next.frame);
  EXPECT_EQ(target->late_replies(), 0u) << "bytes of the first reply reached the second exchange";
}

TEST(RtuReplyEnd, AnExceptionReplyIsReadWhole) {
  ScriptedSlave slave([](const Bytes& req) { return whole(rtu_frame(1, Bytes{uint8_t(req[1] | 0x80), 0x02})); });
  auto target = open_target(slave.uri());
  target->set_wait(Target::Wait::reply);
  Reply r = target->transact(1, read_request(3, 0x7000, 1));
  ASSERT_TRUE(r.pdu) << r.framing_error << " " << to_hex(r.frame);
  EXPECT_EQ(*r.pdu, hex("83 02"));
}

TEST(RtuReplyEnd, AReplyOfAnUnknownFunctionCodeEndsBySilence) {
  ScriptedSlave slave([](const Bytes&) {
    Bytes reply = rtu_frame(1, hex("41 AA BB CC"));
    return std::vector<Part>{{Bytes(reply.begin(), reply.begin() + 4), {}}, {Bytes(reply.begin() + 4, reply.end()), 2ms}};
  });
  auto target = open_target(slave.uri());
  target->set_wait(Target::Wait::reply);
  Reply r = target->transact(1, hex("41 00"));
  ASSERT_TRUE(r.pdu) << r.framing_error << " " << to_hex(r.frame);
  EXPECT_EQ(*r.pdu, hex("41 AA BB CC"));
}

// A request the device may answer or leave unanswered waits for the
// longest reply the standard gives its function code: an FC 06 request for
// its 8-byte echo, an FC 03 request for its 125 registers. A frame no device
// may answer (here over-long: MB-SL v1.02 §2.4.2; also broadcast, another
// slave id, a bad CRC, a split) waits for the shortest reply, an exception,
// whatever its function code: a reply that comes anyway, later, is a late
// reply to it (late_reply_test.cpp).
TEST(RtuReplyEnd, TheSilenceWindowCoversTheLongestReplyOfTheFunctionCode) {
  ScriptedSlave slave([](const Bytes& req) {
    return whole(req.size() == 8 && req[1] == 3 && req[5] == 1 ? kRegisterReply : Bytes{});
  });
  auto target = open_target(slave.uri());
  target->set_wait(Target::Wait::reply);
  for (int i = 0; i < 20; ++i) ASSERT_TRUE(target->transact(1, read_request(3, 0, 1)).pdu) << i;
  target->set_wait(Target::Wait::window);
  auto window_after = [&](const Bytes& pdu) {
    EXPECT_TRUE(target->transact(1, pdu).silent());
    return target->silence_window();
  };
  auto write_single = window_after(hex("06 00 01 00 03"));
  auto read_125 = window_after(read_request(3, 0, 125));
  // Between them only the longest reply's characters differ: 8 and 255 bytes.
  EXPECT_NEAR(double((read_125 - write_single).count()), double(wire_time(255 - 8, 115200).count()), 2.0);

  auto over_long = [](Bytes pdu) {
    pdu.resize(267, 0x00);  // 270 bytes with slave and CRC: over the 256 of an RTU frame
    return rtu_frame(1, pdu);
  };
  auto raw_window_after = [&](const Bytes& adu) {
    EXPECT_TRUE(target->send_raw(adu, std::nullopt).silent());
    return target->silence_window();
  };
  auto forbidden_write = raw_window_after(over_long(hex("06 00 01 00 03")));
  auto forbidden_read = raw_window_after(over_long(read_request(3, 0, 125)));
  auto forbidden_unknown = raw_window_after(over_long(hex("41 00")));
  EXPECT_EQ(target->late_replies(), 0u);
  EXPECT_EQ(forbidden_read, forbidden_write);
  EXPECT_EQ(forbidden_unknown, forbidden_write);
  // The 270-byte request against the 8-byte one, and a 5-byte reply against an 8-byte one.
  EXPECT_NEAR(double((forbidden_write - write_single).count()), double((wire_time(270 - 8, 115200) - wire_time(8 - 5, 115200)).count()),
              2.0);
}

// Replies held up past their windows (a busy device or host) come in while
// a later request waits: they answer the unanswered requests, not this one,
// so they are counted late and this request gets its own reply, not a
// verdict of "wrong byte count" on an earlier one's.
TEST(RtuReplyEnd, LateRepliesToEarlierRequestsAreNotTakenForThisOnes) {
  std::atomic<int64_t> hold_us{0};
  ScriptedSlave slave([&](const Bytes& req) {
    uint16_t quantity = uint16_t(req[4] << 8 | req[5]);
    Bytes pdu{3, uint8_t(2 * quantity)};
    for (uint16_t i = 0; i < quantity; ++i) pdu.insert(pdu.end(), {0x12, uint8_t(i)});
    return std::vector<Part>{{rtu_frame(1, pdu), std::chrono::microseconds(hold_us.exchange(0))}};
  });
  auto target = open_target(slave.uri());
  target->set_wait(Target::Wait::reply);
  for (int i = 0; i < 20; ++i) ASSERT_TRUE(target->transact(1, read_request(3, 0, 1)).pdu) << i;

  // One register asked, answered 200 ms after its window closed: judged
  // silent; two registers asked while the slave still holds that reply: silent too.
  hold_us = std::chrono::duration_cast<std::chrono::microseconds>(target->silence_window() + 200ms).count();
  target->set_wait(Target::Wait::window);
  ASSERT_TRUE(target->transact(1, read_request(3, 0, 1)).silent());
  ASSERT_TRUE(target->transact(1, read_request(3, 0, 2)).silent());
  // Three registers asked: the one- and two-register replies come first.
  target->set_wait(Target::Wait::reply);
  Reply r = target->transact(1, read_request(3, 0, 3));
  ASSERT_TRUE(r.pdu) << r.framing_error << " " << to_hex(r.frame);
  EXPECT_EQ(*r.pdu, hex("03 06 12 00 12 01 12 02"));
  EXPECT_EQ(target->late_replies(), 2u);
}

// The same request twice: a late reply to the first answers the second as
// well, and is taken as its reply (the second's own is late in its turn).
TEST(RtuReplyEnd, ALateReplyThatAnswersThisRequestTooIsItsReply) {
  std::atomic<int64_t> hold_us{0};
  ScriptedSlave slave([&](const Bytes&) {
    return std::vector<Part>{{kRegisterReply, std::chrono::microseconds(hold_us.exchange(0))}};
  });
  auto target = open_target(slave.uri());
  target->set_wait(Target::Wait::reply);
  for (int i = 0; i < 20; ++i) ASSERT_TRUE(target->transact(1, read_request(3, 0, 1)).pdu) << i;
  hold_us = std::chrono::duration_cast<std::chrono::microseconds>(target->silence_window() + 100ms).count();
  target->set_wait(Target::Wait::window);
  ASSERT_TRUE(target->transact(1, read_request(3, 0, 1)).silent());
  target->set_wait(Target::Wait::reply);
  Reply r = target->transact(1, read_request(3, 0, 1));
  ASSERT_TRUE(r.pdu) << r.framing_error << " " << to_hex(r.frame);
  EXPECT_EQ(*r.pdu, hex("03 02 12 34"));
  // Read one by one, the first reply is taken as the second's and the
  // second's own is late in its turn; read together (a busy host), the first
  // is late and the second is its own. Either way one reply is late once the
  // line is quiet again, and nothing is a framing error.
  EXPECT_LE(target->late_replies(), 1u);
  // Quiet again: the slave has written both replies (on a busy host the
  // second may still be on its way when the next request goes out; that
  // case is OwedReplyAfterTheNextRequestIsLate's).
  for (int i = 0; i < 1000 && slave.answered.load() < 22; ++i) std::this_thread::sleep_for(5ms);
  ASSERT_EQ(slave.answered.load(), 22);
  Reply next = target->transact(1, read_request(3, 0, 1));
  ASSERT_TRUE(next.pdu) << next.framing_error << " " << to_hex(next.frame);
  EXPECT_EQ(target->late_replies(), 1u);
}

// As above, but the second request's own reply comes only after the next
// request, another one, went out (a slave or host held up): it answers the
// request owed, not this one, so it is late, and this request waits for its
// own, not "function code 0x03, request was 0x06" (a fuzz run on a busy host).
TEST(RtuReplyEnd, OwedReplyAfterTheNextRequestIsLate) {
  std::atomic<int64_t> hold_us{0};
  std::atomic<int> n{0};
  ScriptedSlave slave([&](const Bytes& req) {
    int i = n++;
    auto hold = std::chrono::microseconds(hold_us.exchange(0));
    if (i == 21) hold = 150ms;  // the second read's own reply: after the write went out
    if (req[1] == 6) return std::vector<Part>{{req, 30ms}};  // not read in the same chunk as the late one
    return std::vector<Part>{{kRegisterReply, hold}};
  });
  auto target = open_target(slave.uri());
  target->set_wait(Target::Wait::reply);
  for (int i = 0; i < 20; ++i) ASSERT_TRUE(target->transact(1, read_request(3, 0, 1)).pdu) << i;
  hold_us = std::chrono::duration_cast<std::chrono::microseconds>(target->silence_window() + 100ms).count();
  target->set_wait(Target::Wait::window);
  ASSERT_TRUE(target->transact(1, read_request(3, 0, 1)).silent());
  target->set_wait(Target::Wait::reply);
  Reply r = target->transact(1, read_request(3, 0, 1));  // takes the first read's reply
  ASSERT_TRUE(r.pdu) << r.framing_error << " " << to_hex(r.frame);
  EXPECT_EQ(target->late_replies(), 0u);
  Bytes write = hex("06 00 01 00 03");
  Reply w = target->transact(1, write);
  ASSERT_TRUE(w.pdu) << w.framing_error << " " << to_hex(w.frame);
  EXPECT_EQ(*w.pdu, write);
  EXPECT_EQ(target->late_replies(), 1u);
  ASSERT_EQ(w.late.size(), 1u);
  EXPECT_EQ(w.late[0].frame, kRegisterReply);
  EXPECT_EQ(w.late[0].request, rtu_frame(1, read_request(3, 0, 1)));
}

// Both replies in one read while the first request is unanswered: the first
// frame is that one's late reply, the second this request's.
TEST(RtuReplyEnd, TwoRepliesReadTogetherAreTheLateOneThenThisOne) {
  std::atomic<int> n{0};
  ScriptedSlave slave([&](const Bytes&) {
    int i = n++;
    if (i == 20) return std::vector<Part>{};  // the first read of the pair goes unanswered for now
    if (i == 21) {  // the late reply and this one, in one write: one read takes both
      Bytes both = kRegisterReply;
      both.insert(both.end(), kRegisterReply.begin(), kRegisterReply.end());
      return std::vector<Part>{{both, std::chrono::microseconds(0)}};
    }
    return std::vector<Part>{{kRegisterReply, std::chrono::microseconds(0)}};
  });
  auto target = open_target(slave.uri());
  target->set_wait(Target::Wait::reply);
  for (int i = 0; i < 20; ++i) ASSERT_TRUE(target->transact(1, read_request(3, 0, 1)).pdu) << i;
  target->set_wait(Target::Wait::window);
  ASSERT_TRUE(target->transact(1, read_request(3, 0, 1)).silent());
  target->set_wait(Target::Wait::reply);
  Reply r = target->transact(1, read_request(3, 0, 1));
  ASSERT_TRUE(r.pdu) << r.framing_error << " " << to_hex(r.frame);
  EXPECT_EQ(*r.pdu, hex("03 02 12 34"));
  EXPECT_EQ(target->late_replies(), 1u);
  ASSERT_EQ(r.late.size(), 1u);
}

// With nothing unanswered and nothing owed, a second copy of the reply in the
// same read is the device answering twice: trailing bytes, not a late reply.
TEST(RtuReplyEnd, AReplyTwiceWithNothingOwedIsTrailingBytes) {
  ScriptedSlave slave([&](const Bytes&) {
    Bytes both = kRegisterReply;
    both.insert(both.end(), kRegisterReply.begin(), kRegisterReply.end());
    return std::vector<Part>{{both, std::chrono::microseconds(0)}};
  });
  auto target = open_target(slave.uri());
  target->set_wait(Target::Wait::reply);
  Reply r = target->transact(1, read_request(3, 0, 1));
  EXPECT_FALSE(r.pdu) << to_hex(r.frame);
  EXPECT_EQ(r.frame.size(), 2 * kRegisterReply.size());
  EXPECT_TRUE(r.late.empty());
  EXPECT_EQ(target->late_replies(), 0u);
}

}  // namespace
}  // namespace mbc::conf
