// The one path of every command's frames: the frame policy, then the
// journal, then the one Link (the Session), through check::Exchange. The
// fuzzer and the properties send this way (issue 35, "one seam"); these are
// the behaviours the Session's old Target view carried, held on that path:
// a refusal and a stop surface as Refused and Stopped, a pipelined batch on
// Modbus TCP passes the policy and the journal request by request before it
// goes out, in-process targets advance, power-cycle and start afresh, a live
// one reconnects.
#include <gtest/gtest.h>
#include <fmt/core.h>

#include <chrono>
#include <fstream>
#include <sstream>

#include "blackbox/engine.h"
#include "check/exchange.h"
#include "loader.h"
#include "modbus/pdu.h"
#include "policy/policy.h"
#include "properties/properties.h"
#include "serve_process.h"
#include "session/session.h"

namespace mbc::conf {
namespace {

using serve_test::ServeProcess;
using serve_test::TempDir;

std::string read_all(const std::string& path) {
  std::ifstream f(path);
  std::stringstream ss;
  ss << f.rdbuf();
  return ss.str();
}

// The first holding register hsc60's spec lets a live command write with no
// opt-in (the policy's own answer), and one it never lets out.
const spec::Register* writable(const spec::Spec& s, const PolicyFacts& f) {
  for (const auto& r : s.registers)
    if (r.table == spec::Table::holding && r.access == spec::Access::rw && !r.command && r.words == 1 && allowed_write(f, r))
      return &r;
  return nullptr;
}

class OnePathLive : public ::testing::Test {
 protected:
  void SetUp() override {
    ASSERT_TRUE(server_.wait_listening(1)) << server_.log();
    uri_ = fmt::format("tcp://127.0.0.1:{}?unit=1", server_.endpoint("tcp")->port());
  }
  SessionOptions options() {
    SessionOptions o;
    o.command = "test";
    o.out_dir = out_.path();
    return o;
  }
  spec::Spec spec_ = spec::load_spec_by_id("hsc60");
  ServeProcess server_{{"--device", "hsc60@1", "--tcp", "127.0.0.1:0"}};
  TempDir out_;
  std::string uri_;
};

// Modbus TCP pipelines: a batch whose every request the policy allows goes
// out at once, and the write in it was journaled (its value read first)
// before the batch went out. A batch with a refused request (a broadcast
// write, no opt-in) goes one by one up to it: the refusal is that request's,
// and what follows it is not sent.
TEST_F(OnePathLive, APipelinedBatchPassesThePolicyAndTheJournalBeforeItGoesOut) {
  Session session(uri_, &spec_, options());
  ASSERT_TRUE(session.pipelines());
  const spec::Register* r = writable(spec_, session.policy_facts());
  ASSERT_NE(r, nullptr);
  check::Exchange x(session);
  std::vector<check::Step> batch = {check::frame(session.info().framing, 1, read_request(3, r->address, 1)),
                                    check::frame(session.info().framing, 1, write_single_register(r->address, 7)),
                                    check::frame(session.info().framing, 1, read_request(3, r->address, 1))};
  auto sent = x.send_all(batch, 16, Target::Wait::reply);
  ASSERT_EQ(sent.size(), 3u);
  for (const auto& s : sent) {
    EXPECT_FALSE(s.refused);
    EXPECT_TRUE(s.reply.pdu);
  }
  EXPECT_EQ(session.frames(), 3u);
  EXPECT_EQ(x.counters().frames_sent, 3u);
  // The journal holds the register's value from before the batch.
  EXPECT_NE(read_all(session.journal_path()).find(fmt::format("orig holding 0x{:04X} 1", r->address)), std::string::npos)
      << read_all(session.journal_path());

  std::vector<check::Step> refused = {check::frame(session.info().framing, 1, read_request(3, r->address, 1)),
                                      check::frame(session.info().framing, 0, write_single_register(r->address, 8)),
                                      check::frame(session.info().framing, 1, read_request(3, r->address, 1))};
  sent = x.send_all(refused, 16, Target::Wait::reply);
  ASSERT_EQ(sent.size(), 2u) << "the request after the refused one went out";
  EXPECT_FALSE(sent[0].refused);
  ASSERT_TRUE(sent[1].refused);
  EXPECT_FALSE(sent[1].stopped);
  EXPECT_EQ(session.frames(), 4u);
  EXPECT_EQ(session.refused(), 1u);
  session.restore();
}

// A refused frame surfaces as it did through the old view: Refused (a
// logic_error) to the properties, which discard the case, and a
// target-error finding naming the policy to the fuzzer; nothing is sent.
TEST_F(OnePathLive, ARefusedFrameIsRefusedToThePropertiesAndTheFuzzer) {
  Session session(uri_, &spec_, options());
  const spec::Register* r = writable(spec_, session.policy_facts());
  ASSERT_NE(r, nullptr);
  props::SpecView view(spec_, session.info(), {});
  props::Session s(session, view, nullptr);
  EXPECT_THROW(s.send_to(0, write_single_register(r->address, 1)), Refused);
  EXPECT_TRUE(s.steps().empty());
  EXPECT_EQ(session.frames(), 0u);

  blackbox::Plan plan = blackbox::make_plan(spec_, session.info(), {});
  check::Exchange x(session);
  check::Step bc = check::frame(session.info().framing, 0, write_single_register(r->address, 1));
  auto f = blackbox::execute(x, plan, bc);
  ASSERT_TRUE(f);
  EXPECT_EQ(f->kind, blackbox::FindingKind::target_error);
  EXPECT_NE(f->message.find("refused by the frame policy"), std::string::npos) << f->message;
  EXPECT_EQ(session.frames(), 0u);
  // The same read goes out and is answered.
  EXPECT_TRUE(s.send(read_request(3, r->address, 1)).pdu);
  EXPECT_EQ(session.frames(), 1u);
  session.restore();
}

// A live target reconnects through the session, and starts afresh by
// reconnecting (its registers are the drive's: nothing is reset).
TEST_F(OnePathLive, RestartReconnectsALiveTarget) {
  Session session(uri_, &spec_, options());
  check::Exchange x(session);
  EXPECT_TRUE(session.reconnect());
  EXPECT_TRUE(x.transact(read_request(3, 0, 1)).pdu);
  EXPECT_NO_THROW(session.restart());
  EXPECT_TRUE(x.transact(read_request(3, 0, 1)).pdu);
  EXPECT_EQ(session.late_replies(), 0u);
}

// After the deadline (a stop) every frame is refused as stopped, and the
// properties and the fuzzer see Stopped, never Refused; advance,
// power_cycle, trip_fault and restart throw Stopped too.
TEST(OnePath, AfterAStopEveryFrameAndStepThrowsStopped) {
  spec::Spec spec = spec::load_spec_by_id("hsc60");
  SessionOptions o;
  o.command = "test";
  o.deadline = std::chrono::steady_clock::now() - std::chrono::seconds(1);
  Session session("ref:hsc60", &spec, o);
  Sent sent = session.transact(1, read_request(3, 0, 1), Target::Wait::reply);
  ASSERT_TRUE(sent.refused);
  EXPECT_TRUE(sent.stopped);
  props::SpecView view(spec, session.info(), {});
  props::Session s(session, view, nullptr);
  EXPECT_THROW(s.send(read_request(3, 0, 1)), Stopped);
  EXPECT_THROW(s.advance(1000), Stopped);
  EXPECT_THROW(s.power_cycle(), Stopped);
  EXPECT_THROW(s.target().trip_fault(), Stopped);
  EXPECT_THROW(session.restart(), Stopped);
  EXPECT_EQ(session.frames(), 0u);
}

// In process: the properties' steps go through the session, the clock
// advances and the power cycles, and restart() gives a target at power-on
// (a value written before it is gone; the property cases start there).
TEST(OnePath, AnInProcessTargetAdvancesPowerCyclesAndStartsAfresh) {
  spec::Spec spec = spec::load_spec_by_id("hsc60");
  SessionOptions o;
  o.command = "test";
  Session session("ref:hsc60", &spec, o);
  ASSERT_TRUE(session.info().virtual_clock);
  ASSERT_TRUE(session.info().power_cycle);
  const spec::Register* r = writable(spec, session.policy_facts());
  ASSERT_NE(r, nullptr);
  props::SpecView view(spec, session.info(), {});
  props::Session s(session, view, nullptr);
  auto read = [&] {
    Reply got = s.send(read_request(3, r->address, 1));
    return got.pdu && got.pdu->size() == 4 ? std::optional<uint16_t>(uint16_t((*got.pdu)[2] << 8 | (*got.pdu)[3])) : std::nullopt;
  };
  auto before = read();
  ASSERT_TRUE(before);
  const uint16_t other = uint16_t(*before == 1 ? 2 : 1);
  ASSERT_TRUE(s.send(write_single_register(r->address, other)).pdu);
  ASSERT_EQ(read(), other);
  s.advance(100'000);
  EXPECT_EQ(s.steps().back().kind, props::Step::Kind::advance);
  s.power_cycle();
  EXPECT_EQ(s.steps().back().kind, props::Step::Kind::power_cycle);
  EXPECT_EQ(session.frames(), 3u);  // advance and power_cycle send no frame
  ASSERT_EQ(s.steps().size(), 5u);
  session.restart();
  EXPECT_EQ(read(), before) << "restart() did not give a target at power-on";
}

}  // namespace
}  // namespace mbc::conf
