// Safety with live drives: what may be written (from the spec's access,
// command and persistence). Putting a served device back is the journal's
// restore: conformance/tests/session/restore_test.cpp.
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

TargetInfo live_info() {
  TargetInfo i;
  i.live = true;
  return i;
}

bool is_serial_setting(const spec::Spec& s, const Register& r) {
  for (const auto& st : s.serial.settings)
    if (st.register_address == r.address) return true;
  return false;
}

TEST(MayWrite, CommandRegistersNeedAllowMotionOnLiveTargets) {
  int commands = 0;
  for (const auto& id : spec::spec_ids()) {
    auto s = spec::load_spec_by_id(id);
    for (const auto& r : s.registers) {
      if (r.access != spec::Access::command && !r.command) continue;
      ++commands;
      EXPECT_TRUE(may_write(s, r, TargetInfo{}, {}).allowed) << id << " ref targets allow everything";
      auto d = may_write(s, r, live_info(), {});
      EXPECT_FALSE(d.allowed) << id << " " << r.address;
      EXPECT_NE(d.reason.find("--allow-motion"), std::string::npos) << d.reason;
      bool eeprom = r.command && r.command->eeprom;
      EXPECT_EQ(may_write(s, r, live_info(), {.allow_motion = true}).allowed, !eeprom) << id << " " << r.address;
      EXPECT_TRUE(may_write(s, r, live_info(), {.allow_motion = true, .allow_eeprom_writes = true}).allowed);
    }
  }
  EXPECT_GT(commands, 0) << "the specs name command registers";
}

TEST(MayWrite, StoredOnWriteNeedsAllowEepromUnlessTheSpecHasASwitch) {
  int stored = 0, switched = 0;
  for (const auto& id : spec::spec_ids()) {
    auto s = spec::load_spec_by_id(id);
    for (const auto& r : s.registers) {
      if (r.command || r.access == spec::Access::command) continue;
      const auto& p = r.persistence;
      bool on_write = p.store != spec::Store::none && p.by == spec::PersistBy::on_write;
      auto d = may_write(s, r, live_info(), {});
      if (is_serial_setting(s, r)) {
        // Slave id, baud rate, frame format: never written on a live line, whatever the opt-ins.
        EXPECT_FALSE(d.allowed) << id << " " << r.address;
        EXPECT_FALSE(may_write(s, r, live_info(), {.allow_motion = true, .allow_eeprom_writes = true}).allowed);
        continue;
      }
      if (on_write && !p.unless_register) {
        ++stored;
        EXPECT_FALSE(d.allowed) << id << " " << r.address;
        EXPECT_NE(d.reason.find("--allow-eeprom-writes"), std::string::npos) << d.reason;
        EXPECT_TRUE(may_write(s, r, live_info(), {.allow_eeprom_writes = true}).allowed);
      } else {
        switched += on_write;
        EXPECT_TRUE(d.allowed) << id << " " << r.address << ": " << d.reason;
      }
    }
  }
  EXPECT_GT(stored, 0);
  EXPECT_GT(switched, 0) << "57HS-R registers persist unless 0x0016 = 1";
}

}  // namespace
}  // namespace mbc::conf
