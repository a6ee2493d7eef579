// "The other reading" (issue 26): for every fact of every device spec that is
// inferred, observed or printed two ways, a reference variant takes the other
// reading (`ref:ID?reading=KEY`, spec/loader/readings.h), and every MUST case
// of that device passes against every variant. A drive that does what its
// manual prints can read an unsettled fact either way, so no MUST may rest on
// one. The variants must differ from the device: each is checked to change
// what its fact says, and together they change the verdict of some cases.
#include <gtest/gtest.h>

#include <fmt/core.h>

#include "cases/case.h"
#include "loader.h"
#include "readings.h"
#include "runner/runner.h"

namespace mbc::conf {
namespace {

const spec::Spec& standard() {
  static spec::Spec s = spec::load_spec_by_id("modbus-standard");
  return s;
}

class OtherReading : public ::testing::TestWithParam<std::string> {};

TEST_P(OtherReading, EveryMustCasePassesAgainstEveryVariant) {
  spec::Spec s = spec::load_spec_by_id(GetParam());
  auto readings = spec::contested_readings(s);
  auto base_target = open_target("ref:" + GetParam());
  GenContext g{s, base_target->info(), {}, &standard(), std::nullopt};
  std::vector<Case> cases = all_cases(g);
  size_t must = 0;
  for (const auto& c : cases) must += c.level == Level::must && c.skip_reason.empty();
  ASSERT_GT(must, 0u);
  DeviceRun base = run_cases(*base_target, s, cases);
  size_t changed = 0;
  for (const auto& rd : readings) {
    SCOPED_TRACE(rd.key + " (" + rd.fact + " -> " + rd.other + ")");
    auto t = open_target("ref:" + GetParam() + "?reading=" + rd.key);
    DeviceRun run = run_cases(*t, s, cases);
    EXPECT_TRUE(run.error.empty()) << run.error;
    ASSERT_EQ(run.cases.size(), base.cases.size());
    bool differs = false;
    for (size_t i = 0; i < run.cases.size(); ++i) {
      const auto& c = run.cases[i];
      if (c.level == Level::must) {
        EXPECT_NE(c.outcome, Outcome::fail) << c.id << " [" << c.clause << "] fails against a drive that reads " << rd.fact
                                            << " as " << rd.other << ": " << c.message;
      }
      differs = differs || c.outcome != base.cases[i].outcome || c.message != base.cases[i].message;
    }
    changed += differs;
  }
  if (!readings.empty()) {
    EXPECT_GT(changed, 0u) << "no variant changed any case: the variants do not take another reading";
  }
  std::cout << fmt::format("{}: {} contested facts, {} MUST cases, {} variants change some case\n", GetParam(),
                           readings.size(), must, changed);
}

INSTANTIATE_TEST_SUITE_P(All, OtherReading,
                         ::testing::Values("sihong-57hs-r", "hsc60", "hanstar-7trsm5740q", "rieding-dhe", "modbus-standard"),
                         [](const auto& info) {
                           std::string n = info.param;
                           for (auto& ch : n)
                             if (ch == '-') ch = '_';
                           return n;
                         });

TEST(OtherReading, EachVariantChangesItsFact) {
  spec::Spec s = spec::load_spec_by_id("sihong-57hs-r");
  auto readings = spec::contested_readings(s);
  ASSERT_FALSE(readings.empty());
  for (const auto& rd : readings) {
    spec::Variant v = spec::other_reading(s, rd.key);
    bool differs = !v.answers.empty() || v.spec.profile.function_codes.size() != s.profile.function_codes.size();
    for (size_t i = 0; i < s.registers.size() && !differs; ++i) {
      const auto &a = s.registers[i], &b = v.spec.registers[i];
      differs = a.access != b.access || a.range != b.range || a.default_value != b.default_value || a.word_order != b.word_order ||
                a.type != b.type || a.takes_effect != b.takes_effect || a.persistence.store != b.persistence.store ||
                a.persistence.unless_register != b.persistence.unless_register;
    }
    for (const auto& f : s.profile.function_codes)
      if (const auto* g = v.spec.profile.function(f.code); g && g->max_quantity != f.max_quantity) differs = true;
    for (spec::Violation x : spec::kAllViolations) {
      auto p = s.profile.policy(x), q = v.spec.profile.policy(x);
      if (p.kind != q.kind || p.code != q.code) differs = true;
    }
    EXPECT_TRUE(differs) << rd.key << ": the variant is the device itself";
  }
  EXPECT_THROW(spec::other_reading(s, "0x0000.read"), std::invalid_argument);  // stated: no other reading
  EXPECT_THROW(open_target("ref:sihong-57hs-r?reading=nonsense"), std::invalid_argument);
}

}  // namespace
}  // namespace mbc::conf
