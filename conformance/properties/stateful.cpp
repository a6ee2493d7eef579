#include "properties/stateful.h"

#include <fmt/core.h>
#include <rapidcheck.h>
#include <rapidcheck/state.h>

#include <fstream>
#include <sstream>

#include "modbus/bytes.h"
#include "modbus/crc16.h"
#include "modbus/judge.h"
#include "modbus/limits.h"
#include "modbus/rtu.h"
#include "properties/control.h"
#include "properties/generators.h"

namespace mbc::conf::props {

using spec::Access;
using spec::Register;
using spec::Table;
using spec::Violation;

Expected refusal_of(const std::vector<facts::Breach>& breaches) {
  Expected e = expected_of(breaches.front().policy);
  for (size_t i = 1; i < breaches.size(); ++i) e.either.push_back(expected_of(breaches[i].policy));
  return e;
}

namespace {

using Words = std::map<uint16_t, std::optional<uint16_t>>;  // address -> word; nullopt = not known


// The model: what the spec lets a master know about the device's state.
// Tracked are the words of the writable registers (SpecView::writable) and
// their stored (EEPROM/flash) copies.
struct Model {
  const SpecView* view = nullptr;
  const DeviceFacts* facts = nullptr;
  uint8_t unit = 1;
  bool raw = false, virtual_clock = false, power_cycle = false, live = false;  // what the target offers
  Framing framing = &mbc::kRtu;  // the target's: how its replies are framed
  Words words;
  Words stored;
  // A save command in progress (device facts: settle time): the words it
  // will store, and the virtual time left until it has.
  std::optional<Words> saving;
  uint64_t save_left_us = 0;
};

// How the model's target is judged: a live line may hold other units (check/judge.h).
check::JudgeContext context(const Model& m) {
  check::JudgeContext c{m.unit, m.framing, &m.view->spec(), {}};
  c.shared_line = m.live;
  return c;
}

// What the model says one frame must do.
struct Prediction {
  enum class Kind { normal, refused, silence, any } kind = Kind::any;
  Expected refusal;                    // refused: the policy's answer
  Violation violation{};
  std::optional<Bytes> exact;          // normal: the exact reply PDU (write echoes)
  std::optional<std::pair<uint16_t, uint16_t>> read;  // normal FC 03: start, quantity (tracked words compared)
  bool or_refused = false;             // normal, or refused by value_out_of_range (range depends on unknown words)
  Words updates;                       // applied when the frame is acted on
  bool save = false, factory_reset = false;
  std::string why;                     // the rule, for messages
};

Prediction refused(const std::vector<facts::Breach>& breaches, std::string why) {
  Prediction p;
  p.kind = Prediction::Kind::refused;
  p.violation = breaches.front().violation;
  p.refusal = refusal_of(breaches);
  p.why = std::move(why);
  return p;
}

Prediction refused(const Model& m, Violation v, std::string why) {
  facts::Breach b;
  b.violation = v;
  b.policy = facts::policy(b.relies, m.view->spec(), v);
  return refused(std::vector<facts::Breach>{b}, std::move(why));
}

bool is_fact(const Model& m, const std::optional<CommandFact>& f, uint16_t address, uint16_t value) {
  if (!f) return false;
  const Register* r = m.view->spec().find_by_key(f->key);
  return r && r->address == address && r->words == 1 && value == uint16_t(f->value);
}

// A write of `values` at `start` to holding registers, which the classifier
// found valid (`maybe`: its value may be out of range, a word of it unknown).
Prediction predict_write(const Model& m, uint16_t start, std::span<const uint16_t> values, Bytes echo,
                         const std::optional<facts::Breach>& maybe) {
  const spec::Spec& s = m.view->spec();
  Prediction p;
  p.kind = Prediction::Kind::normal;
  p.exact = std::move(echo);
  // Every register the write touches.
  std::vector<const Register*> touched;
  for (size_t i = 0; i < values.size(); ++i) {
    const Register* r = s.register_covering(uint16_t(start + i));
    if (r && (touched.empty() || touched.back() != r)) touched.push_back(r);
  }
  for (const Register* r : touched) {
    if (r->access == Access::command || r->access == Access::wo) {
      if (values.size() == 1 && is_fact(m, m.facts ? m.facts->save : std::nullopt, r->address, values[0])) {
        p.save = true;
      } else if (values.size() == 1 && is_fact(m, m.facts ? m.facts->factory_reset : std::nullopt, r->address, values[0])) {
        p.factory_reset = true;
      } else {
        // What a command does is the device's (spec: command.effect, in words).
        p.kind = Prediction::Kind::any;
        p.why = fmt::format("a write to command register 0x{:04X}", r->address);
        return p;
      }
    }
  }
  // The range of a half-written 2-word value may depend on a word the model does not know.
  p.or_refused = maybe.has_value();
  for (size_t i = 0; i < values.size(); ++i) {
    uint16_t a = uint16_t(start + i);
    if (m.words.count(a)) p.updates[a] = p.or_refused ? std::nullopt : std::optional<uint16_t>(values[i]);
  }
  if (maybe) p.refusal = expected_of(maybe->policy);
  p.why = "a valid write: echoed (MBAP v1.1b3 §6.6, §6.12)";
  return p;
}

std::string breach_text(const facts::Classified& c) {
  std::string t;
  for (const auto& b : c.breaches) t += (t.empty() ? "" : ", ") + std::string(spec::to_string(b.violation));
  return t;
}

Prediction predict_pdu(const Model& m, std::span<const uint8_t> pdu) {
  // What the request breaks (MBAP v1.1b3 §6, §7 and the spec): the one
  // classifier; the words the model holds complete a half-written value.
  facts::KnownWord known = [&m](Table t, uint16_t a) -> std::optional<uint16_t> {
    if (t != Table::holding) return std::nullopt;
    auto it = m.words.find(a);
    return it == m.words.end() ? std::nullopt : it->second;
  };
  facts::Classified c = facts::classify(m.view->spec(), pdu, known);
  uint8_t fc = pdu[0];
  if (!c.valid()) return refused(c.breaches, fmt::format("{} ({})", describe_pdu(pdu, true), breach_text(c)));
  switch (fc) {
    case 3:
    case 4: {
      Prediction p;
      p.kind = Prediction::Kind::normal;
      if (fc == 3) p.read = std::make_pair(be16(pdu, 1), be16(pdu, 3));
      p.why = "a valid read";
      return p;
    }
    case 6: {
      uint16_t value = be16(pdu, 3);
      return predict_write(m, be16(pdu, 1), std::span<const uint16_t>(&value, 1), Bytes(pdu.begin(), pdu.end()), c.maybe);
    }
    case 16: {
      uint16_t qty = be16(pdu, 3);
      std::vector<uint16_t> values(qty);
      for (uint16_t i = 0; i < qty; ++i) values[i] = be16(pdu, 6 + 2 * i);
      return predict_write(m, be16(pdu, 1), values, Bytes(pdu.begin(), pdu.begin() + 5), c.maybe);
    }
    default: {
      // Functions the model does not follow: any well-formed answer; the
      // register writers among them make the holding image unknown.
      Prediction p;
      p.kind = Prediction::Kind::any;
      p.why = fmt::format("FC {:02} is not modelled", fc);
      if (fc == 22 || fc == 23)
        for (const auto& [a, w] : m.words) p.updates[a] = std::nullopt;
      return p;
    }
  }
}

Prediction predict(const Model& m, std::span<const uint8_t> adu) {
  Prediction silence;
  silence.kind = Prediction::Kind::silence;
  // MB-SL v1.02 §2.5.1.1: an RTU frame is 4..256 bytes.
  if (adu.size() < 4 || adu.size() > kMaxRtuAdu) {
    silence.why = "not an RTU frame (4..256 bytes)";
    return silence;
  }
  const auto& serial = m.view->spec().serial;
  bool broadcast = serial.broadcast_address && adu[0] == *serial.broadcast_address;
  if (!crc_ok(adu)) {
    if (adu[0] != m.unit) {
      silence.why = "bad CRC, not for this slave";
      return silence;
    }
    return refused(m, Violation::crc_error, "bad CRC (MB-SL v1.02 §2.4.2)");
  }
  if (!broadcast && adu[0] != m.unit) {
    silence.why = fmt::format("for slave {} (MB-SL v1.02 §2.2)", adu[0]);
    return silence;
  }
  const Bytes pdu = rtu_unframe(adu).pdu;  // the CRC was checked above
  Prediction p = predict_pdu(m, pdu);
  if (!broadcast) return p;
  // MB-SL v1.02 §2.1: no reply to broadcast; writes act per the spec.
  silence.why = "broadcast (MB-SL v1.02 §2.1)";
  bool acted = p.kind == Prediction::Kind::normal || p.kind == Prediction::Kind::any;
  if (acted && !p.read && serial.broadcast_writes != "ignored") {
    for (auto& [a, w] : p.updates) silence.updates[a] = serial.broadcast_writes == "applied" ? w : std::nullopt;
    silence.save = p.save && serial.broadcast_writes == "applied";
    silence.factory_reset = p.factory_reset && serial.broadcast_writes == "applied";
  }
  return silence;
}

// A refusal the model allows, as a frame-script expectation: each reading
// (`either`); "any exception or silence" (a policy the manual leaves open) as
// each exception code the standard (MBAP v1.1b3 §7: 01-04) or the spec knows,
// or silence, which is what the replay's judge takes too.
check::Expect refusal_expect(const spec::Spec& s, const Expected& x) {
  using K = check::Expect::Kind;
  std::vector<check::Expect> alts;
  auto one = [&](const Expected& e) {
    if (e.kind == Expected::Kind::exception) alts.push_back({.kind = K::exception, .code = uint8_t(e.code)});
    else if (e.kind == Expected::Kind::silence) alts.push_back({.kind = K::silence});
    else {
      for (int code = 1; code < 128; ++code)
        if (check::exception_code_known(&s, uint8_t(code))) alts.push_back({.kind = K::exception, .code = uint8_t(code)});
      alts.push_back({.kind = K::silence});
    }
  };
  one(x);
  for (const auto& e : x.either) one(e);
  // One of each: the first is the expectation, the rest its readings.
  std::vector<check::Expect> unique;
  for (auto& e : alts)
    if (std::none_of(unique.begin(), unique.end(), [&](const check::Expect& u) { return u.kind == e.kind && u.code == e.code; }))
      unique.push_back(std::move(e));
  check::Expect out = unique.front();
  out.either.assign(unique.begin() + 1, unique.end());
  return out;
}

// The words of `qty` registers from `start` as the model holds them, if it knows every one.
std::optional<std::vector<uint16_t>> known_words(const Model& m, uint16_t start, uint16_t qty) {
  std::vector<uint16_t> w;
  for (uint16_t i = 0; i < qty; ++i) {
    auto it = m.words.find(uint16_t(start + i));
    if (it == m.words.end() || !it->second) return std::nullopt;
    w.push_back(*it->second);
  }
  return w;
}

// What the model predicts for a frame, as a frame-script expectation
// (written into counterexamples and regressions): as strict as the model,
// so that `mbconform replay` of a counterexample fails where the model does.
check::Expect expectation(const Model& m, const Prediction& p) {
  using K = check::Expect::Kind;
  const spec::Spec& s = m.view->spec();
  switch (p.kind) {
    case Prediction::Kind::silence: return {.kind = K::silence};
    case Prediction::Kind::any: return {.kind = K::any_or_silence};
    case Prediction::Kind::refused: return refusal_expect(s, p.refusal);
    case Prediction::Kind::normal: break;
  }
  check::Expect e{.kind = K::normal};
  if (p.exact) {
    e = {.kind = K::reply, .pdu = *p.exact};
  } else if (p.read) {
    // Every word read known to the model: the reply holds exactly them (MBAP v1.1b3 §6.3).
    if (auto w = known_words(m, p.read->first, p.read->second)) e = {.kind = K::registers, .words = *w};
  }
  if (p.or_refused) {
    // Or refused: the range depends on a word the model does not know.
    check::Expect r = refusal_expect(s, p.refusal);
    std::vector<check::Expect> more = std::move(r.either);
    r.either.clear();
    e.either.push_back(std::move(r));
    for (auto& x : more) e.either.push_back(std::move(x));
  }
  return e;
}

std::string reply_text(const Reply& r) {
  if (r.silent()) return "silence";
  if (!r.pdu) return fmt::format("{} ({})", to_hex(r.frame), r.framing_error);
  return fmt::format("{} ({})", to_hex(r.frame), describe_pdu(*r.pdu, false));
}

// Checks one reply against the prediction; "" when it agrees.
std::string judge(const Model& m, const Prediction& p, std::span<const uint8_t> adu, const Reply& rep) {
  std::span<const uint8_t> pdu = adu.size() >= 4 ? mbc::kRtu.pdu_bytes(adu) : adu;
  if (!rep.silent() && !rep.pdu) return fmt::format("bad reply frame {}: {}", to_hex(rep.frame), rep.framing_error);
  switch (p.kind) {
    case Prediction::Kind::silence:
      // On a multi-drop line a frame for another unit is answered by that unit (check/judge.h).
      if (rep.silent() || !check::reply_is_targets(adu.empty() ? m.unit : adu[0], rep.frame, context(m))) return "";
      return fmt::format("expected silence ({}), got {}", p.why, reply_text(rep));
    case Prediction::Kind::refused:
      return p.refusal.allows(rep) ? ""
                                   : fmt::format("expected {} ({}: {}), got {}", p.refusal.text(),
                                                 spec::to_string(p.violation), p.why, reply_text(rep));
    case Prediction::Kind::any:
      if (rep.pdu && !judge_reply(pdu, *rep.pdu).problems.empty())
        return fmt::format("malformed reply {}: {}", to_hex(rep.frame), judge_reply(pdu, *rep.pdu).problems.front());
      return "";
    case Prediction::Kind::normal: break;
  }
  if (rep.silent()) return fmt::format("expected a reply ({}), got silence", p.why);
  Judged j = judge_reply(pdu, *rep.pdu);
  if (p.or_refused && j.kind == Judged::Kind::exception && p.refusal.allows(rep)) return "";
  if (!j.problems.empty()) return fmt::format("malformed reply {}: {}", to_hex(rep.frame), j.problems.front());
  if (j.kind == Judged::Kind::exception) return fmt::format("expected a normal reply ({}), got {}", p.why, reply_text(rep));
  if (p.exact && *rep.pdu != *p.exact) return fmt::format("expected {} , got {}", to_hex(*p.exact), reply_text(rep));
  if (p.read) {
    for (uint16_t i = 0; i < p.read->second && i < j.registers.size(); ++i) {
      uint16_t a = uint16_t(p.read->first + i);
      auto it = m.words.find(a);
      if (it != m.words.end() && it->second && *it->second != j.registers[i])
        return fmt::format("0x{:04X} reads 0x{:04X}, the model holds 0x{:04X} (last written or restored)", a,
                           j.registers[i], *it->second);
    }
  }
  return "";
}

// A save stores the by: save_command registers as they were when it was
// commanded; if one changed meanwhile, which value it stored is not stated.
// Whether it also stores on_write registers the do-not-persist switch held
// back is not stated either (57HS-R §6.1).
void finish_save(Model& m) {
  const spec::Spec& s = m.view->spec();
  for (auto& [a, w] : m.stored) {
    const Register* r = s.register_covering(a);
    std::optional<uint16_t> then = (*m.saving)[a], now = m.words[a];
    if (r->persistence.by == spec::PersistBy::save_command) w = then == now ? now : std::nullopt;
    else if (w != now) w = std::nullopt;
  }
  m.saving.reset();
}

void apply_advance(Model& m, uint64_t us) {
  if (!m.saving) return;
  if (us >= m.save_left_us) return finish_save(m);
  m.save_left_us -= us;
}

// The model after a frame (the reply was already judged to agree).
void apply_frame(Model& m, const Prediction& p, const Reply* rep) {
  bool acted = p.kind == Prediction::Kind::normal || p.kind == Prediction::Kind::silence || p.kind == Prediction::Kind::any;
  if (p.or_refused && rep && rep->pdu && !rep->pdu->empty() && ((*rep->pdu)[0] & 0x80)) acted = false;
  if (!acted) return;
  for (const auto& [a, w] : p.updates) {
    m.words[a] = w;
    // Written while a save is in progress: which value the save copies is not stated.
    if (m.saving && m.saving->count(a)) (*m.saving)[a] = std::nullopt;
  }
  // Persistence (spec registers[].persistence): stored on write unless the
  // do-not-persist switch is on; a save stores the save_command registers.
  const spec::Spec& s = m.view->spec();
  for (const auto& [a, w] : p.updates) {
    const Register* r = s.register_covering(a);
    if (!r || r->persistence.by != spec::PersistBy::on_write) continue;
    std::optional<bool> suppressed = false;
    if (r->persistence.unless_register) {
      auto it = m.words.find(*r->persistence.unless_register);
      if (it == m.words.end() || !it->second) suppressed = std::nullopt;
      else suppressed = int64_t(*it->second) == r->persistence.unless_value;
      // Whether the switch holds the write back may itself be inferred (57HS-R
      // 0x00E0, erratum pv-autosave): then what is stored is not known.
      if (suppressed == true && r->basis_of(spec::Fact::persistence_unless).basis != spec::Basis::stated) suppressed = std::nullopt;
    }
    if (suppressed == false) m.stored[a] = w;
    else if (!suppressed) m.stored[a] = std::nullopt;
  }
  if (p.save) {
    m.saving = m.words;
    m.save_left_us = m.facts && m.facts->save ? m.facts->save->settle_us : 0;
    if (m.save_left_us == 0) finish_save(m);
  }
  if (p.factory_reset)
    for (auto& [a, w] : m.words) {
      const Register* r = s.register_covering(a);
      auto d = m.view->default_raw(*r);
      std::optional<uint16_t> word;
      if (d) word = m.view->words_of(*r, *d)[a - r->address];
      w = word;
      if (m.stored.count(a)) m.stored[a] = word;
    }
}

void apply_power_cycle(Model& m) {
  if (m.saving) {
    // Power lost during a save: the store holds the old value, the value at
    // the command, or one written since (when the save copies is not stated).
    for (auto& [a, w] : m.stored)
      if (w != (*m.saving)[a] || w != m.words[a]) w = std::nullopt;
    m.saving.reset();
  }
  for (auto& [a, w] : m.words) {
    const Register* r = m.view->spec().register_covering(a);
    if (r->basis_of(spec::Fact::persistence).basis != spec::Basis::stated) {
      w = std::nullopt;  // an inferred persistence is not held against the device (spec/README.md)
    } else if (r->persistence.store != spec::Store::none) {
      w = m.stored[a];
    } else {
      auto d = m.view->default_raw(*r);
      w = d ? std::optional<uint16_t>(m.view->words_of(*r, *d)[a - r->address]) : std::nullopt;
    }
  }
}

// The model at the start: the tracked words as read (the spec does not say
// what a device holds before its first power cycle in this run), stored = as read.
std::optional<Model> initial_model(Session& s, std::string& error) {
  Model m;
  m.view = &s.view();
  m.facts = s.facts();
  m.unit = s.unit();
  const TargetInfo& t = s.target().info();
  m.raw = t.raw && t.framing == &mbc::kRtu;
  m.framing = t.framing;
  m.virtual_clock = t.virtual_clock;
  m.power_cycle = t.power_cycle;
  m.live = t.live;
  // Not recorded: a replay reads the initial model itself.
  Transact quiet = [&s](std::span<const uint8_t> pdu, const std::string&) { return s.target().transact(pdu); };
  for (const Register* r : s.view().writable()) {
    ReadResult rr = read_register(quiet, s.view(), *r);
    if (!rr.raw) {
      error = fmt::format("reading 0x{:04X} for the initial model: {}", r->address, rr.error);
      return std::nullopt;
    }
    auto w = s.view().words_of(*r, *rr.raw);
    for (int k = 0; k < r->words; ++k) {
      m.words[uint16_t(r->address + k)] = w[k];
      if (r->persistence.store != spec::Store::none) m.stored[uint16_t(r->address + k)] = w[k];
    }
  }
  return m;
}

// Raw targets get the frame as is; the others (Modbus TCP) its PDU for its
// unit (StepCmd makes no corrupted frames for them).
Reply send_step(Session& s, bool raw, const Step& st) {
  if (raw || st.frame.size() < 4) return s.send_raw(st.frame, st.note);
  return s.send_to(st.frame[0], mbc::kRtu.pdu_bytes(st.frame), st.note);
}

// Whether the last step's reply meets the expectation it is written with
// (check/judge.h, as `mbconform replay` judges it); "" when it does.
std::string script_miss(Session& s, const Model& m, const Reply& rep) {
  if (s.steps().empty()) return "";
  check::JudgeContext ctx = context(m);
  ctx.spec = &s.spec();
  auto miss = check::judge(s.steps().back().script(), rep, ctx);
  return miss ? miss->why : "";
}

// ---- the RapidCheck commands -------------------------------------------------

struct Sut {
  Session& session;
};

// One step: a frame (valid or not), time passing, or a power cycle; kinds
// drawn with weights from what the spec and the target offer.
struct StepCmd final : rc::state::Command<Model, Sut> {
  Step step;

  explicit StepCmd(const Model& m) {
    const SpecView& v = *m.view;
    std::vector<std::pair<size_t, int>> weights = {{30, 0}, {10, 2}};  // valid read, rejection
    if (!v.writable().empty()) weights.push_back({30, 1});              // valid write
    weights.push_back({4, 3});                                          // other slave
    if (m.raw) weights.push_back({4, 4});                               // corrupted byte
    // Random broadcast writes reach drives no snapshot restores: reference targets only
    // (broadcast-unanswered puts back what it broadcasts on a live line).
    if (v.spec().serial.broadcast_address && v.broadcast_unavailable().empty() && !m.live && !v.writable().empty())
      weights.push_back({4, 5});
    if (m.virtual_clock) weights.push_back({6, 6});                     // time passes
    if (m.power_cycle) weights.push_back({4, 7});
    if (m.facts && m.facts->save && !m.live) weights.push_back({3, 8});
    size_t total = 0;
    for (auto [w, k] : weights) total += w;
    size_t x = pick<size_t>(0, total);
    int kind = weights.front().second;
    for (auto [w, k] : weights) {
      if (x < w) {
        kind = k;
        break;
      }
      x -= w;
    }
    auto frame = [&](uint8_t unit, const Bytes& pdu, std::string note) {
      step.frame = rtu_frame(unit, pdu);
      step.note = std::move(note);
    };
    switch (kind) {
      case 0: {
        auto r = pick_valid_read(v);
        frame(m.unit, r.pdu, r.note);
        break;
      }
      case 1: {
        auto r = pick_valid_write(v);
        frame(m.unit, r.pdu, r.note);
        break;
      }
      case 2: {
        auto kinds = rejection_kinds(v);
        if (kinds.empty()) {
          auto r = pick_valid_read(v);
          frame(m.unit, r.pdu, r.note);
        } else {
          Bad b = kinds[pick<size_t>(0, kinds.size())]();
          frame(m.unit, b.pdu, b.note);
        }
        break;
      }
      case 3: {
        uint8_t other = uint8_t(pick<int>(1, 247));
        if (other >= m.unit) ++other;
        // A read: a valid write to another slave would change a drive nothing restores.
        auto r = pick_valid_read(v);
        frame(other, r.pdu, fmt::format("{} to slave {}", r.note, other));
        break;
      }
      case 4: {
        auto r = v.writable().empty() ? pick_valid_read(v) : pick_valid_write(v);
        frame(m.unit, r.pdu, "");
        size_t at = pick<size_t>(0, step.frame.size());
        uint8_t mask = uint8_t(pick<int>(1, 256));
        step.frame[at] ^= mask;
        step.note = fmt::format("{}, byte {} XOR {:02X}", r.note, at, mask);
        break;
      }
      case 5: {
        auto r = pick_valid_write(v);
        frame(uint8_t(*v.spec().serial.broadcast_address), r.pdu, "broadcast " + r.note);
        break;
      }
      case 6:
        step.kind = Step::Kind::advance;
        step.advance_us = uint64_t(pick<int>(1, 2'000'000));
        break;
      case 7: step.kind = Step::Kind::power_cycle; break;
      case 8: {
        const CommandFact& c = *m.facts->save;
        const Register* r = v.spec().find_by_key(c.key);
        frame(m.unit, v.write_request(*r, uint32_t(c.value)), fmt::format("save ({})", c.section));
        break;
      }
    }
  }

  void apply(Model& m) const override {
    if (step.kind == Step::Kind::power_cycle) return apply_power_cycle(m);
    if (step.kind == Step::Kind::advance) return apply_advance(m, step.advance_us);
    if (step.kind == Step::Kind::frame) apply_frame(m, predict(m, step.frame), nullptr);
  }

  void run(const Model& m, Sut& sut) const override {
    if (step.kind == Step::Kind::advance) return sut.session.advance(step.advance_us);
    if (step.kind == Step::Kind::power_cycle) return sut.session.power_cycle();
    Prediction p = predict(m, step.frame);
    Reply rep = send_step(sut.session, m.raw, step);
    sut.session.expect_last(expectation(m, p));
    std::string why = judge(m, p, step.frame, rep);
    // The expectation the counterexample will carry holds too (what `replay` judges).
    if (why.empty()) why = script_miss(sut.session, m, rep);
    if (!why.empty()) RC_FAIL(fmt::format("{}{}: {}", to_hex(step.frame), step.note.empty() ? "" : " (" + step.note + ")", why));
  }

  void show(std::ostream& os) const override {
    os << step.line();
    if (!step.note.empty()) os << "   # " << step.note;
  }
};

// Reads every tracked register and compares it with the model.
std::string final_image_check(Session& s, const Model& m) {
  for (const Register* r : s.view().writable()) {
    ReadResult rr = read_register(s.transact(), s.view(), *r);
    // The read goes into the counterexample with what the model holds.
    if (auto known = known_words(m, r->address, uint16_t(r->words)))
      s.expect_last({.kind = check::Expect::Kind::registers, .words = *known});
    else
      s.expect_last({.kind = check::Expect::Kind::normal});
    if (!rr.raw) return fmt::format("final read of {}: {}", describe(*r), rr.error);
    auto w = s.view().words_of(*r, *rr.raw);
    for (int k = 0; k < r->words; ++k) {
      auto it = m.words.find(uint16_t(r->address + k));
      if (it != m.words.end() && it->second && *it->second != w[k])
        return fmt::format("final image: 0x{:04X} reads 0x{:04X}, the model holds 0x{:04X}", r->address + k, w[k],
                           *it->second);
    }
  }
  return "";
}

void stateful_check(Session& s) {
  std::string error;
  auto m0 = initial_model(s, error);
  if (!m0) RC_FAIL(error);
  auto cmds = *rc::state::gen::commands(*m0, rc::state::gen::execOneOfWithArgs<StepCmd>());
  Sut sut{s};
  rc::state::runAll(cmds, *m0, sut);
  Model end = *m0;
  rc::state::applyAll(cmds, end);
  if (auto why = final_image_check(s, end); !why.empty()) RC_FAIL(why);
}

}  // namespace

Invariant stateful_invariant() {
  return {"stateful-model", "the spec (registers, access, ranges, exception policy, persistence, broadcast); MBAP v1.1b3; MB-SL v1.02",
          "Random sequences of valid and invalid frames, with time passing and power cycles, get the replies and "
          "leave the register image that a model written from the spec predicts, after every step.",
          [](const SpecView& v, const TargetInfo& t, const DeviceFacts*) {
            if (v.image_reads().empty()) return std::string("no readable registers");
            return std::string();
          },
          stateful_check};
}

std::string replay(Session& s, const std::vector<Step>& steps) {
  // A control property's counterexample: its expectations are the control model's.
  if (auto c = control_replay(s, steps)) return *c;
  std::string error;
  auto m = initial_model(s, error);
  if (!m) return error;
  for (size_t i = 0; i < steps.size(); ++i) {
    const Step& st = steps[i];
    if (st.kind == Step::Kind::advance) {
      s.advance(st.advance_us);
      apply_advance(*m, st.advance_us);
      continue;
    }
    if (st.kind == Step::Kind::power_cycle) {
      s.power_cycle();
      apply_power_cycle(*m);
      continue;
    }
    Prediction p = predict(*m, st.frame);
    Reply rep = send_step(s, m->raw, st);
    s.expect_last(expectation(*m, p));
    if (std::string why = judge(*m, p, st.frame, rep); !why.empty())
      return fmt::format("step {} ({}): {}", i + 1, st.line(), why);
    // The expectation written in the file holds too.
    if (auto miss = check::judge(st.script(), rep, context(*m)))
      return fmt::format("step {} ({}): {}", i + 1, st.line(), miss->why);
    apply_frame(*m, p, &rep);
  }
  return final_image_check(s, *m);
}

Regression parse_regression(const std::string& path) {
  check::Script sc = check::parse_file(path);  // throws with path:line:col
  Regression r;
  r.path = path;
  r.device_id = sc.device;
  r.fault = sc.fault;
  r.note = sc.comment;
  for (const auto& st : sc.steps) {
    Step s;
    s.note = st.note;
    s.expect = st.expect;
    switch (st.kind) {
      case check::Step::Kind::frame:
        s.frame = rtu_frame(st.unit, st.pdu);
        s.framing = st.framing;
        s.tid = st.tid;
        break;
      case check::Step::Kind::raw:
        if (st.framing != &mbc::kRtu || st.gap)
          throw check::ParseError(fmt::format("{}:{}:1: error: step: the model replays RTU frames without pauses", path, st.line));
        s.frame = st.bytes;
        break;
      case check::Step::Kind::advance:
        s.kind = Step::Kind::advance;
        s.advance_us = st.us;
        break;
      case check::Step::Kind::power_cycle: s.kind = Step::Kind::power_cycle; break;
      case check::Step::Kind::wait:
        throw check::ParseError(fmt::format("{}:{}:1: error: step: the model has no real time (use advance)", path, st.line));
    }
    r.steps.push_back(std::move(s));
  }
  if (r.device_id.empty()) throw std::runtime_error(path + ": no 'device ID' line");
  return r;
}

std::string format_regression(const std::string& device_id, const std::string& fault, const std::string& comment,
                              const std::vector<Step>& steps) {
  check::Script sc;
  sc.device = device_id;
  sc.fault = fault;
  sc.comment = comment;
  for (const auto& s : steps) sc.steps.push_back(s.script());
  return check::format(sc);
}

}  // namespace mbc::conf::props
