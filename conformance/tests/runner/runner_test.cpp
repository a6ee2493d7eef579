// The runner against the reference devices in-process: every MUST case
// passes on the correct devices, each injected fault (reference/faults) is
// caught by a named case that passes on the correct device, and the cases'
// expectations are the spec's (checked against the spec's own data here,
// never against what the reference answers).
#include <gtest/gtest.h>

#include <set>

#include "cases/case.h"
#include "loader.h"
#include "modbus/crc16.h"
#include "runner/runner.h"

namespace mbc::conf {
namespace {

struct Ran {
  spec::Spec spec;
  std::vector<Case> cases;
  DeviceRun run;
};

const spec::Spec& standard() {
  static spec::Spec s = spec::load_spec_by_id("modbus-standard");
  return s;
}

std::vector<Case> cases_for(const spec::Spec& s, const TargetInfo& info) {
  GenContext g{s, info, {}, &standard(), std::nullopt};
  return all_cases(g);
}

Ran run_ref(const std::string& uri, const std::string& only_id = "") {
  auto t = open_target(uri);
  Ran r{spec::load_spec_by_id(t->info().device_id), {}, {}};
  for (auto& c : cases_for(r.spec, t->info()))
    if (only_id.empty() || c.id == only_id) r.cases.push_back(std::move(c));
  r.run = run_cases(*t, r.spec, r.cases);
  return r;
}

class ReferenceDevice : public ::testing::TestWithParam<std::string> {};

TEST_P(ReferenceDevice, EveryMustCasePasses) {
  Ran r = run_ref("ref:" + GetParam());
  ASSERT_FALSE(r.run.cases.empty());
  EXPECT_TRUE(r.run.error.empty()) << r.run.error;
  size_t pass = 0;
  for (const auto& c : r.run.cases) {
    if (c.level == Level::must) {
      EXPECT_NE(c.outcome, Outcome::fail) << c.id << " [" << c.clause << "]: " << c.message;
    }
    if (c.outcome == Outcome::pass) ++pass;
    // OBSERVED never fails; MUST never ends as "observed".
    if (c.level == Level::observed) {
      EXPECT_TRUE(c.outcome == Outcome::observed || c.outcome == Outcome::skip) << c.id;
    } else {
      EXPECT_NE(c.outcome, Outcome::observed) << c.id;
    }
  }
  EXPECT_GT(pass, 5u);  // 7TRSM5740Q: 9 (its policy is unspecified, most of its cases are OBSERVED)
  EXPECT_GT(r.run.frames_sent, r.run.cases.size() / 2);
  EXPECT_FALSE(r.run.latencies_us.empty());
}

TEST_P(ReferenceDevice, EveryPrintedFrameHasAnExamplesCase) {
  auto t = open_target("ref:" + GetParam());
  spec::Spec s = spec::load_spec_by_id(GetParam());
  auto cases = cases_for(s, t->info());
  std::set<std::string> groups;  // one case per worked sequence, one per lone frame
  for (const auto& ex : s.examples) groups.insert(ex.sequence.empty() ? "frame:" + ex.id : "seq:" + ex.sequence);
  size_t n = 0;
  for (const auto& c : cases) n += c.family == "examples";
  EXPECT_EQ(n, groups.size());
}

TEST_P(ReferenceDevice, CaseIdsAreUniqueAndCiteAClause) {
  auto t = open_target("ref:" + GetParam());
  spec::Spec s = spec::load_spec_by_id(GetParam());
  std::set<std::string> ids;
  for (const auto& c : cases_for(s, t->info())) {
    EXPECT_TRUE(ids.insert(c.id).second) << "duplicate id " << c.id;
    EXPECT_EQ(c.id.rfind(s.device.id + "/" + c.family + "/", 0), 0u) << c.id;
    EXPECT_FALSE(c.clause.empty()) << c.id;
    EXPECT_FALSE(c.requirement.empty()) << c.id;
    EXPECT_TRUE(!c.steps.empty() || !c.skip_reason.empty() || c.family == "deviations") << c.id;
  }
}

INSTANTIATE_TEST_SUITE_P(All, ReferenceDevice,
                         ::testing::Values("sihong-57hs-r", "hsc60", "hanstar-7trsm5740q", "rieding-dhe", "modbus-standard"),
                         [](const auto& info) {
                           std::string n = info.param;
                           for (auto& ch : n)
                             if (ch == '-') ch = '_';
                           return n;
                         });

const Case* find_case(const std::vector<Case>& cs, const std::string& id) {
  for (const auto& c : cs)
    if (c.id == id) return &c;
  return nullptr;
}

// The expected answers are the spec's policy and printed frames.
TEST(Cases, ExpectationsAreTheSpecs) {
  auto t = open_target("ref:sihong-57hs-r");
  spec::Spec s = spec::load_spec_by_id("sihong-57hs-r");
  auto cs = cases_for(s, t->info());

  // 6.2.4: 0x0026 (range 0~1) written with 2 -> the policy's value_out_of_range code.
  const Case* c = find_case(cs, "sihong-57hs-r/registers/0x0026/above-max");
  ASSERT_NE(c, nullptr);
  const spec::Register* r = s.find_register(0x0026);
  ASSERT_TRUE(r && r->range);
  bool saw = false;
  for (const auto& st : c->steps)
    if (st.pdu.size() == 5 && st.pdu[0] == 6) {
      saw = true;
      EXPECT_EQ(st.pdu[4], uint8_t(r->range->max + 1));
      EXPECT_EQ(st.expect.kind, Expect::Kind::exception);
      EXPECT_EQ(st.expect.code, s.profile.policy(spec::Violation::value_out_of_range).code);
    }
  EXPECT_TRUE(saw);
  EXPECT_EQ(c->level, Level::must);

  // A printed frame with an erratum: the resolved response is expected and the erratum recorded.
  const spec::Example* ex = nullptr;
  for (const auto& e : s.examples)
    if (e.resolved_response && !e.errata.empty()) ex = &e;
  ASSERT_NE(ex, nullptr);
  const Case* ec = nullptr;
  for (const auto& k : cs)
    if (k.family == "examples" && k.id.size() > ex->id.size() && k.id.substr(k.id.size() - ex->id.size()) == ex->id) ec = &k;
  ASSERT_NE(ec, nullptr) << ex->id;
  auto want = parse_hex(*ex->resolved_response);
  ASSERT_TRUE(want);
  ASSERT_FALSE(ec->steps.empty());
  const Step& last = ec->steps.back();
  EXPECT_EQ(last.expect.pdu, Bytes(want->begin() + 1, want->end() - 2));
  if (crc_ok(*want)) {
    ASSERT_TRUE(last.expect.adu);
    EXPECT_EQ(*last.expect.adu, *want);
  }
  for (const auto& id : ex->errata) EXPECT_NE(std::find(ec->errata.begin(), ec->errata.end(), id), ec->errata.end()) << id;
}

// Where the manual is silent (every policy kind of the 7TRSM5740Q), the
// cases record what the device does: OBSERVED, never MUST.
TEST(Cases, UnstatedPolicyIsObserved) {
  auto t = open_target("ref:hanstar-7trsm5740q");
  spec::Spec s = spec::load_spec_by_id("hanstar-7trsm5740q");
  size_t n = 0;
  for (const auto& c : cases_for(s, t->info()))
    if (c.id.find("/unsupported") != std::string::npos || c.id.find("/below-min") != std::string::npos ||
        c.id.find("/read-only") != std::string::npos) {
      ++n;
      EXPECT_EQ(c.level, Level::observed) << c.id;
    }
  EXPECT_GT(n, 0u);
}

// Each fault breaks one requirement; the named case fails on the broken
// device and passes on the correct one. (modbus-standard's accept-out-of-range
// has no MUST case: the standard leaves a range check to the application,
// so its write-out-of-range example and 0x0212/above-max are OBSERVED.)
struct FaultCase {
  const char* device;
  const char* fault;
  const char* case_id;
};

class Fault : public ::testing::TestWithParam<FaultCase> {};

TEST_P(Fault, IsCaughtByItsNamedCase) {
  const FaultCase& f = GetParam();
  Ran good = run_ref(std::string("ref:") + f.device, f.case_id);
  ASSERT_EQ(good.run.cases.size(), 1u) << f.case_id << " is not generated";
  EXPECT_EQ(good.run.cases[0].outcome, Outcome::pass) << good.run.cases[0].message;
  Ran bad = run_ref(std::string("ref:") + f.device + "?fault=" + f.fault, f.case_id);
  ASSERT_EQ(bad.run.cases.size(), 1u);
  EXPECT_EQ(bad.run.cases[0].outcome, Outcome::fail) << f.fault << " not caught by " << f.case_id;
  EXPECT_EQ(bad.run.cases[0].level, Level::must);
}

INSTANTIATE_TEST_SUITE_P(
    Reference, Fault,
    ::testing::Values(
        FaultCase{"sihong-57hs-r", "wrong-exception-code", "sihong-57hs-r/examples/6.2.4/unmapped-address"},
        FaultCase{"sihong-57hs-r", "wrong-exception-code", "sihong-57hs-r/registers/0x0026/above-max"},
        FaultCase{"sihong-57hs-r", "off-by-one-limit", "sihong-57hs-r/function-codes/fc03/quantity-limit+1"},
        FaultCase{"rieding-dhe", "refuse-limit", "rieding-dhe/function-codes/fc03/quantity-limit"},
        // (57HS-R's FC 16 is printed two ways since issue 37, so its FC 16 cases are OBSERVED.)
        FaultCase{"modbus-standard", "swapped-words", "modbus-standard/registers/0x0200/word-order"},
        FaultCase{"hsc60", "swapped-words", "hsc60/examples/四_1.2.3/fc16-write-travel"},
        FaultCase{"sihong-57hs-r", "accept-out-of-range", "sihong-57hs-r/registers/0x0020/above-max"},
        FaultCase{"sihong-57hs-r", "accept-read-only", "sihong-57hs-r/registers/0x0000/read-only"},
        FaultCase{"sihong-57hs-r", "lost-write", "sihong-57hs-r/examples/6.2.2/write-accel-time-500"},
        FaultCase{"hsc60", "reply-other-slave", "hsc60/framing/address/wrong-slave"},
        FaultCase{"sihong-57hs-r", "accept-bad-crc", "sihong-57hs-r/framing/rtu/crc-error"},
        FaultCase{"modbus-standard", "answer-broadcast", "modbus-standard/framing/broadcast/no-reply"},
        FaultCase{"modbus-standard", "ignore-broadcast", "modbus-standard/framing/broadcast/write-applied"},
        FaultCase{"hsc60", "bad-reply-crc", "hsc60/examples/四_1.2.2/fc06-write-speed-low"},
        FaultCase{"sihong-57hs-r", "wrong-byte-count", "sihong-57hs-r/examples/6.2.1/read-max-speed"},
        FaultCase{"sihong-57hs-r", "forget-persistent", "sihong-57hs-r/registers/0x0010/persists"},
        FaultCase{"modbus-standard", "keep-volatile", "modbus-standard/registers/0x0000/volatile"}),
    [](const auto& info) {
      std::string n = std::string(info.param.fault) + "_" + std::to_string(info.index);
      for (auto& ch : n)
        if (ch == '-') ch = '_';
      return n;
    });

TEST(Runner, StopsWhenAsked) {
  auto t = open_target("ref:hsc60");
  spec::Spec s = spec::load_spec_by_id("hsc60");
  auto cs = cases_for(s, t->info());
  std::atomic<bool> stop{false};
  RunOptions opt;
  opt.stop = &stop;
  opt.on_case = [&](const CaseResult&, size_t done, size_t) {
    if (done == 5) stop = true;
  };
  DeviceRun d = run_cases(*t, s, cs, opt);
  EXPECT_EQ(d.cases.size(), 5u);
  EXPECT_TRUE(d.interrupted);
}

// The bound counts every byte at the line rate (11 bits a character, MB-SL
// v1.02 §2.5.1) plus a t3.5 silence per frame (1.75 ms above 19200 baud).
TEST(Runner, WireTimeBoundCountsBytesAndGaps) {
  Ran r = run_ref("ref:sihong-57hs-r");
  ASSERT_TRUE(r.run.baud);
  int baud = *r.run.baud;
  double bytes = double(r.run.bytes_sent + r.run.bytes_received) * 11.0 / baud;
  double gap = baud > 19200 ? 1.75e-3 : 3.5 * 11.0 / baud;
  EXPECT_GE(r.run.wire_time_bound_seconds, bytes + gap * double(r.run.frames_sent) * 0.999);
  EXPECT_LE(r.run.wire_time_bound_seconds, bytes + 2 * gap * double(r.run.frames_sent) * 1.001);
}

}  // namespace
}  // namespace mbc::conf
