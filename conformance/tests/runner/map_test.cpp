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

std::vector<Case> cases_on(const map::Map& m, bool live = false) {
  static const spec::Spec applied_base = standard();
  spec::Spec s = map::apply(applied_base, m);
  auto t = open_target("ref:modbus-standard");
  TargetInfo info = t->info();
  info.live = live;
  GenContext g{s, info, {}, &standard(), std::nullopt};
  g.map = map::terms(m);
  return all_cases(g);
}

bool has(const std::vector<Case>& cs, const std::string& suffix) {
  return std::any_of(cs.begin(), cs.end(), [&](const Case& c) { return c.id.ends_with(suffix); });
}

// The readable blocks of `t` the spec maps, joined where they touch: what
// the probe must find.
std::string spec_blocks(const spec::Spec& s, spec::Table t) {
  std::string out;
  int64_t first = -1, last = -2;
  auto flush = [&] {
    if (first >= 0) out += fmt::format("{:04X}-{:04X} ", first, last);
  };
  std::vector<const spec::Register*> regs;
  for (const auto& r : s.registers)
    if (r.table == t && r.access != spec::Access::wo) regs.push_back(&r);
  std::sort(regs.begin(), regs.end(), [](auto* a, auto* b) { return a->address < b->address; });
  for (const auto* r : regs) {
    if (int64_t(r->address) != last + 1) {
      flush();
      first = r->address;
    }
    last = std::max<int64_t>(last, r->last_address());
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
  DirectLink link(*t);
  map::Map m = map::probe(link);
  // Four tables of seeds outrun the budget (the map says so, partial); the
  // blocks are found before that.
  EXPECT_LE(m.requests, map::kDefaultBudget);
  for (auto table : {spec::Table::holding, spec::Table::coil, spec::Table::input, spec::Table::discrete_input})
    EXPECT_EQ(found_blocks(m, table), spec_blocks(standard(), table)) << map::table_name(table);
  ASSERT_FALSE(m.unmapped.empty());
  for (const auto& u : m.unmapped) EXPECT_EQ(u.answer, "exception 02") << map::table_name(u.table);
  EXPECT_TRUE(m.deviations.empty());
  // Facts found by a probe are observed, never stated.
  spec::Spec s = map::apply(standard(), m);
  ASSERT_FALSE(s.registers.empty());
  EXPECT_EQ(s.registers.front().basis_of(spec::Fact::read).basis, spec::Basis::observed);
  EXPECT_EQ(s.registers.front().basis_of(spec::Fact::write).basis, spec::Basis::observed);
}

// A drive's map has gaps: single registers among unmapped addresses, and
// clusters far from 0 (the Hanstar's at 1000, 2000, 2202, 2402, 3000, 4002).
// The probe finds at least 95% of each device's readable registers (its
// spec's, counted register by register) within the default budget.
TEST(Map, ProbeFindsTheGappedMapsOfTheDrives) {
  for (const char* id : {"sihong-57hs-r", "hsc60", "hanstar-7trsm5740q", "rieding-dhe"}) {
    spec::Spec s = spec::load_spec_by_id(id);
    auto t = open_target(std::string("ref:") + id);
    DirectLink link(*t);
    map::Map m = map::probe(link);
    EXPECT_LE(m.requests, map::kDefaultBudget) << id;
    size_t readable = 0, found = 0;
    std::string missed;
    for (const auto& r : s.registers) {
      if (r.access == spec::Access::wo) continue;
      ++readable;
      bool all = true;
      for (uint32_t a = r.address; a <= r.last_address(); ++a) all = all && m.covers(r.table, uint16_t(a));
      if (all) ++found;
      else missed += fmt::format(" 0x{:04X}", r.address);
    }
    ASSERT_GT(readable, 0u) << id;
    EXPECT_GE(found * 100, readable * 95) << id << ": found " << found << " of " << readable << "; missed" << missed
                                          << "\n" << m.describe();
    // Nothing the spec does not map.
    for (const auto& b : m.blocks)
      for (uint32_t a = b.first; a <= b.last; ++a)
        EXPECT_NE(s.register_covering(uint16_t(a), b.table), nullptr) << id << " " << map::table_name(b.table) << " " << a;
  }
}

// jsmodbus answered a read of 8 coils at 0xC1 with a well-formed byte
// though its table ends at 0xC7, and a read of 0xC8 alone with no data: a
// multi-item read that reaches past the table's end must not make the map.
// This stand-in has the same off-by-one (a read may end one past its 200
// coils) and answers a read that starts past them with a byte count of 0.
class BitsPastTheEnd : public Target {
 public:
  BitsPastTheEnd() {
    info_.uri = "fake:bits-past-end";
    info_.kind = conf::TargetKind::ref;
  }
  const TargetInfo& info() const override { return info_; }
  Reply transact(uint8_t, std::span<const uint8_t> pdu) override {
    Reply r;
    uint8_t fc = pdu[0];
    uint32_t a = uint32_t(pdu[1] << 8 | pdu[2]), n = uint32_t(pdu[3] << 8 | pdu[4]);
    if (fc != 1) {
      r.pdu = Bytes{uint8_t(fc | 0x80), 1};
    } else if (a < 200 && a + n <= 201) {
      Bytes p{fc, uint8_t((n + 7) / 8)};
      p.resize(2 + (n + 7) / 8, 0);
      r.pdu = p;
    } else if (a < 200) {
      r.pdu = Bytes{uint8_t(fc | 0x80), 2};
    } else {
      r.pdu = Bytes{fc, 0};
    }
    r.frame = *r.pdu;
    return r;
  }
  Reply send_raw(std::span<const uint8_t>, std::optional<size_t>) override { throw std::logic_error("no raw"); }
  void advance(std::chrono::microseconds) override {}
  void power_cycle() override {}

 private:
  TargetInfo info_;
};

TEST(Map, BitsAnsweredPastTheTablesEndAreADeviationNotTheMap) {
  BitsPastTheEnd t;
  DirectLink link(t);
  map::Map m = map::probe(link);
  EXPECT_EQ(m.describe(), "coils 0x0000-0x00C7");
  ASSERT_FALSE(m.deviations.empty());
  EXPECT_NE(m.deviations.front().find("past its table's end"), std::string::npos) << m.deviations.front();
}

TEST(Map, ATimeBoundStopsTheProbe) {
  auto t = open_target("ref:hanstar-7trsm5740q");
  DirectLink link(*t);
  map::Map m = map::probe(link, map::ProbeLimits{map::kDefaultBudget, std::chrono::milliseconds(0), nullptr});
  EXPECT_TRUE(m.partial);
  EXPECT_EQ(m.partial_by, "time");
}

TEST(Map, ABudgetTooSmallGivesAPartialMap) {
  auto t = open_target("ref:modbus-standard");
  DirectLink link(*t);
  map::Map m = map::probe(link, 20);
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
  // Without a stated access, the cases that write wait for --allow-writes
  // on a live target (the frame policy).
  for (const auto& c : cases_on(map::parse_inline("holding=0-199,coils=0-199,input=0-199,discrete=0-199"), true)) {
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
