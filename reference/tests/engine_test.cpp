// The engine against each device's exception policy, with the expected
// outcome taken from the spec's policy (or the standard where it is silent),
// and against garbage: no input crashes it or changes state unless valid.
#include <gtest/gtest.h>

#include <random>

#include "engine/device.h"
#include "loader.h"
#include "modbus/crc16.h"
#include "modbus/hex.h"

using namespace mbc;
using spec::Violation;

namespace {

Bytes adu(std::initializer_list<uint8_t> body) {
  Bytes b(body);
  uint16_t c = crc16(b);
  b.push_back(uint8_t(c & 0xFF));
  b.push_back(uint8_t(c >> 8));
  return b;
}

Bytes with_crc(Bytes b) {
  uint16_t c = crc16(b);
  b.push_back(uint8_t(c & 0xFF));
  b.push_back(uint8_t(c >> 8));
  return b;
}

// The reply the spec's policy demands for `v` (nullopt = silence).
std::optional<uint8_t> policy_code(const spec::Spec& s, Violation v) {
  auto p = s.profile.policy(v);
  if (v == Violation::quantity_zero && !s.profile.exception_policy.count(v)) p = s.profile.policy(Violation::quantity_over_limit);
  switch (p.kind) {
    case spec::PolicyEntry::Kind::exception: return uint8_t(p.code);
    case spec::PolicyEntry::Kind::silent: return std::nullopt;
    case spec::PolicyEntry::Kind::unspecified: {
      // The standard's answer (modbus-standard.yaml), which the reference gives when the manual is silent.
      static const spec::Spec standard = spec::load_spec_by_id("modbus-standard");
      return s.device.id == "modbus-standard" ? std::nullopt : policy_code(standard, v);
    }
  }
  return std::nullopt;
}

void expect_policy(const spec::Spec& s, Violation v, uint8_t fc, const std::optional<Bytes>& reply) {
  auto code = policy_code(s, v);
  SCOPED_TRACE(s.device.id + std::string(" ") + spec::to_string(v));
  if (!code) {
    EXPECT_FALSE(reply) << to_hex(*reply);
    return;
  }
  ASSERT_TRUE(reply);
  ASSERT_EQ(reply->size(), 5u) << to_hex(*reply);
  EXPECT_EQ((*reply)[1], uint8_t(fc | 0x80));
  EXPECT_EQ((*reply)[2], *code);
  EXPECT_TRUE(crc_ok(*reply));
}

class PerDevice : public ::testing::TestWithParam<std::string> {};

TEST_P(PerDevice, OutOfRangeWriteGetsThePolicyAndChangesNothing) {
  spec::Spec s = spec::load_spec_by_id(GetParam());
  int tested = 0;
  for (const auto& r : s.registers) {
    if (r.table != spec::Table::holding || r.words != 1 || r.access != spec::Access::rw || !r.range) continue;
    if (r.range->max >= (r.is_signed() ? 32767 : 65535)) continue;
    ref::Device d(s, 1);
    auto before = d.holding_image();
    uint16_t bad = uint16_t(int64_t(r.range->max) + 1);
    auto reply = d.handle_rtu(adu({1, 6, uint8_t(r.address >> 8), uint8_t(r.address), uint8_t(bad >> 8), uint8_t(bad)}));
    expect_policy(s, Violation::value_out_of_range, 6, reply);
    EXPECT_EQ(d.holding_image(), before) << "register " << r.address;
    ++tested;
  }
  if (tested == 0) GTEST_SKIP() << "no ranged rw register";
}

TEST_P(PerDevice, ReadOverTheLimitGetsThePolicy) {
  spec::Spec s = spec::load_spec_by_id(GetParam());
  const auto* fc3 = s.profile.function(3);
  if (!fc3) GTEST_SKIP();
  int limit = fc3->max_quantity.value_or(125);
  if (limit >= 125) GTEST_SKIP() << "the limit is the standard's";
  ref::Device d(s, 1);
  uint16_t start = s.registers.front().address;
  uint16_t qty = uint16_t(limit + 1);
  expect_policy(s, Violation::quantity_over_limit, 3,
                d.handle_rtu(adu({1, 3, uint8_t(start >> 8), uint8_t(start), uint8_t(qty >> 8), uint8_t(qty)})));
}

TEST_P(PerDevice, UnsupportedFunctionGetsThePolicy) {
  spec::Spec s = spec::load_spec_by_id(GetParam());
  for (uint8_t fc : {2, 4, 20, 24, 65, 100}) {
    if (s.profile.function(fc)) continue;
    ref::Device d(s, 1);
    expect_policy(s, Violation::unsupported_function, fc, d.handle_rtu(adu({1, fc, 0, 0, 0, 1})));
  }
}

TEST_P(PerDevice, QuantityZeroGetsThePolicy) {
  spec::Spec s = spec::load_spec_by_id(GetParam());
  ref::Device d(s, 1);
  uint16_t start = s.registers.front().address;
  expect_policy(s, Violation::quantity_zero, 3, d.handle_rtu(adu({1, 3, uint8_t(start >> 8), uint8_t(start), 0, 0})));
}

TEST_P(PerDevice, ReadPastTheMapGetsThePolicy) {
  spec::Spec s = spec::load_spec_by_id(GetParam());
  auto last = s.last_address();
  ASSERT_TRUE(last);
  if (*last == 0xFFFF) GTEST_SKIP();
  ref::Device d(s, 1);
  uint16_t a = uint16_t(*last + 1);
  expect_policy(s, Violation::address_past_map, 3, d.handle_rtu(adu({1, 3, uint8_t(a >> 8), uint8_t(a), 0, 1})));
}

TEST_P(PerDevice, WrongSlaveAndBadCrcChangeNothingAndGetNoReply) {
  spec::Spec s = spec::load_spec_by_id(GetParam());
  ref::Device d(s, 1);
  auto before = d.holding_image();
  const spec::Register* rw = nullptr;
  for (const auto& r : s.registers)
    if (r.access == spec::Access::rw && r.words == 1 && r.table == spec::Table::holding) {
      rw = &r;
      break;
    }
  ASSERT_TRUE(rw);
  Bytes good = adu({1, 6, uint8_t(rw->address >> 8), uint8_t(rw->address), 0, 1});
  Bytes other = adu({2, 6, uint8_t(rw->address >> 8), uint8_t(rw->address), 0, 1});
  EXPECT_FALSE(d.handle_rtu(other));
  for (size_t i = 0; i < good.size(); ++i) {
    Bytes bad = good;
    bad[i] ^= 0x01;
    auto reply = d.handle_rtu(bad);
    if (bad[0] == 1) expect_policy(s, Violation::crc_error, bad[1], reply);
    else EXPECT_FALSE(reply);
  }
  EXPECT_EQ(d.holding_image(), before);
}

TEST_P(PerDevice, GarbageNeverCrashesAndRepliesAreWellFormed) {
  spec::Spec s = spec::load_spec_by_id(GetParam());
  ref::Device d(s, 1);
  std::mt19937 rng(12345);
  for (int i = 0; i < 20000; ++i) {
    Bytes b(1 + rng() % 300);
    for (auto& x : b) x = uint8_t(rng());
    b[0] = 1;
    if (i % 2) {
      b.resize(std::min<size_t>(b.size(), 254));
      b = with_crc(b);
    }
    auto before = d.holding_image();
    auto reply = d.handle_rtu(b);
    if (!crc_ok(b) || b.size() < 4 || b.size() > 256) {
      EXPECT_EQ(d.holding_image(), before);
    }
    if (reply) {
      ASSERT_LE(reply->size(), 256u);
      ASSERT_TRUE(crc_ok(*reply));
      ASSERT_EQ((*reply)[0], 1);
      ASSERT_EQ((*reply)[1] & 0x7F, b[1] & 0x7F);
    }
    d.advance(100);
  }
}

INSTANTIATE_TEST_SUITE_P(Specs, PerDevice, ::testing::ValuesIn(spec::spec_ids()), [](const auto& info) {
  std::string n = info.param;
  for (char& c : n)
    if (!isalnum(static_cast<unsigned char>(c))) c = '_';
  return n;
});

// Broadcast writes apply on every device and are never answered (MB-SL v1.02 §2.1).
TEST(Bus, BroadcastAppliesEverywhereWithoutReply) {
  spec::Spec s = spec::load_spec_by_id("modbus-standard");
  ref::Bus bus;
  bus.add(std::make_unique<ref::Device>(s, 1));
  bus.add(std::make_unique<ref::Device>(s, 2));
  EXPECT_FALSE(bus.handle_rtu(adu({0, 6, 0, 1, 0, 42})));
  EXPECT_EQ(bus.find(1)->word(1), 42);
  EXPECT_EQ(bus.find(2)->word(1), 42);
  EXPECT_FALSE(bus.handle_rtu(adu({3, 3, 0, 1, 0, 1})));  // nobody at 3
  auto r = bus.handle_rtu(adu({2, 3, 0, 1, 0, 1}));
  ASSERT_TRUE(r);
  EXPECT_EQ(to_hex(*r), to_hex(adu({2, 3, 2, 0, 42})));
}

// Persistence (57HS-R §6.1): RW/S registers are stored on write, RW ones
// only by the save command; a power cycle keeps what was stored and
// restores the rest to defaults.
TEST(Persistence, PowerCycleKeepsStoredAndResetsVolatile) {
  spec::Spec s = spec::load_spec_by_id("sihong-57hs-r");
  const spec::Register* stored = nullptr;
  const spec::Register* vol = nullptr;
  for (const auto& r : s.registers) {
    if (r.access != spec::Access::rw || r.words != 1 || !r.range || !r.default_value || r.range->max <= *r.default_value) continue;
    if (!stored && r.persistence.by == spec::PersistBy::on_write) stored = &r;
    if (!vol && r.persistence.by == spec::PersistBy::save_command) vol = &r;
  }
  ASSERT_TRUE(stored && vol);
  ref::Device d(s, 1);
  int64_t sv = int64_t(*stored->default_value) + 1, vv = int64_t(*vol->default_value) + 1;
  ASSERT_TRUE(d.handle_rtu(adu({1, 6, uint8_t(stored->address >> 8), uint8_t(stored->address), uint8_t(sv >> 8), uint8_t(sv)})));
  ASSERT_TRUE(d.handle_rtu(adu({1, 6, uint8_t(vol->address >> 8), uint8_t(vol->address), uint8_t(vv >> 8), uint8_t(vv)})));
  d.power_cycle();
  EXPECT_EQ(d.value(*stored), sv);
  EXPECT_EQ(d.value(*vol), int64_t(*vol->default_value));  // never saved
  d.set_value(*vol, vv);
  d.save_persistent();
  d.power_cycle();
  EXPECT_EQ(d.value(*vol), vv);
  d.factory_reset();
  EXPECT_EQ(d.value(*stored), int64_t(*stored->default_value));
}

}  // namespace
