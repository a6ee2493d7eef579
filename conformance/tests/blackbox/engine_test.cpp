// The black-box fuzzer's engine (conformance/blackbox/engine.h): its
// generator, its judge and its reducer. Expected outcomes come from the
// Modbus standard and the specs, written out by hand below.
#include <gtest/gtest.h>

#include <algorithm>
#include <random>
#include <set>
#include <thread>

#include "blackbox/engine.h"
#include "modbus/crc16.h"
#include "loader.h"
#include "modbus/pdu.h"
#include "modbus/rtu.h"
#include "targets/target.h"

namespace mbc::conf::blackbox {
namespace {

using K = check::Expect::Kind;

// A target as an RTU drive on a live line would present itself.
TargetInfo live_rtu(uint8_t unit) {
  TargetInfo i;
  i.uri = "rtu:///dev/null";
  i.kind = conf::TargetKind::rtu;
  i.framing = &mbc::kRtu;
  i.unit = unit;
  i.live = true;
  i.raw = true;
  return i;
}

// ---- generator ----

// On a live drive the generator never writes the serial settings the spec
// lists (57HS-R §6.1: 0x0014 baud rate, 0x0015 slave id), never sends a
// write to another slave id or to broadcast, and sends raw frames only on a
// target that can; each step expects what MB-SL v1.02 §2.1 gives it.
TEST(Generator, LiveDriveStaysSafeAndExpectsWhatTheStandardSays) {
  spec::Spec s = spec::load_spec_by_id("sihong-57hs-r");
  ASSERT_FALSE(s.serial.settings.empty());
  std::set<uint16_t> settings;
  for (const auto& st : s.serial.settings) settings.insert(st.register_address);
  Plan p = make_plan(s, live_rtu(1), WritePolicy{});
  Generator gen(p, 42);
  int writes = 0, raws = 0, silences = 0;
  for (int i = 0; i < 20000; ++i) {
    Step st = gen.next();
    ASSERT_NE(st.kind, Step::Kind::advance) << "a live drive has no virtual clock";
    Bytes pdu;
    uint8_t unit = 1;
    if (st.kind == Step::Kind::raw) {
      ++raws;
      // A frame not addressed to unit 1 must get no reply (MB-SL v1.02 §2.1).
      if (st.bytes[0] != 1) {
        EXPECT_EQ(st.expect.kind, K::silence) << check::line(st);
      }
      // A frame with a bad CRC must get none either (§2.4.2: the 57HS-R is silent on CRC errors).
      if (st.bytes[0] == 1 && !st.gap && !crc_ok(st.bytes)) {
        EXPECT_EQ(st.expect.kind, K::silence) << check::line(st);
      }
      silences += st.expect.kind == K::silence;
      if (st.bytes.size() < 4 || !crc_ok(st.bytes) || st.gap) continue;
      unit = st.bytes[0];
      pdu.assign(st.bytes.begin() + 1, st.bytes.end() - 2);
    } else {
      ASSERT_EQ(st.kind, Step::Kind::frame);
      EXPECT_LE(st.pdu.size(), 253u);  // MBAP v1.1b3 §4.1
      // A fuzzed request may be dropped; a reply must be well formed.
      EXPECT_EQ(st.expect.kind, K::any_or_silence);
      pdu = st.pdu;
    }
    if (pdu.size() < 5) continue;
    if (pdu[0] == 6 || pdu[0] == 16) {
      ++writes;
      EXPECT_EQ(unit, 1) << "a write to another drive or to broadcast: " << check::line(st);
      // What a receiver can take: at most the standard's 123 registers (MBAP v1.1b3 §6.12), up to 0xFFFF.
      uint16_t start = be16(pdu, 1), count = pdu[0] == 6 ? 1 : std::min<uint16_t>(be16(pdu, 3), 123);
      for (uint32_t a = start; a < uint32_t(start) + count && a <= 0xFFFF; ++a) {
        EXPECT_FALSE(settings.count(uint16_t(a))) << "writes serial setting 0x" << std::hex << a << ": " << check::line(st);
      }
      // Every write is one the frame policy lets out (policy/policy.h).
      EXPECT_TRUE(allowed(PolicyFacts{&s, p.info, {}}, unit, pdu)) << check::line(st);
    }
  }
  EXPECT_GT(writes, 100);
  EXPECT_GT(raws, 100);
  EXPECT_GT(silences, 10);
}

TEST(Generator, SameSeedSameSteps) {
  spec::Spec s = spec::load_spec_by_id("hsc60");
  auto t = open_target("ref:hsc60");
  Plan p = make_plan(s, t->info(), WritePolicy{});
  Generator a(p, 7), b(p, 7), c(p, 8);
  bool differs = false;
  for (int i = 0; i < 500; ++i) {
    Step x = a.next(), y = b.next(), z = c.next();
    EXPECT_EQ(check::line(x), check::line(y));
    differs |= check::line(x) != check::line(z);
  }
  EXPECT_TRUE(differs);
}

// Over Modbus TCP there is no RTU framing to break: no raw RTU frames, and
// frames are printed as MBAP with an unknown transaction id.
TEST(Generator, TcpTargetGetsNoRtuBytes) {
  spec::Spec s = spec::load_spec_by_id("modbus-standard");
  TargetInfo i = live_rtu(1);
  i.kind = conf::TargetKind::tcp;
  i.framing = &mbc::kTcp;
  Plan p = make_plan(s, i, WritePolicy{});
  Generator gen(p, 3);
  for (int n = 0; n < 3000; ++n) {
    Step st = gen.next();
    ASSERT_EQ(st.kind, Step::Kind::frame) << check::line(st);
    ASSERT_EQ(check::line(st).rfind("mbap * 00 00 ", 0), 0u) << check::line(st);
  }
}

// ---- judge ----

struct JudgeTest : ::testing::Test {
  spec::Spec s = spec::load_spec_by_id("modbus-standard");
  Plan p = make_plan(s, live_rtu(1), WritePolicy{});
  Reply reply(uint8_t unit, const Bytes& pdu) {
    Reply r;
    r.frame = rtu_frame(unit, pdu);
    r.pdu = pdu;
    return r;
  }
  Step generated(Step st) {
    st.expect = expect_for(p, st);
    return st;
  }
  std::string kind(const Step& st, const Reply& r) {
    auto f = judge(p, st, r);
    return f ? to_string(f->kind) : "";
  }
};

TEST_F(JudgeTest, WellFormedRepliesAreNoFinding) {
  Step read = generated(check::frame(&mbc::kRtu, 1, {0x03, 0x00, 0x00, 0x00, 0x01}));
  EXPECT_EQ(kind(read, reply(1, {0x03, 0x02, 0x12, 0x34})), "");
  EXPECT_EQ(kind(read, reply(1, {0x83, 0x02})), "");  // MBAP v1.1b3 §7: 02 illegal data address
}

TEST_F(JudgeTest, MalformedReplyAndUnknownException) {
  Step read = generated(check::frame(&mbc::kRtu, 1, {0x03, 0x00, 0x00, 0x00, 0x01}));
  // One register asked, a byte count of 4 (MBAP v1.1b3 §6.3: 2 x N).
  EXPECT_EQ(kind(read, reply(1, {0x03, 0x04, 0x12, 0x34, 0x00, 0x00})), "malformed-reply");
  EXPECT_EQ(kind(read, reply(1, {0x83, 0x55})), "unknown-exception-code");
  Reply bad_crc = reply(1, {0x03, 0x02, 0x12, 0x34});
  bad_crc.pdu.reset();
  bad_crc.framing_error = "CRC wrong";
  EXPECT_EQ(kind(read, bad_crc), "malformed-framing");
}

TEST_F(JudgeTest, NoReplyToBroadcastOtherSlaveOrCorruptedFrame) {
  Bytes write{0x06, 0x00, 0x00, 0x00, 0x01};
  Step broadcast = generated(check::raw_rtu(rtu_frame(0, write)));
  Step other = generated(check::raw_rtu(rtu_frame(9, write)));
  Bytes corrupted = rtu_frame(1, write);
  corrupted.back() ^= 0x01;
  Step bad = generated(check::raw_rtu(corrupted));
  for (const Step* st : {&broadcast, &other, &bad}) {
    EXPECT_EQ(st->expect.kind, K::silence) << check::line(*st);
    Reply silent;
    EXPECT_EQ(kind(*st, silent), "");
  }
  EXPECT_EQ(kind(broadcast, reply(0, write)), "answered-broadcast");
  EXPECT_EQ(kind(bad, reply(1, write)), "answered-corrupted-frame");
  // A live line may hold slave 9 (MB-SL v1.02 §2.2): its reply, carrying its
  // address, is its own; the target's fault is a reply carrying the target's.
  EXPECT_EQ(kind(other, reply(9, write)), "");
  EXPECT_EQ(kind(other, reply(1, write)), "answered-other-slave");
  Reply garbled = reply(9, write);
  garbled.frame.back() ^= 0xFF;  // whose it is cannot be told: not held against the target
  garbled.pdu.reset();
  EXPECT_EQ(kind(other, garbled), "");
  EXPECT_EQ(kind(broadcast, reply(7, write)), "");  // a reply to a broadcast that names slave 7
  // Alone on its line (in process), every reply is the target's.
  TargetInfo alone = live_rtu(1);
  alone.live = false;
  Plan solo = make_plan(s, alone, WritePolicy{});
  auto f = judge(solo, other, reply(9, write));
  ASSERT_TRUE(f);
  EXPECT_EQ(f->kind, FindingKind::answered_other_slave);
}

// The finding kinds' names are stable (reports, reproducers' file names, quirks files).
TEST(FindingKinds, NamesRoundTrip) {
  std::set<std::string> names;
  for (FindingKind k : kAllFindingKinds) {
    names.insert(to_string(k));
    EXPECT_EQ(finding_kind(to_string(k)), k) << to_string(k);
  }
  EXPECT_EQ(names.size(), std::size(kAllFindingKinds));
  EXPECT_EQ(std::string(to_string(FindingKind::answered_other_slave)), "answered-other-slave");
  EXPECT_EQ(std::string(to_string(FindingKind::malformed_reply)), "malformed-reply");
  EXPECT_FALSE(finding_kind("no-such-kind"));
}

// A reply that came after its frame was judged silent (Reply::late, the
// RTU target pairs it with the frame it answers) is judged as that frame's
// reply would have been: forbidden for broadcast, another slave id or a
// corrupted frame (MB-SL v1.02 §2.1, §2.4.2); a well-formed request's late
// reply is the device's pace, and one paired with nothing says nothing.
TEST_F(JudgeTest, ALateReplyToAFrameThatHadToStaySilentIsAFinding) {
  Bytes write{0x06, 0x00, 0x00, 0x00, 0x01};
  Step read = generated(check::frame(&mbc::kRtu, 1, {0x03, 0x00, 0x00, 0x00, 0x01}));
  auto with_late = [&](const Bytes& request, uint8_t from) {
    Reply r = reply(1, {0x03, 0x02, 0x12, 0x34});
    r.late.push_back({rtu_frame(from, write), request, std::chrono::milliseconds(40)});
    return r;
  };
  Bytes corrupted = rtu_frame(1, write);
  corrupted.back() ^= 0x01;
  EXPECT_EQ(kind(read, with_late(rtu_frame(0, write), 0)), "answered-broadcast");
  EXPECT_EQ(kind(read, with_late(rtu_frame(9, write), 9)), "");  // slave 9's own reply (a live line)
  EXPECT_EQ(kind(read, with_late(rtu_frame(9, write), 1)), "answered-other-slave");
  EXPECT_EQ(kind(read, with_late(corrupted, 1)), "answered-corrupted-frame");
  EXPECT_EQ(kind(read, with_late(rtu_frame(1, write), 1)), "");
  EXPECT_EQ(kind(read, with_late({}, 0)), "");
}

TEST_F(JudgeTest, ProbeMustBeAnsweredNormally) {
  Step probe = probe_step(p);
  EXPECT_EQ(probe.expect.kind, K::normal);
  EXPECT_EQ(kind(probe, Reply{}), "no-answer");
  EXPECT_EQ(kind(probe, reply(1, {uint8_t(probe.pdu[0] | 0x80), 0x04})), "probe-refused");
}

// ---- reducer ----

// k frames that together make the failure, planted among noise: ddmin
// returns exactly those k, in their order.
TEST(Reducer, ReturnsExactlyThePlantedFrames) {
  std::mt19937 rng(1);
  for (int k = 1; k <= 5; ++k) {
    for (int trial = 0; trial < 5; ++trial) {
      std::vector<int> steps(200);
      for (int i = 0; i < 200; ++i) steps[i] = 1000 + i;  // noise
      std::vector<int> planted;
      std::set<size_t> at;
      while (at.size() < size_t(k)) at.insert(rng() % steps.size());
      for (size_t i : at) {
        steps[i] = int(i);  // below 1000: necessary
        planted.push_back(int(i));
      }
      std::function<bool(const std::vector<int>&)> fails = [&](const std::vector<int>& v) {
        return std::all_of(planted.begin(), planted.end(), [&](int x) { return std::find(v.begin(), v.end(), x) != v.end(); });
      };
      int runs = 0;
      EXPECT_EQ(ddmin<int>(steps, fails, 10000, runs), planted) << "k=" << k;
    }
  }
}

// On a device that answers broadcast writes (MB-SL v1.02 §2.1 says it must
// not): 40 reads with one broadcast write among them reduce, on fresh
// targets, to that write alone.
TEST(Reducer, RealTargetReducesToTheFrameThatFails) {
  const std::string uri = "ref:hsc60?fault=answer-broadcast";
  spec::Spec s = spec::load_spec_by_id("hsc60");
  auto t = open_target(uri);
  Plan p = make_plan(s, t->info(), WritePolicy{});
  std::vector<Step> steps;
  for (int i = 0; i < 40; ++i) {
    Step st = check::frame(&mbc::kRtu, 1, read_request(3, uint16_t(i % 4), 1));
    st.expect = expect_for(p, st);
    steps.push_back(st);
  }
  Step bc = check::raw_rtu(rtu_frame(0, write_single_register(0x0000, 1)));
  bc.expect = expect_for(p, bc);
  steps.insert(steps.begin() + 23, bc);
  DirectLink link(open_target(uri));
  Open open = [&] { link.replace(open_target(uri)); };
  auto f = run_fresh(link, open, p, steps);
  ASSERT_TRUE(f);
  ASSERT_EQ(f->kind, FindingKind::answered_broadcast);
  std::function<bool(const std::vector<Step>&)> fails = [&](const std::vector<Step>& v) {
    auto g = run_fresh(link, open, p, v);
    return g && g->kind == FindingKind::answered_broadcast;
  };
  int runs = 0;
  auto min = ddmin<Step>(steps, fails, 400, runs);
  ASSERT_EQ(min.size(), 1u);
  EXPECT_EQ(check::line(min[0]), check::line(bc));
  // The correct device does not fail it.
  DirectLink good(open_target("ref:hsc60"));
  Open correct = [&] { good.replace(open_target("ref:hsc60")); };
  EXPECT_FALSE(run_fresh(good, correct, p, min));
}

}  // namespace
}  // namespace mbc::conf::blackbox

namespace mbc::conf::blackbox {
namespace {

// Sending stops (a stop signal, fuzz's deadline) while a finding is being
// reduced: the finding is kept, as far as its reduction got, and says so.
// The session's target then cannot start afresh (Session::restart
// throws Stopped): here the first reopen stops, as the deadline would.
TEST(Reducer, AFindingWhoseReductionIsCutOffIsKeptUnreduced) {
  const std::string uri = "ref:hsc60?fault=answer-broadcast";
  spec::Spec s = spec::load_spec_by_id("hsc60");
  DirectLink first(open_target(uri));
  Plan p = make_plan(s, first.info(), WritePolicy{});
  bool stopped = false;
  Open open = [&] {
    stopped = true;
    throw std::runtime_error("sending stopped: the deadline ran out");
  };
  Options o;
  o.duration = std::chrono::milliseconds(10'000);
  o.seed = 7;
  o.stopped = [&] { return stopped; };
  std::vector<Reported> heard;
  Outcome out = fuzz(first, open, p, o, [&](const Reported& r) { heard.push_back(r); });
  ASSERT_EQ(out.findings.size(), 1u);
  ASSERT_EQ(heard.size(), 1u);
  const Reported& r = out.findings[0];
  EXPECT_EQ(r.finding.kind, FindingKind::answered_broadcast);
  EXPECT_TRUE(r.cut_off);
  EXPECT_FALSE(r.reproduced);
  // The last batch as sent, ending with the frame that was answered.
  ASSERT_FALSE(r.steps.empty());
  ASSERT_EQ(r.steps.back().kind, Step::Kind::raw);
  EXPECT_EQ(r.steps.back().bytes.at(0), 0) << check::line(r.steps.back());
  EXPECT_NE(reproducer(p, r, "replay").comment.find("reduction was cut off"), std::string::npos);
}

// Cut off after the finding reproduced on a fresh target, before ddmin
// could remove anything: those steps are kept, said to reproduce it.
TEST(Reducer, ACutOffAfterTheFindingReproducedKeepsWhatReproduces) {
  const std::string uri = "ref:hsc60?fault=answer-broadcast";
  spec::Spec s = spec::load_spec_by_id("hsc60");
  DirectLink first(open_target(uri));
  Plan p = make_plan(s, first.info(), WritePolicy{});
  int opened = 0;
  Open open = [&] {
    ++opened;
    first.replace(open_target(uri));
  };
  Options o;
  o.duration = std::chrono::milliseconds(10'000);
  o.seed = 7;
  o.stopped = [&] { return opened > 0; };  // stops as the first fresh target opens
  Outcome out = fuzz(first, open, p, o, {});
  ASSERT_EQ(out.findings.size(), 1u);
  const Reported& r = out.findings[0];
  EXPECT_TRUE(r.cut_off);
  EXPECT_TRUE(r.reproduced);
  EXPECT_EQ(opened, 1) << "runs after the stop";
  ASSERT_FALSE(r.steps.empty());
  EXPECT_EQ(r.steps.back().bytes.at(0), 0) << check::line(r.steps.back());
}

}  // namespace
}  // namespace mbc::conf::blackbox

namespace mbc::conf::blackbox {
namespace {

// A target that takes `pace` per exchange, as a slow serial line does.
class Paced final : public Target {
 public:
  Paced(std::unique_ptr<Target> inner, std::chrono::microseconds pace) : inner_(std::move(inner)), pace_(pace) {}
  const TargetInfo& info() const override { return inner_->info(); }
  Reply transact(uint8_t unit, std::span<const uint8_t> pdu) override {
    std::this_thread::sleep_for(pace_);
    return inner_->transact(unit, pdu);
  }
  Reply send_raw(std::span<const uint8_t> bytes, std::optional<size_t> gap_after) override {
    std::this_thread::sleep_for(pace_);
    return inner_->send_raw(bytes, gap_after);
  }
  void advance(std::chrono::microseconds dt) override { inner_->advance(dt); }
  void power_cycle() override { inner_->power_cycle(); }

 private:
  std::unique_ptr<Target> inner_;
  std::chrono::microseconds pace_;
};

// The deadline is looked at before each exchange, not only between batches:
// a batch of 1000 frames that take 2 ms each (2 s) stops once 500 ms ran
// out. Each exchange sleeps, so however slow the host, all 1000 cannot fit;
// 500 ms leave a slow host (ASan, under load) the time to start the batch.
TEST(Fuzz, TheDeadlineIsLookedAtBeforeEachExchange) {
  spec::Spec s = spec::load_spec_by_id("hsc60");
  DirectLink first(std::make_unique<Paced>(open_target("ref:hsc60"), std::chrono::milliseconds(2)));
  Plan p = make_plan(s, first.info(), WritePolicy{});
  Options o;
  o.duration = std::chrono::milliseconds(500);
  o.batch = 1000;
  Open open = [&] { first.replace(std::make_unique<Paced>(open_target("ref:hsc60"), std::chrono::milliseconds(2))); };
  Outcome out = fuzz(first, open, p, o, {});
  EXPECT_TRUE(out.findings.empty());
  EXPECT_GT(out.frames, 0);
  EXPECT_LT(out.frames, o.batch) << "the whole batch went out past the deadline";
  EXPECT_EQ(out.batches, 1);
}

}  // namespace
}  // namespace mbc::conf::blackbox

namespace mbc::conf::blackbox {
namespace {

// A live line whose receiver reads a split frame as one (a host that held
// it up past the pause) unless the pause is long: it answers the split
// frame at the target's own pause, and stays silent at the long one.
class HeldUpReceiver final : public Target {
 public:
  explicit HeldUpReceiver(bool always) : always_(always) {
    info_ = live_rtu(1);
    info_.baud = 115200;
  }
  const TargetInfo& info() const override { return info_; }
  Reply transact(uint8_t unit, std::span<const uint8_t> pdu) override {
    Reply r;
    r.request = rtu_frame(unit, pdu);
    r.frame = rtu_frame(unit, Bytes{3, 2, 0, 0});
    r.pdu = Bytes{3, 2, 0, 0};
    return r;
  }
  Reply send_raw(std::span<const uint8_t> bytes, std::optional<size_t> gap_after) override {
    Reply r;
    r.request.assign(bytes.begin(), bytes.end());
    pauses.push_back(gap_);
    if (gap_after && (always_ || gap_ < std::chrono::milliseconds(100))) {
      r.frame = rtu_frame(1, Bytes{6, 0, 0, 0, 1});
      r.pdu = Bytes{6, 0, 0, 0, 1};
    }
    return r;
  }
  std::optional<std::chrono::microseconds> split_gap() const override { return gap_; }
  void set_split_gap(std::chrono::microseconds g) override { gap_ = g; }
  void advance(std::chrono::microseconds) override {}
  void power_cycle() override {}
  std::vector<std::chrono::microseconds> pauses;

 private:
  TargetInfo info_;
  bool always_;
  std::chrono::microseconds gap_{3500};
};

// A split frame answered at the target's own pause is sent again with a
// pause of 250 ms (as the runner does); only an answer then is a finding
// (MB-SL v1.02 §2.5.1.1: a pause inside a frame breaks it).
TEST(Fuzz, ASplitFrameAnsweredIsSentAgainWithALongPauseBeforeItIsAFinding) {
  spec::Spec s = spec::load_spec_by_id("hsc60");
  Step split = check::raw_rtu(rtu_frame(1, write_single_register(0x0000, 1)));
  split.gap = 3;
  for (bool always : {false, true}) {
    HeldUpReceiver t(always);
    Plan p = make_plan(s, t.info(), WritePolicy{});
    split.expect = expect_for(p, split);
    DirectLink link(t);
    check::Exchange x(link);
    auto f = execute(x, p, split);
    ASSERT_EQ(t.pauses.size(), 2u);
    EXPECT_EQ(t.pauses[0], std::chrono::microseconds(3500));
    EXPECT_EQ(t.pauses[1], std::chrono::milliseconds(250));
    EXPECT_EQ(t.split_gap(), std::chrono::microseconds(3500)) << "the pause is put back";
    if (always) {
      ASSERT_TRUE(f);
      EXPECT_EQ(f->kind, FindingKind::answered_corrupted_frame);
    } else {
      EXPECT_FALSE(f) << f->message;
    }
  }
}

}  // namespace
}  // namespace mbc::conf::blackbox
