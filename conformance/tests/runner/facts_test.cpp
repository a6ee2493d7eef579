// The level of a case follows from where its facts come from (spec/README.md,
// "Where each fact comes from"): a fixture spec has each fact marked inferred
// in turn, and every case relying on that fact must leave MUST; a fact's
// value is changed in turn, and every case whose frames or expectations
// change must have recorded that fact (so the accessor of cases/facts.h is
// the only way the generators read it); across the real specs no MUST case
// relies on an inferred or observed fact.
#include <gtest/gtest.h>

#include <map>
#include <set>

#include "cases/case.h"
#include "cases/common.h"
#include "cases/facts.h"
#include "loader.h"
#include "runner/runner.h"

namespace mbc::conf {
namespace {

using spec::Basis;
using spec::Fact;

const spec::Spec& standard() {
  static spec::Spec s = spec::load_spec_by_id("modbus-standard");
  return s;
}

spec::Spec fixture() {
  auto r = spec::load_spec_file(std::string(MBCONFORM_SOURCE_DIR) + "/spec/tests/valid/minimal.yaml");
  EXPECT_TRUE(r.ok());
  return *r.spec;
}

// Every capability on, so every family generates all it can.
TargetInfo full_target() {
  TargetInfo t;
  t.uri = "ref:fixture";
  t.kind = conf::TargetKind::ref;
  t.framing = &mbc::kRtu;
  t.virtual_clock = t.power_cycle = t.raw = true;
  return t;
}

std::vector<Case> cases_of(const spec::Spec& s) {
  GenContext g{s, full_target(), {}, &standard(), std::nullopt};
  return all_cases(g);
}

bool relies_on(const Case& c, const std::string& fact) {
  for (const auto& r : facts::all_relies(c))
    if (r.fact == fact) return true;
  return false;
}

spec::FactBasis inferred_basis() {
  spec::FactBasis b;
  b.basis = Basis::inferred;
  b.why = "marked inferred by the test";
  b.searched = "everywhere";
  return b;
}

std::string register_fact(const spec::Register& r, Fact f) {
  char buf[64];
  std::snprintf(buf, sizeof buf, "register 0x%04X %s", r.address, spec::to_string(f));
  return buf;
}

// A case's frames and expectations, to see which cases a change touches.
std::string shape(const Case& c) {
  std::string s = std::string(to_string(c.level)) + "|" + c.skip_reason;
  auto expect = [](const Expect& e) {
    std::string x = std::to_string(int(e.kind)) + ":" + to_hex(e.pdu) + ":" + std::to_string(e.code) + ":";
    for (auto w : e.words) x += std::to_string(w) + ",";
    return x;
  };
  for (const auto& st : c.steps) {
    s += "|" + to_hex(st.pdu) + to_hex(st.bytes) + "=" + expect(st.expect);
    for (const auto& a : st.expect.either) s += "/" + expect(a);
  }
  return s;
}

TEST(Facts, EveryFactMarkedInferredTakesItsCasesOffMust) {
  spec::Spec base = fixture();
  auto before = cases_of(base);
  size_t moved = 0, facts_used = 0;
  for (size_t i = 0; i < base.registers.size(); ++i) {
    for (Fact f : spec::kRegisterFacts) {
      spec::Spec s = base;
      s.registers[i].basis[f] = inferred_basis();
      std::string name = register_fact(s.registers[i], f);
      auto after = cases_of(s);
      ASSERT_EQ(after.size(), before.size()) << name;
      bool used = false;
      for (size_t k = 0; k < after.size(); ++k) {
        if (!relies_on(after[k], name)) continue;
        used = true;
        EXPECT_NE(after[k].level, Level::must) << after[k].id << " relies on " << name << " marked inferred";
        EXPECT_NE(after[k].requirement.find("marked inferred by the test"), std::string::npos)
            << after[k].id << ": the report must name the inference";
        moved += before[k].level == Level::must;
      }
      facts_used += used;
    }
  }
  for (spec::Violation v : spec::kAllViolations) {
    spec::Spec s = base;
    auto it = s.profile.exception_policy.find(v);
    if (it == s.profile.exception_policy.end() || it->second.kind == spec::PolicyEntry::Kind::unspecified) continue;
    it->second.basis = inferred_basis();
    std::string name = base.device.id + " exception_policy." + spec::to_string(v);
    bool used = false;
    for (const auto& c : cases_of(s))
      if (relies_on(c, name)) {
        used = true;
        EXPECT_NE(c.level, Level::must) << c.id << " relies on " << name << " marked inferred";
      }
    EXPECT_TRUE(used) << "no case relies on " << name;
  }
  // A function code's facts: that it is supported, and its limit.
  size_t fc_used = 0;
  for (size_t i = 0; i < base.profile.function_codes.size(); ++i)
    for (const char* k : {"supported", "max_quantity"}) {
      spec::Spec s = base;
      s.profile.function_codes[i].basis[k] = inferred_basis();
      std::string name = "FC " + std::to_string(s.profile.function_codes[i].code) + " " + k;
      auto after = cases_of(s);
      ASSERT_EQ(after.size(), before.size()) << name;
      for (size_t n = 0; n < after.size(); ++n) {
        if (!relies_on(after[n], name)) continue;
        fc_used += 1;
        EXPECT_NE(after[n].level, Level::must) << after[n].id << " relies on " << name << " marked inferred";
        moved += before[n].level == Level::must;
      }
    }
  EXPECT_GT(facts_used, 10u);
  EXPECT_GT(fc_used, 5u);
  EXPECT_GT(moved, 20u);  // the rule bites: MUST cases did move
}

// The stated fixture keeps its MUST cases: the rule does not demote by default.
TEST(Facts, StatedFactsKeepMust) {
  size_t must = 0;
  for (const auto& c : cases_of(fixture())) {
    must += c.level == Level::must;
    for (const auto& r : facts::all_relies(c)) EXPECT_FALSE(r.basis.is_inferred()) << c.id << ": " << r.fact;
  }
  EXPECT_GT(must, 20u);
}

// Changing a fact's value changes only cases that recorded the fact: the
// generators read it through the accessor, not around it.
TEST(Facts, CasesAFactChangesRecordThatFact) {
  spec::Spec base = fixture();
  std::map<std::string, std::string> before;
  std::set<std::string> must;  // a fact can only wrong a case that may fail: MUST ones
  for (const auto& c : cases_of(base)) {
    before[c.id] = shape(c);
    if (c.level == Level::must) must.insert(c.id);
  }
  size_t checked = 0;
  for (size_t i = 0; i < base.registers.size(); ++i) {
    const spec::Register& r0 = base.registers[i];
    std::vector<std::pair<Fact, spec::Spec>> mutants;
    if (r0.range) {
      spec::Spec s = base;
      s.registers[i].range->max -= 1;
      mutants.push_back({Fact::range, s});
    }
    if (r0.default_value) {
      spec::Spec s = base;
      s.registers[i].default_value = *r0.default_value + 1;
      mutants.push_back({Fact::default_value, s});
    }
    if (r0.words == 2) {
      spec::Spec s = base;
      s.registers[i].word_order = r0.word_order == spec::WordOrder::high_first ? spec::WordOrder::low_first : spec::WordOrder::high_first;
      mutants.push_back({Fact::word_order, s});
    }
    for (auto& [f, s] : mutants) {
      std::string name = register_fact(r0, f);
      for (const auto& c : cases_of(s)) {
        auto it = before.find(c.id);
        if (it != before.end() && it->second == shape(c)) continue;
        if (!must.count(c.id) && c.level != Level::must) continue;
        ++checked;
        EXPECT_TRUE(relies_on(c, name)) << c.id << " changed with " << name << " but does not record it";
      }
    }
  }
  for (spec::Violation v : spec::kAllViolations) {
    spec::Spec s = base;
    auto it = s.profile.exception_policy.find(v);
    if (it == s.profile.exception_policy.end() || it->second.kind != spec::PolicyEntry::Kind::exception) continue;
    it->second.code = it->second.code == 4 ? 5 : 4;
    std::string name = base.device.id + " exception_policy." + spec::to_string(v);
    for (const auto& c : cases_of(s)) {
      auto b = before.find(c.id);
      if (b != before.end() && b->second == shape(c)) continue;
      if (!must.count(c.id) && c.level != Level::must) continue;
      ++checked;
      EXPECT_TRUE(relies_on(c, name)) << c.id << " changed with " << name << " but does not record it";
    }
  }
  EXPECT_GT(checked, 10u);
}

// The rule on the real specs: no MUST case relies on an inferred or observed fact.
class EachSpec : public ::testing::TestWithParam<std::string> {};

TEST_P(EachSpec, NoMustCaseReliesOnAnInferredFact) {
  spec::Spec s = spec::load_spec_by_id(GetParam());
  for (const auto& c : cases_of(s)) {
    if (c.level != Level::must) continue;
    for (const auto& r : facts::all_relies(c))
      EXPECT_FALSE(r.basis.is_inferred()) << c.id << " is MUST but relies on " << facts::describe(r);
  }
}

INSTANTIATE_TEST_SUITE_P(Specs, EachSpec, ::testing::ValuesIn(spec::spec_ids()), [](const auto& info) {
  std::string n = info.param;
  for (char& ch : n)
    if (!isalnum(static_cast<unsigned char>(ch))) ch = '_';
  return n;
});

// A case relying on an `either` fact keeps its level, accepts both readings,
// and the run records which reading the device chose.
TEST(Facts, EitherPassesOnTheReadingTheDeviceChoseAndRecordsIt) {
  auto t = open_target("ref:sihong-57hs-r");
  spec::Spec s = spec::load_spec_by_id("sihong-57hs-r");
  GenContext g{s, t->info(), {}, &standard(), std::nullopt};
  std::vector<Case> picked;
  for (auto& c : all_cases(g))
    if (c.id == "sihong-57hs-r/examples/6.2.4/crc-error" || c.id == "sihong-57hs-r/framing/rtu/crc-error") picked.push_back(c);
  ASSERT_EQ(picked.size(), 2u);
  for (const auto& c : picked) {
    EXPECT_EQ(c.level, Level::must) << c.id;
    bool has_either = false;
    for (const auto& st : c.steps) has_either |= !st.expect.either.empty();
    EXPECT_TRUE(has_either) << c.id << ": the printed reply 01 83 01 must be accepted too";
  }
  DeviceRun run = run_cases(*t, s, picked);
  for (const auto& r : run.cases) {
    EXPECT_EQ(r.outcome, Outcome::pass) << r.id << ": " << r.message;
    ASSERT_TRUE(r.extra.contains("either")) << r.id;
    EXPECT_NE(r.extra["either"][0]["chose"].get<std::string>(), "neither reading") << r.id;
  }
}

// An `either` fact fails only when no reading matches: a policy whose two
// readings are both wrong for the reference device fails.
TEST(Facts, EitherFailsWhenNoReadingMatches) {
  auto t = open_target("ref:sihong-57hs-r");
  spec::Spec s = spec::load_spec_by_id("sihong-57hs-r");
  auto& p = s.profile.exception_policy[spec::Violation::value_out_of_range];
  spec::PolicyEntry a, b;
  a.kind = b.kind = spec::PolicyEntry::Kind::exception;
  a.code = 3;
  b.code = 4;
  p.readings = {a, b};
  p.kind = a.kind;
  p.code = a.code;
  p.basis.basis = Basis::either;
  GenContext g{s, t->info(), {}, &standard(), std::nullopt};
  std::vector<Case> picked;
  for (auto& c : all_cases(g))
    if (c.id.find("/above-max") != std::string::npos && c.level == Level::must && picked.empty()) picked.push_back(c);
  ASSERT_EQ(picked.size(), 1u);
  DeviceRun run = run_cases(*t, s, picked);
  EXPECT_EQ(run.cases[0].outcome, Outcome::fail) << run.cases[0].message;
}

}  // namespace
}  // namespace mbc::conf

namespace mbc::conf {
namespace {

// The engine and the spec agree: each reference device, run against its own
// spec, differs from an expectation only where the spec says it may: a
// declared erratum, a declared deviation from the standard, or a printed
// example whose given state the bus cannot set.
class EngineAgrees : public ::testing::TestWithParam<std::string> {};

TEST_P(EngineAgrees, NoDiffersOutcomeThatIsNotDeclared) {
  auto t = open_target("ref:" + GetParam());
  spec::Spec s = spec::load_spec_by_id(GetParam());
  GenContext g{s, t->info(), {}, &standard(), std::nullopt};
  auto cases = all_cases(g);
  DeviceRun run = run_cases(*t, s, cases);
  size_t observed = 0;
  for (const auto& r : run.cases) {
    if (r.outcome != Outcome::observed) continue;
    ++observed;
    if (r.message.find("differs") == std::string::npos) continue;
    bool declared = !r.errata.empty() || r.family == "deviations" || r.requirement.find("reply recorded") != std::string::npos;
    EXPECT_TRUE(declared) << r.id << ": " << r.message;
  }
  EXPECT_GT(run.cases.size(), 10u);
}

INSTANTIATE_TEST_SUITE_P(Specs, EngineAgrees, ::testing::ValuesIn(spec::spec_ids()), [](const auto& info) {
  std::string n = info.param;
  for (char& ch : n)
    if (!isalnum(static_cast<unsigned char>(ch))) ch = '_';
  return n;
});

}  // namespace
}  // namespace mbc::conf
