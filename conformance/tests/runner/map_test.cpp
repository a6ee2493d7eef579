// A server's map without a spec (conformance/map/): the probe finds the
// blocks the reference modbus-standard device serves, stays within its
// budget and says when it ran out; the inline and file forms give the same
// blocks; the map decides where the standard's cases are placed, and a map
// of 0-65535 has no past-the-end case.
#include <fmt/core.h>
#include <gtest/gtest.h>
#include <unistd.h>

#include <filesystem>
#include <fstream>

#include "cases/case.h"
#include "loader.h"
#include "map/map.h"

namespace mbc::conf {
namespace {

const spec::Spec& standard() {
  static spec::Spec s = spec::load_spec_by_id("modbus-standard");
  return s;
}

std::vector<Case> cases_on(const map::Map& m) {
  static const spec::Spec applied_base = standard();
  spec::Spec s = map::apply(applied_base, m);
  auto t = open_target("ref:modbus-standard");
  GenContext g{s, t->info(), {}, &standard(), std::nullopt};
  g.map = map::terms(m, false);
  return all_cases(g);
}

bool has(const std::vector<Case>& cs, const std::string& suffix) {
  return std::any_of(cs.begin(), cs.end(), [&](const Case& c) { return c.id.ends_with(suffix); });
}

// The readable blocks of `t` the spec maps, joined where they touch, that
// hold a sampled address (one every map::kStride): what the probe must find
// (a block between two samples is not looked for).
std::string spec_blocks(spec::Table t) {
  std::string out;
  int64_t first = -1, last = -2;
  auto flush = [&] {
    bool sampled = first >= 0 && (first % map::kStride == 0 || first / map::kStride != last / map::kStride);
    if (sampled) out += fmt::format("{:04X}-{:04X} ", first, last);
  };
  for (const auto& r : standard().registers) {
    if (r.table != t || r.access == spec::Access::wo) continue;
    if (int64_t(r.address) != last + 1) {
      flush();
      first = r.address;
    }
    last = r.last_address();
  }
  flush();
  return out;
}

std::string found_blocks(const map::Map& m, spec::Table t) {
  std::string out;
  for (const auto& b : m.blocks)
    if (b.table == t) out += fmt::format("{:04X}-{:04X} ", b.first, b.last);
  return out;
}

TEST(Map, ProbeFindsTheServedBlocksWithReadsOnly) {
  auto t = open_target("ref:modbus-standard");
  map::Map m = map::probe(*t);
  EXPECT_FALSE(m.partial) << m.partial_at;
  EXPECT_LE(m.requests, map::kDefaultBudget);
  for (auto table : {spec::Table::holding, spec::Table::coil, spec::Table::input, spec::Table::discrete_input})
    EXPECT_EQ(found_blocks(m, table), spec_blocks(table)) << map::table_name(table);
  ASSERT_FALSE(m.unmapped.empty());
  for (const auto& u : m.unmapped) EXPECT_EQ(u.answer, "exception 02") << map::table_name(u.table);
  // Facts found by a probe are observed, never stated.
  spec::Spec s = map::apply(standard(), m);
  ASSERT_FALSE(s.registers.empty());
  EXPECT_EQ(s.registers.front().basis_of(spec::Fact::read).basis, spec::Basis::observed);
  EXPECT_EQ(s.registers.front().basis_of(spec::Fact::write).basis, spec::Basis::observed);
}

TEST(Map, ABudgetTooSmallGivesAPartialMap) {
  auto t = open_target("ref:modbus-standard");
  map::Map m = map::probe(*t, 20);
  EXPECT_TRUE(m.partial);
  EXPECT_FALSE(m.partial_at.empty());
  EXPECT_LE(m.requests, 20);
}

TEST(Map, InlineAndFileGiveTheSameBlocks) {
  map::Map inl = map::parse_inline("holding=0-199+0x0400-0x0427:rw,coils=0-63,input=16-45,discrete=0-15");
  auto dir = std::filesystem::temp_directory_path() / fmt::format("mbc_map_test.{}", getpid());
  std::filesystem::create_directories(dir);
  std::ofstream(dir / "m.yaml") << "mbconform_map: 1\n"
                                   "holding: [{from: 0, to: 199}, {from: 0x0400, to: 0x0427, access: rw}]\n"
                                   "coils: [{from: 0, to: 63}]\ninput: [{from: 16, to: 45}]\ndiscrete: [{from: 0, to: 15}]\n";
  map::Map file = map::load_file((dir / "m.yaml").string());
  EXPECT_EQ(inl.describe(), file.describe());
  std::ofstream(dir / "bad.yaml") << "mbconform_map: 1\nholding: [{from: 10, to: 5}]\n";
  try {
    map::load_file((dir / "bad.yaml").string());
    ADD_FAILURE() << "a range that ends before it starts was accepted";
  } catch (const std::runtime_error& e) {
    EXPECT_NE(std::string(e.what()).find("bad.yaml:2:"), std::string::npos) << e.what();
  }
  EXPECT_THROW(map::parse_inline("holding=9-1"), std::invalid_argument);
  EXPECT_THROW(map::parse_inline("registers=0-9"), std::invalid_argument);
  std::filesystem::remove_all(dir);
}

TEST(Map, TheMapPlacesTheStandardsCases) {
  auto cs = cases_on(map::parse_inline("holding=0-199,coils=0-199,input=0-199,discrete=0-199"));
  EXPECT_TRUE(has(cs, "/standard/fc05/past-map"));
  EXPECT_TRUE(has(cs, "/function-codes/fc03/past-map"));
  EXPECT_TRUE(has(cs, "/standard/order/fc03-quantity-before-address"));
  EXPECT_TRUE(has(cs, "/standard/fc05/value-00FF"));
  // Without a stated access, the cases that write wait for --allow-writes.
  for (const auto& c : cs) {
    if (c.id.ends_with("/standard/fc05/value-00FF")) {
      EXPECT_NE(c.skip_reason.find("--allow-writes"), std::string::npos);
    }
  }
  // A server that answers every address: nothing is past its end.
  auto all = cases_on(map::parse_inline("holding=0-65535,coils=0-65535,input=0-65535,discrete=0-65535"));
  for (const auto& c : all) {
    EXPECT_FALSE(c.id.ends_with("past-map")) << c.id;
    EXPECT_FALSE(c.id.find("/standard/order/") != std::string::npos) << c.id;
  }
  EXPECT_TRUE(has(all, "/standard/fc05/value-00FF"));  // the map-independent checks stay
}

}  // namespace
}  // namespace mbc::conf
