#include "session/restore.h"

#include <fmt/core.h>
#include <fmt/ranges.h>

#include <algorithm>
#include <deque>
#include <set>
#include <fstream>
#include <iterator>
#include <map>
#include <memory>
#include <thread>

#include "modbus/judge.h"
#include "modbus/limits.h"
#include "modbus/pdu.h"
#include "safety/safety.h"
#include "policy/policy.h"
#include "session/identity.h"

namespace mbc::conf {
namespace {

// After a restore: how long the line settles before it is looked at again,
// and how many times.
constexpr std::chrono::milliseconds kSettle{300};
constexpr int kSettleRounds = 3;

bool is_command(const spec::Register* r) { return r && (r->access == spec::Access::command || r->command); }

// The write a restore would send for `value` at `address` (the policy judges
// it by the registers it reaches).
Bytes write_pdu(spec::Table table, uint16_t address, const std::vector<uint16_t>& value) {
  if (table == spec::Table::coil) {
    if (value.size() == 1) return write_single_coil(address, value[0] != 0);
    auto bits = std::make_unique<bool[]>(value.size());
    for (size_t k = 0; k < value.size(); ++k) bits[k] = value[k] != 0;
    return write_multiple_coils(address, std::span<const bool>(bits.get(), value.size()));
  }
  if (value.size() == 1) return write_single_register(address, value[0]);
  return write_multiple_registers(address, value);
}

// The spec's stop as the words of its register (2-word registers in the spec's word order).
std::optional<std::pair<const spec::Register*, std::vector<uint16_t>>> stop_words(const spec::Spec& s) {
  if (!s.control || !s.control->motion || !s.control->motion->stop) return std::nullopt;
  const auto& st = *s.control->motion->stop;
  const spec::Register* r = s.find_by_key(st.key);
  if (!r) return std::nullopt;
  const auto v = uint32_t(st.value);
  if (r->words == 1) return std::pair{r, std::vector<uint16_t>{uint16_t(v)}};
  const uint16_t hi = uint16_t(v >> 16), lo = uint16_t(v);
  return std::pair{r, r->word_order == spec::WordOrder::low_first ? std::vector<uint16_t>{lo, hi} : std::vector<uint16_t>{hi, lo}};
}

}  // namespace

// ---- shared helpers -----------------------------------------------------------

std::string journal_label(const spec::Spec* s, spec::Table table, uint16_t address) {
  if (s)
    if (const auto* r = s->find_register(address, table)) return register_label(*r);
  return fmt::format("{} 0x{:04X}", journal_table_name(table), address);
}

int journal_read_limit(const spec::Spec* s, spec::Table table) {
  const int fc = table == spec::Table::coil ? 1 : 3;
  int most = standard_max_quantity(fc);
  if (s)
    if (const auto* f = s->profile.function(fc); f && f->max_quantity) most = std::min(most, *f->max_quantity);
  return std::max(most, 1);
}

bool no_reply(const std::string& why) { return why.find("no reply") != std::string::npos; }

// A batch that fails is read again entry by entry, so a drive that takes only
// single reads costs what it did. Two silent entries in a row end the
// reading: a dead target costs two time-outs, not one per register.
std::vector<std::optional<std::vector<uint16_t>>> read_entries(Target& t, const spec::Spec* s,
                                                               const std::vector<const JournalEntry*>& es,
                                                               std::vector<std::string>& whys) {
  std::vector<std::optional<std::vector<uint16_t>>> out(es.size());
  whys.assign(es.size(), "");
  int silent = 0;
  for (size_t i = 0; i < es.size();) {
    size_t j = i + 1;
    int words = int(es[i]->value.size());
    const int most = journal_read_limit(s, es[i]->table);
    while (j < es.size() && es[j]->table == es[i]->table &&
           es[j]->address == uint32_t(es[j - 1]->address) + es[j - 1]->value.size() &&
           words + int(es[j]->value.size()) <= most) {
      words += int(es[j]->value.size());
      ++j;
    }
    if (j - i > 1) {
      std::string why;
      if (auto all = read_table(t, es[i]->table, es[i]->address, words, why); all && int(all->size()) == words) {
        size_t at = 0;
        for (size_t k = i; k < j; ++k) {
          out[k] = std::vector<uint16_t>(all->begin() + long(at), all->begin() + long(at + es[k]->value.size()));
          at += es[k]->value.size();
        }
        silent = 0;
        i = j;
        continue;
      }
    }
    for (size_t k = i; k < j; ++k) {
      if (silent >= 2) {
        whys[k] = "no reply (the target stopped answering)";
        continue;
      }
      out[k] = read_table(t, es[k]->table, es[k]->address, int(es[k]->value.size()), whys[k]);
      silent = !out[k] && no_reply(whys[k]) ? silent + 1 : 0;
    }
    i = j;
  }
  return out;
}

// ---- the policy ------------------------------------------------------------------

std::optional<Refusal> restore_refusal(const spec::Spec& s, const TargetInfo& info, uint8_t unit,
                                       std::span<const uint8_t> pdu, bool stop_operation) {
  WritePolicy p;
  // Putting a stored value back costs the one stored write it undoes; the
  // command that journaled it had the opt-ins for the map it used.
  p.allow_eeprom_writes = true;
  p.allow_writes = true;
  // A restore never starts motion: the one command it sends is the spec's stop.
  p.allow_motion = stop_operation;
  return allowed(PolicyFacts{&s, info, p}, unit, pdu).refused;
}

// ---- identity ------------------------------------------------------------------

std::string spec_fingerprint(const spec::Spec& s) {
  if (s.path.empty()) return "";
  std::ifstream in(s.path, std::ios::binary);
  if (!in) return "";
  std::string all((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
  return fmt::format("{:08X}", journal_crc32(all));
}

std::string journal_identity(Target& t, const spec::Spec& s) {
  const Target::Wait kept_wait = Target::Wait::automatic;
  t.set_wait(Target::Wait::reply);
  IdentityOptions o;
  o.attempts = 2;
  o.stated_only = false;  // a drive compared with itself: an inferred reading tells drives apart too
  const Identity id = read_identity(s, [&](const Bytes& pdu, std::string& error) -> std::optional<Reply> {
    try {
      return t.transact(t.info().unit, pdu);
    } catch (const std::exception& e) {
      error = e.what();
      return std::nullopt;
    }
  }, o);
  t.set_wait(kept_wait);
  if (id.by_fc43) return id.objects.empty() ? "FC 43/14: no identification" : id.objects_text();
  // Which registers answer, not their values (which change).
  std::vector<std::string> seen;
  for (const IdentityRead& r : id.reads) {
    using K = IdentityRead::Kind;
    const std::string what = r.kind == K::exception  ? fmt::format("exception {:02X}", r.exception)
                             : r.kind == K::answered ? "answers"
                             : r.kind == K::malformed && !r.pdu.empty() ? "malformed"
                                                                         : "no reply";
    seen.push_back(fmt::format("FC {:02} 0x{:04X} {}", r.fc, r.reg->address, what));
  }
  if (seen.empty()) return "no register the spec says is readable";
  return fmt::format("{}", fmt::join(seen, ", "));
}

std::string journal_mismatch(Target& t, const spec::Spec& s, const JournalContents& c) {
  auto get = [&](const char* key) {
    auto it = c.header.find(key);
    return it == c.header.end() ? std::string() : it->second;
  };
  const std::string device = get("device"), unit = get("unit");
  if (device.empty() || unit.empty())
    return fmt::format("the journal's header names no {} (a damaged header): it cannot be matched to the target",
                       device.empty() ? "device" : "unit");
  if (device != s.device.id)
    return fmt::format("the journal was made on a {}; the spec given is {}'s", device, s.device.id);
  if (unit != std::to_string(t.info().unit))
    return fmt::format("the journal was made on unit {}; the target is unit {}", unit, t.info().unit);
  if (const std::string kept = get("spec-crc32"), now = spec_fingerprint(s); !kept.empty() && !now.empty() && kept != now)
    return fmt::format("the spec {} changed since the journal was made (CRC-32 {} then, {} now): its registers may not be "
                       "the ones journaled", s.path, kept, now);
  if (const std::string kept = get("identity"); !kept.empty())
    if (const std::string now = journal_identity(t, s); now != kept) {
      if (now.find("answers") == std::string::npos && now.find("exception") == std::string::npos &&
          now.find("VendorName") == std::string::npos)
        return fmt::format("unit {} does not answer the reads that identify it ({}): is the target right?", unit, now);
      return fmt::format("unit {} is not the drive the journal was made on: it answered \"{}\" then, \"{}\" now", unit, kept, now);
    }
  return "";
}

// ---- the control -----------------------------------------------------------------
// A control with states (a spec's control: may hold only `motion:`, the
// facts of a move, and no state machine to walk).
static bool state_machine(const spec::Spec& s) { return s.control && !s.control->states.empty(); }


namespace {

std::optional<std::map<std::string, uint16_t>> control_words(Target& t, const spec::Spec& s, std::string& why) {
  std::map<std::string, uint16_t> words;
  for (const auto& st : s.control->states)
    for (const auto& m : st.status) {
      if (words.count(m.register_key)) continue;
      const spec::Register* r = s.find_by_key(m.register_key);
      if (!r) {
        why = "the status register " + m.register_key + " is not in the spec";
        return std::nullopt;
      }
      auto v = read_table(t, r->table, r->address, 1, why);
      if (!v || v->empty()) return std::nullopt;
      words[m.register_key] = (*v)[0];
    }
  return words;
}

std::string control_state_named(const spec::Control& c, const std::map<std::string, uint16_t>& words) {
  for (const auto& st : c.states) {
    bool all = !st.status.empty();
    for (const auto& m : st.status) {
      auto it = words.find(m.register_key);
      all = all && it != words.end() && m.matches(it->second);
    }
    if (all) return st.id;
  }
  return "";
}

// How long a command's automatic steps may take: every stated time, and a margin.
std::chrono::milliseconds control_settle(const spec::Control& c) {
  double most = 0;
  for (const auto& t : c.transitions)
    if (t.within_ms) most = std::max(most, *t.within_ms);
  for (const auto& cmd : c.commands)
    if (cmd.stop_within_ms) most = std::max(most, *cmd.stop_within_ms);
  return std::chrono::milliseconds(int64_t(std::min(most, 10'000.0)) + 50);
}

}  // namespace

bool is_control_command_register(const spec::Spec& s, spec::Table table, uint16_t address) {
  if (!state_machine(s) || table != spec::Table::holding) return false;
  for (const auto& cmd : s.control->commands)
    if (const spec::Register* r = s.find_by_key(cmd.register_key); r && address >= r->address && address <= r->last_address())
      return true;
  return false;
}

std::string control_record(Target& t, const spec::Spec& s) {
  if (!state_machine(s)) return "";
  std::string why;
  auto words = control_words(t, s, why);
  if (!words) return "";
  std::string state = control_state_named(*s.control, *words);
  std::string line = "control " + (state.empty() ? std::string("unknown") : state);
  for (const auto& [key, w] : *words) line += fmt::format(" {}={:04X}", key, w);
  return line;
}

std::string control_to_safe(Target& t, const spec::Spec& s, std::vector<std::string>& did) {
  if (!state_machine(s)) return "";
  const spec::Control& c = *s.control;
  const uint8_t unit = t.info().unit;
  t.set_wait(Target::Wait::reply);
  // The words last written to the command registers (an edge needs them).
  std::map<std::string, uint16_t> last;
  std::string why;
  for (const auto& cmd : c.commands)
    if (!last.count(cmd.register_key))
      if (const spec::Register* r = s.find_by_key(cmd.register_key))
        if (auto v = read_table(t, r->table, r->address, 1, why); v && !v->empty()) last[cmd.register_key] = (*v)[0];
  auto holds = [&](const spec::ControlTransition& tr) {
    for (const auto& w : tr.when) {
      const spec::Register* r = s.find_by_key(w.register_key);
      std::string no;
      auto v = r ? read_table(t, r->table, r->address, 1, no) : std::nullopt;
      if (!v || v->empty() || std::find(w.values.begin(), w.values.end(), int64_t((*v)[0])) == w.values.end()) return false;
    }
    return true;
  };
  // The states an automatic step leaves (a quick stop completed, a fault reaction done).
  auto settled = [&](std::string st) {
    for (int k = 0; k < 8; ++k) {
      bool moved = false;
      for (const auto& tr : c.transitions)
        if (tr.automatic() && (tr.from == st || tr.from == "*") &&
            (tr.event == "motion_done" || tr.event == "time" || tr.event == "reaction_done") && holds(tr)) {
          st = tr.to;
          moved = true;
          break;
        }
      if (!moved) break;
    }
    return st;
  };
  for (int step = 0; step < 8; ++step) {
    auto words = control_words(t, s, why);
    if (!words) return "the status could not be read: " + why;
    const std::string now = control_state_named(c, *words);
    if (now.empty()) return "the status names no state of the spec's control";
    if (now == c.safe) return "";
    // Shortest path to safe by commands whose transitions start no motion.
    std::map<std::string, std::pair<std::string, const spec::ControlCommand*>> from;  // state -> (previous, command)
    std::deque<std::string> queue{now};
    from[now] = {"", nullptr};
    while (!queue.empty() && !from.count(c.safe)) {
      std::string st = queue.front();
      queue.pop_front();
      for (const auto& tr : c.transitions) {
        if (tr.automatic() || tr.motion || (tr.from != st && tr.from != "*")) continue;
        const spec::ControlCommand* cmd = c.command(tr.command);
        if (!cmd || (cmd->motion && !cmd->stops) || !holds(tr)) continue;
        std::string to = settled(tr.to);
        if (from.emplace(to, std::make_pair(st, cmd)).second) queue.push_back(to);
      }
    }
    if (!from.count(c.safe)) return fmt::format("no command of the spec's control leads from {} to {} without motion", now, c.safe);
    std::string at = c.safe;
    while (from[at].first != now) at = from[at].first;
    const spec::ControlCommand& cmd = *from[at].second;
    const spec::Register* r = s.find_by_key(cmd.register_key);
    if (!r) return "the command register " + cmd.register_key + " is not in the spec";
    std::vector<uint16_t> words_to_write;
    if (cmd.trigger == spec::Trigger::edge && (last[cmd.register_key] & cmd.edge_mask))
      words_to_write.push_back(uint16_t(cmd.word() & ~cmd.edge_mask));
    words_to_write.push_back(cmd.word());
    for (uint16_t w : words_to_write) {
      Bytes pdu = write_single_register(r->address, w);
      if (auto no = restore_refusal(s, t.info(), unit, pdu, true)) return no->reason;
      Reply got = t.transact(unit, pdu);
      if (!got.pdu) return fmt::format("{} = 0x{:04X} ({}): no reply", cmd.register_key, w, cmd.id);
      Judged j = judge_reply(pdu, *got.pdu);
      if (j.kind != Judged::Kind::normal)
        return fmt::format("{} = 0x{:04X} ({}): {}", cmd.register_key, w, cmd.id, describe_pdu(*got.pdu, false));
      last[cmd.register_key] = w;
    }
    did.push_back(fmt::format("{} -> {}: {} = 0x{:04X} ({}, {})", now, at, cmd.register_key, cmd.word(), cmd.id, cmd.section));
    std::this_thread::sleep_for(control_settle(c));
  }
  return "the safe state was not reached in 8 commands";
}

// ---- the restore ------------------------------------------------------------------

RestoreReport restore_journal(Target& t, const spec::Spec& s, const JournalContents& c, Journal& record) {
  RestoreReport rep;
  rep.journal = record.path();
  rep.kept = c.originals.size() + c.commands.size();
  std::vector<std::string> unrecorded;
  auto note = [&](const std::string& text) {
    if (!record.try_record(text)) unrecorded.push_back(text);
  };
  for (const auto& u : c.unread)
    rep.unread.push_back(fmt::format("{} 0x{:04X}{}: written, but it could not be read first ({})", journal_table_name(u.table),
                                     u.address, u.count > 1 ? fmt::format("-0x{:04X}", u.address + u.count - 1) : "", u.why));
  for (const auto& tr : c.torn) {
    if (tr.last)
      rep.notes.push_back(fmt::format("journal line {}: cut off while it was written ({}): skipped; the write it was to "
                                      "guard was not sent", tr.line, tr.why));
    else
      rep.not_restored.push_back(fmt::format("journal line {}: damaged ({}): skipped; what it held is not known", tr.line, tr.why));
  }
  auto name = [&](const JournalEntry& e) { return e.name.empty() ? journal_label(&s, e.table, e.address) : e.name; };
  auto line = [&](const char* kind, const JournalEntry& e, const std::string& why = "") {
    note(fmt::format("{} {} 0x{:04X}{}{}", kind, journal_table_name(e.table), e.address, why.empty() ? "" : " ", why));
  };
  auto valued = [&](const char* kind, const JournalEntry& e, const std::string& why = "") {
    std::string words = std::to_string(e.value.size());
    for (uint16_t w : e.value) words += fmt::format(" {:04X}", w);
    note(fmt::format("{} {} 0x{:04X} {}{}{}", kind, journal_table_name(e.table), e.address, words, why.empty() ? "" : " ", why));
  };
  auto earlier = [&](const JournalEntry& e) -> const JournalRestored* {
    for (const auto& r : c.restored)
      if (r.table == e.table && r.address == e.address) return &r;
    return nullptr;
  };
  const uint8_t unit = t.info().unit;

  // The drive's control (spec control:): to the safe state first (stop,
  // disable), before any register goes back; a control command register is
  // then left as the safe state's commands left it.
  // A control the command never commanded (no control command register
  // written) and still in the state the journal recorded is left there: the
  // restore puts the drive back as it was (a 57HS-R enabled before a run that
  // only read is not released). A commanded control goes to the safe state
  // first (stop, disable: issue 38), even when it is back where it started;
  // where the spec's control has no motion-free way there from the state the
  // drive was found in (a Hanstar just powered on), it is left in that state.
  bool commanded = false;
  for (const auto& e : c.originals) commanded |= is_control_command_register(s, e.table, e.address);
  for (const auto& k : c.commands) commanded |= is_control_command_register(s, k.table, k.address);
  const bool recorded = !c.control_state.empty() && c.control_state != "unknown";
  auto state_now = [&] {
    std::string no;
    auto words = control_words(t, s, no);
    return words ? control_state_named(*s.control, *words) : std::string();
  };
  bool safe = false;
  if (state_machine(s) && (commanded || recorded)) {
    const std::string before = recorded ? c.control_state : "";
    std::string now = recorded ? state_now() : "";
    auto leave = [&](const std::string& why) {
      safe = now == s.control->safe;
      rep.notes.push_back(fmt::format("control: in {}, the state before the command: {}", now, why));
      note(fmt::format("left control {}: {}", now, why));
    };
    if (!commanded && !now.empty() && now == before) {
      leave(fmt::format("not commanded by the run, so left there, not taken to the safe state {}", s.control->safe));
    } else {
      std::vector<std::string> did;
      std::string why = control_to_safe(t, s, did);
      for (const auto& d : did) note("stopped control " + d);
      if (why.empty()) {
        safe = true;
        rep.notes.push_back(fmt::format("control: in the safe state {}{}{}", s.control->safe,
                                        did.empty() ? "" : fmt::format(" ({})", fmt::join(did, "; ")),
                                        before.empty() ? "" : fmt::format(", from {} before the command", before)));
      } else if (did.empty() && !before.empty() && (now = state_now()) == before) {
        leave(fmt::format("no motion-free way to the safe state {} ({})", s.control->safe, why));
      } else {
        rep.not_restored.push_back(fmt::format("control: the safe state {} was not reached: {}", s.control->safe, why));
        note(fmt::format("not-restored control: the safe state {} was not reached: {}", s.control->safe, why));
      }
    }
  }
  const std::set<uint16_t> setpoints = state_machine(s) ? control_setpoints(s) : std::set<uint16_t>{};

  // What goes back, in order (the persistence switch first); what the policy
  // or the register's access keeps out; the command registers to stop.
  std::vector<const JournalEntry*> order;
  std::vector<std::string> commands_written;
  bool needs_stop = false;
  for (const auto& k : c.commands) {
    const spec::Register* r = s.register_covering(k.address, k.table);
    if (r && r->command && !r->command->motion) {
      rep.notes.push_back(fmt::format("{}: a command that starts no motion was written: nothing to put back",
                                      journal_label(&s, k.table, r->address)));
      continue;
    }
    needs_stop = true;
    commands_written.push_back(journal_label(&s, k.table, r ? r->address : k.address));
  }
  for (int pass = 0; pass < 2; ++pass)
    for (const auto& e : c.originals) {
      if (e.persist_switch != (pass == 0)) continue;
      const spec::Register* r = s.register_covering(e.address, e.table);
      if (r && r->access == spec::Access::ro) {
        rep.notes.push_back(fmt::format("{}: read-only: it changes by side effect, so it is not put back", name(e)));
        continue;
      }
      if (is_control_command_register(s, e.table, e.address)) {
        rep.notes.push_back(fmt::format("{}: a control command register: left as the commands to the safe state {} wrote it, "
                                        "not written back (the word it held is a command)", name(e), s.control->safe));
        continue;
      }
      if (is_command(r)) {  // a journal of format 1 kept a command register's value: stopped instead
        needs_stop = true;
        commands_written.push_back(name(e));
        continue;
      }
      // The "do not persist" switch is the session's own write (it turned it
      // on): the policy never lets a check write it, the restore puts it back.
      // A set-point of the control moves nothing once the drive is in its safe state.
      const bool setpoint_in_safe = safe && e.table == spec::Table::holding && setpoints.count(e.address);
      if (auto no = e.persist_switch ? std::nullopt
                                     : restore_refusal(s, t.info(), unit, write_pdu(e.table, e.address, e.value), setpoint_in_safe)) {
        std::string msg = fmt::format("{}: not written back: {}", name(e), no->reason);
        rep.not_restored.push_back(msg);
        line("not-restored", e, msg);
        continue;
      }
      order.push_back(&e);
    }

  // A command register has no value to put back: what its write started is
  // undone by the spec's stop, first, before any setpoint goes back.
  if (needs_stop) {
    const std::string what = fmt::format("{}", fmt::join(commands_written, ", "));
    auto stop = stop_words(s);
    if (!stop) {
      rep.not_restored.push_back(fmt::format("{}: a command register was written, and the spec names no stop operation "
                                             "(control.motion.stop) to undo it", what));
      note(fmt::format("not-restored command {}: the spec names no stop", what));
    } else {
      const auto& [reg, words] = *stop;
      Bytes pdu = write_pdu(reg->table, reg->address, words);
      std::string why;
      if (auto no = restore_refusal(s, t.info(), unit, pdu, true)) {
        why = no->reason;
      } else {
        t.set_wait(Target::Wait::reply);
        Reply got = t.transact(unit, pdu);
        Judged j = got.pdu ? judge_reply(pdu, *got.pdu) : Judged{};
        if (!got.pdu) why = "no reply";
        else if (j.kind == Judged::Kind::exception) why = fmt::format("exception {:02X}", j.exception_code);
        else if (!j.ok()) why = j.problems.empty() ? "malformed reply" : j.problems.front();
      }
      const std::string op = fmt::format("{} = {} (control.motion.stop, {})", register_label(*reg),
                                         s.control->motion->stop->value, s.control->motion->stop->section);
      if (why.empty()) {
        rep.notes.push_back(fmt::format("stopped: {} after writes to {}", op, what));
        note(fmt::format("stopped {} after {}", op, what));
      } else {
        rep.not_restored.push_back(fmt::format("{}: the stop {} failed: {}", what, op, why));
        note(fmt::format("not-restored command {}: the stop failed: {}", what, why));
      }
    }
  }

  auto finish = [&] {
    if (!unrecorded.empty()) {
      std::vector<std::string> first(unrecorded.begin(), unrecorded.begin() + long(std::min<size_t>(unrecorded.size(), 8)));
      rep.notes.push_back(fmt::format("the journal could not record {} line(s) of this restore ({}): {}{}", unrecorded.size(),
                                      record.failed().empty() ? "not open" : record.failed(), fmt::join(first, "; "),
                                      unrecorded.size() > first.size() ? "; ..." : ""));
    }
  };
  if (order.empty()) {
    note(fmt::format("end {} {} kept, 0 written back, 0 verified, {} not restored",
                     rep.not_restored.empty() ? "restored" : "incomplete", rep.kept, rep.not_restored.size()));
    finish();
    return rep;
  }
  // One liveness probe, one reconnect, one more probe: a dead target costs
  // a few time-outs, not one per register.
  auto alive = [&](const JournalEntry& e) {
    std::string why;
    if (read_table(t, e.table, e.address, int(e.value.size()), why)) return true;
    if (!t.reconnect()) return false;
    return read_table(t, e.table, e.address, int(e.value.size()), why).has_value();
  };
  auto give_up = [&](size_t from, const std::string& why) {
    rep.gave_up = true;
    for (size_t k = from; k < order.size(); ++k) {
      rep.not_restored.push_back(fmt::format("{}: not restored: {}", name(*order[k]), why));
      line("not-restored", *order[k], why);
    }
  };
  std::vector<const JournalEntry*> done;
  if (!alive(*order.front())) {
    give_up(0, "the target does not answer (one probe, one reconnect)");
  } else {
    int silent_in_a_row = 0;
    std::vector<std::string> whys;
    const auto before = read_entries(t, &s, order, whys);
    for (size_t k = 0; k < order.size(); ++k) {
      const JournalEntry& e = *order[k];
      const std::string& why = whys[k];
      const auto& now = before[k];
      if (now && *now == e.value) {
        done.push_back(&e);
        silent_in_a_row = 0;
        continue;
      }
      // An earlier restore put this address back; it changed since: the
      // user's value now, not the command's, and it stays.
      if (const JournalRestored* was = earlier(e)) {
        std::string msg = now ? fmt::format("{}: reads {:04X}, changed since an earlier restore put back {:04X}: left as it is",
                                            name(e), fmt::join(*now, " "), fmt::join(was->value, " "))
                              : fmt::format("{}: an earlier restore put it back, and it cannot be read now ({}): not "
                                            "overwritten blind", name(e), why);
        rep.notes.push_back(msg);
        line("left", e, msg);
        continue;
      }
      std::string err = write_table_verified(t, s, e.table, e.address, e.value, name(e));
      if (err.empty()) {
        ++rep.restored;
        valued("restored", e);
        done.push_back(&e);
        silent_in_a_row = 0;
        continue;
      }
      rep.not_restored.push_back(err);
      line("not-restored", e, err);
      if (no_reply(err) || (!now && no_reply(why))) {
        if (++silent_in_a_row >= 2 && !alive(e)) {
          give_up(k + 1, "the target stopped answering during the restore");
          break;
        }
      } else {
        silent_in_a_row = 0;
      }
    }
  }
  // Verify everything put back once more: a write with a side effect on
  // another register (a mode that resets a setpoint) shows up here.
  if (!rep.gave_up) {
    std::vector<std::string> vwhys;
    const auto after = read_entries(t, &s, done, vwhys);
    for (size_t i = 0; i < done.size(); ++i) {
      const JournalEntry* e = done[i];
      const auto& now = after[i];
      if (now && *now == e->value) {
        ++rep.verified;
        valued("verified", *e);
      } else {
        std::string msg = now ? fmt::format("{}: reads {:04X} after the restore (kept {:04X})", name(*e), fmt::join(*now, " "),
                                            fmt::join(e->value, " "))
                              : fmt::format("{}: verify failed: {}", name(*e), vwhys[i]);
        rep.not_restored.push_back(msg);
        line("not-restored", *e, msg);
      }
    }
  }
  // Frames the stopped command left queued (in a serial adapter, a
  // gateway, a server the host holds up) may still be applied after the
  // restore: let the line settle, look again, put back what changed.
  for (int round = 0; round < kSettleRounds && !rep.gave_up && rep.not_restored.empty() && !done.empty(); ++round) {
    std::this_thread::sleep_for(kSettle);
    bool changed = false;
    std::vector<std::string> swhys;
    const auto settled = read_entries(t, &s, done, swhys);
    for (size_t i = 0; i < done.size(); ++i) {
      const JournalEntry* e = done[i];
      if (settled[i] && *settled[i] == e->value) continue;
      changed = true;
      std::string err = write_table_verified(t, s, e->table, e->address, e->value, name(*e));
      if (err.empty()) {
        ++rep.restored;
        valued("restored", *e, "again, after the line settled");
      } else {
        rep.not_restored.push_back(err);
        line("not-restored", *e, err);
      }
    }
    if (!changed) break;
  }
  note(fmt::format("end {} {} kept, {} written back, {} verified, {} not restored",
                   rep.not_restored.empty() ? "restored" : "incomplete", rep.kept, rep.restored, rep.verified,
                   rep.not_restored.size()));
  finish();
  return rep;
}

}  // namespace mbc::conf
