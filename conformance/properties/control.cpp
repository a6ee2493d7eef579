#include "properties/control.h"

#include <fmt/core.h>
#include <fmt/ranges.h>
#include <rapidcheck.h>
#include <rapidcheck/state.h>

#include <algorithm>
#include <chrono>
#include <deque>
#include <map>
#include <thread>

#include "check/judge.h"
#include "modbus/judge.h"
#include "properties/generators.h"

namespace mbc::conf::props {

using spec::Control;
using spec::ControlCommand;
using spec::ControlState;
using spec::ControlTransition;
using spec::Register;
using spec::Trigger;

namespace {

// The normal reply to a write: FC 06 echoes it, FC 16 its first 5 bytes (MBAP v1.1b3 §6.6, §6.12).
Bytes echo_of(const Bytes& req) { return req.size() > 5 && req[0] == 0x10 ? Bytes(req.begin(), req.begin() + 5) : req; }

[[noreturn]] void fail(const std::string& message) {
  RC_FAIL(message);
  throw std::logic_error("unreachable");
}

const Control& control_of(const Session& s) { return *s.spec().control; }
const Control& control_of(const SpecView& v) { return *v.spec().control; }

// ---- the model: what the spec says the control's state may be ----------------

// The states the drive may be in (several where the spec leaves it open:
// a transition not stated, an automatic step with no stated time), the last
// word written to each command register (an edge needs it), and the values
// of the registers a transition's `when` reads.
struct Ctl {
  std::set<std::string> states;
  std::set<uint16_t> zeroed;  // the set-points written 0 (the frame policy's knowledge)
  std::map<std::string, std::optional<uint16_t>> last;
  std::map<std::string, std::optional<int64_t>> values;
  // Where each possible state came from (the transition ids), for messages.
  std::string why;
};

// One write the commands are made of: a command's word, or an edge
// command's word with its edge bits cleared (what makes the next edge).
struct Write {
  std::string key;
  uint16_t word = 0;
  std::string label;
};

std::vector<Write> command_writes(const Control& c) {
  std::vector<Write> out;
  auto add = [&](const std::string& key, uint16_t word, std::string label) {
    for (const auto& w : out)
      if (w.key == key && w.word == word) return;
    out.push_back({key, word, std::move(label)});
  };
  for (const auto& cmd : c.commands) {
    add(cmd.register_key, cmd.word(), cmd.id);
    if (cmd.trigger == Trigger::edge) add(cmd.register_key, uint16_t(cmd.word() & ~cmd.edge_mask), cmd.id + " released");
  }
  return out;
}

// Whether a command takes part in the state machine (a mode's start command
// does not: it changes no state).
bool has_transitions(const Control& c, const std::string& id) {
  return std::any_of(c.transitions.begin(), c.transitions.end(), [&](const ControlTransition& t) { return t.command == id; });
}

// true, false, or nullopt when a register it reads is not known.
std::optional<bool> holds(const Ctl& m, const std::vector<spec::ValueCondition>& when) {
  bool unknown = false;
  for (const auto& w : when) {
    auto it = m.values.find(w.register_key);
    if (it == m.values.end() || !it->second) {
      unknown = true;
      continue;
    }
    if (std::find(w.values.begin(), w.values.end(), *it->second) == w.values.end()) return false;
  }
  if (unknown) return std::nullopt;
  return true;
}

// The commands `word` gives on register `key`: level and write triggers by
// their bits, an edge when one of its bits rises (certain = false when the
// last word is not known).
std::vector<std::pair<const ControlCommand*, bool>> commands_given(const Control& c, const Ctl& m, const std::string& key,
                                                                   uint16_t word) {
  std::vector<std::pair<const ControlCommand*, bool>> out;
  std::optional<uint16_t> last;
  if (auto it = m.last.find(key); it != m.last.end()) last = it->second;
  for (const auto& cmd : c.commands) {
    if (cmd.register_key != key || !cmd.selected_by(word)) continue;
    if (cmd.trigger != Trigger::edge) {
      out.push_back({&cmd, true});
    } else if ((word & cmd.edge_mask) != 0) {
      if (!last) out.push_back({&cmd, false});
      else if ((~*last & word & cmd.edge_mask) != 0) out.push_back({&cmd, true});
    }
  }
  return out;
}

struct WriteOutcome {
  bool defined_somewhere = false;    // some possible state takes a transition
  bool undefined_somewhere = false;  // some possible state has none for it
};

// The model after `word` is written to `key` (before automatic steps).
WriteOutcome apply_write(const Control& c, Ctl& m, const std::string& key, uint16_t word) {
  WriteOutcome o;
  auto given = commands_given(c, m, key, word);
  std::set<std::string> next;
  std::vector<std::string> whys;
  for (const auto& s : m.states) {
    bool defined = false, may_stay = false;
    for (const auto& [cmd, certain] : given) {
      if (!has_transitions(c, cmd->id)) continue;
      for (const ControlTransition* t : c.transitions_on(s, cmd->id)) {
        auto h = holds(m, t->when);
        if (h == false) continue;
        defined = true;
        next.insert(t->to);
        whys.push_back(fmt::format("{} -{}-> {} (transition {}, {}{})", s, cmd->id, t->to, t->id, t->section,
                                   t->basis.basis == spec::Basis::stated ? "" : ", not stated: either"));
        if (!certain || !h || t->basis.basis != spec::Basis::stated) may_stay = true;
      }
    }
    if (!defined || may_stay) next.insert(s);
    if (!defined) whys.push_back(fmt::format("{}: {} not defined there: {} ({})", s, fmt::format("0x{:04X}", word),
                                             c.undefined.kind == spec::UndefinedCommand::Kind::ignored ? "ignored" : "refused",
                                             c.undefined.section));
    o.defined_somewhere |= defined;
    o.undefined_somewhere |= !defined || may_stay;
  }
  m.states = std::move(next);
  m.why = fmt::format("{}", fmt::join(whys, "; "));
  // The word is stored unless the drive refuses it.
  const bool refused = c.undefined.kind == spec::UndefinedCommand::Kind::exception;
  if (!refused || !o.undefined_somewhere) m.last[key] = word;
  else if (o.defined_somewhere) m.last[key] = std::nullopt;
  return o;
}

// An automatic step's stated time: its own, or (the axis stopped) the stop time of the commands that stop.
std::optional<double> step_ms(const Control& c, const ControlTransition& t) {
  if (t.within_ms) return t.within_ms;
  if (t.event == "motion_done") {
    std::optional<double> most;
    for (const auto& cmd : c.commands)
      if (cmd.stops && cmd.stop_within_ms) most = std::max(most.value_or(0), *cmd.stop_within_ms);
    return most;
  }
  return std::nullopt;
}

// How long after a command the status is read: every stated time, and a margin.
double settle_ms(const Control& c) {
  double most = 0;
  for (const auto& t : c.transitions)
    if (t.automatic())
      if (auto ms = step_ms(c, t)) most = std::max(most, *ms);
  for (const auto& cmd : c.commands)
    if (cmd.stop_within_ms) most = std::max(most, *cmd.stop_within_ms);
  return most + 20;
}

// The automatic steps the drive takes without a command while `ms` pass
// (the axis stands still: set-points 0): each whose time is stated and
// within `ms` is taken; one with no stated time, or not stated, may be.
void apply_automatic(const Control& c, Ctl& m, double ms) {
  for (int round = 0; round < 8; ++round) {
    std::set<std::string> next;
    for (const auto& s : m.states) {
      bool moved = false, may_stay = false;
      for (const auto& t : c.transitions) {
        if (!t.automatic() || (t.from != s && t.from != "*")) continue;
        if (t.event != "motion_done" && t.event != "time" && t.event != "reaction_done") continue;
        auto h = holds(m, t.when);
        if (h == false) continue;
        moved = true;
        next.insert(t.to);
        auto within = step_ms(c, t);
        if (!h || !within || *within > ms || t.basis.basis != spec::Basis::stated) may_stay = true;
      }
      if (!moved || may_stay) next.insert(s);
    }
    if (next == m.states) return;
    m.states = std::move(next);
  }
}

// A fault the drive detects (event "fault"): the transitions from every state.
void apply_fault(const Control& c, Ctl& m) {
  std::set<std::string> next;
  for (const auto& s : m.states) {
    bool moved = false;
    for (const auto& t : c.transitions)
      if (t.automatic() && t.event == "fault" && (t.from == s || t.from == "*")) {
        next.insert(t.to);
        moved = true;
        if (t.basis.basis != spec::Basis::stated) next.insert(s);
      }
    if (!moved) next.insert(s);
  }
  m.states = std::move(next);
  // The drive wrote what it detected (57HS-R: the alarm code a transition's
  // `when` reads): those registers are unknown now.
  for (auto& [key, value] : m.values) value = std::nullopt;
}

std::string states_text(const Control& c, const std::set<std::string>& states) {
  std::vector<std::string> names;
  for (const auto& id : states) {
    const ControlState* st = c.state(id);
    names.push_back(st && !st->name.en.empty() ? fmt::format("{} ({})", st->name.en, id) : id);
  }
  return names.size() == 1 ? names.front() : fmt::format("one of {}", fmt::join(names, ", "));
}

// ---- the target ---------------------------------------------------------------

const Register& reg(const Session& s, const std::string& key) {
  const Register* r = s.spec().find_by_key(key);
  if (!r) fail(fmt::format("the spec's control names register key '{}', which spec {} does not have", key, s.spec().device.id));
  return *r;
}

check::JudgeContext judge_context(Session& s) {
  check::JudgeContext ctx{s.unit(), s.target().info().framing, &s.spec(), {}};
  ctx.shared_line = s.target().info().live;
  return ctx;
}

// Time passes: on the virtual clock (recorded: a replay advances it too), else in real time.
void wait_ms(Session& s, double ms) {
  if (s.target().info().virtual_clock) s.advance(uint64_t(ms * 1000));
  else std::this_thread::sleep_for(std::chrono::microseconds(uint64_t(ms * 1000)));
}

// Sends a write of `raw` to `r` with expectation `e`; fails when the reply misses it.
Reply write_checked(Session& s, const Register& r, uint32_t raw, check::Expect e, const std::string& note) {
  Bytes req = s.view().write_request(r, raw);
  // A write the frame policy holds back says nothing of the drive: the case
  // is given up and the property, if too few ran, is skipped for want of
  // the opt-in the refusal names (never failed).
  if (Decision d = s.allowed(req); !d) {
    s.view().note_refusal(*d.refused);
    RC_DISCARD(fmt::format("{}: the frame policy holds it back: {}", note, d.refused->reason));
  }
  Reply rep = s.send(req, note);
  if (e.kind == check::Expect::Kind::none) e = {.kind = check::Expect::Kind::reply, .pdu = echo_of(req)};
  // Refused where the manual does not state that the write is taken (a
  // register whose write is inferred, FC 16 on a drive whose FC 16 is printed
  // two ways): a drive that does what its manual prints may refuse it, and the
  // case ends there.
  if (rep.pdu && rep.pdu->size() >= 2 && ((*rep.pdu)[0] & 0x80) && e.kind != check::Expect::Kind::exception) {
    const bool fc16_open = req[0] == 0x10 && s.spec().profile.function(0x10) &&
                           s.spec().profile.function(0x10)->basis_of("supported").basis != spec::Basis::stated;
    const bool write_open = r.basis_of(spec::Fact::write).basis != spec::Basis::stated;
    if (fc16_open || write_open) {
      RC_SUCCEED(fmt::format("{}: refused with exception {:02X}, and the manual does not state that {} is taken ({}): not held", note,
                             (*rep.pdu)[1], fc16_open ? "FC 16" : "the write of " + r.key,
                             fc16_open ? "its FC 16 support is not stated" : r.basis_of(spec::Fact::write).why));
      throw std::logic_error("unreachable");
    }
  }
  s.expect_last(e);
  if (auto miss = check::judge(s.steps().back().script(), rep, judge_context(s)))
    fail(fmt::format("{}: expected {}, got {}", note, check::expect_text(s.steps().back().expect), miss->why));
  return rep;
}

int64_t as_value(const Register& r, uint32_t raw) {
  if (r.is_signed()) return r.words == 1 ? int64_t(int16_t(raw)) : int64_t(int32_t(raw));
  return int64_t(raw);
}

// A read that failed. A register whose readability the manual does not state
// (Rieding's status area, erratum area-overlap) may refuse it on a drive that
// does what its manual prints: the case ends there, nothing more is held.
[[noreturn]] void unread(const Register& r, const std::string& key, const std::string& note, const std::string& error) {
  if (r.basis_of(spec::Fact::read).basis != spec::Basis::stated) {
    RC_SUCCEED(fmt::format("{}: reading {}: {}; the manual does not state that {} is readable ({}): not held", note, key, error,
                           key, r.basis_of(spec::Fact::read).why));
    throw std::logic_error("unreachable");
  }
  fail(fmt::format("{}: reading {}: {}", note, key, error));
}

int64_t read_value(Session& s, const std::string& key, const std::string& note) {
  const Register& r = reg(s, key);
  ReadResult rr = read_register(s.transact(), s.view(), r);
  if (!s.steps().empty()) s.expect_last({.kind = check::Expect::Kind::normal});
  if (!rr.raw) unread(r, key, note, rr.error);
  return as_value(r, *rr.raw);
}

// The status registers the states are named by, in spec order.
std::vector<std::string> status_keys(const Control& c) {
  std::vector<std::string> keys;
  for (const auto& st : c.states)
    for (const auto& m : st.status)
      if (std::find(keys.begin(), keys.end(), m.register_key) == keys.end()) keys.push_back(m.register_key);
  return keys;
}

// The state a reading names: every match holds.
bool names(const ControlState& st, const std::map<std::string, uint16_t>& words) {
  for (const auto& m : st.status) {
    auto it = words.find(m.register_key);
    if (it == words.end() || !m.matches(it->second)) return false;
  }
  return !st.status.empty();
}

// Reads the status and checks it names one of the model's states; the
// reads carry that expectation (one reading per possible state).
void check_status(Session& s, const Ctl& m, const std::string& after) {
  const Control& c = control_of(s);
  std::map<std::string, uint16_t> words;
  for (const auto& key : status_keys(c)) {
    const Register& r = reg(s, key);
    ReadResult rr = read_register(s.transact(), s.view(), r);
    std::vector<check::Expect> alts;
    for (const auto& id : m.states) {
      const ControlState* st = c.state(id);
      uint16_t mask = 0, value = 0;
      if (st)
        for (const auto& x : st->status)
          if (x.register_key == key) {
            mask |= x.mask;
            value |= x.value;
          }
      check::Expect e = mask ? check::Expect{.kind = check::Expect::Kind::registers, .words = {value}, .masks = {mask}}
                             : check::Expect{.kind = check::Expect::Kind::normal};
      e.reading = id;
      alts.push_back(std::move(e));
    }
    if (!alts.empty()) {
      check::Expect e = alts.front();
      e.either.assign(alts.begin() + 1, alts.end());
      s.expect_last(e);
    }
    if (!rr.raw) unread(r, key, "after " + after, rr.error);
    words[key] = uint16_t(*rr.raw);
  }
  for (const auto& id : m.states)
    if (const ControlState* st = c.state(id); st && names(*st, words)) return;
  std::vector<std::string> named;
  for (const auto& st : c.states)
    if (names(st, words)) named.push_back(st.name.en.empty() ? st.id : st.name.en);
  std::string read;
  for (const auto& [k, w] : words) read += fmt::format("{}{} 0x{:04X}", read.empty() ? "" : ", ", k, w);
  fail(fmt::format("after {}: {} reads {}, which names {}; the spec's state is {}{}", after, "the status", read,
                   named.empty() ? "no state" : fmt::format("{}", fmt::join(named, ", ")), states_text(c, m.states),
                   m.why.empty() ? "" : " (" + m.why + ")"));
}

// The expectation of a command write's reply: echoed, or (undefined and
// the spec says refused) the exception; either when both may hold.
check::Expect write_expect(const Control& c, const Bytes& req, const WriteOutcome& o) {
  check::Expect echo{.kind = check::Expect::Kind::reply, .pdu = echo_of(req)};
  if (c.undefined.kind != spec::UndefinedCommand::Kind::exception || !o.undefined_somewhere) return echo;
  check::Expect ex{.kind = check::Expect::Kind::exception, .code = uint8_t(c.undefined.code)};
  if (!o.defined_somewhere) return ex;
  echo.either.push_back(ex);
  return echo;
}

// Writes one command word and checks the reply and then the status against the model (updated).
void give(Session& s, Ctl& m, const Write& w) {
  const Control& c = control_of(s);
  const Register& r = reg(s, w.key);
  Bytes req = s.view().write_request(r, w.word);
  WriteOutcome o = apply_write(c, m, w.key, w.word);
  const std::string note = fmt::format("{} = 0x{:04X} ({})", w.key, w.word, w.label);
  write_checked(s, r, w.word, write_expect(c, req, o), note);
  const double ms = settle_ms(c);
  apply_automatic(c, m, ms);
  wait_ms(s, ms);
  check_status(s, m, note);
}

// The set-points of every mode written 0: enabling then moves nothing.
void zero_setpoints(Session& s) {
  const Control& c = control_of(s);
  std::set<std::string> done;
  for (const auto& mode : c.modes)
    for (const auto& key : mode.setpoint_keys) {
      if (!done.insert(key).second) continue;
      const Register& r = reg(s, key);
      write_checked(s, r, 0, {}, fmt::format("{} = 0 (set-point of mode {}, before any enable)", key, mode.id));
    }
}

// The model at the start: the command registers' last words and the
// condition registers read, the status read. On a target that starts at
// power-on (ref:) the state is the spec's initial one.
Ctl initial(Session& s, bool setpoints_zero = true) {
  const Control& c = control_of(s);
  Ctl m;
  if (setpoints_zero) zero_setpoints(s);
  m.zeroed = s.zeroed();
  // The last word of each command register; one the spec makes write-only
  // (access wo) cannot be read: unknown (only an edge needs it).
  for (const auto& cmd : c.commands) {
    if (m.last.count(cmd.register_key)) continue;
    if (reg(s, cmd.register_key).access == spec::Access::wo) m.last[cmd.register_key] = std::nullopt;
    else m.last[cmd.register_key] = uint16_t(read_value(s, cmd.register_key, "the initial model"));
  }
  for (const auto& t : c.transitions)
    for (const auto& w : t.when)
      if (!m.values.count(w.register_key)) m.values[w.register_key] = read_value(s, w.register_key, "the initial model");
  if (!s.target().info().live) {
    m.states = {c.initial};
    m.why = fmt::format("the state after power-on ({})", c.section);
    apply_automatic(c, m, settle_ms(c));
    wait_ms(s, settle_ms(c));
    check_status(s, m, "power-on");
    return m;
  }
  // A live drive: in whatever state it is; the status says which.
  for (const auto& st : c.states) m.states.insert(st.id);
  check_status(s, m, "the start");
  std::map<std::string, uint16_t> words;
  for (const auto& key : status_keys(c)) words[key] = uint16_t(read_value(s, key, "the start"));
  std::set<std::string> now;
  for (const auto& st : c.states)
    if (names(st, words)) now.insert(st.id);
  m.states = now;
  m.why = "as read at the start";
  return m;
}

// ---- paths between states -----------------------------------------------------

struct Node {
  Ctl m;
  std::vector<Write> path;
};

bool may_send(const SpecView& v, const Ctl& m, const Write& w) {
  const Register* r = v.spec().find_by_key(w.key);
  if (!r) return false;
  PolicyFacts f = v.policy_facts();
  f.zeroed = m.zeroed;
  Decision d = allowed(f, f.target.unit, v.write_request(*r, w.word));
  if (!d) v.note_refusal(*d.refused);  // a case given up for it is skipped for want of its opt-in
  return bool(d);
}

// Every state reachable from `start` by command writes the policy lets go
// out, each with a shortest path; only where the spec's outcome is one state.
std::map<std::string, Node> reachable(const Session& s, const Ctl& start) {
  const Control& c = control_of(s);
  std::map<std::string, Node> seen;
  auto key_of = [](const Ctl& m) {
    std::string k = *m.states.begin();
    for (const auto& [reg, w] : m.last) k += fmt::format("|{}", w ? int(*w) : -1);
    return k;
  };
  std::map<std::string, bool> visited;
  std::deque<Node> queue;
  if (start.states.size() != 1) return seen;
  queue.push_back({start, {}});
  visited[key_of(start)] = true;
  const auto writes = command_writes(c);
  while (!queue.empty() && visited.size() < 400) {
    Node n = std::move(queue.front());
    queue.pop_front();
    seen.emplace(*n.m.states.begin(), n);
    for (const auto& w : writes) {
      if (!may_send(s.view(), n.m, w)) continue;
      Node next = n;
      apply_write(c, next.m, w.key, w.word);
      apply_automatic(c, next.m, settle_ms(c));
      if (next.m.states.size() != 1) continue;
      next.path.push_back(w);
      if (visited.emplace(key_of(next.m), true).second) queue.push_back(std::move(next));
    }
  }
  return seen;
}

// Takes the target along a path, checking every step.
void walk(Session& s, Ctl& m, const std::vector<Write>& path) {
  for (const auto& w : path) give(s, m, w);
}

// ---- faults caused out of band ------------------------------------------------

// Whether a fault can be caused on this target: through the bus the spec
// states none; a reference target trips one out of band.
// (Target::trip_fault: a ref: target takes the model's `fault` step; the
// properties' oracle is still the spec's transitions on event `fault`.)
bool ref_can_trip(const TargetInfo& t) { return t.kind == TargetKind::ref && !t.live; }
bool can_trip(Session& s) { return ref_can_trip(s.target().info()); }
constexpr const char* kTripNote = "trip: a fault caused out of band (Target::trip_fault)";
void trip(Session& s) {
  if (!s.target().trip_fault()) fail("the target could not be made to detect a fault (Target::trip_fault)");
  // Kept in the counterexample: `props --replay` trips the fault again here.
  s.advance(0, kTripNote);
}

bool has_fault_path(const Control& c) {
  return std::any_of(c.transitions.begin(), c.transitions.end(), [](const ControlTransition& t) { return t.automatic() && t.event == "fault"; });
}

// ---- rc::state: one command per control command ---------------------------

struct Sut {
  Session& session;
};

// The commands hold the view (one for every run while RapidCheck shrinks), never a run's session.
struct WriteCmd final : rc::state::Command<Ctl, Sut> {
  Write w;
  const SpecView* s;
  WriteCmd(const SpecView& view, const std::vector<Write>& writes) : s(&view) { w = pick_of(writes); }
  void checkPreconditions(const Ctl& m) const override { RC_PRE(may_send(*s, m, w)); }
  void apply(Ctl& m) const override {
    const Control& c = control_of(*s);
    apply_write(c, m, w.key, w.word);
    apply_automatic(c, m, settle_ms(c));
  }
  void run(const Ctl& m, Sut& sut) const override {
    Ctl copy = m;
    give(sut.session, copy, w);
  }
  void show(std::ostream& os) const override { os << fmt::format("{} = 0x{:04X} ({})", w.key, w.word, w.label); }
};

struct TripCmd final : rc::state::Command<Ctl, Sut> {
  const SpecView* s;
  explicit TripCmd(const SpecView& view) : s(&view) {}
  void apply(Ctl& m) const override {
    const Control& c = control_of(*s);
    apply_fault(c, m);
    m.why = "a fault detected (caused out of band)";
    apply_automatic(c, m, settle_ms(c));
  }
  void run(const Ctl& m, Sut& sut) const override {
    trip(sut.session);
    const Control& c = control_of(*s);
    Ctl next = m;
    apply(next);
    wait_ms(sut.session, settle_ms(c));
    check_status(sut.session, next, "a fault");
  }
  void show(std::ostream& os) const override { os << "fault (out of band)"; }
};

void status_names_state(Session& s) {
  const Control& c = control_of(s);
  Ctl m0 = initial(s);
  const auto writes = command_writes(c);
  const bool trips = can_trip(s) && has_fault_path(c);
  using Cmd = std::shared_ptr<const rc::state::Command<Ctl, Sut>>;
  const SpecView* view = &s.view();
  auto gen = [view, writes, trips](const Ctl&) {
    return rc::gen::exec([view, writes, trips]() -> Cmd {
      if (trips && pick<int>(0, 10) == 0) return std::make_shared<TripCmd>(*view);
      return std::make_shared<WriteCmd>(*view, writes);
    });
  };
  auto cmds = *rc::state::gen::commands(m0, gen);
  Sut sut{s};
  rc::state::runAll(cmds, m0, sut);
}

// ---- the targeted properties --------------------------------------------------

// A state reached in one determined way, drawn among those reachable.
std::pair<std::string, Node> pick_reachable(Session& s, const Ctl& m0, const std::function<bool(const ControlState&)>& which) {
  const Control& c = control_of(s);
  auto all = reachable(s, m0);
  std::vector<std::pair<std::string, Node>> fit;
  for (auto& [id, n] : all)
    if (const ControlState* st = c.state(id); st && which(*st)) fit.emplace_back(id, n);
  if (fit.empty()) return {};
  return fit[pick<size_t>(0, fit.size())];
}

void undefined_command(Session& s) {
  const Control& c = control_of(s);
  Ctl m = initial(s);
  auto [id, node] = pick_reachable(s, m, [](const ControlState&) { return true; });
  if (id.empty()) fail("no state is reachable from the start by the spec's commands");
  walk(s, m, node.path);
  // The commands the spec does not define in this state.
  std::vector<Write> undefined;
  for (const auto& w : command_writes(c)) {
    if (!may_send(s.view(), m, w)) continue;
    auto given = commands_given(c, m, w.key, w.word);
    bool any = false, defined = false;
    for (const auto& [cmd, certain] : given) {
      if (!has_transitions(c, cmd->id)) continue;
      any = true;
      defined |= !c.transitions_on(id, cmd->id).empty();
    }
    if (any && !defined) undefined.push_back(w);
  }
  RC_PRE(!undefined.empty());
  Write w = pick_of(undefined);
  w.label += fmt::format(", not defined in {}", id);
  give(s, m, w);
}

// The mode the stop property runs, and whether its actual is a speed (it
// reads 0 at standstill) or a position (it reads the same twice).
struct Axis {
  const spec::ControlMode* mode = nullptr;
  bool speed = false;
};

// A speed mode first (it runs until stopped), else the position mode: one
// with a set-point and an actual, selected by its `select` write or started
// by its start command. A speed mode's actual that a position or homing mode
// also reads is a position (HSC60: the pulse count).
Axis moving_mode(const Control& c) {
  auto usable = [](const spec::ControlMode& m) {
    return !m.setpoint_keys.empty() && !m.actual_key.empty() && (m.select || !m.start_command.empty());
  };
  auto counts_position = [&](const std::string& key) {
    return std::any_of(c.modes.begin(), c.modes.end(), [&](const spec::ControlMode& m) {
      return (m.id == "position" || m.id == "homing") && m.actual_key == key;
    });
  };
  Axis a;
  for (const auto& mode : c.modes) {
    if (!usable(mode)) continue;
    if (mode.id == "speed") return {&mode, !counts_position(mode.actual_key)};
    if (!a.mode && mode.id == "position") a = {&mode, false};
  }
  return a;
}

void stop_from_motion(Session& s) {
  const Control& c = control_of(s);
  std::vector<const ControlCommand*> stops;
  for (const auto& cmd : c.commands)
    if (cmd.stops) stops.push_back(&cmd);
  Ctl m = initial(s);
  Axis axis = moving_mode(c);
  // A start command with transitions starts from where it has one (57HS-R:
  // standstill), one with none (Rieding) from any moving state.
  const ControlCommand* start = axis.mode ? c.command(axis.mode->start_command) : nullptr;
  const bool start_has_transitions = start && has_transitions(c, start->id);
  auto [id, node] = pick_reachable(s, m, [&](const ControlState& st) {
    return st.motion && !st.fault && (!start_has_transitions || !c.transitions_on(st.id, start->id).empty());
  });
  if (id.empty()) fail("no moving state is reachable from the start by the spec's commands");
  const ControlCommand& stop = *pick_of(stops);
  int64_t setpoint = 0;
  if (axis.mode) {
    // The mode that moves the axis, a set-point that moves it, then the state.
    if (const auto& sel = axis.mode->select)
      write_checked(s, reg(s, sel->key), uint32_t(sel->value), {},
                    fmt::format("{} = {} (select mode {}, {})", sel->key, sel->value, axis.mode->id, sel->section));
    const Register& sp = reg(s, axis.mode->setpoint_keys.front());
    double top = c.top_speed.value_or(1000);
    if (sp.range) top = std::min(top, sp.range->max);
    setpoint = std::max<int64_t>(1, int64_t(top * pick<int>(1, 11) / 10));
    write_checked(s, sp, uint32_t(setpoint), {}, fmt::format("{} = {} (set-point)", sp.key, setpoint));
    m.zeroed = s.zeroed();
  }
  walk(s, m, node.path);
  if (start) {
    const std::string key = start->register_key;
    // Its bits over the last word's others (CiA 402 bit 4 in the controlword);
    // a command of any write (mask 0) its own word.
    const uint16_t word =
        start->mask ? uint16_t((m.last[key].value_or(0) & ~start->mask) | (start->word() & start->mask)) : start->word();
    const Register& r = reg(s, key);
    WriteOutcome o = apply_write(c, m, key, word);
    write_checked(s, r, word, write_expect(c, echo_of(s.view().write_request(r, word)), o),
                  fmt::format("{} = 0x{:04X} (start: {}, {})", key, word, start->id, start->section));
  }
  const std::string actual = axis.mode ? axis.mode->actual_key : "";
  auto sample = [&](const std::string& why) { return actual.empty() ? 0 : read_value(s, actual, why); };
  // A speed within 1 % of the set-point is standstill (a real drive's
  // actual velocity jitters around 0; the reference reads 0).
  const int64_t still_speed = std::abs(setpoint) / 100;
  auto standing = [&](int64_t speed) { return std::abs(speed) <= still_speed; };
  // On a live target the time is the wall clock's: the sampling below judges
  // against when each read was sent, never against the summed waits.
  const bool live = !s.target().info().virtual_clock;
  int64_t before = 0, before2 = 0;
  bool moves = actual.empty();
  // 200 ms to get going (up to 2 s on a live drive, whose ramp is its own).
  for (double waited = 0; !moves && waited < (live ? 2000 : 200);) {
    const double step = waited == 0 ? 200 : 100;
    wait_ms(s, step);
    waited += step;
    before = before2 = sample("moving");
    if (!axis.speed) {
      wait_ms(s, 20);
      before2 = sample("moving");
    }
    moves = axis.speed ? !standing(before) : before2 != before;
  }
  if (!moves) {
    const std::string what = fmt::format("in {} with {} = {}, the axis does not move ({} reads {})", id,
                                         axis.mode->setpoint_keys.front(), setpoint, actual, before2);
    // A set-point in % of another parameter (Rieding 0802H: of PN-103, with
    // no printed default) moves the axis only as far as that one is set.
    if (reg(s, axis.mode->setpoint_keys.front()).unit.find('%') != std::string::npos)
      RC_DISCARD(what + ": its speed is a % of a parameter, nothing to stop");
    fail(what);
  }
  const Register& r = reg(s, stop.register_key);
  const std::string stop_note = fmt::format("{} = 0x{:04X} ({}, stops: {})", stop.register_key, stop.word(), stop.id, stop.section);
  WriteOutcome stop_outcome = apply_write(c, m, stop.register_key, stop.word());
  write_checked(s, r, stop.word(), write_expect(c, echo_of(s.view().write_request(r, stop.word())), stop_outcome), stop_note);
  // Sampled until it stands: a speed reads (about) 0, a position the same
  // over kStill samples (a slow deceleration moves less than a pulse per
  // sample). The drive had the stop when its reply came (t = 0); it still
  // moved at `moving_at` at least: a speed read away from 0 then, or a
  // position that changed after the read before was sent.
  constexpr double kSampleMs = 10;
  constexpr int kStill = 5;
  const auto t0 = std::chrono::steady_clock::now();
  double t = 0;  // ms since the stop's reply
  auto clock = [&] {
    return live ? std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count() : t;
  };
  const double limit = stop.stop_within_ms.value_or(10'000);
  const double bound = limit + kStill * kSampleMs + (live ? 500 : 10);
  // A speed that holds one value away from 0 this long after the stop was
  // never slowed (any deceleration from the set-point changes it sooner).
  constexpr double kSteadyMs = 2000;
  int64_t prev = before2, now = before2;
  double prev_sent = 0, moving_at = 0, steady_since = 0;
  int still = 0;
  bool stopped = false, steady = false;
  while (clock() < bound) {
    wait_ms(s, kSampleMs);
    t += kSampleMs;
    const double sent = clock();
    now = sample(fmt::format("{:.0f} ms after {}", sent, stop.id));
    if (axis.speed ? !standing(now) : now != prev) moving_at = axis.speed ? sent : prev_sent;
    still = now == prev ? still + 1 : 0;
    if (still == 0) steady_since = sent;
    stopped = axis.speed ? standing(now) : still >= kStill;
    steady = axis.speed && !stopped && sent - steady_since >= kSteadyMs;
    if (stopped || steady) break;
    prev = now;
    prev_sent = sent;
  }
  if (stop.stop_within_ms && moving_at > *stop.stop_within_ms)
    fail(fmt::format("{} ({}) from {} at {} = {}: {} still {} {:.0f} ms after the stop was answered (read {}; stated: "
                     "stopped within {} ms)",
                     stop.id, stop.section, id, axis.mode ? axis.mode->setpoint_keys.front() : "", setpoint, actual,
                     axis.speed ? "ran" : "moved", moving_at, now, *stop.stop_within_ms));
  // With no stated time how long it takes is observed, but not never.
  if (steady)
    fail(fmt::format("{} ({}) from {} at {} = {}: {} has read {} since {:.0f} ms after the stop was answered, steady for "
                     "{:.0f} ms: the stop was not acted on",
                     stop.id, stop.section, id, axis.mode->setpoint_keys.front(), setpoint, actual, now, steady_since,
                     kSteadyMs));
  // A speed within the tolerance may still be ramping its last steps: up to
  // 500 ms more for it to read 0 (a drive that jitters around 0 never does).
  for (double settle = 0; stopped && axis.speed && now != 0 && settle < 500; settle += kSampleMs) {
    wait_ms(s, kSampleMs);
    t += kSampleMs;
    now = sample("settling");
  }
  // The state the spec's transitions give the stop (Quick stop active, then Switch on disabled).
  const double stood = clock();
  apply_automatic(c, m, stood);
  check_status(s, m, stop_note);
  // It stays stopped.
  wait_ms(s, 100);
  int64_t later = sample("stopped");
  if (stopped && (axis.speed ? !standing(later) : later != now))
    fail(fmt::format("{} from {}: the axis stood at {:.0f} ms, then {} reads {} (it moves again)", stop.id, id, stood,
                     actual, later));
}

void fault_reset(Session& s) {
  const Control& c = control_of(s);
  Ctl m = initial(s);
  auto [id, node] = pick_reachable(s, m, [](const ControlState& st) { return !st.fault; });
  if (id.empty()) fail("no state is reachable from the start by the spec's commands");
  walk(s, m, node.path);
  const ControlCommand* reset = nullptr;
  for (const auto& t : c.transitions)
    if (!t.automatic() && c.state(t.from) && c.state(t.from)->fault) reset = c.command(t.command);
  // The reset's word held before the fault: a level would act on it later.
  const bool held_before = reset && reset->trigger == Trigger::edge && pick_bool();
  if (held_before) give(s, m, {reset->register_key, reset->word(), reset->id + " (before the fault: no fault to reset)"});
  trip(s);
  apply_fault(c, m);
  m.why = "a fault detected (caused out of band)";
  apply_automatic(c, m, settle_ms(c));
  wait_ms(s, settle_ms(c));
  check_status(s, m, fmt::format("a fault in {}", id));
  if (!reset) return;
  if (reset->trigger == Trigger::edge) {
    // The word held, written again: no edge, no reset.
    if (!held_before) give(s, m, {reset->register_key, reset->word(), reset->id + " (the first: an edge)"});
    else give(s, m, {reset->register_key, reset->word(), reset->id + " (held: no edge)"});
    give(s, m, {reset->register_key, reset->word(), reset->id + " (held: no edge)"});
    give(s, m, {reset->register_key, uint16_t(reset->word() & ~reset->edge_mask), reset->id + " released"});
  }
  give(s, m, {reset->register_key, reset->word(), reset->id});
}

void mode_switch(Session& s) {
  const Control& c = control_of(s);
  std::vector<const spec::ControlMode*> modes;
  for (const auto& mode : c.modes)
    if (mode.select) modes.push_back(&mode);
  Ctl m = initial(s);
  auto [id, node] = pick_reachable(s, m, [](const ControlState&) { return true; });
  if (id.empty()) fail("no state is reachable from the start by the spec's commands");
  walk(s, m, node.path);
  const spec::ControlMode& mode = *pick_of(modes);
  const auto& sel = *mode.select;
  const bool accepted = mode.select_in.empty() || std::find(mode.select_in.begin(), mode.select_in.end(), id) != mode.select_in.end();
  std::optional<int64_t> shown_before;
  if (!mode.display_key.empty()) shown_before = read_value(s, mode.display_key, "the mode shown before");
  const Register& r = reg(s, sel.key);
  Bytes req = s.view().write_request(r, uint32_t(sel.value));
  check::Expect e{.kind = check::Expect::Kind::reply, .pdu = echo_of(req)};
  if (!accepted) {
    // Not accepted there: refused, or taken and not shown (the spec does not say which).
    e = {.kind = check::Expect::Kind::any};
  }
  const std::string note = fmt::format("{} = {} (select mode {} in {}, {})", sel.key, sel.value, mode.id, id, mode.section);
  Reply rep = write_checked(s, r, uint32_t(sel.value), e, note);
  wait_ms(s, settle_ms(c));
  if (!mode.display_key.empty()) {
    int64_t shown = read_value(s, mode.display_key, note);
    const bool echoed = rep.pdu && !rep.pdu->empty() && !((*rep.pdu)[0] & 0x80);
    if (accepted && shown != sel.value)
      fail(fmt::format("{}: accepted there (select_in), and {} shows {}, not {}", note, mode.display_key, shown, sel.value));
    if (!accepted && shown == sel.value && shown_before != sel.value)
      fail(fmt::format("{}: the spec allows it only in {}, and {} shows the mode selected ({}{})", note,
                       fmt::join(mode.select_in, ", "), mode.display_key, shown, echoed ? ", the write echoed" : ""));
  }
  // Selecting a mode changes no control state.
  check_status(s, m, note);
}

// With every set-point written 0, nothing moves (spec/README.md "Control" 5.:
// the set-points are the registers whose 0 moves nothing; Rieding 五: 电机的实际
// 转速=额定转速*0.01*写入的数值, 电机转动的圈数=写入参数的值*0.1). The frame
// policy rests on it: a command that may move goes out to a live drive without
// --allow-motion only once every set-point was written 0. Here every command
// the policy then lets out (never a mode's start) is given, in a random order,
// and the actual of every mode the spec states reads as it did at rest.
// The actual of a mode that is not stated (inferred, either) is not held.
std::vector<const spec::ControlMode*> still_modes(const Control& c) {
  std::vector<const spec::ControlMode*> out;
  for (const auto& mode : c.modes)
    if (!mode.actual_key.empty() && !mode.setpoint_keys.empty() && mode.basis.basis == spec::Basis::stated) out.push_back(&mode);
  return out;
}

void zero_setpoints_still(Session& s) {
  const Control& c = control_of(s);
  Ctl m = initial(s);  // every set-point written 0 first
  std::map<std::string, int64_t> at_rest;
  for (const auto* mode : still_modes(c))
    if (!at_rest.count(mode->actual_key)) at_rest[mode->actual_key] = read_value(s, mode->actual_key, "at rest, set-points 0");
  PolicyFacts f = s.view().policy_facts();
  f.zeroed = m.zeroed;
  std::vector<Write> motion_free;
  for (const auto& w : command_writes(c))
    if (const Register* r = s.spec().find_by_key(w.key); r && control_motion(f, s.view().write_request(*r, w.word)).empty())
      motion_free.push_back(w);
  RC_PRE(!motion_free.empty());
  // A mode selected first, where its selection is itself motion-free (not a
  // start: Rieding's speed mode is selected by its run command).
  std::vector<const spec::ControlMode*> selectable;
  for (const auto* mode : still_modes(c))
    if (mode->select && (mode->select_in.empty() || (m.states.size() == 1 && std::find(mode->select_in.begin(), mode->select_in.end(),
                                                                                           *m.states.begin()) != mode->select_in.end())))
      if (const Register* r = s.spec().find_by_key(mode->select->key);
          r && control_motion(f, s.view().write_request(*r, uint32_t(mode->select->value))).empty())
        selectable.push_back(mode);
  if (!selectable.empty() && pick_bool()) {
    const spec::ControlMode* mode = pick_of(selectable);
    const auto& sel = *mode->select;
    if (std::none_of(c.commands.begin(), c.commands.end(), [&](const ControlCommand& x) { return x.register_key == sel.key; })) {
      write_checked(s, reg(s, sel.key), uint32_t(sel.value), {}, fmt::format("{} = {} (select mode {}, {})", sel.key, sel.value, mode->id, sel.section));
    } else {
      give(s, m, {sel.key, uint16_t(sel.value), "select mode " + mode->id});
    }
  }
  const int n = pick<int>(1, 7);
  for (int i = 0; i < n; ++i) {
    Write w = pick_of(motion_free);
    give(s, m, w);
    wait_ms(s, 300);
    for (const auto& [key, was] : at_rest)
      if (int64_t now = read_value(s, key, "set-points 0"); now != was)
        fail(fmt::format("with every set-point 0, {} = 0x{:04X} ({}) moved the axis: {} read {} at rest, {} now", w.key, w.word,
                         w.label, key, was, now));
  }
}

std::function<std::string(const SpecView&, const TargetInfo&, const DeviceFacts*)> needs_control(
    std::function<std::string(const Control&, const SpecView&, const TargetInfo&)> more = {}) {
  return [more](const SpecView& v, const TargetInfo& t, const DeviceFacts*) -> std::string {
    if (!v.spec().control) return "the spec has no control: section (spec/README.md \"Control\")";
    const Control& c = *v.spec().control;
    if (c.states.empty() || c.commands.empty()) return "the spec's control has no states or no commands";
    for (const auto& key : status_keys(c))
      if (!v.spec().find_by_key(key)) return fmt::format("the control's status register '{}' is not in the spec", key);
    return more ? more(c, v, t) : "";
  };
}

}  // namespace

std::vector<Invariant> control_invariants() {
  return {
      {"control-status-names-state", "spec control: states[].status, transitions, automatic steps and their times",
       "After every command the status reading names the state the spec's transitions (and automatic steps within "
       "their stated times) lead to; a transition not stated, or a step with no stated time, accepts either state.",
       needs_control(), status_names_state},
      {"control-undefined-command", "spec control.undefined",
       "A command the spec does not define in a state leaves the drive as control.undefined says (ignored: the state "
       "unchanged; exception: refused, the state unchanged).",
       needs_control(), undefined_command},
      {"control-stop-from-motion", "spec control: commands[].stops, stop_within_ms; modes (set-point, actual)",
       "A command that stops (quick stop, emergency stop) stops the axis from every moving state within the stated "
       "time; with no stated time the time is observed, not held.",
       needs_control([](const Control& c, const SpecView& v, const TargetInfo& t) -> std::string {
         if (std::none_of(c.commands.begin(), c.commands.end(), [](const ControlCommand& x) { return x.stops; }))
           return "the spec's control names no command that stops (stops: true)";
         if (std::none_of(c.states.begin(), c.states.end(), [](const ControlState& x) { return x.motion; }))
           return "the spec's control has no moving state (motion: true)";
         // A position move whose distance is its start command's own word (Rieding 0804H), not a set-point the
         // property chooses: how long it runs is not known, so the stop cannot be timed against it.
         if (Axis a = moving_mode(c); a.mode && !a.speed)
           if (const ControlCommand* start = c.command(a.mode->start_command);
               start && std::find(a.mode->setpoint_keys.begin(), a.mode->setpoint_keys.end(), start->register_key) ==
                            a.mode->setpoint_keys.end() &&
               std::any_of(c.commands.begin(), c.commands.end(), [&](const ControlCommand& x) { return x.id == start->id && x.write; }))
             return fmt::format("the moving mode {} starts with {}, a fixed word to {} that is no set-point: the move's length "
                                "is the command's, not one the property can choose long enough to stop",
                                a.mode->id, start->id, start->register_key);
         if (t.live && !v.policy_facts().opt_ins.allow_motion) return "moves the axis: needs --allow-motion";
         return "";
       }),
       stop_from_motion},
      {"control-fault-reset", "spec control: transitions on event fault, reaction_done, and the fault reset",
       "A fault takes the drive to the fault state (through its fault reaction); the reset acts as its trigger says "
       "(an edge: not on a word held) and leaves the fault state.",
       needs_control([](const Control& c, const SpecView&, const TargetInfo& t) -> std::string {
         if (!has_fault_path(c)) return "the spec's control has no transition on a fault";
         if (!ref_can_trip(t)) return "the spec states no way to cause a fault through the bus, and the target cannot trip one out of band";
         return "";
       }),
       fault_reset},
      {"control-zero-setpoints-still", "spec control.modes: setpoints (their 0 moves nothing), actual; Rieding 五",
       "With every set-point of the modes written 0, no command the frame policy then lets out as motion-free (any "
       "but a mode's start) moves the axis: the actual of every stated mode reads as it did at rest.",
       needs_control([](const Control& c, const SpecView&, const TargetInfo& t) -> std::string {
         if (still_modes(c).empty()) return "the spec's control states no mode with set-points and an actual";
         if (t.live) return "live target: the actuals are not sampled in real time yet";
         return "";
       }),
       zero_setpoints_still},
      {"control-mode-switch", "spec control.modes: select, display, select_in",
       "Selecting a mode is accepted (and shown) where select_in allows it, not elsewhere, and changes no control state.",
       needs_control([](const Control& c, const SpecView&, const TargetInfo&) -> std::string {
         if (std::none_of(c.modes.begin(), c.modes.end(), [](const spec::ControlMode& x) { return x.select.has_value(); }))
           return "the spec's control has no mode to select";
         return "";
       }),
       mode_switch},
  };
}

std::string control_walk(Session& s, std::vector<std::string>& skipped) {
  if (!s.spec().control) return "the spec has no control: section";
  const Control& c = control_of(s);
  std::string failed;
  // A step that fails ends the walk with its message (RC_FAIL throws outside RapidCheck too).
  try {
    Ctl m = initial(s);  // the set-points 0 first
    // Mode starts move the axis with any set-point: never in a walk.
    std::set<std::string> starts;
    for (const auto& mode : c.modes)
      if (!mode.start_command.empty()) starts.insert(mode.start_command);
    auto fits = [&](const Write& w) {
      for (const auto& id : starts)
        if (const ControlCommand* cmd = c.command(id); cmd && cmd->register_key == w.key && cmd->selected_by(w.word) &&
                                                        (cmd->trigger != Trigger::edge || (w.word & cmd->edge_mask)))
          return false;
      return may_send(s.view(), m, w);
    };
    // In a fault: the reset first (an edge: released, then given).
    if (m.states.size() == 1 && c.state(*m.states.begin()) && c.state(*m.states.begin())->fault)
      for (const auto& t : c.transitions)
        if (!t.automatic() && t.from == *m.states.begin())
          if (const ControlCommand* reset = c.command(t.command)) {
            if (reset->trigger == Trigger::edge) give(s, m, {reset->register_key, uint16_t(reset->word() & ~reset->edge_mask), reset->id + " released"});
            give(s, m, {reset->register_key, reset->word(), reset->id});
            break;
          }
    // Every state reachable without motion, each by a shortest path from where the walk is.
    std::vector<std::string> visit;
    for (const auto& st : c.states)
      if (!st.fault) visit.push_back(st.id);
    auto path_to = [&](const std::string& id) -> std::optional<std::vector<Write>> {
      if (m.states.size() != 1) return std::nullopt;
      // reachable() with the walk's own filter.
      std::map<std::string, bool> visited;
      std::deque<Node> queue{{m, {}}};
      const auto writes = command_writes(c);
      while (!queue.empty() && visited.size() < 400) {
        Node n = std::move(queue.front());
        queue.pop_front();
        if (*n.m.states.begin() == id) return n.path;
        for (const auto& w : writes) {
          if (!fits(w)) continue;
          Node next = n;
          apply_write(c, next.m, w.key, w.word);
          apply_automatic(c, next.m, settle_ms(c));
          if (next.m.states.size() != 1) continue;
          next.path.push_back(w);
          std::string k = *next.m.states.begin();
          for (const auto& [reg, word] : next.m.last) k += fmt::format("|{}", word ? int(*word) : -1);
          if (visited.emplace(k, true).second) queue.push_back(std::move(next));
        }
      }
      return std::nullopt;
    };
    for (const auto& id : visit) {
      auto path = path_to(id);
      if (!path) {
        skipped.push_back(fmt::format("{}: not reachable without motion or an opt-in of the frame policy", id));
        continue;
      }
      walk(s, m, *path);
      // Every mode selected where the spec accepts it.
      for (const auto& mode : c.modes) {
        if (!mode.select) continue;
        if (!mode.select_in.empty() && std::find(mode.select_in.begin(), mode.select_in.end(), id) == mode.select_in.end()) continue;
        const Register& r = reg(s, mode.select->key);
        if (!s.allowed(s.view().write_request(r, uint32_t(mode.select->value)))) {
          skipped.push_back(fmt::format("select mode {} in {}: the frame policy refuses it", mode.id, id));
          continue;
        }
        write_checked(s, r, uint32_t(mode.select->value), {}, fmt::format("{} = {} (select mode {} in {})", mode.select->key, mode.select->value, mode.id, id));
        wait_ms(s, settle_ms(c));
        if (!mode.display_key.empty())
          if (int64_t shown = read_value(s, mode.display_key, "mode shown"); shown != mode.select->value)
            return fmt::format("select mode {} in {}: {} shows {}, not {}", mode.id, id, mode.display_key, shown, mode.select->value);
        check_status(s, m, fmt::format("select mode {}", mode.id));
      }
    }
    // Back to the safe state.
    if (auto path = path_to(c.safe)) walk(s, m, *path);
    else skipped.push_back(fmt::format("the safe state {}: not reachable without an opt-in", c.safe));
  } catch (const rc::detail::CaseResult& r) {
    // A status the manual does not state readable, refused: the walk ends, and says so.
    if (r.type == rc::detail::CaseResult::Type::Success) skipped.push_back(r.description);
    else failed = r.description;
  }
  return failed;
}

std::optional<std::string> control_replay(Session& s, const std::vector<Step>& steps) {
  bool control = false;
  for (const auto& st : steps)
    if (!st.expect.masks.empty()) control = true;
  if (!control) return std::nullopt;
  // The expectations were written from the control model: the replay holds
  // each reply to its own, as `mbconform replay` does.
  for (size_t i = 0; i < steps.size(); ++i) {
    const Step& st = steps[i];
    if (st.kind == Step::Kind::advance) {
      if (st.note == kTripNote && !s.target().trip_fault())
        return fmt::format("step {}: the target cannot trip a fault out of band (a ref: target can)", i + 1);
      s.advance(st.advance_us, st.note);
      continue;
    }
    if (st.kind == Step::Kind::power_cycle) {
      s.power_cycle();
      continue;
    }
    Reply rep = st.frame.size() >= 4 ? s.send_to(st.frame[0], mbc::kRtu.pdu_bytes(st.frame), st.note) : s.send_raw(st.frame, st.note);
    if (auto miss = check::judge(st.script(), rep, judge_context(s)))
      return fmt::format("step {} ({}): expected {}: {}", i + 1, st.line(), check::expect_text(st.expect), miss->why);
  }
  return std::string();
}

}  // namespace mbc::conf::props
