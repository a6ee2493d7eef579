// "The other reading" (issue 26): for every fact of every device spec that is
// inferred, observed or printed two ways, a reference variant takes the other
// reading (`ref:ID?reading=KEY`, spec/loader/readings.h), and every MUST case
// of that device passes against every variant. A drive that does what its
// manual prints can read an unsettled fact either way, so no MUST may rest on
// one. The variants must differ from the device: each is checked to change
// what its fact says, and together they change the verdict of some cases.
#include <gtest/gtest.h>

#include <fmt/core.h>
#include <fmt/ranges.h>

#include <algorithm>
#include <fstream>
#include <functional>
#include <set>
#include <sstream>

#include "cases/case.h"
#include "cases/facts.h"
#include "erratum_extra.h"
#include "loader.h"
#include "modbus/crc16.h"
#include "modbus/hex.h"
#include "readings.h"
#include "runner/runner.h"
#include "yaml_json.h"

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
    bool differs = !v.answers.empty() || v.spec.profile.function_codes.size() != s.profile.function_codes.size() ||
                   v.spec.registers.size() != s.registers.size();  // a register read as not there
    for (size_t i = 0; i < s.registers.size() && !differs; ++i) {
      const auto &a = s.registers[i], &b = v.spec.registers[i];
      differs = a.address != b.address || a.access != b.access || a.range != b.range || a.default_value != b.default_value || a.word_order != b.word_order ||
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

// Issue 37's review built a drive on the other side of each contradiction it
// found, and these cases were MUST and failed against it. Each finding now
// has its erratum, a variant that takes the review's side, and its cases
// name the erratum and are no MUST; the variant runs them and every MUST of
// the device without a failure.
struct Finding {
  const char* device;
  const char* erratum;
  std::vector<const char*> keys;   // the variants that take the review's side
  std::vector<std::string> cases;  // the review's failing MUST cases, after "<device>/"
};

std::vector<Finding> review_findings() {
  std::vector<std::string> reserved;  // 92~130 and 134~150, one read case each
  for (unsigned a = 0x005C; a <= 0x0096; ++a)
    if (a < 0x0083 || a > 0x0085) reserved.push_back(fmt::format("registers/0x{:04X}/read", a));
  return {
      {"hsc60", "reserved-overlap", {"0x005C.read", "0x0086.read", "0x005C.write", "0x0086.write"}, reserved},
      {"sihong-57hs-r", "x4-filter-no-terminal", {"0x0139.read", "0x0139.write"},
       {"registers/0x0139/read", "registers/0x0139/write-min", "registers/0x0139/write-max", "registers/0x0139/write-mid"}},
      {"rieding-dhe", "plus-one-parameters", {"address.plus-one-parameters"},
       {"registers/0x0000/read", "registers/0x0036/write-min", "registers/0x0036/write-max", "registers/0x0036/write-mid"}},
      {"rieding-dhe", "pn117-118-undefined", {"0x0074.read", "0x0075.read"}, {"registers/0x0074/read", "registers/0x0075/read"}},
      {"sihong-57hs-r", "supported-fc-list", {"fc16.supported"},
       {"examples/6.2.3/write-total-pulses", "function-codes/fc16/quantity-1", "function-codes/fc16/gap",
        "function-codes/fc16/past-map", "function-codes/fc16/runs-past-map", "registers/0x0024/word-order",
        "registers/0x000A/read-only"}},
      {"sihong-57hs-r", "start-cmd-access", {"0x0027.read"}, {"registers/0x0027/write-only", "examples/6.2.4/read-write-only"}},
  };
}

TEST(OtherReading, TheReviewsDrivesFailNoMust) {
  size_t checked = 0;
  for (const auto& f : review_findings()) {
    SCOPED_TRACE(std::string(f.device) + " " + f.erratum);
    spec::Spec s = spec::load_spec_by_id(f.device);
    ASSERT_TRUE(s.find_erratum(f.erratum));
    auto readings = spec::contested_readings(s);
    auto base_target = open_target(std::string("ref:") + f.device);
    GenContext g{s, base_target->info(), {}, &standard(), std::nullopt};
    std::vector<Case> cases = all_cases(g);
    for (const auto& want : f.cases) {
      const std::string id = std::string(f.device) + "/" + want;
      auto c = std::find_if(cases.begin(), cases.end(), [&](const Case& x) { return x.id == id; });
      ASSERT_NE(c, cases.end()) << id << " is no longer a case";
      EXPECT_NE(c->level, Level::must) << id << " is still a MUST";
      ++checked;
    }
    for (const char* key : f.keys) {
      auto rd = std::find_if(readings.begin(), readings.end(), [&](const spec::Reading& r) { return r.key == key; });
      ASSERT_NE(rd, readings.end()) << "no variant " << key;
      EXPECT_TRUE(std::find(rd->errata.begin(), rd->errata.end(), f.erratum) != rd->errata.end())
          << key << " does not name " << f.erratum << " as its doubt";
      DeviceRun run = run_cases(*open_target(std::string("ref:") + f.device + "?reading=" + key), s, cases);
      for (const auto& r : run.cases) {
        if (r.level == Level::must) {
          EXPECT_NE(r.outcome, Outcome::fail) << key << ": " << r.id << ": " << r.message;
        }
        const bool reviewed = std::any_of(f.cases.begin(), f.cases.end(),
                                          [&](const std::string& w) { return r.id == std::string(f.device) + "/" + w; });
        if (reviewed) {
          EXPECT_TRUE(std::find(r.errata.begin(), r.errata.end(), f.erratum) != r.errata.end())
              << r.id << " does not name " << f.erratum << " among the errata it relies on";
        }
      }
    }
  }
  EXPECT_EQ(checked, 56u + 4 + 4 + 2 + 7 + 2);  // the review's 75 cases that rest on a contradiction
}

}  // namespace
}  // namespace mbc::conf

// Issue 37: every erratum that changes behaviour has an other-reading variant
// (a contested fact whose doubt comes from it). One without a variant says
// why: the standard decides it (decided_by:), or it is a typo or nit, or
// no case rests on it (contests: []). Then no case may rest on what it names:
// a fact it contests is in no case's reliances, and changing what it is
// about (about: unit, name, note, labels, does, crc ...) in everything that
// cites it changes no case.
namespace mbc::conf::errata_claims {

using spec::Spec;

// What a case sends and expects, as one comparable text.
void print_expect(std::string& out, const Expect& e) {
  out += fmt::format(" e{}:{}:{}:", int(e.kind), to_hex(e.pdu), int(e.code));
  if (e.adu) out += to_hex(*e.adu);
  for (auto w : e.words) out += fmt::format("{:04X}", w);
  out += fmt::format(":{}", e.memo);
  for (const auto& x : e.either) print_expect(out, x);
}
std::vector<std::string> fingerprint(const std::vector<Case>& cases) {
  std::vector<std::string> out;
  for (const auto& c : cases) {
    std::string f = fmt::format("{} {} skip={}", c.id, to_string(c.level), c.skip_reason);
    for (const auto& s : c.steps) {
      f += fmt::format(" | s{}:{}:{}:{}:{}", int(s.kind), int(s.unit), to_hex(s.pdu), to_hex(s.bytes), s.us);
      print_expect(f, s.expect);
    }
    out.push_back(std::move(f));
  }
  return out;
}

std::vector<Case> cases_of(const Spec& s) {
  auto t = open_target("ref:" + s.device.id);
  GenContext g{s, t->info(), {}, &standard(), std::nullopt};
  return all_cases(g);
}

bool cites(const std::vector<std::string>& ids, const std::string& id) {
  return std::find(ids.begin(), ids.end(), id) != ids.end();
}

// A printed frame with its last (CRC) byte changed.
void bump_crc(std::string& hex) {
  if (hex.size() < 2) return;
  std::string last = hex.substr(hex.size() - 2);
  hex.replace(hex.size() - 2, 2, last == "00" ? "01" : "00");
}

// The spec with every part `about` names changed in what cites erratum `e`.
Spec perturbed(Spec s, const spec::Erratum& e, std::vector<std::string> about) {
  auto has = [&](const char* part) { return cites(about, part); };
  std::set<std::string> enums, bitfields;
  for (auto& r : s.registers) {
    if (!cites(r.errata, e.id)) continue;
    if (has("unit")) r.unit = "perturbed-unit";
    if (has("scale")) r.scale = r.scale * 7 + 3;
    if (has("name")) r.name = {"改", "perturbed name"};
    if (has("note")) {
      r.note = "perturbed note";
      if (r.command) r.command->effect = "perturbed effect";
    }
    if (has("printed")) r.printed.clear();
    if (has("labels")) {
      if (!r.enum_id.empty()) enums.insert(r.enum_id);
      if (!r.bitfield_id.empty()) bitfields.insert(r.bitfield_id);
    }
  }
  for (auto& b : s.bitfields)
    for (auto& f : b.fields)
      if (f.erratum == e.id) bitfields.insert(b.id);
  if (has("labels")) {
    for (auto& en : s.enums)
      if (enums.count(en.id))
        for (auto& v : en.values) v.name = {"改", "perturbed label"};
    for (auto& b : s.bitfields)
      if (bitfields.count(b.id))
        for (auto& f : b.fields) f.name = {"改", "perturbed label"};
  }
  for (auto& x : s.examples) {
    if (!cites(x.errata, e.id)) continue;
    if (has("does")) x.does = "perturbed";
    if (has("crc")) {
      // Only a misprint the spec resolves: the printed CRC is then not what goes out.
      if (x.resolved_request) bump_crc(x.request);
      if (auto b = x.response ? parse_hex(*x.response) : std::nullopt; b && !crc_ok(*b)) bump_crc(*x.response);
    }
  }
  return s;
}

// The facts of what cites `e` that it contests, as cases name them.
std::set<std::string> contested_facts(const Spec& s, const spec::Erratum& e) {
  std::set<std::string> out;
  for (const auto& r : s.registers)
    if (cites(r.errata, e.id))
      for (spec::Fact f : spec::kRegisterFacts)
        if (e.contests_fact(spec::to_string(f))) out.insert(fmt::format("register 0x{:04X} {}", r.address, spec::to_string(f)));
  for (const auto& f : s.profile.function_codes)
    if (f.erratum == e.id)
      for (const char* k : {"supported", "max_quantity"})
        if (e.contests_fact(k)) out.insert(fmt::format("FC {} {}", f.code, k));
  for (const auto& [v, p] : s.profile.exception_policy)
    if ((p.erratum == e.id || p.basis.erratum == e.id) && e.contests_fact("policy"))
      out.insert(fmt::format("{} exception_policy.{}", s.device.id, spec::to_string(v)));
  for (const auto& x : s.examples)
    if (cites(x.errata, e.id) && e.contests_fact("example")) out.insert("example " + x.id);
  return out;
}

// The errata the spec's `serial:` objects cite (each takes `erratum:`,
// spec/README.md "serial"): the loader keeps them in no field of Spec, so
// they are read from the spec's own file, as the loader's rule erratum-linked
// reads every `erratum:` of the document.
std::set<std::string> serial_citations(const Spec& s) {
  std::set<std::string> out;
  std::ifstream in(s.path);
  std::stringstream text;
  text << in.rdbuf();
  spec::Diagnostics diags;
  auto doc = spec::yaml_to_json(text.str(), s.path, diags);
  if (!doc || !doc->root.contains("serial")) return out;
  std::function<void(const nlohmann::json&)> walk = [&](const nlohmann::json& j) {
    if (j.is_array())
      for (const auto& x : j) walk(x);
    if (!j.is_object()) return;
    for (auto it = j.begin(); it != j.end(); ++it) {
      if (it.key() != "erratum") walk(*it);
      else if (it->is_string()) out.insert(it->get<std::string>());
      else if (it->is_array())
        for (const auto& x : *it)
          if (x.is_string()) out.insert(x.get<std::string>());
    }
  };
  walk(doc->root["serial"]);
  return out;
}

// Whether anything in the spec cites `e`: every place the spec language lets
// an entry cite an erratum (spec/README.md): a register (`erratum:`, an
// `area:`, a fact printed two ways), an example (and its basis), a function
// code (and its facts), an exception policy entry (its basis, its readings),
// a bit field, `device.manual.erratum`, the control's states, commands,
// transitions, modes and `undefined` (their basis), and `serial:`.
bool cited(const Spec& s, const spec::Erratum& e) {
  auto by = [&](const spec::FactBasis& b) { return b.erratum == e.id; };
  for (const auto& r : s.registers) {
    if (cites(r.errata, e.id)) return true;
    for (const auto& [f, b] : r.basis)
      if (by(b)) return true;
  }
  for (const auto& x : s.examples)
    if (cites(x.errata, e.id) || by(x.basis)) return true;
  for (const auto& f : s.profile.function_codes) {
    if (f.erratum == e.id) return true;
    for (const auto& [k, b] : f.basis)
      if (by(b)) return true;
  }
  for (const auto& [v, p] : s.profile.exception_policy) {
    if (p.erratum == e.id || by(p.basis)) return true;
    for (const auto& r : p.readings)
      if (r.erratum == e.id) return true;
  }
  for (const auto& b : s.bitfields)
    for (const auto& f : b.fields)
      if (f.erratum == e.id) return true;
  if (s.device.manual.erratum == e.id) return true;
  if (s.control) {
    const auto& c = *s.control;
    for (const auto& x : c.states)
      if (by(x.basis)) return true;
    for (const auto& x : c.commands)
      if (by(x.basis)) return true;
    for (const auto& x : c.transitions)
      if (by(x.basis)) return true;
    for (const auto& x : c.modes)
      if (by(x.basis)) return true;
    if (by(c.undefined.basis)) return true;
  }
  return serial_citations(s).count(e.id) > 0;
}

// Why an erratum's claim does not hold, if it does not: a behavioural
// erratum without a variant, a contested fact a case relies on, or an
// `about` whose change changes a case.
struct Claims {
  const Spec& s;
  std::vector<spec::Reading> readings = spec::contested_readings(s);
  std::vector<std::string> base = fingerprint(cases_of(s));
  std::set<std::string> relied = [this] {
    std::set<std::string> out;
    for (const auto& c : cases_of(s))
      for (const auto& r : facts::all_relies(c)) out.insert(r.fact);
    return out;
  }();

  bool has_variant(const spec::Erratum& e) const {
    return std::any_of(readings.begin(), readings.end(), [&](const spec::Reading& rd) { return cites(rd.errata, e.id); });
  }

  std::vector<std::string> problems(const spec::Erratum& e) const {
    std::vector<std::string> out;
    if (has_variant(e)) return out;
    bool nothing = e.contests_given && e.contests.empty();
    const spec::ErratumExtra x = spec::erratum_extra(s, e.id);
    if (x.decided_by.empty() && x.cls == "contradiction" && !nothing)
      out.push_back(fmt::format("{} contests {} of what cites it but no other-reading variant takes the other side: mark the facts"
                                " either or inferred, or say why no case rests on it (class: typo|nit, contests: [], decided_by:)",
                                e.id, e.contests_given ? fmt::format("[{}]", fmt::join(e.contests, ", ")) : "everything"));
    if (!x.decided_by.empty()) {
      if (e.settled_by.empty()) out.push_back(e.id + ": decided_by names the standard's clause between a text and the frames that settle it (settled_by:)");
      return out;
    }
    if (!nothing && x.cls == "contradiction")
      for (const auto& f : contested_facts(s, e))
        if (relied.count(f)) out.push_back(fmt::format("a case relies on {}, which {} contests, and no variant reads it the other way", f, e.id));
    if (cited(s, e) && x.about.empty() && !e.settled())
      out.push_back(e.id + " is cited and has no variant: say what of its citers it is about (about:)");
    if (x.about.empty()) return out;
    auto after = fingerprint(cases_of(perturbed(s, e, x.about)));
    if (after.size() != base.size()) {
      out.push_back(fmt::format("changing the {} that {} is about changes which cases exist", fmt::join(x.about, ", "), e.id));
      return out;
    }
    for (size_t i = 0; i < base.size(); ++i)
      if (after[i] != base[i])
        out.push_back(fmt::format("changing the {} that {} is about changes a case: {}", fmt::join(x.about, ", "), e.id, base[i].substr(0, 160)));
    return out;
  }
};

class ErratumClaims : public ::testing::TestWithParam<std::string> {};

TEST_P(ErratumClaims, EveryBehaviouralErratumHasAVariantAndTheOthersTouchNoCase) {
  Spec s = spec::load_spec_by_id(GetParam());
  Claims claims{s};
  size_t with_variant = 0, without = 0, about = 0;
  for (const auto& e : s.errata) {
    for (const auto& p : claims.problems(e)) ADD_FAILURE() << p;
    bool v = claims.has_variant(e);
    with_variant += v;
    without += !v;
    about += !v && !spec::erratum_extra(s, e.id).about.empty();
  }
  std::cout << fmt::format("{}: {} errata, {} with a variant, {} without ({} checked by changing what they are about)\n",
                           GetParam(), s.errata.size(), with_variant, without, about);
}

INSTANTIATE_TEST_SUITE_P(Drives, ErratumClaims, ::testing::Values("sihong-57hs-r", "hsc60", "hanstar-7trsm5740q", "rieding-dhe"),
                         [](const auto& info) {
                           std::string n = info.param;
                           for (auto& ch : n)
                             if (ch == '-') ch = '_';
                           return n;
                         });

// The checks can fail. The review's 0x0139 (an erratum naming the register
// while its read and write stay stated): with contests [read, write] and no
// variant, the relied-on facts are named; with contests: [] and about:
// [range]-like changes (a part a case does read), the change is seen.
TEST(ErratumClaims, TheChecksCatchAClaimThatHidesAFact) {
  Spec s = spec::load_spec_by_id("sihong-57hs-r");
  for (auto& r : s.registers)
    if (r.address == 0x0139) r.basis.clear();  // as before issue 37: read and write stated
  spec::Erratum x4 = *s.find_erratum("x4-filter-no-terminal");
  Claims claims{s};
  ASSERT_FALSE(claims.has_variant(x4));
  auto p = claims.problems(x4);
  EXPECT_TRUE(std::any_of(p.begin(), p.end(), [](const std::string& m) { return m.find("register 0x0139 read") != std::string::npos; }))
      << fmt::format("{}", fmt::join(p, "; "));
  // The old claim, contests: [] with nothing said: cited, so it must say what it is about.
  x4.contests.clear();
  for (auto& e : s.errata)
    if (e.id == x4.id) e = x4;
  p = Claims{s}.problems(x4);
  EXPECT_TRUE(std::any_of(p.begin(), p.end(), [](const std::string& m) { return m.find("about:") != std::string::npos; }));
  // A change to a part a case reads is seen by the comparison.
  Claims c2{s};
  Spec changed = s;
  for (auto& r : changed.registers)
    if (r.address == 0x0139) r.range = spec::Range{0, 100};
  EXPECT_NE(fingerprint(cases_of(changed)), c2.base);
  // And a part no case reads is not: 0x0139's note.
  EXPECT_EQ(fingerprint(cases_of(perturbed(s, x4, {"note"}))), c2.base);
}

// An erratum cited only from `serial:` or from the control's entries is
// cited (it was "cited by nothing": the claims of such an erratum went
// unchecked): the ones the four drives' specs cite that way, and a new one a
// control transition alone cites, which then must say what it is about.
TEST(ErratumClaims, AnErratumCitedOnlyFromSerialOrControlIsCited) {
  const std::vector<std::pair<std::string, std::string>> only_there = {
      {"sihong-57hs-r", "dip-address-zero"},           // serial.slave_id
      {"sihong-57hs-r", "alarm-clear-power-cycle"},    // a control transition
      {"hsc60", "slave-id-default-broadcast"},         // serial.slave_id, serial.broadcast
      {"hsc60", "baud-unit-hz"},                       // serial.baud_rates
      {"hanstar-7trsm5740q", "limit-alarm-command"},   // control transitions
  };
  for (const auto& [id, erratum] : only_there) {
    Spec s = spec::load_spec_by_id(id);
    const spec::Erratum* e = s.find_erratum(erratum);
    ASSERT_TRUE(e) << id << " " << erratum;
    EXPECT_TRUE(cited(s, *e)) << id << ": " << erratum << " is cited by nothing";
  }
  Spec s = spec::load_spec_by_id("hanstar-7trsm5740q");
  ASSERT_TRUE(s.control && !s.control->transitions.empty());
  spec::Erratum x;
  x.id = "control-only-test";
  x.kind = "text_vs_text";
  s.errata.push_back(x);
  EXPECT_FALSE(cited(s, x));
  s.control->transitions.front().basis.erratum = x.id;
  EXPECT_TRUE(cited(s, x));
  auto p = Claims{s}.problems(x);
  EXPECT_TRUE(std::any_of(p.begin(), p.end(), [](const std::string& m) { return m.find("is cited and has no variant") != std::string::npos; }))
      << fmt::format("{}", fmt::join(p, "; "));
}

}  // namespace mbc::conf::errata_claims
