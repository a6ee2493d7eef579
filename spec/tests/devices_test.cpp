// The five committed specs load cleanly and resolve as the manuals print them.
#include <gtest/gtest.h>

#include <fstream>

#include <nlohmann/json.hpp>

#include "dump.h"
#include "loader.h"

using namespace mbc::spec;

TEST(Devices, EveryCommittedSpecLoadsWithoutDiagnostics) {
  auto ids = spec_ids();
  for (const char* id : {"sihong-57hs-r", "hsc60", "hanstar-7trsm5740q", "rieding-dhe", "modbus-standard"})
    EXPECT_NE(std::find(ids.begin(), ids.end(), id), ids.end()) << id << " is missing from spec/devices";
  for (const auto& id : ids) {
    auto r = load_spec_file(spec_path(id));
    std::string all;
    for (const auto& d : r.diagnostics) all += "\n  " + d.str();
    EXPECT_TRUE(r.ok()) << id << all;
  }
}

// 57HS-R §6.1 prints 0x0090~0x009F as one row: sixteen registers, each addressable.
TEST(Devices, AddressRangesExpandToOneRegisterEach) {
  Spec s = load_spec_by_id("sihong-57hs-r");
  for (unsigned a = 0x0090; a <= 0x009F; ++a) EXPECT_TRUE(s.find_register(uint16_t(a))) << std::hex << a;
}

// HSC60 §四 1.2.3: the FC16 frame writes 0x3880, 0x0001 to 68/69 = 80000
// pulses, so the travel is one 32-bit value with its low word first.
TEST(Devices, Hsc60TravelIsLowWordFirst) {
  Spec s = load_spec_by_id("hsc60");
  const Register* r = s.find_register(68);
  ASSERT_TRUE(r);
  EXPECT_EQ(r->words, 2);
  EXPECT_EQ(r->word_order, WordOrder::low_first);
}

// Hanstar §6.3.3: 2004 written as 00 00 03 E8 = 1000 steps: high word first.
TEST(Devices, HanstarStepsAreHighWordFirst) {
  Spec s = load_spec_by_id("hanstar-7trsm5740q");
  const Register* r = s.find_register(2004);
  ASSERT_TRUE(r);
  EXPECT_EQ(r->word_order, WordOrder::high_first);
  const FunctionCode* fc16 = s.profile.function(16);
  ASSERT_TRUE(fc16);
  ASSERT_TRUE(fc16->max_quantity);
  EXPECT_EQ(*fc16->max_quantity, 2);  // §6.1: "一次最多只能写 2 个寄存器"
}

// Rieding §三: FC 03 reads at most 12 registers; the command word is at 0800H.
TEST(Devices, RiedingLimitsAndCommandArea) {
  Spec s = load_spec_by_id("rieding-dhe");
  ASSERT_TRUE(s.profile.function(3));
  EXPECT_EQ(s.profile.function(3)->max_quantity.value_or(0), 12);
  EXPECT_FALSE(s.profile.function(16));
  const Register* cmd = s.find_register(0x0800);
  ASSERT_TRUE(cmd);
  EXPECT_NE(cmd->access, Access::ro);
}

// 57HS-R §6.2.4 gives the exception codes their own meanings.
TEST(Devices, SihongExceptionPolicyIsItsOwn) {
  Spec s = load_spec_by_id("sihong-57hs-r");
  EXPECT_EQ(s.profile.policy(Violation::unmapped_address).code, 3);
  EXPECT_EQ(s.profile.policy(Violation::address_past_map).code, 4);
  EXPECT_EQ(s.profile.policy(Violation::quantity_over_limit).code, 5);
  EXPECT_EQ(s.profile.policy(Violation::read_write_only).code, 6);
  EXPECT_EQ(s.profile.policy(Violation::value_out_of_range).code, 7);
  EXPECT_EQ(s.profile.function(3)->max_quantity.value_or(0), 16);
}

TEST(Dump, HasTheDocumentedFields) {
  auto j = to_json(load_spec_by_id("sihong-57hs-r"));
  ASSERT_TRUE(j["registers"].is_array());
  for (const auto& r : j["registers"])
    for (const char* k : {"address", "words", "name", "access", "type", "range", "default"}) ASSERT_TRUE(r.contains(k)) << k;
  ASSERT_TRUE(j["examples"].is_array());
  for (const auto& e : j["examples"])
    for (const char* k : {"request", "response", "section"}) ASSERT_TRUE(e.contains(k)) << k;
  // The example frames are dumped exactly as printed (§6.2.1).
  bool found = false;
  for (const auto& e : j["examples"])
    if (e["request"] == "01 03 00 23 00 01 75 C0" && e["response"] == "01 03 02 00 3C B8 55") found = true;
  EXPECT_TRUE(found);
}

// The dump says where a fact comes from: an inferred one with its reason and
// the sections searched, one printed two ways with both readings.
TEST(Dump, ShowsWhereEachFactComesFrom) {
  auto h = to_json(load_spec_by_id("hanstar-7trsm5740q"));
  bool inferred = false;
  for (const auto& r : h["registers"])
    if (r["address"] == 3000) {
      ASSERT_TRUE(r.contains("basis"));
      EXPECT_EQ(r["basis"]["read"]["basis"], "inferred");
      EXPECT_FALSE(r["basis"]["read"]["why"].get<std::string>().empty());
      EXPECT_FALSE(r["basis"]["read"]["searched"].get<std::string>().empty());
      inferred = true;
    }
  EXPECT_TRUE(inferred);
  auto s = to_json(load_spec_by_id("sihong-57hs-r"));
  const auto& crc = s["profile"]["exception_policy"]["crc_error"]["basis"];
  EXPECT_EQ(crc["basis"], "either");
  EXPECT_EQ(crc["readings"].size(), 2u);
}

// Issue 26: every inferred fact of every committed spec says which sections
// were searched for a statement (the errata report lists them beside every
// case they take off MUST), and the committed reports carry that list.
TEST(Devices, EveryInferredFactNamesTheSectionsSearched) {
  size_t inferred = 0;
  for (const auto& id : spec_ids()) {
    Spec s = load_spec_by_id(id);
    auto check = [&](const FactBasis& b, const std::string& what) {
      if (b.basis != Basis::inferred) return;
      ++inferred;
      EXPECT_FALSE(b.searched.empty()) << id << ": " << what << " is inferred but names no sections searched";
      EXPECT_FALSE(b.why.empty()) << id << ": " << what << " is inferred but says not why";
    };
    for (const auto& r : s.registers)
      for (const auto& [f, b] : r.basis) check(b, "register " + std::to_string(r.address) + " " + to_string(f));
    for (const auto& f : s.profile.function_codes)
      for (const auto& [k, b] : f.basis) check(b, "FC " + std::to_string(f.code) + " " + k);
    for (const auto& [v, p] : s.profile.exception_policy) check(p.basis, std::string("exception_policy.") + to_string(v));
    for (const auto& e : s.examples) check(e.basis, "example " + e.id);
  }
  EXPECT_GT(inferred, 20u);
}

TEST(Devices, ErrataReportsListTheCasesAnInferredFactTakesOffMust) {
  size_t listed = 0;
  for (const char* id : {"sihong-57hs-r", "hsc60", "hanstar-7trsm5740q", "rieding-dhe"}) {
    std::ifstream in(std::string(MBCONFORM_SOURCE_DIR) + "/reports/manuals/" + id + ".json");
    ASSERT_TRUE(in) << id;
    nlohmann::json r = nlohmann::json::parse(in);
    ASSERT_TRUE(r.contains("observed_cases")) << id;
    for (const auto& c : r["observed_cases"]) {
      ++listed;
      EXPECT_FALSE(c["facts"].empty()) << c["case"];
      for (const auto& f : c["facts"]) {
        if (f["basis"] != "inferred") continue;
        EXPECT_FALSE(f.value("searched", std::string()).empty()) << id << ": " << c["case"] << " relies on " << f["fact"]
                                                               << " with no sections searched";
      }
    }
  }
  EXPECT_GT(listed, 10u);
}

// Issue 26: the rule erratum-contested holds on every committed spec, and
// bites: dropping a settled_by puts the facts it settled back in doubt.
// Issue 37: FC 16 is printed two ways (6.2.3's frames, 6.2.4's text). With
// its `either` taken away, the fact named by supported-fc-list would be
// stated; and the printed FC 16 frame may not settle the text (settled_by
// is refused for a text against a frame).
TEST(Devices, AFactAnErratumNamesIsNotStatedUnlessAFrameSettlesIt) {
  std::ifstream in(spec_path("sihong-57hs-r"));
  std::string text((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
  ASSERT_TRUE(load_spec_text(text, "sihong-57hs-r.yaml").ok());
  auto has = [](const LoadResult& r, const std::string& what) {
    for (const auto& d : r.diagnostics)
      if (d.rule == "erratum-contested" && d.message.find(what) != std::string::npos) return true;
    return false;
  };
  std::string stated = text;
  auto from = stated.find("      basis:\n        supported: {either:");
  ASSERT_NE(from, std::string::npos);
  auto to = stated.find("erratum: supported-fc-list}\n", from);
  ASSERT_NE(to, std::string::npos);
  stated.erase(from, to + std::string("erratum: supported-fc-list}\n").size() - from);
  EXPECT_TRUE(has(load_spec_text(stated, "sihong-57hs-r.yaml"), "FC 16 supported"))
      << "FC 16 supported, named by supported-fc-list, stays stated";
  std::string settled = text;
  auto at = settled.find("    contests: [supported, example]\n");
  ASSERT_NE(at, std::string::npos);
  settled.insert(at, "    settled_by: [read-max-speed]\n");
  EXPECT_TRUE(has(load_spec_text(settled, "sihong-57hs-r.yaml"), "is a printed text against a printed frame"))
      << "a printed frame settles the 6.2.4 text";
}
