// The one restore (conformance/session/restore.h), against `mbconform serve`:
//   - what the journal keeps before a command writes, and putting a served
//     device back from it: registers, coils, the 57HS-R "do not persist"
//     switch through serve's EEPROM files (the tests Snapshot had);
//   - the frame policy: never a line setting or a command register written
//     back, a command undone by the spec's stop;
//   - a torn record skipped, the rest restored; a second restore leaves what
//     changed since; a journal refused on another drive or unit (exit 2);
//   - read-only registers never journaled; command registers written
//     without a read on a drive silent there; a full file during a command.
#include <fcntl.h>
#include <fmt/core.h>
#include <gtest/gtest.h>
#include <nlohmann/json.hpp>
#include <sys/resource.h>
#include <sys/wait.h>
#include <unistd.h>

#include <chrono>
#include <cmath>
#include <csignal>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <set>
#include <sstream>
#include <thread>

#include "check/exchange.h"
#include "loader.h"
#include "modbus/crc16.h"
#include "modbus/hex.h"
#include "modbus/judge.h"
#include "modbus/pdu.h"
#include "safety/safety.h"
#include "serve_process.h"
#include "session/journal.h"
#include "session/restore.h"
#include "session/session.h"

namespace mbc::conf {
namespace {

using serve_test::ServeProcess;
using serve_test::TempDir;
using spec::Register;
using namespace std::chrono_literals;

std::vector<uint16_t> read(Target& t, uint16_t address, int words) {
  Bytes req = read_request(3, address, uint16_t(words));
  Reply r = t.transact(req);
  if (!r.pdu) throw std::runtime_error("no reply reading " + std::to_string(address));
  return judge_reply(req, *r.pdu).registers;
}

std::vector<bool> read_coils(Target& t, uint16_t address, int n) {
  Bytes req = read_request(1, address, uint16_t(n));
  Reply r = t.transact(req);
  if (!r.pdu) throw std::runtime_error("no reply reading coils");
  return judge_reply(req, *r.pdu).bits;
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

std::string joined(const std::vector<std::string>& v) {
  std::string s;
  for (const auto& x : v) s += x + "\n";
  return s;
}

struct Served {
  spec::Spec spec;
  std::unique_ptr<ServeProcess> serve;
  std::string uri;
};

Served serve_tcp(const std::string& id, std::vector<std::string> extra = {}) {
  Served s{spec::load_spec_by_id(id), nullptr, ""};
  int slave = s.spec.serial.slave_default.value_or(1);
  std::vector<std::string> args{"--device", fmt::format("{}@{}", id, slave), "--tcp", "127.0.0.1:0"};
  args.insert(args.end(), extra.begin(), extra.end());
  s.serve = std::make_unique<ServeProcess>(args);
  if (!s.serve->wait_listening(1)) throw std::runtime_error(s.serve->log());
  s.uri = fmt::format("tcp://{}?unit={}", s.serve->endpoint("tcp")->address, slave);
  return s;
}

SessionOptions options(const std::string& out) {
  SessionOptions o;
  o.command = "test";
  o.out_dir = out;
  return o;
}

// ---- what the journal keeps, and putting it back (the tests Snapshot had) ----

// A device without a switch (hsc60 keeps by a save command): the journal
// keeps what the command may write, and the restore puts back what changed,
// verified by reading back.
TEST(JournalRestore, RestoresChangedRegistersOverTheWire) {
  for (const std::string id : {"hsc60", "modbus-standard"}) {
    SCOPED_TRACE(id);
    TempDir out;
    Served sv = serve_tcp(id);
    Session session(sv.uri, &sv.spec, options(out.path()));
    session.keep();
    EXPECT_TRUE(session.notes().empty()) << joined(session.notes());
    JournalContents c = read_journal(session.journal_path());
    ASSERT_GT(c.originals.size(), 0u);
    EXPECT_FALSE(c.header["identity"].empty());
    // Every kept register holds what the spec says it powers up with.
    for (const auto& k : c.originals) {
      EXPECT_FALSE(k.persist_switch);
      const Register* r = sv.spec.find_register(k.address, k.table);
      ASSERT_TRUE(r);
      if (r->words == 1 && r->default_value && !r->is_signed()) {
        EXPECT_EQ(k.value[0], uint16_t(int64_t(*r->default_value))) << k.name;
      }
    }
    auto other = open_target(sv.uri);
    int changed = 0;
    for (const auto& k : c.originals) {
      const Register* r = sv.spec.find_register(k.address, k.table);
      if (k.table != spec::Table::holding || is_serial_setting(sv.spec, *r) || changed == 5) continue;
      if (auto v = other_value(*r, k.value[0])) {
        write(*other, k.address, *v);
        ++changed;
      }
    }
    ASSERT_GT(changed, 0);
    RestoreReport rep = session.restore();
    EXPECT_TRUE(rep.not_restored.empty()) << joined(rep.not_restored);
    EXPECT_EQ(rep.restored, size_t(changed));
    for (const auto& k : c.originals)
      if (k.table == spec::Table::holding) {
        EXPECT_EQ(read(*other, k.address, int(k.value.size())), k.value) << k.name;
      }
  }
}

// Coils drive outputs: a command that writes them has every one put back.
TEST(JournalRestore, RestoresCoils) {
  TempDir out;
  Served sv = serve_tcp("modbus-standard");
  Session session(sv.uri, &sv.spec, options(out.path()));
  session.keep();
  JournalContents c = read_journal(session.journal_path());
  auto other = open_target(sv.uri);
  int coils = 0;
  for (const auto& k : c.originals) {
    if (k.table != spec::Table::coil) continue;
    ++coils;
    Bytes req = write_single_coil(k.address, k.value[0] == 0);
    Reply r = other->transact(req);
    ASSERT_TRUE(r.pdu && judge_reply(req, *r.pdu).ok()) << k.name;
    ASSERT_EQ(read_coils(*other, k.address, 1), std::vector<bool>{k.value[0] == 0}) << k.name;
  }
  ASSERT_GT(coils, 0) << "modbus-standard has writable coils";
  RestoreReport rep = session.restore();
  EXPECT_TRUE(rep.not_restored.empty()) << joined(rep.not_restored);
  for (const auto& k : c.originals)
    if (k.table == spec::Table::coil) {
      EXPECT_EQ(read_coils(*other, k.address, 1), std::vector<bool>{k.value[0] != 0}) << k.name;
    }
}

// Registers a drive will not read before the command are one finding: one
// line, adjacent addresses as ranges (the HSC60 serves none of
// modbus-standard's 0x0200 block).
TEST(JournalRestore, UnreadableRegistersAreOneLineWithRanges) {
  TempDir out;
  auto s = spec::load_spec_by_id("modbus-standard");
  ServeProcess serve({"--device", "hsc60@1", "--tcp", "127.0.0.1:0"});
  ASSERT_TRUE(serve.wait_listening(1)) << serve.log();
  Session session(fmt::format("tcp://{}?unit=1", serve.endpoint("tcp")->address), &s, options(out.path()));
  session.keep();
  ASSERT_EQ(session.notes().size(), 1u) << joined(session.notes());
  const std::string& line = session.notes().front();
  EXPECT_EQ(line.find("could not be read before the run"), 0u) << line;
  EXPECT_NE(line.find("0x0200-0x"), std::string::npos) << line;
  EXPECT_EQ(line.find('\n'), std::string::npos) << line;
}

// 57HS-R §6.1: RW/S registers are stored on write unless 0x0016 = 1. The
// session turns the switch on, so a change made during the command is not in
// EEPROM after a restart of the device; the restore puts the switch back.
TEST(JournalRestore, DoNotPersistSwitchKeepsRunWritesOutOfEeprom) {
  const std::string id = "sihong-57hs-r";
  auto s = spec::load_spec_by_id(id);
  int slave = s.serial.slave_default.value_or(1);
  TempDir eeprom, out;
  auto start = [&] {
    auto p = std::make_unique<ServeProcess>(std::vector<std::string>{
        "--device", fmt::format("{}@{}", id, slave), "--tcp", "127.0.0.1:0", "--eeprom", eeprom.path()});
    if (!p->wait_listening(1)) throw std::runtime_error(p->log());
    return p;
  };
  auto serve = start();
  auto uri = [&] { return fmt::format("tcp://{}?unit={}", serve->endpoint("tcp")->address, slave); };
  std::string journal;
  const Register* sw = nullptr;
  const Register* stored = nullptr;  // a register the switch keeps out of EEPROM
  uint16_t switch_was = 0, before = 0;
  {
    Session session(uri(), &s, options(out.path()));
    session.keep();
    EXPECT_TRUE(session.notes().empty()) << joined(session.notes());
    journal = session.journal_path();
    JournalContents c = read_journal(journal);
    ASSERT_FALSE(c.originals.empty());
    ASSERT_TRUE(c.originals.front().persist_switch) << "the switch is journaled first";
    sw = s.find_register(c.originals.front().address);
    ASSERT_TRUE(sw);
    switch_was = c.originals.front().value[0];
    for (size_t k = 1; k < c.originals.size(); ++k) {
      EXPECT_NE(c.originals[k].address, sw->address);
      const Register* r = s.find_register(c.originals[k].address, c.originals[k].table);
      if (!stored && r->persistence.unless_register == sw->address && !is_serial_setting(s, *r) &&
          other_value(*r, c.originals[k].value[0]))
        stored = r;
    }
    ASSERT_TRUE(stored);
    auto t = open_target(uri());
    EXPECT_EQ(read(*t, sw->address, 1), std::vector<uint16_t>{uint16_t(stored->persistence.unless_value)});
    before = read(*t, stored->address, 1)[0];
    write(*t, stored->address, *other_value(*stored, before));
    t.reset();
    ASSERT_EQ(serve->stop(SIGTERM), 0);  // serve saves EEPROM on SIGTERM
    // The session's own restore has no target now; the journal keeps it all.
  }
  serve = start();
  auto t = open_target(uri());
  EXPECT_EQ(read(*t, stored->address, 1), std::vector<uint16_t>{before}) << "the command's write reached EEPROM";
  Journal record = Journal::append_to(journal);
  RestoreReport rep = restore_journal(*t, s, read_journal(journal), record);
  EXPECT_TRUE(rep.not_restored.empty()) << joined(rep.not_restored);
  EXPECT_EQ(read(*t, sw->address, 1), std::vector<uint16_t>{switch_was});
}

// Without --allow-eeprom-writes the journal leaves out registers stored on
// every write; command and read-only registers are never kept.
TEST(JournalRestore, KeepsOnlyWhatThePolicyLetsTheRunWrite) {
  TempDir out;
  Served sv = serve_tcp("sihong-57hs-r");
  Session session(sv.uri, &sv.spec, options(out.path()));
  session.keep();
  for (const auto& k : read_journal(session.journal_path()).originals) {
    const Register* r = sv.spec.find_register(k.address, k.table);
    ASSERT_TRUE(r);
    if (k.persist_switch) continue;
    EXPECT_TRUE(allowed_write(PolicyFacts{&sv.spec, session.info(), {}}, *r)) << k.name;
    EXPECT_FALSE(r->command) << k.name;
    EXPECT_EQ(r->access, spec::Access::rw) << k.name;
  }
}

// ---- the policy ----------------------------------------------------------------

// A journal holding the baud register and a motion command (as a tampered or
// old journal may): the restore writes neither; the command is undone by the
// spec's stop (57HS-R 0x0028 = 0, §7.6.2).
TEST(JournalRestore, NeverWritesALineSettingOrACommandAndStopsTheCommand) {
  TempDir out;
  Served sv = serve_tcp("sihong-57hs-r");
  const Register* baud = sv.spec.find_register(0x0014);
  const Register* start = sv.spec.find_by_key("start_command");
  const Register* plain = nullptr;
  for (const auto& r : sv.spec.registers)
    if (r.table == spec::Table::holding && r.access == spec::Access::rw && !r.command && !is_serial_setting(sv.spec, r) &&
        other_value(r, 0) && r.words == 1) {
      plain = &r;
      break;
    }
  ASSERT_TRUE(baud && start && plain);
  auto t = open_target(sv.uri);
  const uint16_t baud_now = read(*t, baud->address, 1)[0], plain_now = read(*t, plain->address, 1)[0];
  std::string path;
  {
    Journal j = Journal::create(out.path(), {{"device", sv.spec.device.id}, {"unit", std::to_string(t->info().unit)}});
    j.keep({{spec::Table::holding, baud->address, {uint16_t(baud_now ^ 1)}, false, ""},
            {spec::Table::holding, start->address, {1}, false, ""},
            {spec::Table::holding, plain->address, {plain_now}, false, ""}},
           {}, {{spec::Table::holding, start->address, 1}});
    path = j.path();
  }
  write(*t, plain->address, *other_value(*plain, plain_now));
  Journal record = Journal::append_to(path);
  RestoreReport rep = restore_journal(*t, sv.spec, read_journal(path), record);
  EXPECT_EQ(read(*t, baud->address, 1), std::vector<uint16_t>{baud_now}) << "the baud register was written";
  EXPECT_EQ(read(*t, plain->address, 1), std::vector<uint16_t>{plain_now});
  ASSERT_EQ(rep.not_restored.size(), 1u) << joined(rep.not_restored);
  EXPECT_NE(rep.not_restored[0].find("baud"), std::string::npos) << rep.not_restored[0];
  const std::string notes = joined(rep.notes);
  EXPECT_NE(notes.find("stopped: "), std::string::npos) << notes;
  EXPECT_NE(notes.find("0x0028"), std::string::npos) << notes;
  JournalContents after = read_journal(path);
  for (const auto& r : after.restored) EXPECT_NE(r.address, start->address) << "a command's old value was written back";
  for (const auto& r : after.restored) EXPECT_NE(r.address, baud->address);
}

// A control the run left where it was before its first command (the journal's
// `control` record) stays there: a drive in Operation enabled before the run
// is not disabled by the restore (on the 57HS-R that would release the motor);
// a control the run changed is taken to the safe state (issue 38, Deliver 6).
TEST(JournalRestore, AControlTheRunDidNotCommandStaysAndACommandedOneGoesToTheSafeState) {
  Served sv = serve_tcp("cia402-modbus");
  auto t = open_target(sv.uri);
  for (bool changed : {false, true}) {
    SCOPED_TRACE(changed ? "commanded by the run" : "not commanded by the run");
    TempDir out;
    write(*t, 0x0000, 0x06);  // Shutdown: Ready to switch on
    write(*t, 0x0000, 0x0F);  // Switch on + Enable operation, target velocity 0: Operation enabled
    std::this_thread::sleep_for(100ms);
    ASSERT_EQ(read(*t, 0x0001, 1)[0] & 0x6F, 0x27) << "not in Operation enabled";
    std::string path;
    {
      Journal j = Journal::create(out.path(), {{"device", sv.spec.device.id}, {"unit", std::to_string(t->info().unit)}});
      const std::string line = control_record(*t, sv.spec);
      ASSERT_EQ(line.rfind("control operation_enabled", 0), 0u) << line;
      j.record(line);
      // A run that commands the control journals the controlword; one that
      // does not, only the register it writes (the quick stop option code).
      if (changed)
        j.keep({{spec::Table::holding, 0x0000, {0x0F}, false, ""}}, {}, {});
      else
        j.keep({{spec::Table::holding, 0x000D, {2}, false, ""}}, {}, {});
      path = j.path();
    }
    if (changed) write(*t, 0x0000, 0x06);  // the run's last command: Shutdown
    else write(*t, 0x000D, 2);
    std::this_thread::sleep_for(100ms);
    Journal record = Journal::append_to(path);
    RestoreReport rep = restore_journal(*t, sv.spec, read_journal(path), record);
    EXPECT_TRUE(rep.not_restored.empty()) << joined(rep.not_restored);
    const uint16_t status = read(*t, 0x0001, 1)[0];
    if (changed)
      EXPECT_EQ(status & 0x4F, 0x40) << "statusword " << status << ": not in Switch on disabled, the safe state\n" << joined(rep.notes);
    else
      EXPECT_EQ(status & 0x6F, 0x27) << "statusword " << status << ": taken out of Operation enabled, where the run found it\n"
                                     << joined(rep.notes);
  }
}

// ---- torn records, second restores -----------------------------------------------

TEST(JournalRestore, ATornRecordIsSkippedAndTheRestStillRestores) {
  Served sv = serve_tcp("hsc60");
  std::vector<const Register*> regs;
  for (const auto& r : sv.spec.registers)
    if (r.table == spec::Table::holding && r.access == spec::Access::rw && !r.command && r.words == 1 &&
        other_value(r, 0) && regs.size() < 2)
      regs.push_back(&r);
  ASSERT_EQ(regs.size(), 2u);
  auto t = open_target(sv.uri);
  const uint16_t a = read(*t, regs[0]->address, 1)[0], b = read(*t, regs[1]->address, 1)[0];
  for (bool last : {true, false}) {
    SCOPED_TRACE(last ? "the last line cut inside its value" : "a damaged line before the last");
    TempDir out;
    std::string path;
    {
      Journal j = Journal::create(out.path(), {{"device", "hsc60"}, {"unit", "1"}});
      j.keep({{spec::Table::holding, regs[0]->address, {a}, false, ""}});
      j.keep({{spec::Table::holding, regs[1]->address, {b}, false, ""}});
      path = j.path();
    }
    std::string text;
    {
      std::ifstream in(path);
      std::stringstream ss;
      ss << in.rdbuf();
      text = ss.str();
    }
    const std::string damaged = fmt::format("0x{:04X} 1 {:04X}", regs[last ? 1 : 0]->address, last ? b : a);
    auto at = text.find(damaged);
    ASSERT_NE(at, std::string::npos) << text;
    if (last) text.resize(at + damaged.size() - 2);  // "...1 00": a torn word, not 0x0000
    else text[at + damaged.size() - 1] = text[at + damaged.size() - 1] == '0' ? '1' : '0';
    std::ofstream(path, std::ios::trunc) << text;
    const uint16_t a2 = *other_value(*regs[0], a), b2 = *other_value(*regs[1], b);
    write(*t, regs[0]->address, a2);
    write(*t, regs[1]->address, b2);
    Journal record = Journal::append_to(path);
    RestoreReport rep = restore_journal(*t, sv.spec, read_journal(path), record);
    if (last) {
      EXPECT_EQ(read(*t, regs[0]->address, 1)[0], a);
      EXPECT_EQ(read(*t, regs[1]->address, 1)[0], b2) << "the torn value was written";
      EXPECT_TRUE(rep.not_restored.empty()) << joined(rep.not_restored);
      EXPECT_NE(joined(rep.notes).find("journal line 5: cut off"), std::string::npos) << joined(rep.notes);
    } else {
      EXPECT_EQ(read(*t, regs[0]->address, 1)[0], a2) << "the damaged value was written";
      EXPECT_EQ(read(*t, regs[1]->address, 1)[0], b);
      ASSERT_EQ(rep.not_restored.size(), 1u) << joined(rep.not_restored);
      EXPECT_NE(rep.not_restored[0].find("journal line 4: damaged"), std::string::npos) << rep.not_restored[0];
    }
    write(*t, regs[0]->address, a);
    write(*t, regs[1]->address, b);
  }
}

TEST(JournalRestore, ASecondRestoreLeavesWhatChangedSince) {
  TempDir out;
  Served sv = serve_tcp("hsc60");
  Session session(sv.uri, &sv.spec, options(out.path()));
  session.keep();
  JournalContents c = read_journal(session.journal_path());
  const JournalEntry* e = nullptr;
  const Register* r = nullptr;
  for (const auto& k : c.originals)
    if (k.table == spec::Table::holding && k.value.size() == 1 && (r = sv.spec.find_register(k.address)) && other_value(*r, k.value[0])) {
      e = &k;
      break;
    }
  ASSERT_TRUE(e);
  auto t = open_target(sv.uri);
  write(*t, e->address, *other_value(*r, e->value[0]));
  RestoreReport first = session.restore();
  EXPECT_TRUE(first.not_restored.empty()) << joined(first.not_restored);
  EXPECT_EQ(first.restored, 1u);
  ASSERT_EQ(read(*t, e->address, 1), e->value);
  // The user sets it after the restore: a second restore keeps the user's value.
  const uint16_t users = *other_value(*r, e->value[0]);
  write(*t, e->address, users);
  Journal record = Journal::append_to(session.journal_path());
  RestoreReport second = restore_journal(*t, sv.spec, read_journal(session.journal_path()), record);
  EXPECT_EQ(read(*t, e->address, 1), std::vector<uint16_t>{users});
  EXPECT_EQ(second.restored, 0u);
  EXPECT_TRUE(second.not_restored.empty()) << joined(second.not_restored);
  EXPECT_NE(joined(second.notes).find("left as it is"), std::string::npos) << joined(second.notes);
}

// ---- what is journaled ---------------------------------------------------------------

// 57HS-R 0x0009 (output terminal state) changes by side effect: a write to it
// is not journaled, and the restore does not end with "NOT RESTORED 0x0009".
TEST(JournalRestore, ReadOnlyRegistersAreNeverJournaled) {
  TempDir out;
  Served sv = serve_tcp("sihong-57hs-r");
  const Register* ro = sv.spec.find_register(0x0009);
  ASSERT_TRUE(ro && ro->access == spec::Access::ro);
  Session session(sv.uri, &sv.spec, options(out.path()));
  session.keep();
  Sent sent = session.transact(session.info().unit, write_single_register(0x0009, 0x00FF), Target::Wait::reply);
  EXPECT_FALSE(sent.refused);
  for (const auto& k : read_journal(session.journal_path()).originals) EXPECT_NE(k.address, 0x0009);
  RestoreReport rep = session.restore();
  EXPECT_TRUE(rep.not_restored.empty()) << joined(rep.not_restored);
}

// Hanstar 6.3.2: the stop command is written with no read first, on a drive
// silent when its command registers are read; the restore stops the motor.
TEST(JournalRestore, ACommandIsWrittenWithoutAReadOnADriveSilentThere) {
  TempDir out;
  Served sv = serve_tcp("hanstar-7trsm5740q", {"--fault", "silent-command-reads"});
  const Register* fwd = sv.spec.find_by_key("forward_command");
  ASSERT_TRUE(fwd);
  std::string why;
  auto probe = open_target(sv.uri);
  EXPECT_FALSE(read_table(*probe, spec::Table::holding, fwd->address, 2, why)) << "the fault answers a command read";
  SessionOptions o = options(out.path());
  o.policy.allow_motion = true;
  Session session(sv.uri, &sv.spec, o);
  session.keep();
  Sent sent = session.transact(session.info().unit, write_multiple_registers(fwd->address, std::vector<uint16_t>{0, 1000}),
                               Target::Wait::reply);
  ASSERT_FALSE(sent.refused) << sent.refused->reason;
  JournalContents c = read_journal(session.journal_path());
  ASSERT_EQ(c.commands.size(), 1u);
  EXPECT_EQ(c.commands[0].address, fwd->address);
  RestoreReport rep = session.restore();
  EXPECT_TRUE(rep.not_restored.empty()) << joined(rep.not_restored);
  EXPECT_NE(joined(rep.notes).find("stopped: "), std::string::npos) << joined(rep.notes);
}

// ---- a case's own restore ---------------------------------------------------------------

// A link whose writes are refused once the case's steps are sent: the write
// back after the case fails, and the case and the device say so.
class RefusesWritesBack final : public Link {
 public:
  explicit RefusesWritesBack(Target& t) : d_(t) {}
  const TargetInfo& info() const override { return d_.info(); }
  Sent transact(uint8_t unit, std::span<const uint8_t> pdu, Target::Wait wait) override {
    if (!pdu.empty() && (pdu[0] == 6 || pdu[0] == 16)) return Sent{{}, Refusal{"refused by the test", ""}, false};
    return d_.transact(unit, pdu, wait);
  }
  Sent send_raw(std::span<const uint8_t> adu, std::optional<size_t> gap, Target::Wait wait) override {
    return d_.send_raw(adu, gap, wait);
  }
  std::chrono::microseconds silence_window() const override { return d_.silence_window(); }
  uint64_t late_replies() const override { return d_.late_replies(); }
  std::optional<std::chrono::microseconds> split_gap() const override { return d_.split_gap(); }
  void set_split_gap(std::chrono::microseconds g) override { d_.set_split_gap(g); }
  bool reconnect() override { return d_.reconnect(); }
  void advance(std::chrono::microseconds dt) override { d_.advance(dt); }
  void power_cycle() override { d_.power_cycle(); }
  std::vector<Sent> transact_all(std::span<const Target::Request> requests, size_t depth, Target::Wait wait) override {
    return d_.transact_all(requests, depth, wait);
  }
  bool pipelines() const override { return false; }
  bool trip_fault() override { return d_.trip_fault(); }

 private:
  DirectLink d_;
};

TEST(CaseRestore, AWriteBackThatFailsIsReported) {
  auto s = spec::load_spec_by_id("hsc60");
  const Register* r = nullptr;
  for (const auto& x : s.registers)
    if (x.table == spec::Table::holding && x.access == spec::Access::rw && x.words == 1) {
      r = &x;
      break;
    }
  ASSERT_TRUE(r);
  auto t = open_target("ref:hsc60");
  RefusesWritesBack link(*t);
  DeviceRun run;
  check::Exchange x(link, run);
  check::Case c;
  c.id = "test/touches";
  c.touches = {{r->address, 1}};
  c.steps = {check::frame(t->info().framing, t->info().unit, read_request(3, r->address, 1))};
  CaseResult res = check::run_case(x, s, c);
  ASSERT_TRUE(res.extra.contains("restore_failed")) << res.extra.dump();
  EXPECT_NE(res.extra["restore_failed"][0].get<std::string>().find("refused by the test"), std::string::npos) << res.extra.dump();
  ASSERT_EQ(run.restore_failures.size(), 1u);
  EXPECT_EQ(run.restore_failures[0].rfind("test/touches: ", 0), 0u) << run.restore_failures[0];
  // Through a link that takes the write back: nothing to report.
  DirectLink direct(*t);
  DeviceRun clean;
  check::Exchange y(direct, clean);
  res = check::run_case(y, s, c);
  EXPECT_FALSE(res.extra.contains("restore_failed")) << res.extra.dump();
  EXPECT_TRUE(clean.restore_failures.empty());
}

// ---- the commands ----------------------------------------------------------------------

// Runs mbconform with `args`; stdout and stderr through a pipe (a file-size
// limit does not reach a pipe). `fsize` > 0: the child's RLIMIT_FSIZE.
int mbconform(const std::vector<std::string>& args, std::string* out = nullptr, rlim_t fsize = 0) {
  int fds[2];
  if (pipe(fds) != 0) return -1;
  pid_t pid = fork();
  if (pid == 0) {
    close(fds[0]);
    dup2(fds[1], 1);
    dup2(fds[1], 2);
    if (fsize) {
      rlimit lim{fsize, fsize};
      setrlimit(RLIMIT_FSIZE, &lim);
      // As from a shell: SIGXFSZ at its default (end the process), whatever this test process inherited.
      signal(SIGXFSZ, SIG_DFL);
    }
    std::vector<char*> argv;
    std::string bin = serve_test::mbconform_bin();
    argv.push_back(bin.data());
    for (const auto& a : args) argv.push_back(const_cast<char*>(a.c_str()));
    argv.push_back(nullptr);
    execv(bin.c_str(), argv.data());
    _exit(127);
  }
  close(fds[1]);
  std::string got;
  char buf[4096];
  for (ssize_t n; (n = ::read(fds[0], buf, sizeof buf)) > 0;) got.append(buf, size_t(n));
  close(fds[0]);
  int status = 0;
  waitpid(pid, &status, 0);
  if (out) *out = got;
  return WIFEXITED(status) ? WEXITSTATUS(status) : 128 + WTERMSIG(status);
}

std::map<uint16_t, std::vector<uint16_t>> holding_points(Target& t, const spec::Spec& s) {
  std::map<uint16_t, std::vector<uint16_t>> out;
  for (const auto& r : s.registers) {
    if (r.table != spec::Table::holding || r.access == spec::Access::wo || r.access == spec::Access::command) continue;
    std::string why;
    if (auto v = read_table(t, r.table, r.address, r.words, why)) out[r.address] = *v;
  }
  return out;
}

// A journal made on hsc60 unit 1 is not restored onto a 57HS-R at unit 1,
// nor onto unit 2: one line, exit 2, nothing written. --force-identity goes on.
TEST(RestoreCommand, AJournalOfAnotherDriveOrUnitIsRefusedWithOneLine) {
  TempDir out;
  Served hsc = serve_tcp("hsc60");
  Served other = serve_tcp("sihong-57hs-r");
  std::string journal;
  {
    Session session(hsc.uri, &hsc.spec, options(out.path()));
    session.keep();
    journal = session.journal_path();
    session.restore();  // an end, but the CLI tries again anyway
  }
  JournalContents c = read_journal(journal);
  ASSERT_FALSE(c.originals.empty());
  auto o = open_target(other.uri);
  const auto before = holding_points(*o, other.spec);
  // The 57HS-R as "unit 1" (its own unit rewritten): the identity differs.
  const std::string as_unit_1 = other.uri.substr(0, other.uri.find('?')) + "?unit=" + std::to_string(o->info().unit);
  std::string text;
  EXPECT_EQ(mbconform({"restore", journal, "--target", as_unit_1}, &text), 2) << text;
  EXPECT_NE(text.find("not the drive the journal was made on"), std::string::npos) << text;
  EXPECT_NE(text.find("nothing written"), std::string::npos) << text;
  EXPECT_EQ(std::count(text.begin(), text.end(), '\n'), 1) << text;
  EXPECT_EQ(holding_points(*o, other.spec), before);
  // Another unit of the right device.
  const std::string unit_2 = hsc.uri.substr(0, hsc.uri.find('?')) + "?unit=2";
  EXPECT_EQ(mbconform({"restore", journal, "--target", unit_2}, &text), 2) << text;
  EXPECT_NE(text.find("made on unit 1; the target is unit 2"), std::string::npos) << text;
  // Another spec than the journal's.
  EXPECT_EQ(mbconform({"restore", journal, "--device", "sihong-57hs-r"}, &text), 2) << text;
  // The journal's own drive.
  EXPECT_EQ(mbconform({"restore", journal}, &text), 0) << text;
  // A spec file edited since the journal was made.
  const std::string copy = out / "hsc60.yaml";
  std::filesystem::copy_file(hsc.spec.path, copy);
  auto loaded = spec::load_spec_file(copy);
  ASSERT_TRUE(loaded.ok());
  std::string from_copy;
  {
    TempDir out2;
    Session session(hsc.uri, &*loaded.spec, options(out2.path()));
    session.keep();
    from_copy = out / "copy-journal.txt";
    std::filesystem::copy_file(session.journal_path(), from_copy);
    session.restore();
  }
  EXPECT_EQ(mbconform({"restore", from_copy, "--spec", copy}, &text), 0) << text;
  std::ofstream(copy, std::ios::app) << "# edited\n";
  EXPECT_EQ(mbconform({"restore", from_copy, "--spec", copy}, &text), 2) << text;
  EXPECT_NE(text.find("changed since the journal was made"), std::string::npos) << text;
  // Forced: it goes on (the 57HS-R at its own unit; what it writes is its business).
  EXPECT_NE(mbconform({"restore", journal, "--target", as_unit_1, "--force-identity"}, &text), 2) << text;
  EXPECT_NE(text.find("--force-identity: restoring anyway"), std::string::npos) << text;
}

// A full disk during a command: the write it cannot journal is not sent,
// sending stops, the drive is put back from memory, and the command says what
// it could not record. A file-size limit stands for the full disk.
TEST(RestoreCommand, AFullDiskStopsTheCommandBeforeTheWriteItCannotJournal) {
  TempDir dir;
  const std::string pty = dir / "ttyMB";
  ServeProcess serve({"--device", "hsc60@1", "--pty", pty});
  ASSERT_TRUE(serve.wait_listening(1)) << serve.log();
  auto s = spec::load_spec_by_id("hsc60");
  const Register* plain = nullptr;
  for (const auto& r : s.registers)
    if (r.table == spec::Table::holding && r.access == spec::Access::rw && !r.command && r.words == 1 &&
        other_value(r, 0)) {
      plain = &r;
      break;
    }
  ASSERT_TRUE(plain);
  const std::string uri = fmt::format("rtu://{}?unit=1&baud=115200&parity=N", pty);
  auto t = open_target(uri);
  const auto before = holding_points(*t, s);
  ASSERT_TRUE(before.count(plain->address));
  // A plain register (journaled before the first frame), then an unmapped
  // address (journaled at its write): the disk fills in between.
  auto frame = [](uint16_t address, uint16_t value) {
    Bytes f{1};
    Bytes pdu = write_single_register(address, value);
    f.insert(f.end(), pdu.begin(), pdu.end());
    append_crc(f);
    return "rtu " + to_hex(f) + "\n";
  };
  std::ofstream(dir / "script.txt") << "mbconform-script 1\n"
                                    << frame(plain->address, *other_value(*plain, before.at(plain->address)[0]))
                                    << frame(0x7000, 1) << frame(plain->address, before.at(plain->address)[0] ^ 1);
  // First without a limit: where the unmapped address's record starts.
  std::string text;
  const std::string free_out = dir / "free";
  ASSERT_NE(mbconform({"replay", dir / "script.txt", "--target", uri, "--device", "hsc60", "--allow-writes", "--out", free_out}, &text), 2) << text;
  std::string journal;
  for (const auto& e : std::filesystem::directory_iterator(free_out))
    if (e.path().filename().string().rfind("journal", 0) == 0) journal = e.path();
  ASSERT_FALSE(journal.empty()) << text;
  std::ifstream in(journal);
  std::stringstream ss;
  ss << in.rdbuf();
  const auto at = ss.str().find("unread holding 0x7000");
  ASSERT_NE(at, std::string::npos) << ss.str();
  EXPECT_EQ(holding_points(*t, s), before);
  // Then with the disk full inside that record.
  const std::string full_out = dir / "full";
  int rc = mbconform({"replay", dir / "script.txt", "--target", uri, "--device", "hsc60", "--allow-writes", "--out", full_out}, &text, rlim_t(at + 8));
  EXPECT_EQ(rc, 2) << text;
  EXPECT_NE(text.find("the journal could not be written"), std::string::npos) << text;
  EXPECT_NE(text.find("the journal could not record"), std::string::npos) << text;
  EXPECT_EQ(text.find("NOT RESTORED"), std::string::npos) << text;
  EXPECT_EQ(holding_points(*t, s), before) << text;
  // The journal on disk still restores (its torn record named).
  journal.clear();
  for (const auto& e : std::filesystem::directory_iterator(full_out))
    if (e.path().filename().string().rfind("journal", 0) == 0) journal = e.path();
  ASSERT_FALSE(journal.empty());
  EXPECT_EQ(mbconform({"restore", journal}, &text), 0) << text;
  EXPECT_NE(text.find("cut off"), std::string::npos) << text;
}

// The same for `props` (issue 41: a full disk during props left 19 points
// changed, and both its own restore and the printed `restore` failed). A
// file-size limit stands for the full disk, first inside the journal's first
// record of a write made during a property, then past the whole journal but
// short of the reports: one INCOMPLETE line for the property cut off, exit
// 2, the drive put back from memory, the journal on disk still restores, and
// no report is left torn or presented as whole.
TEST(RestoreCommand, AFullDiskDuringPropsStopsItRestoresAndLeavesNoTornReport) {
  TempDir dir;
  Served sv = serve_tcp("hsc60");
  auto t = open_target(sv.uri);
  const auto before = holding_points(*t, sv.spec);
  ASSERT_FALSE(before.empty());
  // Two properties that write: mapped registers (journaled before the first
  // frame) and, in responses-well-formed, unmapped addresses (journaled at
  // their write, during the run).
  auto props = [&](const std::string& out, rlim_t fsize, std::string& text) {
    return mbconform({"props", "--target", sv.uri, "--device", "hsc60", "--allow-writes", "--seed", "7", "--cases", "20",
                      "--only", "read-after-write", "--only", "responses-well-formed", "--out", out, "-q"},
                     &text, fsize);
  };
  auto journal_in = [](const std::string& out) {
    for (const auto& e : std::filesystem::directory_iterator(out))
      if (e.path().filename().string().rfind("journal", 0) == 0) return e.path().string();
    return std::string();
  };
  auto slurp = [](const std::string& path) {
    std::ifstream in(path);
    std::stringstream ss;
    ss << in.rdbuf();
    return ss.str();
  };
  auto no_report = [&](const std::string& out, const std::string& text) {
    for (const char* name : {"junit.xml", "report.json", "report.html", "junit.xml.part", "report.json.part", "report.html.part"})
      EXPECT_FALSE(std::filesystem::exists(std::filesystem::path(out) / name)) << name << "\n" << text;
    EXPECT_NE(text.find("no report written"), std::string::npos) << text;
    EXPECT_EQ(text.find("reports: " + out), std::string::npos) << text;
  };
  // Without a limit: where the first record written during the run starts,
  // and how long the journal and the reports grow.
  std::string text;
  const std::string free_out = dir / "free";
  ASSERT_EQ(props(free_out, 0, text), 0) << text;
  const std::string free_journal = journal_in(free_out);
  ASSERT_FALSE(free_journal.empty()) << text;
  const std::string jtext = slurp(free_journal);
  const auto at = jtext.find("\nunread holding ");
  ASSERT_NE(at, std::string::npos) << jtext;
  const auto report_size = std::filesystem::file_size(std::filesystem::path(free_out) / "report.json");
  ASSERT_GT(report_size, jtext.size() + 1024) << "the reports must outgrow the journal for the second limit";
  EXPECT_EQ(holding_points(*t, sv.spec), before);

  // 1. The disk full inside the first record written during a property.
  const std::string full_out = dir / "full";
  int rc = props(full_out, rlim_t(at + 9), text);
  EXPECT_EQ(rc, 2) << text;
  EXPECT_NE(text.find("INCOMPLETE: the journal could not be written"), std::string::npos) << text;
  EXPECT_NE(text.find("the journal could not record"), std::string::npos) << text;
  EXPECT_EQ(text.find("NOT RESTORED"), std::string::npos) << text;
  EXPECT_EQ(text.find("falsified"), std::string::npos) << text;
  EXPECT_EQ(holding_points(*t, sv.spec), before) << text;
  no_report(full_out, text);
  const std::string journal = journal_in(full_out);
  ASSERT_FALSE(journal.empty()) << text;
  EXPECT_LE(std::filesystem::file_size(journal), at + 9);
  // The journal on disk still restores (its torn record named), and the drive is as it was.
  EXPECT_EQ(mbconform({"restore", journal}, &text), 0) << text;
  EXPECT_NE(text.find("cut off"), std::string::npos) << text;
  EXPECT_EQ(holding_points(*t, sv.spec), before) << text;

  // 2. The journal whole, the disk full at the reports.
  const std::string late_out = dir / "late";
  rc = props(late_out, rlim_t(jtext.size() + 512), text);
  EXPECT_EQ(rc, 2) << text;
  EXPECT_NE(text.find("mbconform props: error: writing reports: cannot write"), std::string::npos) << text;
  EXPECT_EQ(text.find("NOT RESTORED"), std::string::npos) << text;
  EXPECT_EQ(holding_points(*t, sv.spec), before) << text;
  no_report(late_out, text);
  const std::string late_journal = journal_in(late_out);
  ASSERT_FALSE(late_journal.empty()) << text;
  EXPECT_EQ(mbconform({"restore", late_journal}, &text), 0) << text;
  EXPECT_EQ(holding_points(*t, sv.spec), before) << text;
}

// A file-size limit (`ulimit -f`, a quota) reached by a command's reports is
// a full disk, not a signal. Against a ref: target no journal is open: its
// SIGXFSZ ended the process with no line, a torn junit.xml.part left behind
// and a signal's exit status. Now, for `run` and `props`: one error line
// naming the file and EFBIG, exit 2, and no report (nor .part) left.
TEST(RestoreCommand, AFileSizeLimitAtTheReportsIsOneLineNotASignal) {
  TempDir dir;
  for (const std::string command : {"run", "props"}) {
    const std::string out = dir / command;
    std::string text;
    std::vector<std::string> args{command, "--target", "ref:hsc60", "--out", out, command == "run" ? "--quiet" : "-q"};
    if (command == "props") args.insert(args.end(), {"--cases", "5", "--seed", "1"});
    EXPECT_EQ(mbconform(args, &text, 8192), 2) << command << ": " << text;
    size_t errors = 0;
    for (size_t at = text.find("error:"); at != std::string::npos; at = text.find("error:", at + 1)) ++errors;
    EXPECT_EQ(errors, 1u) << text;
    EXPECT_NE(text.find("mbconform " + command + ": error: "), std::string::npos) << text;
    EXPECT_NE(text.find("cannot write " + out + "/"), std::string::npos) << text;
    EXPECT_NE(text.find(std::strerror(EFBIG)), std::string::npos) << text;
    for (const char* name : {"junit.xml", "report.json", "report.html", "junit.xml.part", "report.json.part", "report.html.part"})
      EXPECT_FALSE(std::filesystem::exists(std::filesystem::path(out) / name)) << command << ": " << name << "\n" << text;
  }
}

// Issue 37: a drive that stays silent when its command registers are read
// runs every printed example of every device: each example of the spec is a
// case of the run, none is skipped, and none because its value "could not be
// read before the write". Hanstar and Rieding print no reply to a read of a
// command register, so on them such a drive does what its manual prints and
// every MUST example passes. (The 57HS-R prints exception 06 for a read of
// its start command (6.2.4) and the HSC60 a value for a read of 90 and 91:
// silence is a deviation there, which a case may report.)
TEST(SilentCommandReads, EveryPrintedExampleOfEveryDeviceRuns) {
  for (const std::string id : {"sihong-57hs-r", "hsc60", "hanstar-7trsm5740q", "rieding-dhe"}) {
    SCOPED_TRACE(id);
    const bool prints_no_reply = id == "hanstar-7trsm5740q" || id == "rieding-dhe";
    TempDir out;
    Served sv = serve_tcp(id, {"--fault", "silent-command-reads"});
    std::string text;
    int rc = mbconform({"run", "--target", sv.uri, "--device", id, "--filter", "/examples/", "--allow-motion",
                        "--allow-eeprom-writes", "--allow-writes", "--out", out.path(), "-q"},
                       &text);
    EXPECT_NE(rc, 2) << text;
    if (prints_no_reply) {
      EXPECT_EQ(rc, 0) << text;
    }
    std::ifstream in(out / "report.json");
    ASSERT_TRUE(in) << text;
    nlohmann::json j = nlohmann::json::parse(in);
    std::set<std::string> ran;
    int must = 0;
    for (const auto& d : j["devices"])
      for (const auto& c : d["cases"]) {
        const std::string case_id = c.value("id", ""), message = c.value("message", ""), outcome = c.value("outcome", "");
        EXPECT_EQ(message.find("could not be read before the write"), std::string::npos) << case_id << ": " << message;
        // Served over Modbus TCP: a frame with a deliberately wrong CRC cannot be sent (not the journal's doing).
        const bool raw_rtu = message.find("cannot send raw RTU frames") != std::string::npos;
        EXPECT_TRUE(outcome != "skip" || raw_rtu) << case_id << ": " << message;
        if (outcome != "skip" || raw_rtu) ran.insert(case_id.substr(case_id.rfind('/') + 1));
        if (c.value("level", "") == "MUST") {
          ++must;
          if (prints_no_reply) {
            EXPECT_EQ(outcome, "pass") << case_id << ": " << message;
          }
        }
      }
    ASSERT_FALSE(sv.spec.examples.empty());
    for (const auto& x : sv.spec.examples) {  // a sequence's steps run as one case, named after the sequence
      const std::string& name = x.sequence.empty() ? x.id : x.sequence;
      EXPECT_TRUE(ran.count(name)) << "printed example " << name << " did not run";
    }
    if (prints_no_reply) {
      EXPECT_GE(must, 4) << text;  // 6.3.2/6.3.3 (Hanstar), the four 五 sequences (Rieding)
    }
  }
}

}  // namespace
}  // namespace mbc::conf
