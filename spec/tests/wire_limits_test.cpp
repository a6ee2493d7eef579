// The per-function-code quantity limits modbus-standard.yaml states (MBAP
// v1.1b3 §6) agree with the wire maxima modbus/limits.h states (§4.1): each
// limit's request and reply fit a 253-byte PDU, the register limits are the
// largest that fit, and the coil limits are the register limits' byte budget.
#include <gtest/gtest.h>

#include <memory>
#include <span>
#include <vector>

#include "loader.h"
#include "modbus/framing.h"
#include "modbus/function_codes.h"
#include "modbus/limits.h"
#include "modbus/pdu.h"

using namespace mbc;

namespace {

// The largest request and reply PDU of function `code` at quantity q (and,
// for FC 23, write quantity w), built by the wire floor.
std::pair<size_t, size_t> sizes(uint8_t code, uint16_t q, uint16_t w = 0) {
  std::vector<uint16_t> regs(q), wregs(w);
  std::unique_ptr<bool[]> storage(new bool[q]());
  std::span<const bool> bits(storage.get(), q);
  switch (code) {
    case fc::read_coils:
    case fc::read_discrete_inputs: return {read_request(code, 0, q).size(), read_bits_reply(code, bits).size()};
    case fc::read_holding_registers:
    case fc::read_input_registers:
      return {read_request(code, 0, q).size(), read_registers_reply(code, regs).size()};
    case fc::write_multiple_coils: return {write_multiple_coils(0, bits).size(), 5};
    case fc::write_multiple_registers: return {write_multiple_registers(0, regs).size(), 5};
    case fc::read_write_multiple_registers:
      return {read_write_registers(0, q, 0, wregs).size(), read_registers_reply(code, regs).size()};
  }
  return {0, 0};
}

int limit(const spec::Spec& s, int code) {
  const spec::FunctionCode* f = s.profile.function(code);
  EXPECT_TRUE(f && f->max_quantity) << "modbus-standard.yaml states no max_quantity for FC " << code;
  return f && f->max_quantity ? *f->max_quantity : 0;
}

}  // namespace

TEST(WireLimits, FramingsAgreeWithTheMaxima) {
  EXPECT_EQ(kRtu.max_pdu(), kMaxPdu);
  EXPECT_EQ(kTcp.max_pdu(), kMaxPdu);
  EXPECT_EQ(kRtu.max_adu, kMaxRtuAdu);
  EXPECT_EQ(kTcp.max_adu, kMaxTcpAdu);
}

TEST(WireLimits, StandardQuantityLimitsFitThePdu) {
  spec::Spec s = spec::load_spec_by_id("modbus-standard");
  for (int code : {1, 2, 3, 4, 15, 16}) {
    auto [req, rep] = sizes(uint8_t(code), uint16_t(limit(s, code)));
    EXPECT_LE(req, kMaxPdu) << "FC " << code;
    EXPECT_LE(rep, kMaxPdu) << "FC " << code;
  }
  const spec::FunctionCode* rw = s.profile.function(23);
  ASSERT_TRUE(rw && rw->max_read_quantity && rw->max_write_quantity);
  auto [req, rep] = sizes(23, uint16_t(*rw->max_read_quantity), uint16_t(*rw->max_write_quantity));
  EXPECT_LE(req, kMaxPdu);
  EXPECT_LE(rep, kMaxPdu);
}

TEST(WireLimits, RegisterLimitsAreTheLargestThatFit) {
  spec::Spec s = spec::load_spec_by_id("modbus-standard");
  for (int code : {3, 4, 16}) {
    auto [req, rep] = sizes(uint8_t(code), uint16_t(limit(s, code) + 1));
    EXPECT_GT(std::max(req, rep), kMaxPdu) << "FC " << code << ": one more register still fits";
  }
  const spec::FunctionCode* rw = s.profile.function(23);
  ASSERT_TRUE(rw && rw->max_read_quantity && rw->max_write_quantity);
  EXPECT_GT(sizes(23, uint16_t(*rw->max_read_quantity + 1), 0).second, kMaxPdu);
  EXPECT_GT(sizes(23, 0, uint16_t(*rw->max_write_quantity + 1)).first, kMaxPdu);
}

// 2000 coils = 250 bytes = 125 registers; 1968 coils = 246 bytes = 123 registers.
TEST(WireLimits, CoilLimitsAreTheRegisterLimitsByteBudget) {
  spec::Spec s = spec::load_spec_by_id("modbus-standard");
  EXPECT_EQ(limit(s, 1), 8 * 2 * limit(s, 3));
  EXPECT_EQ(limit(s, 2), 8 * 2 * limit(s, 4));
  EXPECT_EQ(limit(s, 15), 8 * 2 * limit(s, 16));
}

// The spec language's statement of the standard and the wire floor's table
// (which the loader's checks and the conformance side read) are the same limits.
TEST(WireLimits, StandardSpecStatesTheWireTable) {
  spec::Spec s = spec::load_spec_by_id("modbus-standard");
  for (int code : {1, 2, 3, 4, 15, 16}) EXPECT_EQ(limit(s, code), standard_max_quantity(code)) << "FC " << code;
  const spec::FunctionCode* rw = s.profile.function(23);
  ASSERT_TRUE(rw && rw->max_read_quantity && rw->max_write_quantity);
  EXPECT_EQ(*rw->max_read_quantity, standard_max_quantity(23));
  EXPECT_EQ(*rw->max_write_quantity, kMaxReadWriteWriteQuantity);
}
