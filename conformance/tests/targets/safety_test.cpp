// Safety with live drives: the snapshot that puts a served device back
// the way it was, including the "do not persist" switch of the 57HS-R
// (0x0016, manual §6.1), checked end to end through serve's EEPROM files.
#include <fmt/core.h>
#include <fmt/ranges.h>
#include <gtest/gtest.h>

#include <cmath>
#include <csignal>

#include "loader.h"
#include "modbus/judge.h"
#include "modbus/pdu.h"
#include "safety/safety.h"
#include "serve_process.h"

namespace mbc::conf {
namespace {

using serve_test::ServeProcess;
using serve_test::TempDir;
using spec::Register;

std::vector<uint16_t> read(Target& t, uint16_t address, int words) {
  Bytes req = read_request(3, address, uint16_t(words));
  Reply r = t.transact(req);
  if (!r.pdu) throw std::runtime_error("no reply reading " + std::to_string(address));
  return judge_reply(req, *r.pdu).registers;
}

void write(Target& t, uint16_t address, uint16_t value) {
  Reply r = t.transact(write_single_register(address, value));
  if (!r.pdu || judge_reply(write_single_register(address, value), *r.pdu).kind != Judged::Kind::normal)
    throw std::runtime_error("write refused at " + std::to_string(address));
}

// A value in the register's range other than `now`, as a raw word.
std::optional<uint16_t> other_value(const Register& r, uint16_t now) {
  if (!r.range || r.words != 1) return std::nullopt;
  for (double v : {r.range->min, r.range->max, std::floor((r.range->min + r.range->max) / 2)})
    if (uint16_t(int64_t(v) & 0xFFFF) != now) return uint16_t(int64_t(v) & 0xFFFF);
  return std::nullopt;
}


bool is_serial_setting(const spec::Spec& s, const Register& r) {
  for (const auto& st : s.serial.settings)
    if (st.register_address == r.address) return true;
  return false;
}

// What may be written on a live target is the frame policy's: its tests
// are conformance/tests/policy/.

// A device without a switch (hsc60 keeps by a save command): the snapshot
// restores what the run changed, verified by reading back.
TEST(Snapshot, RestoresChangedRegistersOverTheWire) {
  for (const std::string id : {"hsc60", "modbus-standard"}) {
    SCOPED_TRACE(id);
    auto s = spec::load_spec_by_id(id);
    int slave = s.serial.slave_default.value_or(1);
    ServeProcess serve({"--device", fmt::format("{}@{}", id, slave), "--tcp", "127.0.0.1:0"});
    ASSERT_TRUE(serve.wait_listening(1)) << serve.log();
    auto t = open_target(fmt::format("tcp://{}?unit={}", serve.endpoint("tcp")->address, slave));
    Snapshot snap = Snapshot::take(*t, s, {});
    EXPECT_TRUE(snap.failures().empty()) << snap.failures().front();
    ASSERT_GT(snap.size(), 0u);
    EXPECT_FALSE(snap.persist_switch());
    // Every kept register holds what the spec says it powers up with.
    for (const auto& k : snap.kept()) {
      const Register* r = s.find_register(k.address, k.table);
      ASSERT_TRUE(r);
      if (r->words == 1 && r->default_value && !r->is_signed()) {
        EXPECT_EQ(k.value[0], uint16_t(int64_t(*r->default_value))) << k.name;
      }
    }
    int changed = 0;
    for (const auto& k : snap.kept()) {
      const Register* r = s.find_register(k.address, k.table);
      if (k.table != spec::Table::holding || is_serial_setting(s, *r) || changed == 5) continue;
      if (auto v = other_value(*r, k.value[0])) {
        write(*t, k.address, *v);
        ++changed;
      }
    }
    ASSERT_GT(changed, 0);
    auto failed = snap.restore(*t);
    EXPECT_TRUE(failed.empty()) << failed.front();
    for (const auto& k : snap.kept()) {
      if (k.table == spec::Table::holding) {
        EXPECT_EQ(read(*t, k.address, k.words), std::vector<uint16_t>(k.value, k.value + k.words)) << k.name;
      }
    }
  }
}

std::vector<bool> read_coils(Target& t, uint16_t address, int n) {
  Bytes req = read_request(1, address, uint16_t(n));
  Reply r = t.transact(req);
  if (!r.pdu) throw std::runtime_error("no reply reading coils");
  return judge_reply(req, *r.pdu).bits;
}

// Coils drive outputs: a run that writes them puts every one back. Flip every
// writable coil of modbus-standard through FC 05, then restore and read back.
TEST(Snapshot, RestoresCoils) {
  auto s = spec::load_spec_by_id("modbus-standard");
  ServeProcess serve({"--device", "modbus-standard@1", "--tcp", "127.0.0.1:0"});
  ASSERT_TRUE(serve.wait_listening(1)) << serve.log();
  auto t = open_target(fmt::format("tcp://{}?unit=1", serve.endpoint("tcp")->address));
  Snapshot snap = Snapshot::take(*t, s, {});
  EXPECT_TRUE(snap.failures().empty()) << snap.failures().front();
  int coils = 0;
  for (const auto& k : snap.kept()) {
    if (k.table != spec::Table::coil) continue;
    ++coils;
    Bytes req = write_single_coil(k.address, k.value[0] == 0);
    Reply r = t->transact(req);
    ASSERT_TRUE(r.pdu && judge_reply(req, *r.pdu).ok()) << k.name;
    ASSERT_EQ(read_coils(*t, k.address, 1), std::vector<bool>{k.value[0] == 0}) << k.name;
  }
  ASSERT_GT(coils, 0) << "modbus-standard has writable coils";
  auto failed = snap.restore(*t);
  EXPECT_TRUE(failed.empty()) << failed.front();
  for (const auto& k : snap.kept()) {
    if (k.table == spec::Table::coil) {
      EXPECT_EQ(read_coils(*t, k.address, 1), std::vector<bool>{k.value[0] != 0}) << k.name;
    }
  }
}

// Registers a drive will not read before the run are one finding: one line,
// adjacent addresses as ranges (the HSC60 serves none of modbus-standard's
// 0x0200 block).
TEST(Snapshot, UnreadableRegistersAreOneLineWithRanges) {
  auto s = spec::load_spec_by_id("modbus-standard");
  ServeProcess serve({"--device", "hsc60@1", "--tcp", "127.0.0.1:0"});
  ASSERT_TRUE(serve.wait_listening(1)) << serve.log();
  auto t = open_target(fmt::format("tcp://{}?unit=1", serve.endpoint("tcp")->address));
  Snapshot snap = Snapshot::take(*t, s, {});
  ASSERT_EQ(snap.failures().size(), 1u) << fmt::format("{}", fmt::join(snap.failures(), "\n"));
  const std::string& line = snap.failures().front();
  EXPECT_EQ(line.find("could not be read before the run"), 0u) << line;
  EXPECT_NE(line.find("0x0200-0x"), std::string::npos) << line;
  EXPECT_EQ(line.find('\n'), std::string::npos) << line;
  snap.restore(*t);
}

// 57HS-R §6.1: RW/S registers are stored on write unless 0x0016 = 1. The
// snapshot turns the switch on, so a change made during the run is not in
// EEPROM after a restart of the device; restore puts the switch back last.
TEST(Snapshot, DoNotPersistSwitchKeepsRunWritesOutOfEeprom) {
  const std::string id = "sihong-57hs-r";
  auto s = spec::load_spec_by_id(id);
  int slave = s.serial.slave_default.value_or(1);
  TempDir eeprom;
  auto start = [&] {
    auto p = std::make_unique<ServeProcess>(std::vector<std::string>{
        "--device", fmt::format("{}@{}", id, slave), "--tcp", "127.0.0.1:0", "--eeprom", eeprom.path()});
    if (!p->wait_listening(1)) throw std::runtime_error(p->log());
    return p;
  };
  auto serve = start();
  auto t = open_target(fmt::format("tcp://{}?unit={}", serve->endpoint("tcp")->address, slave));
  Snapshot snap = Snapshot::take(*t, s, {});
  EXPECT_TRUE(snap.failures().empty()) << snap.failures().front();
  ASSERT_TRUE(snap.persist_switch());
  const Register* sw = s.find_register(snap.persist_switch()->first);
  ASSERT_TRUE(sw);
  const Register* stored = nullptr;  // a register the switch keeps out of EEPROM
  for (const auto& k : snap.kept()) {
    const Register* r = s.find_register(k.address, k.table);
    if (r->persistence.unless_register == sw->address && !is_serial_setting(s, *r) && other_value(*r, k.value[0])) {
      stored = r;
      break;
    }
  }
  ASSERT_TRUE(stored);
  // The switch register itself is stored on write and not kept with the rest.
  for (const auto& k : snap.kept()) EXPECT_NE(k.address, sw->address);
  int64_t on_value = stored->persistence.unless_value;
  EXPECT_EQ(read(*t, sw->address, 1), std::vector<uint16_t>{uint16_t(on_value)});

  uint16_t before = read(*t, stored->address, 1)[0];
  write(*t, stored->address, *other_value(*stored, before));
  t.reset();
  ASSERT_EQ(serve->stop(SIGTERM), 0);  // serve saves EEPROM on SIGTERM
  serve = start();
  t = open_target(fmt::format("tcp://{}?unit={}", serve->endpoint("tcp")->address, slave));
  EXPECT_EQ(read(*t, stored->address, 1), std::vector<uint16_t>{before}) << "the run's write reached EEPROM";

  auto failed = snap.restore(*t);
  EXPECT_TRUE(failed.empty()) << failed.front();
  EXPECT_EQ(read(*t, sw->address, 1), std::vector<uint16_t>{snap.persist_switch()->second});
}

// Without --allow-eeprom-writes a live snapshot leaves out registers stored
// on every write; command registers are never kept.
TEST(Snapshot, KeepsOnlyWhatThePolicyLetsTheRunWrite) {
  auto s = spec::load_spec_by_id("sihong-57hs-r");
  int slave = s.serial.slave_default.value_or(1);
  ServeProcess serve({"--device", fmt::format("sihong-57hs-r@{}", slave), "--tcp", "127.0.0.1:0"});
  ASSERT_TRUE(serve.wait_listening(1));
  auto t = open_target(fmt::format("tcp://{}?unit={}", serve.endpoint("tcp")->address, slave));
  Snapshot snap = Snapshot::take(*t, s, {});
  for (const auto& k : snap.kept()) {
    const Register* r = s.find_register(k.address, k.table);
    EXPECT_TRUE(allowed_write(PolicyFacts{&s, t->info(), {}}, *r)) << k.name;
    EXPECT_FALSE(r->command) << k.name;
    EXPECT_EQ(r->access, spec::Access::rw) << k.name;
  }
  snap.restore(*t);
}

}  // namespace
}  // namespace mbc::conf
