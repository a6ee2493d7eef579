// The `control:` section (spec/README.md, "Control"): a library profile
// resolved onto a device's register keys, a device's override of a profile
// entry, and the library profiles themselves. The rules of spec check have a
// malformed/ fixture each (116-138).
#include <gtest/gtest.h>

#include <filesystem>
#include <fstream>
#include <set>
#include <sstream>

#include "loader.h"

namespace fs = std::filesystem;
using namespace mbc::spec;

namespace {

Spec load_fixture(const std::string& name) {
  auto r = load_spec_file((fs::path(MBCONFORM_TEST_DIR) / "valid" / name).string());
  std::string all;
  for (const auto& d : r.diagnostics) all += "\n  " + d.str();
  EXPECT_TRUE(r.ok()) << name << all;
  return r.spec ? *r.spec : Spec{};
}

// The states whose readings hold for `word` of `key` (every other register 0).
std::vector<std::string> states_matching(const Control& c, const std::string& key, uint16_t word) {
  std::vector<std::string> ids;
  for (const auto& s : c.states) {
    bool all = !s.status.empty();
    for (const auto& m : s.status) all = all && m.matches(m.register_key == key ? word : 0);
    if (all) ids.push_back(s.id);
  }
  return ids;
}

// Every register key the control names, after the profile's mapping.
std::set<std::string> keys_named(const Control& c) {
  std::set<std::string> k;
  for (const auto& s : c.states)
    for (const auto& m : s.status) k.insert(m.register_key);
  for (const auto& x : c.commands) k.insert(x.register_key);
  for (const auto& t : c.transitions)
    for (const auto& w : t.when) k.insert(w.register_key);
  for (const auto& m : c.modes) {
    if (m.select) k.insert(m.select->key);
    if (!m.display_key.empty()) k.insert(m.display_key);
    for (const auto& s : m.setpoint_keys) k.insert(s);
    if (!m.actual_key.empty()) k.insert(m.actual_key);
    if (m.done) k.insert(m.done->register_key);
  }
  return k;
}

const ControlTransition* transition(const Control& c, const std::string& id) {
  for (const auto& t : c.transitions)
    if (t.id == id) return &t;
  return nullptr;
}

}  // namespace

// Issue 38's fifth device: the CiA 402 profile on its register layout.
TEST(Control, Cia402ModbusResolvesTheProfileOntoItsRegisters) {
  Spec s = load_spec_by_id("cia402-modbus");
  ASSERT_TRUE(s.control);
  const Control& c = *s.control;
  EXPECT_EQ(c.profile, "cia402");
  EXPECT_EQ(c.initial, "switch_on_disabled");
  EXPECT_EQ(c.safe, "switch_on_disabled");
  EXPECT_EQ(c.states.size(), 8u);
  // Only the device's keys: the roles modes_of_operation, quick_stop_option_code, ... are gone.
  for (const auto& k : keys_named(c)) EXPECT_TRUE(s.find_by_key(k)) << k << " is not a register key of the device";
  EXPECT_EQ(s.find_by_key("controlword")->address, 0x0000);
  const ControlCommand* shutdown = c.command("shutdown");
  ASSERT_TRUE(shutdown);
  EXPECT_EQ(shutdown->register_key, "controlword");
  EXPECT_EQ(shutdown->mask, 0x87);
  EXPECT_EQ(shutdown->value, 0x06);
  const ControlCommand* reset = c.command("fault_reset");
  ASSERT_TRUE(reset);
  EXPECT_EQ(reset->trigger, Trigger::edge);
  EXPECT_EQ(reset->edge_mask, 0x80);
  EXPECT_TRUE(c.command("quick_stop")->stops);
  // Transition 12 reads 605Ah: the device's quick_stop_option (0x000D), which takes 2.
  const ControlTransition* t12 = transition(c, "12");
  ASSERT_TRUE(t12);
  ASSERT_EQ(t12->when.size(), 1u);
  EXPECT_EQ(t12->when[0].register_key, "quick_stop_option");
  EXPECT_EQ(s.find_by_key("quick_stop_option")->address, 0x000D);
  EXPECT_TRUE(t12->automatic());
  EXPECT_EQ(t12->event, "motion_done");
  // Quick stop from Operation enabled: transition 11.
  auto qs = c.transitions_on("operation_enabled", "quick_stop");
  ASSERT_EQ(qs.size(), 1u);
  EXPECT_EQ(qs[0]->to, "quick_stop_active");
  // Word 0x07 is Switch on in Ready to switch on (3) and Disable operation in Operation enabled (5).
  ASSERT_EQ(c.transitions_on("ready_to_switch_on", "switch_on").size(), 1u);
  EXPECT_EQ(c.transitions_on("operation_enabled", "switch_on")[0]->to, "switched_on");
  // Modes 1, 3, 6 on 0x0002; no torque mode (the layout has no 6071h).
  ASSERT_TRUE(c.mode("position"));
  EXPECT_EQ(c.mode("position")->select->key, "mode_of_operation");
  EXPECT_EQ(c.mode("position")->select->value, 1);
  EXPECT_EQ(c.mode("position")->start_command, "new_setpoint");
  EXPECT_EQ(c.mode("position")->done->mask, 0x0400);  // bit 10 target reached
  ASSERT_TRUE(c.mode("speed"));
  EXPECT_EQ(c.mode("speed")->select->value, 3);
  EXPECT_EQ(c.mode("speed")->setpoint_keys, std::vector<std::string>{"target_velocity"});
  ASSERT_TRUE(c.mode("homing"));
  EXPECT_EQ(c.mode("homing")->select->value, 6);
  EXPECT_EQ(c.mode("homing")->done->mask, 0x1000);  // bit 12 homing attained
  EXPECT_FALSE(c.mode("torque"));
  // The entries cite the profile, and inherit its section when they give none.
  for (const auto& st : c.states) EXPECT_NE(st.section.find("CiA 402"), std::string::npos) << st.id;
  EXPECT_EQ(c.undefined.kind, UndefinedCommand::Kind::ignored);
  EXPECT_EQ(c.undefined.basis.basis, Basis::inferred);
}

// Statuswords a CiA 402 drive reports (the state coding; 0x0237 is the
// Operation enabled word with voltage enabled and remote set that drive
// manuals print) name exactly one state each, and so does every other word.
TEST(Control, Cia402StatuswordsNameOneStateEach) {
  Spec s = load_spec_by_id("cia402-modbus");
  ASSERT_TRUE(s.control);
  const Control& c = *s.control;
  const std::pair<uint16_t, const char*> words[] = {
      {0x0000, "not_ready_to_switch_on"}, {0x0040, "switch_on_disabled"}, {0x0250, "switch_on_disabled"},
      {0x0021, "ready_to_switch_on"},     {0x0231, "ready_to_switch_on"}, {0x0233, "switched_on"},
      {0x0237, "operation_enabled"},      {0x0637, "operation_enabled"},  {0x0017, "quick_stop_active"},
      {0x001F, "fault_reaction_active"},  {0x0008, "fault"},              {0x0218, "fault"}};
  for (auto [w, id] : words) {
    auto m = states_matching(c, "statusword", w);
    ASSERT_EQ(m.size(), 1u) << std::hex << w;
    EXPECT_EQ(m[0], id) << std::hex << w;
  }
  for (unsigned w = 0; w <= 0xFFFF; ++w) EXPECT_LE(states_matching(c, "statusword", uint16_t(w)).size(), 1u) << std::hex << w;
}

// A device overrides a profile entry by id, adds its own, and a mode whose
// roles it does not map is left out.
TEST(Control, ADeviceOverridesAProfileEntryById) {
  Spec s = load_fixture("control-profile-override.yaml");
  ASSERT_TRUE(s.control);
  const Control& c = *s.control;
  const ControlCommand* qs = c.command("quick_stop");
  ASSERT_TRUE(qs);
  EXPECT_EQ(qs->register_key, "cw");
  ASSERT_TRUE(qs->stop_within_ms);
  EXPECT_EQ(*qs->stop_within_ms, 300);
  EXPECT_EQ(qs->section, "9.2");
  EXPECT_EQ(std::count_if(c.commands.begin(), c.commands.end(), [](const auto& x) { return x.id == "quick_stop"; }), 1);
  // The profile's other commands keep the profile's words, on the device's register.
  EXPECT_EQ(c.command("shutdown")->register_key, "cw");
  EXPECT_EQ(c.command("shutdown")->value, 0x06);
  // Transition 16 overridden: this drive never leaves quick stop on Enable operation.
  const ControlTransition* t16 = transition(c, "16");
  ASSERT_TRUE(t16);
  EXPECT_EQ(t16->to, "quick_stop_active");
  EXPECT_EQ(t16->basis.basis, Basis::inferred);
  // Added by the device.
  ASSERT_TRUE(transition(c, "brake"));
  EXPECT_EQ(c.states.size(), 8u);
  EXPECT_EQ(c.section, "9");  // the device's section
  EXPECT_TRUE(c.modes.empty()) << "no mode's roles are mapped";
  for (const auto& k : keys_named(c)) EXPECT_TRUE(s.find_by_key(k)) << k;
}

// Each library profile loads in a small device spec, and no word names two of its states.
TEST(Control, EveryLibraryProfileLoadsAndItsStatesAreDistinguishable) {
  for (const auto& e : fs::directory_iterator(fs::path(MBCONFORM_SOURCE_DIR) / "spec" / "profiles")) {
    if (e.path().extension() != ".yaml") continue;
    std::string id = e.path().stem().string();
    fs::path fixture = fs::path(MBCONFORM_TEST_DIR) / "valid" / ("control-profile-" + id + ".yaml");
    ASSERT_TRUE(fs::exists(fixture)) << "profile " << id << " has no test device " << fixture;
    Spec s = load_fixture(fixture.filename().string());
    ASSERT_TRUE(s.control) << id;
    EXPECT_EQ(s.control->profile, id);
    EXPECT_GE(s.control->states.size(), 2u) << id;
    EXPECT_FALSE(s.control->commands.empty()) << id;
    EXPECT_FALSE(s.control->transitions.empty()) << id;
    std::set<std::string> regs;
    for (const auto& st : s.control->states)
      for (const auto& m : st.status) regs.insert(m.register_key);
    ASSERT_EQ(regs.size(), 1u) << id << ": one status word";
    for (unsigned w = 0; w <= 0xFFFF; ++w)
      EXPECT_LE(states_matching(*s.control, *regs.begin(), uint16_t(w)).size(), 1u) << id << " " << std::hex << w;
  }
}

// The shared seam: an own control (no profile) loads as written.
TEST(Control, AnOwnControlLoadsAsWritten) {
  Spec s = load_fixture("control-own.yaml");
  ASSERT_TRUE(s.control);
  EXPECT_TRUE(s.control->profile.empty());
  EXPECT_EQ(s.control->states.size(), 3u);
  EXPECT_EQ(s.control->command("disable")->stop_within_ms.value_or(0), 200);
  EXPECT_EQ(transition(*s.control, "3")->from, "*");
  EXPECT_EQ(transition(*s.control, "3")->basis.basis, Basis::inferred);
  EXPECT_EQ(s.control->transitions_on("running", "disable").size(), 1u);
}

// The motion facts live in control.motion (one form): operations has none.
TEST(Control, MotionIsPartOfControl) {
  for (const char* id : {"sihong-57hs-r", "hsc60", "hanstar-7trsm5740q"}) {
    Spec s = load_spec_by_id(id);
    ASSERT_TRUE(s.control) << id;
    ASSERT_TRUE(s.control->motion) << id;
    EXPECT_FALSE(s.control->motion->status_key.empty()) << id;
  }
}
