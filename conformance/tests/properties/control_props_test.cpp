// The control and motion properties on every other-reading variant (issue 38):
// a drive built to either reading of a contested fact (`ref:ID?reading=KEY`,
// spec/loader/readings.h) does what its manual prints, so no control or motion
// property may fail on it. The model stays the device's own spec: the variant
// is the drive, not the expectation.
#include <gtest/gtest.h>

#include <fmt/core.h>

#include <algorithm>
#include <set>

#include "loader.h"
#include "modbus/crc16.h"
#include "modbus/pdu.h"
#include "policy/policy.h"
#include "properties/properties.h"
#include "readings.h"
#include "session/link.h"
#include "targets/target.h"

namespace mbc::conf::props {
namespace {

constexpr uint64_t kSeed = 20261204;  // fixed: ctest runs are reproducible

Options options() {
  Options o;
  o.cases = 25;  // per invariant and variant: every variant of every drive runs them all
  o.seed = kSeed;
  o.max_size = 30;
  return o;
}

bool control_or_motion(const Invariant& inv) {
  return inv.name.rfind("control-", 0) == 0 || inv.name.rfind("motion-", 0) == 0;
}

struct Variant {
  std::string device, key;
};

// Open (issue 38): a variant a motion property still fails on, and why. Each
// is run and must still fail, so a fix shows here.
struct Open {
  const char* device;
  const char* key;
  const char* why;
};
// None now: Hanstar 0x0BBC.word_order (accel_steps, a u32 whose word order
// 表 14 does not print) was one until the motion setup stopped writing it
// (spec control.motion.setup: start period = running period, §5.7).
const std::vector<Open> kOpen = {};
const Open* open_of(const std::string& device, const std::string& key) {
  for (const auto& o : kOpen)
    if (device == o.device && key == o.key) return &o;
  return nullptr;
}

std::vector<Variant> variants() {
  std::vector<Variant> out;
  for (const auto& id : spec::spec_ids()) {
    spec::Spec s = spec::load_spec_by_id(id);
    if (!s.control) continue;  // no control, no control property to run
    for (const auto& rd : spec::contested_readings(s)) out.push_back({id, rd.key});
  }
  return out;
}

void PrintTo(const Variant& v, std::ostream* os) { *os << "ref:" << v.device << "?reading=" << v.key; }

// Runs every control and motion invariant on `uri`; the failures, one line each.
std::vector<std::string> failures(const std::string& uri, size_t& ran) {
  std::vector<std::string> out;
  TargetSource src = source_for(uri);
  for (const auto& inv : invariants()) {
    if (!control_or_motion(inv)) continue;
    CaseResult c = run_invariant(inv, src, options());
    if (c.outcome == Outcome::pass) ++ran;
    if (c.outcome == Outcome::fail) out.push_back(fmt::format("{}: {}", c.id, c.message));
  }
  return out;
}

class ControlOnOtherReading : public ::testing::TestWithParam<Variant> {};

TEST_P(ControlOnOtherReading, NoControlOrMotionPropertyFails) {
  const auto& v = GetParam();
  size_t ran = 0;
  auto failed = failures(fmt::format("ref:{}?reading={}", v.device, v.key), ran);
  if (const Open* o = open_of(v.device, v.key)) {
    EXPECT_FALSE(failed.empty()) << "fixed: take " << v.key << " off kOpen";
    GTEST_SKIP() << "open: " << o->why;
  }
  for (const auto& f : failed) ADD_FAILURE() << "a drive that reads " << v.key << " the other way fails " << f;
  RecordProperty("passed", int(ran));
}

INSTANTIATE_TEST_SUITE_P(Props, ControlOnOtherReading, ::testing::ValuesIn(variants()), [](const auto& info) {
  std::string n = info.param.device + "_" + info.param.key;
  for (char& ch : n)
    if (!isalnum(uint8_t(ch))) ch = '_';
  return n;
});

// Every drive with a control has variants here, and the run can fail: the
// same variant with a state-machine fault is caught.
TEST(ControlOnOtherReading, CoversEveryDriveAndCanFail) {
  std::set<std::string> devices;
  for (const auto& v : variants()) devices.insert(v.device);
  for (const char* d : {"sihong-57hs-r", "hsc60", "hanstar-7trsm5740q", "rieding-dhe"})
    EXPECT_TRUE(devices.count(d)) << d << " has a control and contested facts, but no variant ran";
  auto all = variants();
  auto it = std::find_if(all.begin(), all.end(), [](const Variant& v) { return v.device == "sihong-57hs-r"; });
  ASSERT_NE(it, all.end());
  size_t ran = 0;
  auto f = failures(fmt::format("ref:{}?reading={}&fault=transition-wrong-target", it->device, it->key), ran);
  EXPECT_FALSE(f.empty()) << "a wrong transition on the variant " << it->key << " went unnoticed";
}

// The Hanstar variant that reads 3004-3005 (accel_steps) low word first was
// open while the motion setup wrote it: now it passes (the parameterized
// test), and a fault in its moves is still caught there.
TEST(ControlOnOtherReading, HanstarAccelStepsWordOrderCanFail) {
  const std::string variant = "ref:hanstar-7trsm5740q?reading=0x0BBC.word_order";
  EXPECT_EQ(open_of("hanstar-7trsm5740q", "0x0BBC.word_order"), nullptr);
  for (const char* fault : {"overshoot", "overspeed", "creep"}) {
    size_t ran = 0;
    auto f = failures(variant + "&fault=" + fault, ran);
    EXPECT_FALSE(f.empty()) << fault << " on " << variant << " went unnoticed";
  }
}

// A setup write (control.motion.setup, assumes) of a 2-word register whose
// word order the manual does not state reads the same either way: a drive
// built to the other order must be set up as the spec means (the Hanstar's
// accel_steps = 100 was 6553600 steps read low word first).
TEST(MotionSetup, NoWriteRestsOnAWordOrderTheManualLeavesOpen) {
  for (const auto& id : spec::spec_ids()) {
    spec::Spec s = spec::load_spec_by_id(id);
    if (!s.control || !s.control->motion) continue;
    const auto& m = *s.control->motion;
    for (const auto* list : {&m.setup, &m.assumes})
      for (const auto& w : *list) {
        const spec::Register* r = s.find_by_key(w.key);
        ASSERT_NE(r, nullptr) << id << " " << w.key;
        if (r->words != 2 || r->basis_of(spec::Fact::word_order).basis == spec::Basis::stated) continue;
        const uint32_t v = uint32_t(w.value);
        EXPECT_EQ(v >> 16, v & 0xFFFF) << id << ": control.motion writes " << w.key << " = " << w.value
                                       << ", whose word order the manual does not state (" << w.section << ")";
      }
  }
}

// The live-drive frame policy on the Hanstar's motion setup: 2008 changes a
// move's speed (表 16, motion: true) and needs --allow-motion; the start and
// running periods (3008, 3009) need --allow-writes, since 表 14 does not say
// FC 03 reads them back (read inferred): the old value could not be kept for
// the restore. Each goes out with its opt-in.
TEST(MotionSetup, TheFramePolicyJudgesTheHanstarSetupWrites) {
  const spec::Spec s = spec::load_spec_by_id("hanstar-7trsm5740q");
  ASSERT_TRUE(s.control && s.control->motion);
  TargetInfo live;
  live.kind = TargetKind::rtu;
  live.framing = &mbc::kRtu;
  live.live = true;
  live.raw = true;
  live.unit = 1;
  std::set<std::string> keys;
  for (const auto& w : s.control->motion->setup) {
    keys.insert(w.key);
    const spec::Register* r = s.find_by_key(w.key);
    ASSERT_NE(r, nullptr);
    ASSERT_EQ(r->words, 1) << w.key;
    const Bytes pdu = write_single_register(uint16_t(r->address), uint16_t(w.value));
    const bool command = r->access == spec::Access::command;
    if (!command) {
      ASSERT_EQ(r->basis_of(spec::Fact::read).basis, spec::Basis::inferred) << w.key;
    }
    Decision plain = allowed(PolicyFacts{&s, live, {}}, 1, pdu);
    ASSERT_FALSE(plain) << w.key << " went out with no opt-in";
    EXPECT_EQ(plain.refused->opt_in, command ? "--allow-motion" : "--allow-writes") << plain.refused->reason;
    WritePolicy opt_in;
    (command ? opt_in.allow_motion : opt_in.allow_writes) = true;
    EXPECT_TRUE(allowed(PolicyFacts{&s, live, opt_in}, 1, pdu)) << w.key;
  }
  EXPECT_EQ(keys, (std::set<std::string>{"homing_period", "run_period", "speed_period_command"}));
}

// ---- set-points 0 move nothing (control-zero-setpoints-still) ---------------

// A CiA 402 drive that ignores a 0 written to its target velocity (60FFh,
// 0x0004-0x0005): it keeps running at 200 once enabled. The frame policy
// lets the enable out (every set-point was written 0), and the axis moves.
class IgnoresZeroVelocity final : public Target {
 public:
  IgnoresZeroVelocity() : t_(open_target("ref:cia402-modbus")) {}
  const TargetInfo& info() const override { return t_->info(); }
  Reply transact(uint8_t unit, std::span<const uint8_t> pdu) override {
    Reply r = t_->transact(unit, pdu);
    keep_running(unit, Bytes(pdu.begin(), pdu.end()));
    return r;
  }
  Reply send_raw(std::span<const uint8_t> bytes, std::optional<size_t> gap) override {
    Reply r = t_->send_raw(bytes, gap);
    if (bytes.size() > 4 && crc_ok(Bytes(bytes.begin(), bytes.end())))
      keep_running(bytes[0], Bytes(bytes.begin() + 1, bytes.end() - 2));
    return r;
  }
  void advance(std::chrono::microseconds dt) override { t_->advance(dt); }
  void power_cycle() override { t_->power_cycle(); }
  bool trip_fault() override { return t_->trip_fault(); }

 private:
  void keep_running(uint8_t unit, const Bytes& pdu) {
    // FC 16 of 0 to 0x0004-0x0005: the velocity stays 200.
    if (pdu.size() >= 10 && pdu[0] == 0x10 && pdu[1] == 0 && pdu[2] == 4 && pdu[5] == 4 && pdu[6] == 0 && pdu[7] == 0 &&
        pdu[8] == 0 && pdu[9] == 0) {
      const uint16_t v[2] = {0, 200};
      t_->transact(unit, write_multiple_registers(4, std::span<const uint16_t>(v, 2)));
    }
  }
  std::unique_ptr<Target> t_;
};

TEST(ControlZeroSetpointsStill, HoldsOnTheDrivesAndCatchesOneThatIgnoresAZero) {
  const Invariant* inv = find_invariant("control-zero-setpoints-still");
  ASSERT_NE(inv, nullptr);
  for (const char* d : {"cia402-modbus", "sihong-57hs-r", "hsc60", "hanstar-7trsm5740q", "rieding-dhe"}) {
    CaseResult c = run_invariant(*inv, source_for(std::string("ref:") + d), options());
    EXPECT_EQ(c.outcome, Outcome::pass) << d << ": " << c.message;
  }
  spec::Spec s = spec::load_spec_by_id("cia402-modbus");
  auto link = std::make_shared<DirectLink>(std::make_unique<IgnoresZeroVelocity>());
  TargetSource broken{"ref:cia402-modbus (ignores a 0 target velocity)", &s, link.get(),
                      [l = link.get()] { l->replace(std::make_unique<IgnoresZeroVelocity>()); }, link};
  CaseResult c = run_invariant(*inv, broken, options());
  EXPECT_EQ(c.outcome, Outcome::fail) << "a drive that runs with its set-points 0 went unnoticed: " << c.message;
}

// ---- stop times: only a stated one is held (motion-stops) --------------------

// The 57HS-R stops in 0x0022's 100 ms (7.6.2). Held to a stated 20 ms it
// fails; the same 20 ms not stated (inferred) is observed and passes.
TEST(MotionStops, OnlyAStatedDecelerationTimeIsHeld) {
  const Invariant* inv = find_invariant("motion-stops");
  ASSERT_NE(inv, nullptr);
  spec::Spec s = spec::load_spec_by_id("sihong-57hs-r");
  ASSERT_TRUE(s.control && s.control->motion);
  EXPECT_EQ(s.control->motion->decel_basis.basis, spec::Basis::stated) << "7.6.2 states the stop time (0x0022)";
  EXPECT_EQ(spec::load_spec_by_id("hanstar-7trsm5740q").control->motion->decel_basis.basis, spec::Basis::inferred)
      << "5.7 prints the acceleration time only";
  EXPECT_EQ(run_invariant(*inv, source_for("ref:sihong-57hs-r", &s), options()).outcome, Outcome::pass);
  s.control->motion->decel_seconds = 0.02;
  CaseResult c = run_invariant(*inv, source_for("ref:sihong-57hs-r", &s), options());
  EXPECT_EQ(c.outcome, Outcome::fail) << "a stop slower than a stated time went unnoticed: " << c.message;
  s.control->motion->decel_basis = spec::MotionOperations::not_stated_decel();
  c = run_invariant(*inv, source_for("ref:sihong-57hs-r", &s), options());
  EXPECT_EQ(c.outcome, Outcome::pass) << "a time the manual does not state was held: " << c.message;
}

}  // namespace
}  // namespace mbc::conf::props
