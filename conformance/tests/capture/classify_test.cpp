// The one classifier of the oracle (cases/facts.h classify), which the case
// generators, the properties' model and check-capture's judge share. Every
// expectation here is written from the standard (MBAP v1.1b3 §6 per function
// code, §7 exception codes) and from the spec (spec/devices/*.yaml,
// spec/README.md), never from what a device or the classifier answers:
//   - modbus-standard's map: holding 0x0000-0x00FF rw, a gap 0x0100-0x01FF,
//     0x0200 u32, 0x0202 s32, 0x0210 ro, 0x0211 wo, 0x0212 rw 0..100; its
//     policy: 01 unsupported function, 02 addresses, 03 quantity and byte
//     count, 04 a value out of range (inferred);
//   - hsc60's 0x0046, a command register whose spec states what it reads back.
#include <gtest/gtest.h>

#include <algorithm>
#include <string>

#include "cases/case.h"
#include "cases/facts.h"
#include "check/text.h"
#include "loader.h"
#include "modbus/pdu.h"

namespace mbc::conf {
namespace {

using spec::Violation;

const spec::Spec& standard() {
  static spec::Spec s = spec::load_spec_by_id("modbus-standard");
  return s;
}

bool has(const facts::Classified& c, Violation v) {
  return std::any_of(c.breaches.begin(), c.breaches.end(), [v](const facts::Breach& b) { return b.violation == v; });
}

std::vector<Violation> violations(const facts::Classified& c) {
  std::vector<Violation> v;
  for (const auto& b : c.breaches) v.push_back(b.violation);
  return v;
}

bool relies_on(const facts::Relies& r, const std::string& fact) {
  return std::any_of(r.begin(), r.end(), [&](const Reliance& x) { return x.fact == fact; });
}

TEST(Classify, AValidReadGetsANormalReplyOnly) {
  // MBAP v1.1b3 §6.3: 1 <= quantity <= 125 and the addresses exist: the normal response.
  auto c = facts::classify(standard(), read_request(3, 0x0000, 2));
  EXPECT_TRUE(c.valid());
  EXPECT_TRUE(c.allows_normal());
  EXPECT_FALSE(c.allows_silence());
  EXPECT_FALSE(c.allows_exception(2));
  ASSERT_EQ(c.registers.size(), 2u);
  EXPECT_EQ(c.registers[1], std::make_pair(spec::Table::holding, uint16_t(1)));
  EXPECT_TRUE(relies_on(c.relies, "FC 3 supported"));
}

TEST(Classify, QuantityIsCheckedBeforeTheAddress) {
  // §6.3 Figure 13: "0x0001 <= Quantity of Registers <= 0x007D" -> 03, before
  // "Starting Address + Quantity of Registers" -> 02 (the spec's check-order example).
  auto c = facts::classify(standard(), read_request(3, 0x0300, 0));
  EXPECT_EQ(violations(c), std::vector<Violation>{Violation::quantity_zero});
  EXPECT_TRUE(c.allows_exception(3));
  EXPECT_FALSE(c.allows_exception(2));
  EXPECT_FALSE(c.allows_normal());
  EXPECT_FALSE(c.allows_silence());
}

TEST(Classify, TheStandardsQuantityLimitsHoldWhereTheSpecStatesNone) {
  spec::Spec s = standard();
  for (auto& f : s.profile.function_codes) f.max_quantity.reset(), f.max_read_quantity.reset(), f.max_write_quantity.reset();
  // §6.3: at most 125 registers; §6.12: at most 123; §6.17: write at most 121.
  EXPECT_TRUE(facts::classify(s, read_request(3, 0, 125)).valid());
  EXPECT_EQ(violations(facts::classify(s, read_request(3, 0, 126))), std::vector<Violation>{Violation::quantity_over_limit});
  std::vector<uint16_t> w124(124, 0), w123(123, 0);
  // 124 registers: over the limit, and a PDU of 254 bytes, over §4.1's 253 (a length the standard refuses too).
  auto over = facts::classify(s, write_multiple_registers(0, w124));
  EXPECT_TRUE(has(over, Violation::quantity_over_limit));
  EXPECT_TRUE(over.allows_exception(3));
  EXPECT_TRUE(facts::classify(s, write_multiple_registers(0, w123)).valid());
  // §6.1: at most 2000 coils.
  EXPECT_EQ(violations(facts::classify(s, read_request(1, 0, 2001))), std::vector<Violation>{Violation::quantity_over_limit});
}

TEST(Classify, ASpecsLowerLimitIsItsOwnFact) {
  spec::Spec s = standard();
  for (auto& f : s.profile.function_codes)
    if (f.code == 3) f.max_quantity = 16;
  auto c = facts::classify(s, read_request(3, 0, 17));
  ASSERT_EQ(violations(c), std::vector<Violation>{Violation::quantity_over_limit});
  EXPECT_TRUE(relies_on(c.breaches[0].relies, "FC 3 max_quantity"));
  EXPECT_TRUE(facts::classify(s, read_request(3, 0, 16)).valid());
}

TEST(Classify, AddressesPastTheMapInAGapAndDeniedByAccessAre02) {
  // MBAP v1.1b3 §7 code 02: "the combination of reference number and transfer length is invalid".
  auto gap = facts::classify(standard(), read_request(3, 0x00FF, 2));
  EXPECT_EQ(violations(gap), std::vector<Violation>{Violation::unmapped_address});
  EXPECT_TRUE(gap.allows_exception(2));
  auto past = facts::classify(standard(), read_request(3, 0xFFFF, 2));
  EXPECT_EQ(violations(past), std::vector<Violation>{Violation::address_past_map});
  // Several in one request (the gap 0x01F0-0x01FF, write-only 0x0211, past
  // 0x0212): each is listed, and each one's answer meets it (no manual orders them).
  auto both = facts::classify(standard(), read_request(3, 0x01F0, 125));
  EXPECT_EQ(violations(both), (std::vector<Violation>{Violation::address_past_map, Violation::unmapped_address,
                                                       Violation::read_write_only}));
  EXPECT_TRUE(both.allows_exception(2));
  // The spec's access: 0x0210 is read-only, 0x0211 write-only.
  auto ro = facts::classify(standard(), write_single_register(0x0210, 1));
  EXPECT_EQ(violations(ro), std::vector<Violation>{Violation::write_read_only});
  EXPECT_TRUE(relies_on(ro.breaches[0].relies, "register 0x0210 write"));
  EXPECT_EQ(violations(facts::classify(standard(), read_request(3, 0x0211, 1))), std::vector<Violation>{Violation::read_write_only});
}

TEST(Classify, AValueOutsideTheRegistersRangeIsItsPolicy) {
  // 0x0212: range 0..100; modbus-standard's value_out_of_range is 04 (§6.6 Figure 16), inferred.
  auto out = facts::classify(standard(), write_single_register(0x0212, 101));
  ASSERT_EQ(violations(out), std::vector<Violation>{Violation::value_out_of_range});
  EXPECT_TRUE(out.allows_exception(4));
  EXPECT_FALSE(out.allows_exception(3));
  EXPECT_TRUE(out.breaches[0].policy.basis.is_inferred());
  EXPECT_TRUE(relies_on(out.breaches[0].relies, "register 0x0212 range"));
  EXPECT_TRUE(facts::classify(standard(), write_single_register(0x0212, 100)).valid());
  // FC 16 too (§6.12): one register of the write out of range is enough.
  const uint16_t two[] = {5, 200};
  EXPECT_EQ(violations(facts::classify(standard(), write_multiple_registers(0x0211, two))),
            std::vector<Violation>{Violation::value_out_of_range});
}

TEST(Classify, HalfOfATwoWordValueIsDecidedOnlyWithTheOtherWord) {
  spec::Spec s = standard();
  for (auto& r : s.registers)
    if (r.address == 0x0200 && r.words == 2) r.range = spec::Range{0, 70000};
  const uint16_t big[] = {2, 2}, zero[] = {0, 0};  // 0x00020002 either word order: over 70000; 0
  EXPECT_EQ(violations(facts::classify(s, write_multiple_registers(0x0200, big))), std::vector<Violation>{Violation::value_out_of_range});
  EXPECT_TRUE(facts::classify(s, write_multiple_registers(0x0200, zero)).valid());
  // One word of it: either a normal reply or the refusal.
  auto half = facts::classify(s, write_single_register(0x0201, 2));
  EXPECT_TRUE(half.valid());
  ASSERT_TRUE(half.maybe);
  EXPECT_EQ(half.maybe->violation, Violation::value_out_of_range);
  // The other word known (the model's image): decided.
  facts::KnownWord two = [](spec::Table, uint16_t a) -> std::optional<uint16_t> { return a == 0x0200 ? std::optional<uint16_t>(2) : std::nullopt; };
  EXPECT_EQ(violations(facts::classify(s, write_single_register(0x0201, 2), two)), std::vector<Violation>{Violation::value_out_of_range});
  facts::KnownWord nought = [](spec::Table, uint16_t) -> std::optional<uint16_t> { return 0; };
  auto known = facts::classify(s, write_single_register(0x0201, 0), nought);
  EXPECT_TRUE(known.valid());
  EXPECT_FALSE(known.maybe);
}

TEST(Classify, ByteCountAndFunctionCode) {
  // §6.12 Figure 22: "Byte Count == Quantity of Registers x 2" -> 03.
  Bytes bad{0x10, 0x00, 0x00, 0x00, 0x02, 0x02, 0x00, 0x01};
  auto c = facts::classify(standard(), bad);
  EXPECT_EQ(violations(c), std::vector<Violation>{Violation::wrong_byte_count});
  EXPECT_TRUE(c.allows_exception(3));
  // §7: the exception bit makes it no request; a code the profile does not list: 01.
  EXPECT_EQ(violations(facts::classify(standard(), Bytes{0x83, 0x00, 0x00, 0x00, 0x01})),
            std::vector<Violation>{Violation::unsupported_function});
  EXPECT_TRUE(facts::classify(standard(), Bytes{0x83, 0x00, 0x00, 0x00, 0x01}).allows_exception(1));
  // FC 08 with a sub-function the spec does not list (Annex A reserves 0x0013): §6.8 Figure 18 -> 01.
  EXPECT_EQ(violations(facts::classify(standard(), Bytes{0x08, 0x00, 0x13, 0x00, 0x00})),
            std::vector<Violation>{Violation::unsupported_function});
  EXPECT_TRUE(facts::classify(standard(), Bytes{0x08, 0x00, 0x00, 0xA5, 0x37}).valid());  // 00 Return Query Data
  // A read PDU of the wrong length (§6.3: 5 bytes) has a length its fields do not account for.
  EXPECT_EQ(violations(facts::classify(standard(), Bytes{0x03, 0x00, 0x00, 0x00, 0x01, 0x00})),
            std::vector<Violation>{Violation::wrong_byte_count});
}

TEST(Classify, QuantityZeroLeftOutIsAnsweredByTheOverLimitPolicy) {
  // spec/README.md: quantity_zero is optional; the standard checks both in one
  // test ("0x0001 <= Quantity <= N"), so the over-limit policy answers it.
  spec::Spec s = standard();
  s.profile.exception_policy.erase(Violation::quantity_zero);
  spec::PolicyEntry five;
  five.kind = spec::PolicyEntry::Kind::exception;
  five.code = 5;
  five.section = "test";
  s.profile.exception_policy[Violation::quantity_over_limit] = five;
  auto c = facts::classify(s, read_request(3, 0, 0));
  ASSERT_EQ(violations(c), std::vector<Violation>{Violation::quantity_zero});
  EXPECT_TRUE(c.allows_exception(5));
  EXPECT_FALSE(c.allows_exception(3));
  // The same answer for the generators (policy_expect reads facts::policy).
  facts::Relies r;
  EXPECT_EQ(facts::policy(r, s, Violation::quantity_zero).code, 5);
}

TEST(Classify, AnUnstatedPolicyLeavesTheAnswerOpen) {
  // hsc60 states no quantity_zero policy ("unspecified"): any exception or silence.
  spec::Spec s = spec::load_spec_by_id("hsc60");
  auto c = facts::classify(s, read_request(3, 0, 0));
  ASSERT_EQ(violations(c), std::vector<Violation>{Violation::quantity_zero});
  EXPECT_TRUE(c.open());
  EXPECT_TRUE(c.allows_silence());
  EXPECT_TRUE(c.allows_exception(7));
  EXPECT_FALSE(c.allows_normal());
}

TEST(Classify, ACommandRegisterReadsWhereItsSpecSaysWhatItReadsBack) {
  // hsc60 0x0046 (motion command): "the register then reads 6" (command.reads_back).
  spec::Spec s = spec::load_spec_by_id("hsc60");
  const spec::Register* r = s.register_covering(0x0046);
  ASSERT_TRUE(r && r->access == spec::Access::command && r->command && r->command->reads_back);
  EXPECT_TRUE(facts::classify(s, read_request(3, 0x0046, 1)).valid());
  // Without it, a read of a command register is a read of a write-only one.
  for (auto& x : s.registers)
    if (x.address == 0x0046) x.command->reads_back.reset();
  EXPECT_EQ(violations(facts::classify(s, read_request(3, 0x0046, 1))), std::vector<Violation>{Violation::read_write_only});
}

// The case generators write each rejection case for one violation; the
// classifier must find that violation in the request the case sends.
TEST(Classify, EveryGeneratedPolicyCaseBreaksWhatItSays) {
  size_t checked = 0;
  for (const char* id : {"modbus-standard", "hsc60", "sihong-57hs-r", "hanstar-7trsm5740q", "rieding-dhe"}) {
    spec::Spec s = spec::load_spec_by_id(id);
    TargetInfo t;
    t.uri = std::string("ref:") + id;
    t.kind = conf::TargetKind::ref;
    t.virtual_clock = t.power_cycle = t.raw = true;
    GenContext g{s, t, {}, &standard(), std::nullopt};
    for (const Case& c : all_cases(g)) {
      if (c.id.find("/deviations/") != std::string::npos) continue;  // the standard's answers beside the manual's
      for (const auto& st : c.steps) {
        if (st.kind != check::Step::Kind::frame || st.unit != t.unit) continue;
        auto at = st.expect.text.find("(policy ");
        if (at == std::string::npos) continue;
        std::string name = st.expect.text.substr(at + 8);
        name = name.substr(0, name.find_first_of(",)"));
        auto cl = facts::classify(s, st.pdu);
        bool found = std::any_of(cl.breaches.begin(), cl.breaches.end(),
                                 [&](const facts::Breach& b) { return name == spec::to_string(b.violation); });
        EXPECT_TRUE(found) << c.id << ": " << check::line(st) << " expects policy " << name;
        ++checked;
      }
    }
  }
  EXPECT_GT(checked, 50u);
}

}  // namespace
}  // namespace mbc::conf
