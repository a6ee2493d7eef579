// The plugin target with the example plugin (libmodbus's modbus_reply behind
// the C ABI), configured from the modbus-standard spec's tables. Expected
// replies come from the standard (MBAP v1.1b3, MB-SL v1.02) and the spec.
#include <dlfcn.h>
#include <fmt/core.h>
#include <modbus.h>
#include <gtest/gtest.h>

#include <map>
#include <random>

#include "loader.h"
#include "modbus/crc16.h"
#include "modbus/judge.h"
#include "modbus/pdu.h"
#include "modbus/rtu.h"
#include "targets/target.h"

#ifdef EXAMPLE_PLUGIN

namespace mbc::conf {
namespace {

using spec::Table;

constexpr const char* kDevice = "modbus-standard";

// "holding=START:COUNT,..." covering each table the spec maps (one block each).
std::string config_from_spec(const spec::Spec& s, int slave) {
  std::map<Table, std::pair<uint32_t, uint32_t>> span;  // first, one past last
  for (const auto& r : s.registers) {
    auto [it, fresh] = span.try_emplace(r.table, r.address, r.last_address() + 1);
    it->second.first = std::min<uint32_t>(it->second.first, r.address);
    it->second.second = std::max<uint32_t>(it->second.second, r.last_address() + 1);
  }
  std::string c = fmt::format("slave={}", slave);
  const std::pair<Table, const char*> names[] = {
      {Table::coil, "coils"}, {Table::discrete_input, "discrete"}, {Table::holding, "holding"}, {Table::input, "input"}};
  for (auto [t, name] : names)
    if (auto it = span.find(t); it != span.end())
      c += fmt::format(",{}={}:{}", name, it->second.first, it->second.second - it->second.first);
  return c;
}

class PluginTarget : public ::testing::Test {
 protected:
  spec::Spec spec = spec::load_spec_by_id(kDevice);
  uint8_t slave = uint8_t(spec.serial.slave_default.value_or(1));
  std::string uri = fmt::format("plugin:{}?device={}&unit={}&config={}", EXAMPLE_PLUGIN, kDevice, slave,
                                config_from_spec(spec, slave));
  std::unique_ptr<Target> target = open_target(uri);

  const spec::Register& holding() const {
    for (const auto& r : spec.registers)
      if (r.table == Table::holding && r.access == spec::Access::rw && r.words == 1 && r.default_value) return r;
    throw std::logic_error("modbus-standard has a rw holding register with a default");
  }
  uint16_t read(uint16_t address) {
    Bytes req = read_request(3, address, 1);
    Reply r = target->transact(req);
    if (!r.pdu) throw std::runtime_error("no reply: " + r.framing_error);
    Judged j = judge_reply(req, *r.pdu);
    if (!j.ok()) throw std::runtime_error("malformed reply " + to_hex(*r.pdu));
    return j.registers.at(0);
  }
};

TEST_F(PluginTarget, InfoFollowsTheHooksThePluginHas) {
  const TargetInfo& i = target->info();
  EXPECT_EQ(i.kind, conf::TargetKind::plugin);
  EXPECT_EQ(i.device_id, kDevice);
  EXPECT_EQ(i.unit, slave);
  EXPECT_TRUE(i.raw);             // handle_rtu
  EXPECT_TRUE(i.power_cycle);     // power_cycle
  EXPECT_FALSE(i.virtual_clock);  // no advance_time_us
  EXPECT_FALSE(i.live);
  EXPECT_NE(i.implementation.find("libmodbus"), std::string::npos) << i.implementation;
  EXPECT_THROW(target->advance(std::chrono::microseconds(1)), std::logic_error);
  EXPECT_EQ(open_target(i.uri)->info().uri, i.uri);
}

TEST_F(PluginTarget, ReadsTheSpecDefaultAndWritesBack) {
  const auto& r = holding();
  EXPECT_EQ(read(r.address), uint16_t(int64_t(*r.default_value)));
  Bytes w = write_single_register(r.address, 0xBEEF);
  Reply reply = target->transact(w);
  ASSERT_TRUE(reply.pdu) << reply.framing_error;
  EXPECT_EQ(*reply.pdu, w);  // MBAP v1.1b3 §6.6: the echo
  EXPECT_TRUE(crc_ok(reply.frame));
  EXPECT_EQ(read(r.address), 0xBEEF);
}

// modbus-standard keeps nothing across power: a power cycle brings the default back.
TEST_F(PluginTarget, PowerCycleLosesVolatileState) {
  const auto& r = holding();
  ASSERT_EQ(r.persistence.store, spec::Store::none);
  target->transact(write_single_register(r.address, 0x1234));
  ASSERT_EQ(read(r.address), 0x1234);
  target->power_cycle();
  EXPECT_EQ(read(r.address), uint16_t(int64_t(*r.default_value)));
}

// MB-SL v1.02 §2.2, §2.5.1.2, §2.5.1.1: another slave's frame, a CRC error
// and a frame split by a gap get no reply.
TEST_F(PluginTarget, MalformedAndForeignFramesAreSilent) {
  Bytes pdu = read_request(3, holding().address, 1);
  EXPECT_TRUE(target->transact(uint8_t(slave + 1), pdu).silent());
  Bytes bad = rtu_frame(slave, pdu);
  bad.back() ^= 0x5A;
  EXPECT_TRUE(target->send_raw(bad).silent());
  EXPECT_TRUE(target->send_raw(rtu_frame(slave, pdu), 2).silent());
  Reply ok = target->send_raw(rtu_frame(slave, pdu));
  EXPECT_TRUE(ok.pdu) << ok.framing_error;
}

// MBAP v1.1b3 §7: a function code the server does not implement gets exception 01.
TEST_F(PluginTarget, UnknownFunctionCodeGetsIllegalFunction) {
  Bytes pdu{0x41, 0x00};  // 0x41..0x48 are reserved for user functions (MBAP §5)
  Reply r = target->transact(pdu);
  ASSERT_TRUE(r.pdu) << r.framing_error;
  Judged j = judge_reply(pdu, *r.pdu);
  EXPECT_EQ(j.kind, Judged::Kind::exception);
  EXPECT_EQ(j.exception_code, 1);
}

// Whatever bytes arrive, the target returns (no crash, no hang) and any reply
// is framed: CRC right and from our slave.
TEST_F(PluginTarget, ArbitraryBytesNeverBreakTheTarget) {
  std::mt19937 rng(20261130);
  for (int i = 0; i < 2000; ++i) {
    Bytes adu(rng() % 300);
    for (auto& b : adu) b = uint8_t(rng());
    if (!adu.empty() && i % 2) adu[0] = slave;
    if (adu.size() >= 4 && i % 3) {  // a valid CRC a third of the time less often
      uint16_t c = crc16(std::span(adu).first(adu.size() - 2));
      adu[adu.size() - 2] = uint8_t(c);
      adu.back() = uint8_t(c >> 8);
    }
    Reply r = target->send_raw(adu);
    if (!r.silent()) {
      EXPECT_TRUE(r.pdu) << to_hex(adu) << " -> " << to_hex(r.frame) << ": " << r.framing_error;
    }
  }
}

TEST(PluginTargetUri, BadPluginsAreNamedInTheError) {
  auto expect_runtime = [](const std::string& uri, const std::string& needle) {
    try {
      open_target(uri);
      ADD_FAILURE() << uri << " opened";
    } catch (const std::runtime_error& e) {
      EXPECT_NE(std::string(e.what()).find(needle), std::string::npos) << e.what();
    }
  };
  expect_runtime("plugin:/nonexistent/libnope.so", "plugin:/nonexistent/libnope.so");
  Dl_info libmodbus{};  // a real shared library without the entry point
  ASSERT_NE(dladdr(reinterpret_cast<void*>(&modbus_new_rtu), &libmodbus), 0);
  expect_runtime(fmt::format("plugin:{}", libmodbus.dli_fname), "not an mbconform plugin");
  expect_runtime(fmt::format("plugin:{}?config=holding=banana", EXAMPLE_PLUGIN), "holding=banana");
  EXPECT_THROW(open_target(fmt::format("plugin:{}?colour=red", EXAMPLE_PLUGIN)), std::invalid_argument);
  EXPECT_THROW(open_target(fmt::format("plugin:{}?device=no-such-device", EXAMPLE_PLUGIN)), std::invalid_argument);
  EXPECT_THROW(open_target(fmt::format("plugin:{}?unit=0", EXAMPLE_PLUGIN)), std::invalid_argument);
  EXPECT_THROW(open_target("plugin:"), std::invalid_argument);
}

}  // namespace
}  // namespace mbc::conf

#endif  // EXAMPLE_PLUGIN
