// URI parsing, and the in-process ref: target for every device spec: what a
// read returns and when the device stays silent come from the spec (defaults,
// exception policy) and MB over Serial Line v1.02, never from the engine.
#include <fmt/core.h>
#include <gtest/gtest.h>

#include "loader.h"
#include "modbus/crc16.h"
#include "modbus/judge.h"
#include "modbus/pdu.h"
#include "modbus/rtu.h"
#include "spec_registers.h"
#include "targets/target.h"

namespace mbc::conf {
namespace {

TEST(Uri, SplitsSchemeAuthorityPathAndQuery) {
  Uri rtu = parse_uri("rtu:///dev/ttyUSB0?baud=115200&parity=N&data=8&stop=1&unit=3");
  EXPECT_EQ(rtu.scheme, "rtu");
  EXPECT_EQ(rtu.host, "");
  EXPECT_EQ(rtu.path, "/dev/ttyUSB0");
  EXPECT_EQ(rtu.param("baud"), "115200");
  EXPECT_EQ(rtu.param("parity"), "N");
  EXPECT_EQ(rtu.param("unit"), "3");
  EXPECT_EQ(rtu.param("absent"), std::nullopt);

  Uri tcp = parse_uri("tcp://192.168.1.20:1502?unit=5");
  EXPECT_EQ(tcp.host, "192.168.1.20");
  EXPECT_EQ(tcp.port, 1502);
  Uri v6 = parse_uri("rtu-tcp://[::1]:4001");
  EXPECT_EQ(v6.scheme, "rtu-tcp");
  EXPECT_EQ(v6.host, "::1");
  EXPECT_EQ(v6.port, 4001);

  Uri ref = parse_uri("ref:hsc60?unit=2");
  EXPECT_EQ(ref.path, "hsc60");
  // Only the first '=' separates key and value: a plugin's config keeps its own.
  Uri plugin = parse_uri("plugin:./libx.so?config=slave=1,holding=0:16");
  EXPECT_EQ(plugin.path, "./libx.so");
  EXPECT_EQ(plugin.param("config"), "slave=1,holding=0:16");
}

// The kind is named by its URI scheme, and printed by the name the scheme
// spells (mbtls opens a tls target); a scheme no kind takes is no kind.
TEST(TargetKind, EachSchemeNamesItsKindAndItsPrintedName) {
  const std::pair<const char*, const char*> schemes[] = {{"ref", "ref"}, {"tcp", "tcp"},     {"rtu-tcp", "rtu-tcp"},
                                                         {"rtu", "rtu"}, {"mbtls", "tls"},   {"plugin", "plugin"}};
  for (const auto& [scheme, name] : schemes) {
    auto k = kind_of_scheme(scheme);
    ASSERT_TRUE(k) << scheme;
    EXPECT_STREQ(to_string(*k), name) << scheme;
  }
  EXPECT_NE(kind_of_scheme("rtu"), kind_of_scheme("rtu-tcp"));
  EXPECT_FALSE(kind_of_scheme("tls"));  // the scheme is mbtls
  EXPECT_FALSE(kind_of_scheme("modbus"));
  EXPECT_THROW(open_target("modbus://127.0.0.1:502"), std::invalid_argument);
  EXPECT_THROW(kind_of_uri(parse_uri("modbus://127.0.0.1:502"), "modbus://127.0.0.1:502"), std::invalid_argument);
}

// What a kind is before it is opened (`run --plan`): MBAP on tcp and mbtls
// (MB-TCP), RTU frames on the others (rtu-tcp is RTU over a socket); a socket
// or a serial line reaches a real device, ref and a plugin run in process.
TEST(TargetKind, FramingAndLivenessBeforeOpening) {
  using K = TargetKind;
  for (K k : {K::tcp, K::tls}) EXPECT_EQ(framing_of(k), &mbc::kTcp) << to_string(k);
  for (K k : {K::ref, K::rtu, K::rtu_tcp, K::plugin}) EXPECT_EQ(framing_of(k), &mbc::kRtu) << to_string(k);
  for (K k : {K::tcp, K::tls, K::rtu, K::rtu_tcp}) EXPECT_TRUE(is_live(k)) << to_string(k);
  for (K k : {K::ref, K::plugin}) EXPECT_FALSE(is_live(k)) << to_string(k);
}

TEST(Uri, RejectsMalformedText) {
  for (const char* bad : {"hsc60", ":hsc60", "tcp://[::1", "tcp://host:0", "tcp://host:port", "tcp://host:70000"})
    EXPECT_THROW(parse_uri(bad), std::invalid_argument) << bad;
  for (const char* bad : {"ftp://host/x", "ref:", "ref:no-such-device-id?unit=1"}) {
    try {
      open_target(bad);
      ADD_FAILURE() << bad << " opened";
    } catch (const std::invalid_argument&) {
    } catch (const std::runtime_error&) {  // an unknown device id is a spec that cannot be loaded
    }
  }
  EXPECT_THROW(open_target("ftp://host/x"), std::invalid_argument);
  EXPECT_THROW(open_target("ref:hsc60?unit=0"), std::invalid_argument);
  EXPECT_THROW(open_target("ref:hsc60?unit=abc"), std::invalid_argument);
}

class RefTarget : public ::testing::TestWithParam<std::string> {
 protected:
  spec::Spec spec = spec::load_spec_by_id(GetParam());
  std::unique_ptr<Target> target = open_target("ref:" + GetParam());
  uint8_t slave() const { return target->info().unit; }
  // A read of one readable register word the spec maps (FC 03 or 04).
  Bytes probe() const {
    for (const auto& r : spec.registers)
      if ((r.table == spec::Table::holding || r.table == spec::Table::input) && r.access != spec::Access::wo &&
          r.access != spec::Access::command)
        return read_request(r.table == spec::Table::input ? 4 : 3, r.address, uint16_t(r.words));
    throw std::logic_error(spec.device.id + " maps no readable register");
  }
};

TEST_P(RefTarget, InfoCarriesTheSpec) {
  const TargetInfo& i = target->info();
  EXPECT_EQ(i.kind, conf::TargetKind::ref);
  EXPECT_EQ(i.device_id, spec.device.id);
  EXPECT_EQ(i.unit, spec.serial.slave_default.value_or(1));
  EXPECT_EQ(i.baud, spec.serial.baud_default);
  EXPECT_FALSE(i.live);
  EXPECT_TRUE(i.raw && i.power_cycle && i.virtual_clock);
  EXPECT_EQ(framing_of(i.kind), i.framing);
  EXPECT_EQ(is_live(i.kind), i.live);
}

TEST_P(RefTarget, ReadsTheDefaultTheSpecStates) {
  const spec::Register* r = serve_test::pick_default_word(spec);
  if (!r) GTEST_SKIP() << "the spec states no default of a plain word";
  uint8_t fc = r->table == spec::Table::input ? 4 : 3;
  if (!spec.profile.function(fc)) GTEST_SKIP() << "FC " << int(fc) << " not in the profile";
  Bytes req = read_request(fc, r->address, 1);
  Reply reply = target->transact(req);
  ASSERT_TRUE(reply.pdu) << reply.framing_error << " " << to_hex(reply.frame);
  Judged j = judge_reply(req, *reply.pdu);
  ASSERT_TRUE(j.ok()) << describe_pdu(*reply.pdu, false);
  EXPECT_EQ(j.registers, std::vector<uint16_t>{uint16_t(int64_t(*r->default_value) & 0xFFFF)});
  EXPECT_EQ(reply.request, rtu_frame(slave(), req));
  EXPECT_TRUE(crc_ok(reply.frame));
}

// MB-SL v1.02 §2.2: only the addressed slave answers.
TEST_P(RefTarget, OtherSlaveIdsGetSilence) {
  Bytes req = probe();
  for (int other : {spec.serial.slave_min, spec.serial.slave_max, int(slave()) + 1}) {
    if (other == slave() || other < 1 || other > 247) continue;
    Reply reply = target->transact(uint8_t(other), req);
    EXPECT_TRUE(reply.silent()) << "slave " << other << ": " << to_hex(reply.frame);
  }
}

// MB-SL v1.02 §2.5.1.2: the spec's crc_error policy decides: silence, or the
// exception code the manual prints for a CRC error.
TEST_P(RefTarget, BadCrcFollowsThePolicy) {
  Bytes pdu = probe();
  Bytes adu = rtu_frame(slave(), pdu);
  adu[adu.size() - 2] ^= 0x01;
  Reply reply = target->send_raw(adu);
  EXPECT_EQ(reply.request, adu);
  auto policy = spec.profile.policy(spec::Violation::crc_error);
  switch (policy.kind) {
    case spec::PolicyEntry::Kind::silent:
      EXPECT_TRUE(reply.silent()) << to_hex(reply.frame);
      break;
    case spec::PolicyEntry::Kind::exception: {
      ASSERT_TRUE(reply.pdu) << reply.framing_error;
      Judged j = judge_reply(pdu, *reply.pdu);
      EXPECT_EQ(j.kind, Judged::Kind::exception);
      EXPECT_EQ(j.exception_code, policy.code);
      break;
    }
    case spec::PolicyEntry::Kind::unspecified:
      SUCCEED() << "the manual leaves it open";
  }
}

// MB-SL v1.02 §2.5.1.1: a frame cut by a gap is two incomplete frames.
TEST_P(RefTarget, FrameSplitByAGapIsNotAnswered) {
  Bytes adu = rtu_frame(slave(), probe());
  EXPECT_TRUE(target->send_raw(adu, 4).silent());
  EXPECT_TRUE(target->send_raw(adu).pdu);
}

INSTANTIATE_TEST_SUITE_P(Specs, RefTarget, ::testing::ValuesIn(spec::spec_ids()), [](const auto& p) {
  std::string n = p.param;
  for (auto& c : n)
    if (c == '-') c = '_';
  return n;
});

}  // namespace
}  // namespace mbc::conf
