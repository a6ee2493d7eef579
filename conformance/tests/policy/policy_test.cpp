// The frame policy (conformance/policy/): one test per rule, each showing
// the frame refused without its opt-in (named) and let out with it, so that
// removing any one rule makes a test here fail. The specs are built here,
// field by field, so each rule is met by exactly the register made for it;
// a last test runs the shipped specs.
#include <gtest/gtest.h>

#include "loader.h"
#include "modbus/crc16.h"
#include "modbus/mbap.h"
#include "modbus/pdu.h"
#include "modbus/rtu.h"
#include "policy/policy.h"

namespace mbc::conf {
namespace {

using spec::Register;
using spec::Table;

TargetInfo live(uint8_t unit = 1, Framing framing = &mbc::kRtu) {
  TargetInfo i;
  i.kind = framing == &mbc::kRtu ? conf::TargetKind::rtu : conf::TargetKind::tcp;
  i.framing = framing;
  i.live = true;
  i.raw = true;
  i.unit = unit;
  return i;
}

Register reg(uint16_t address, std::string key, std::string en = "", std::string zh = "") {
  Register r;
  r.address = address;
  r.key = key;
  r.name.en = en.empty() ? key : en;
  r.name.zh = zh;
  return r;
}

// One register per rule, the profile's codes, a stated answer to unmapped addresses.
spec::Spec made() {
  spec::Spec s;
  s.device.id = "made";
  for (int fc : {3, 5, 6, 8, 15, 16, 21, 43, 65, 100}) {
    spec::FunctionCode f;
    f.code = fc;
    if (fc == 8) f.subfunctions = {0x00, 0x01, 0x02, 0x04, 0x0A};
    if (fc == 43) f.mei_types = {14};
    s.profile.function_codes.push_back(f);
  }
  spec::PolicyEntry two;
  two.kind = spec::PolicyEntry::Kind::exception;
  two.code = 2;
  s.profile.exception_policy[spec::Violation::unmapped_address] = two;
  s.profile.exception_policy[spec::Violation::address_past_map] = two;
  s.registers.push_back(reg(0x10, "speed"));
  s.registers.push_back(reg(0x11, "line"));
  s.serial.settings.push_back({0x11, "baud_rate", {}, ""});
  s.registers.push_back(reg(0x12, "no-persist"));
  Register kept = reg(0x13, "kept");
  kept.persistence = {spec::Store::eeprom, spec::PersistBy::on_write, std::nullopt, 0x12, 1, ""};
  s.registers.push_back(kept);
  Register motion = reg(0x14, "motion");
  motion.access = spec::Access::command;
  motion.command = spec::Command{"start", std::nullopt, true, false, {}};
  s.registers.push_back(motion);
  Register store = reg(0x15, "store-cmd");
  store.access = spec::Access::command;
  store.command = spec::Command{"save", std::nullopt, false, true, {}};
  s.registers.push_back(store);
  s.registers.push_back(reg(0x16, "save"));
  s.operations.save = spec::RegisterWrite{"save", 1, 0, "", {}};
  s.registers.push_back(reg(0x17, "reset"));
  s.operations.factory_reset = spec::RegisterWrite{"reset", 1, 0, "", {}};
  Register worn = reg(0x18, "worn");
  worn.persistence = {spec::Store::eeprom, spec::PersistBy::on_write, std::nullopt, std::nullopt, 0, ""};
  s.registers.push_back(worn);
  Register guessed = reg(0x19, "guessed");
  guessed.basis[spec::Fact::write] = spec::FactBasis{spec::Basis::inferred, "not printed", "", "", "", "", {}, {}};
  s.registers.push_back(guessed);
  Register seen = reg(0x1A, "seen");
  seen.basis[spec::Fact::read] = spec::FactBasis{spec::Basis::observed, "a probe read it", "", "", "", "", {}, {}};
  s.registers.push_back(seen);
  s.registers.push_back(reg(0x1B, "r1b", "", "运行命令"));
  s.registers.push_back(reg(0x1C, "r1c", "", "波特率"));
  s.registers.push_back(reg(0x1D, "r1d", "", "保存参数"));
  s.registers.push_back(reg(0x1E, "r1e", "Factory defaults"));
  s.registers.push_back(reg(0x30, "after-gap"));
  Register coil = reg(0x00, "coil");
  coil.table = Table::coil;
  s.registers.push_back(coil);
  std::stable_sort(s.registers.begin(), s.registers.end(),
                   [](const Register& a, const Register& b) { return std::pair(a.table, a.address) < std::pair(b.table, b.address); });
  return s;
}

const spec::Spec& the_spec() {
  static const spec::Spec s = made();
  return s;
}

PolicyFacts facts(WritePolicy o = {}, const spec::Spec* s = &the_spec(), TargetInfo t = live()) { return PolicyFacts{s, t, o}; }

Bytes w06(uint16_t a, uint16_t v = 1) { return write_single_register(a, v); }

// Refused, naming `opt_in` (empty: none allows it).
::testing::AssertionResult refused_for(const Decision& d, const std::string& opt_in) {
  if (d) return ::testing::AssertionFailure() << "let out";
  if (d.refused->opt_in != opt_in)
    return ::testing::AssertionFailure() << "opt-in '" << d.refused->opt_in << "', not '" << opt_in << "': " << d.refused->reason;
  if (!opt_in.empty() && d.refused->reason.find(opt_in) == std::string::npos)
    return ::testing::AssertionFailure() << "the reason does not name " << opt_in << ": " << d.refused->reason;
  return ::testing::AssertionSuccess();
}

constexpr WritePolicy kAll{true, true, true, true, true};

TEST(Policy, APlainRegisterOfTheTargetsUnitGoesOut) {
  EXPECT_TRUE(allowed(facts(), 1, w06(0x10)));
  EXPECT_TRUE(allowed(facts(), 1, read_request(3, 0x11, 1))) << "reads of anything";
}

TEST(Policy, SimulationsPassEverything) {
  TargetInfo ref = live();
  ref.live = false;
  for (Bytes pdu : {w06(0x11), w06(0x14), Bytes{65}, Bytes{8, 0, 4, 0, 0}})
    EXPECT_TRUE(allowed(facts({}, &the_spec(), ref), 2, pdu));
}

TEST(Policy, NothingThatChangesADriveGoesToAnotherUnit) {
  EXPECT_TRUE(refused_for(allowed(facts(kAll), 2, w06(0x10)), ""));
  EXPECT_TRUE(refused_for(allowed(facts(kAll), 2, Bytes{8, 0, 1, 0, 0}), ""));
  EXPECT_TRUE(allowed(facts(), 2, read_request(3, 0x10, 1))) << "a read for another slave must stay unanswered: it goes";
}

TEST(Policy, BroadcastNeedsItsOptIn) {
  EXPECT_TRUE(refused_for(allowed(facts(), 0, w06(0x10)), "--allow-broadcast"));
  EXPECT_TRUE(allowed(facts({.allow_broadcast = true}), 0, w06(0x10)));
  EXPECT_TRUE(allowed(facts(), 0, read_request(3, 0x10, 1))) << "MB-SL v1.02 §6.1.2: reads are not executed in broadcast";
}

TEST(Policy, UserDefinedCodesNeedAllowDisruptiveEvenWhenListed) {
  for (uint8_t fc : {65, 100}) {
    EXPECT_TRUE(refused_for(allowed(facts(), 1, Bytes{fc, 0, 0}), "--allow-disruptive")) << int(fc);
    EXPECT_TRUE(allowed(facts({.allow_disruptive = true}), 1, Bytes{fc, 0, 0}));
  }
}

TEST(Policy, WriteFileRecordNeedsAllowDisruptiveEvenWhenListed) {
  Bytes fc21{21, 7, 6, 0, 4, 0, 7, 0, 0};
  EXPECT_TRUE(refused_for(allowed(facts(), 1, fc21), "--allow-disruptive"));
  EXPECT_TRUE(allowed(facts({.allow_disruptive = true}), 1, fc21));
}

TEST(Policy, ACodeTheProfileDoesNotListNeedsAllowDisruptive) {
  EXPECT_TRUE(refused_for(allowed(facts(), 1, Bytes{17}), "--allow-disruptive"));
  EXPECT_TRUE(allowed(facts({.allow_disruptive = true}), 1, Bytes{17}));
  // The reads of the four tables change nothing: the probe of a map sends them.
  EXPECT_TRUE(allowed(facts(), 1, read_request(1, 0, 8)));
  EXPECT_TRUE(allowed(facts(), 1, read_request(4, 0, 8)));
}

TEST(Policy, DiagnosticsThatChangeTheLineNeedAllowDisruptiveEvenWhenListed) {
  for (uint8_t sub : {0x01, 0x04, 0x0A}) {
    Bytes pdu{8, 0, sub, 0, 0};
    EXPECT_TRUE(refused_for(allowed(facts(), 1, pdu), "--allow-disruptive")) << int(sub);
    EXPECT_TRUE(allowed(facts({.allow_disruptive = true}), 1, pdu));
  }
  EXPECT_TRUE(allowed(facts(), 1, Bytes{8, 0, 0, 0x12, 0x34})) << "08/00 returns the query";
  EXPECT_TRUE(allowed(facts(), 1, Bytes{8, 0, 2, 0, 0})) << "08/02 returns the diagnostic register";
  // A sub-function the profile does not list: its effect is not stated.
  EXPECT_TRUE(refused_for(allowed(facts(), 1, Bytes{8, 0, 0x0B, 0, 0}), "--allow-disruptive"));
}

TEST(Policy, AnUnlistedMeiTypeNeedsAllowDisruptive) {
  EXPECT_TRUE(allowed(facts(), 1, Bytes{43, 14, 1, 0}));
  EXPECT_TRUE(refused_for(allowed(facts(), 1, Bytes{43, 13, 0, 0}), "--allow-disruptive"));
}

TEST(Policy, WithoutASpecNothingIsWritten) {
  PolicyFacts none{nullptr, live(), kAll};
  EXPECT_TRUE(refused_for(allowed(none, 1, w06(0x10)), ""));
  EXPECT_TRUE(allowed(PolicyFacts{nullptr, live(), {}}, 1, read_request(3, 0, 1)));
}

TEST(Policy, LineSettingsAreNeverWritten) {
  EXPECT_TRUE(refused_for(allowed(facts(kAll), 1, w06(0x11)), ""));
  uint16_t v[3] = {1, 2, 3};
  EXPECT_TRUE(refused_for(allowed(facts(kAll), 1, write_multiple_registers(0x10, v)), "")) << "inside a multiple write";
}

TEST(Policy, TheDoNotPersistSwitchIsNeverWritten) {
  EXPECT_TRUE(refused_for(allowed(facts(kAll), 1, w06(0x12)), ""));
  // What it holds back is written while it is on (the session holds it on).
  EXPECT_TRUE(allowed(facts(), 1, w06(0x13)));
}

TEST(Policy, CommandRegistersNeedAllowMotion) {
  EXPECT_TRUE(refused_for(allowed(facts(), 1, w06(0x14)), "--allow-motion"));
  EXPECT_TRUE(allowed(facts({.allow_motion = true}), 1, w06(0x14)));
}

TEST(Policy, ACommandThatStoresNeedsBoth) {
  EXPECT_TRUE(refused_for(allowed(facts(), 1, w06(0x15)), "--allow-motion"));
  EXPECT_TRUE(refused_for(allowed(facts({.allow_motion = true}), 1, w06(0x15)), "--allow-eeprom-writes"));
  EXPECT_TRUE(allowed(facts({.allow_motion = true, .allow_eeprom_writes = true}), 1, w06(0x15)));
}

TEST(Policy, SaveAndFactoryResetOperationsNeedAllowEepromWrites) {
  for (uint16_t a : {0x16, 0x17}) {
    EXPECT_TRUE(refused_for(allowed(facts(), 1, w06(a)), "--allow-eeprom-writes")) << a;
    EXPECT_TRUE(allowed(facts({.allow_eeprom_writes = true}), 1, w06(a)));
  }
}

TEST(Policy, StoredOnEveryWriteNeedsAllowEepromWrites) {
  EXPECT_TRUE(refused_for(allowed(facts(), 1, w06(0x18)), "--allow-eeprom-writes"));
  EXPECT_TRUE(allowed(facts({.allow_eeprom_writes = true}), 1, w06(0x18)));
}

TEST(Policy, AnInferredOrObservedAccessNeedsAllowWrites) {
  for (uint16_t a : {0x19, 0x1A}) {
    EXPECT_TRUE(refused_for(allowed(facts(), 1, w06(a)), "--allow-writes")) << a;
    EXPECT_TRUE(allowed(facts({.allow_writes = true}), 1, w06(a)));
  }
}

TEST(Policy, UnmappedAddressesNeedAStatedAnswerOrAllowWrites) {
  EXPECT_TRUE(allowed(facts(), 1, w06(0x25))) << "the policy states exception 02 there";
  spec::Spec open = the_spec();
  open.profile.exception_policy.erase(spec::Violation::unmapped_address);
  EXPECT_TRUE(refused_for(allowed(facts({}, &open), 1, w06(0x25)), "--allow-writes"));
  EXPECT_TRUE(allowed(facts({.allow_writes = true}, &open), 1, w06(0x25)));
  spec::Spec inferred = the_spec();
  inferred.profile.exception_policy[spec::Violation::address_past_map].basis.basis = spec::Basis::inferred;
  EXPECT_TRUE(refused_for(allowed(facts({}, &inferred), 1, w06(0x40)), "--allow-writes")) << "past the map";
}

TEST(Policy, AMapNoManualStatesNeedsAllowWritesForAnyWrite) {
  for (const char* source : {"csv", "discover", "probe", "wb-mqtt-serial"}) {
    spec::Spec s = the_spec();
    s.device.manual.source = source;
    EXPECT_TRUE(refused_for(allowed(facts({}, &s), 1, w06(0x10)), "--allow-writes")) << source;
    EXPECT_TRUE(refused_for(allowed(facts({}, &s), 1, w06(0x25)), "--allow-writes")) << source << ": unmapped";
    EXPECT_TRUE(allowed(facts({.allow_writes = true}, &s), 1, w06(0x10)));
  }
}

TEST(Policy, TheLexiconGuardsAMapNoManualStates) {
  spec::Spec s = the_spec();
  s.device.manual.source = "csv";
  WritePolicy writes{.allow_writes = true};
  EXPECT_TRUE(refused_for(allowed(facts(writes, &s), 1, w06(0x1B)), "--allow-motion")) << "运行命令";
  EXPECT_TRUE(refused_for(allowed(facts(kAll, &s), 1, w06(0x1C)), "")) << "波特率";
  EXPECT_TRUE(refused_for(allowed(facts(writes, &s), 1, w06(0x1D)), "--allow-eeprom-writes")) << "保存参数";
  EXPECT_TRUE(refused_for(allowed(facts(writes, &s), 1, w06(0x1E)), "--allow-eeprom-writes")) << "Factory defaults";
  WritePolicy motion = writes;
  motion.allow_motion = true;
  EXPECT_TRUE(allowed(facts(motion, &s), 1, w06(0x1B)));
  // A manual's spec says what its registers are in its own terms.
  EXPECT_TRUE(allowed(facts(), 1, w06(0x1B)));
  EXPECT_EQ(role_of(s, *s.find_register(0x1C)), spec::Role::baud);
}

TEST(Policy, RolesInTheSpecLanguagesOwnTerms) {
  spec::Spec s = the_spec();
  s.control = spec::Control{};
  s.control->motion = spec::MotionOperations{};
  s.control->motion->start_forward = spec::RegisterWrite{"speed", 1, 0, "", {}};
  EXPECT_EQ(role_of(s, *s.find_register(0x10)), spec::Role::motion);
  EXPECT_TRUE(refused_for(allowed(facts({}, &s), 1, w06(0x10)), "--allow-motion")) << "control.motion start";
  EXPECT_EQ(role_of(the_spec(), *the_spec().find_register(0x16)), spec::Role::save);
  EXPECT_EQ(role_of(the_spec(), *the_spec().find_register(0x17)), spec::Role::factory_reset);
  EXPECT_EQ(role_of(the_spec(), *the_spec().find_register(0x11)), spec::Role::baud);
}

TEST(Policy, AllowedWriteIsTheNaturalWrite) {
  EXPECT_TRUE(allowed_write(facts(), *the_spec().find_register(0x10)));
  EXPECT_TRUE(refused_for(allowed_write(facts(), *the_spec().find_register(0x14)), "--allow-motion"));
  EXPECT_TRUE(allowed_write(facts(), *the_spec().find_register(0x00, Table::coil)));
}

// ---- what a frame writes, and raw bytes as a receiver splits them ----------

TEST(Policy, WritesOfEveryWriteFunction) {
  auto w = writes_of(write_single_register(0x0020, 7));
  ASSERT_TRUE(w);
  EXPECT_EQ(w->table, Table::holding);
  EXPECT_EQ(w->address, 0x0020);
  EXPECT_EQ(w->count, 1);
  uint16_t v[3] = {1, 2, 3};
  w = writes_of(write_multiple_registers(0x0100, v));
  ASSERT_TRUE(w);
  EXPECT_EQ(w->count, 3);
  w = writes_of(write_single_coil(5, true));
  ASSERT_TRUE(w);
  EXPECT_EQ(w->table, Table::coil);
  EXPECT_FALSE(writes_of(read_request(3, 0, 10)));
  // A quantity cut off: as many as a receiver could take.
  w = writes_of(Bytes{16, 0, 0x10});
  ASSERT_TRUE(w);
  EXPECT_EQ(w->count, 123);
}

Bytes rtu(uint8_t unit, const Bytes& pdu) { return rtu_frame(unit, pdu); }
Bytes mbap(uint8_t unit, const Bytes& pdu, uint16_t tid = 1) { return mbap_frame(tid, unit, pdu); }

TEST(Policy, RtuBytesAreJudgedByEveryFrameAReceiverTakes) {
  Bytes ok = rtu(1, w06(0x10));
  EXPECT_TRUE(allowed_raw(facts(), ok));
  // Two frames in one write: the second is a motion write.
  Bytes two = ok;
  for (uint8_t b : rtu(1, w06(0x14))) two.push_back(b);
  EXPECT_TRUE(refused_for(allowed_raw(facts(), two), "--allow-motion"));
  // To another unit, behind a frame that is fine.
  Bytes other = ok;
  for (uint8_t b : rtu(2, w06(0x10))) other.push_back(b);
  EXPECT_TRUE(refused_for(allowed_raw(facts(kAll), other), ""));
  // Over-long: the valid prefix is a frame to a receiver that frames by length.
  Bytes longer = rtu(1, w06(0x11));
  longer.push_back(0x55);
  EXPECT_TRUE(refused_for(allowed_raw(facts(kAll), longer), ""));
  // Split by a pause: each part alone (here the second part is a whole frame).
  Bytes split{0x01, 0x03};
  size_t gap = split.size();
  for (uint8_t b : rtu(1, w06(0x14))) split.push_back(b);
  EXPECT_TRUE(refused_for(allowed_raw(facts(), split, gap), "--allow-motion"));
  // A corrupted byte: nothing a receiver takes.
  Bytes bad = rtu(2, w06(0x11));
  bad[3] ^= 0x10;
  EXPECT_TRUE(allowed_raw(facts(), bad));
}

TEST(Policy, MbapBytesAreJudgedAdusByTheirLengthFields) {
  PolicyFacts tcp = facts({}, &the_spec(), live(1, &mbc::kTcp));
  // Issue 41: three ADUs in one write: a plain write, a unit-2 write, a motion write.
  Bytes three = mbap(1, w06(0x10), 1);
  EXPECT_TRUE(allowed_raw(tcp, three));
  for (uint8_t b : mbap(2, w06(0x10), 2)) three.push_back(b);
  EXPECT_TRUE(refused_for(allowed_raw(tcp, three), ""));
  Bytes motion = mbap(1, w06(0x10), 1);
  for (uint8_t b : mbap(1, read_request(3, 0, 1), 2)) motion.push_back(b);
  for (uint8_t b : mbap(1, w06(0x14), 3)) motion.push_back(b);
  EXPECT_TRUE(refused_for(allowed_raw(tcp, motion), "--allow-motion"));
  // An ADU cut off inside a write: the receiver completes it with what comes next.
  Bytes cut = mbap(1, w06(0x10));
  cut[5] = 20;
  cut.resize(8 + 1);
  EXPECT_TRUE(refused_for(allowed_raw(tcp, cut), ""));
}

// The shipped specs: no line setting of any of them is ever written, every
// command register waits for --allow-motion.
TEST(Policy, TheShippedSpecs) {
  int settings = 0, commands = 0;
  for (const auto& id : spec::spec_ids()) {
    auto s = spec::load_spec_by_id(id);
    for (const auto& st : s.serial.settings) {
      ++settings;
      EXPECT_TRUE(refused_for(allowed(facts(kAll, &s), 1, w06(st.register_address)), "")) << id;
    }
    for (const auto& r : s.registers)
      if (r.access == spec::Access::command && r.table == Table::holding) {
        ++commands;
        EXPECT_TRUE(refused_for(allowed_write(facts({}, &s), r), "--allow-motion")) << id << " " << r.address;
      }
  }
  EXPECT_GT(settings, 0);
  EXPECT_GT(commands, 0);
}

// The drive's control (spec control:): a controlword is judged by the word
// written (issue 38): a command that may move needs --allow-motion unless
// every set-point was written 0 first; a mode's start always; a non-zero
// set-point of a mode with no start command (it follows it) always; a
// command that moves nothing and a mode selection never.
spec::Spec with_control() {
  spec::Spec s = made();
  s.registers.push_back(reg(0x40, "controlword"));
  s.registers.push_back(reg(0x41, "mode"));
  s.registers.push_back(reg(0x42, "target_velocity"));
  s.registers.push_back(reg(0x43, "target_position"));
  std::stable_sort(s.registers.begin(), s.registers.end(),
                   [](const Register& a, const Register& b) { return std::pair(a.table, a.address) < std::pair(b.table, b.address); });
  spec::Control c;
  auto cmd = [&](std::string id, uint16_t mask, uint16_t value, bool motion, spec::Trigger trigger = spec::Trigger::level) {
    spec::ControlCommand x;
    x.id = id;
    x.register_key = "controlword";
    x.mask = mask;
    x.value = value;
    x.motion = motion;
    x.trigger = trigger;
    if (trigger == spec::Trigger::edge) x.edge_mask = value;
    c.commands.push_back(x);
  };
  cmd("shutdown", 0x87, 0x06, false);
  cmd("enable_operation", 0x8F, 0x0F, true);
  cmd("new_setpoint", 0x10, 0x10, true, spec::Trigger::edge);
  spec::ControlMode speed;
  speed.id = "speed";
  speed.select = spec::RegisterWrite{"mode", 3, 0, "", {}};
  speed.setpoint_keys = {"target_velocity"};
  spec::ControlMode position;
  position.id = "position";
  position.select = spec::RegisterWrite{"mode", 1, 0, "", {}};
  position.setpoint_keys = {"target_position"};
  position.start_command = "new_setpoint";
  c.modes = {speed, position};
  s.control = c;
  return s;
}

TEST(Policy, AControlWordIsJudgedByTheCommandItGives) {
  static const spec::Spec s = with_control();
  PolicyFacts f{&s, live(), {}};
  EXPECT_TRUE(allowed(f, 1, w06(0x40, 0x06))) << "shutdown moves nothing";
  EXPECT_TRUE(allowed(f, 1, w06(0x41, 3))) << "a mode selection moves nothing";
  EXPECT_TRUE(allowed(f, 1, w06(0x42, 0))) << "a set-point written 0";
  EXPECT_TRUE(refused_for(allowed(f, 1, w06(0x42, 500)), "--allow-motion")) << "a non-zero set-point the mode follows";
  EXPECT_TRUE(allowed(f, 1, w06(0x43, 500))) << "a set-point of a mode that moves on its start command only";
  EXPECT_TRUE(refused_for(allowed(f, 1, w06(0x40, 0x0F)), "--allow-motion")) << "enable with set-points not known 0";
  EXPECT_TRUE(refused_for(allowed(f, 1, write_multiple_registers(0x40, std::vector<uint16_t>{0x0F, 3, 0, 0})), "--allow-motion"))
      << "FC 16: the words are judged, not the register alone";
  f.zeroed = {0x42};
  EXPECT_TRUE(refused_for(allowed(f, 1, w06(0x40, 0x0F)), "--allow-motion")) << "one set-point still unknown";
  f.zeroed = {0x42, 0x43};
  EXPECT_TRUE(allowed(f, 1, w06(0x40, 0x0F))) << "enable with every set-point 0 moves nothing";
  EXPECT_TRUE(refused_for(allowed(f, 1, w06(0x40, 0x1F)), "--allow-motion")) << "a mode's start moves to any set-point";
  EXPECT_EQ(control_motion(f, w06(0x40, 0x06)), "");
  EXPECT_NE(control_motion(f, w06(0x40, 0x1F)).find("new_setpoint"), std::string::npos) << control_motion(f, w06(0x40, 0x1F));
  f.opt_ins.allow_motion = true;
  f.zeroed.clear();
  EXPECT_TRUE(allowed(f, 1, w06(0x40, 0x1F)));
  EXPECT_TRUE(allowed(f, 1, w06(0x42, 500)));
}

// A motion command that moves by something other than its modes' set-points
// (spec control.commands setpoints): Rieding's internal speeds 1-3 (四 (2)
// D6~D7) run at speeds the manual does not tie to a register, and position
// mode, once enabled, follows external pulses (五): with every set-point
// written 0 they still need --allow-motion. A command that names its own
// set-points is let out once those are 0.
TEST(Policy, AMotionCommandWhoseSpeedTheManualLeavesUnsaidNeedsAllowMotionWithEverySetPointZero) {
  static const spec::Spec s = spec::load_spec_by_id("rieding-dhe");
  PolicyFacts f{&s, live(), {}};
  f.zeroed = control_setpoints(s);
  ASSERT_FALSE(f.zeroed.empty());
  const uint16_t command_word = s.find_by_key("command_word")->address;
  for (uint16_t word : {0x0151, 0x0161, 0x0191, 0x01A1, 0x01D1, 0x01E1, 0x0100}) {
    EXPECT_TRUE(refused_for(allowed(f, 1, w06(command_word, word)), "--allow-motion")) << std::hex << word;
    EXPECT_NE(control_motion(f, w06(command_word, word)).find("the manual does not say what sets its speed"), std::string::npos)
        << control_motion(f, w06(command_word, word));
  }
  EXPECT_EQ(control_motion(f, w06(command_word, 0x0000)), "") << "stop moves nothing";
  EXPECT_NE(control_motion(f, w06(command_word, 0x0111)).find("starts a mode's motion"), std::string::npos) << "a mode's start, as before";
  f.opt_ins.allow_motion = true;
  EXPECT_TRUE(allowed(f, 1, w06(command_word, 0x0151)));

  spec::Spec own = with_control();
  own.registers.push_back(reg(0x44, "jog_speed"));
  spec::ControlCommand jog;
  jog.id = "jog";
  jog.register_key = "controlword";
  jog.mask = 0x300;
  jog.value = 0x100;
  jog.motion = true;
  jog.setpoint_keys = std::vector<std::string>{"jog_speed"};
  own.control->commands.push_back(jog);
  PolicyFacts g{&own, live(), {}};
  g.zeroed = {0x42, 0x43};
  EXPECT_TRUE(refused_for(allowed(g, 1, w06(0x40, 0x100)), "--allow-motion")) << "the modes' set-points are not the jog's";
  EXPECT_NE(control_motion(g, w06(0x40, 0x100)).find("its set-points (jog_speed)"), std::string::npos) << control_motion(g, w06(0x40, 0x100));
  g.zeroed = {0x44};
  EXPECT_TRUE(allowed(g, 1, w06(0x40, 0x100))) << "the jog's own set-point is 0";
  EXPECT_TRUE(control_setpoints(own).count(0x44)) << "a command's own set-points are set-points";
}

}  // namespace
}  // namespace mbc::conf
