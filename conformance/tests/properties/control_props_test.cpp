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
const std::vector<Open> kOpen = {
    {"hanstar-7trsm5740q", "0x0BBC.word_order",
     "control.motion.setup writes accel_steps (3004, u32) = 100, whose word order 表 14 does not print: read the other way it "
     "is 100 << 16 steps and no move ends. The setup needs a value or a write that does not rest on the word order."},
};
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
