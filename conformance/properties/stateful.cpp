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
#include "properties/generators.h"

namespace mbc::conf::props {

using spec::Access;
using spec::Register;
using spec::Table;
using spec::Violation;

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
  Words words;
  Words stored;
  // A save command in progress (device facts: settle time): the words it
  // will store, and the virtual time left until it has.
  std::optional<Words> saving;
  uint64_t save_left_us = 0;
};

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

Prediction refused(const Model& m, Violation v, std::string why) {
  Prediction p;
  p.kind = Prediction::Kind::refused;
  p.violation = v;
  p.refusal = m.view->expected(v);
  p.why = std::move(why);
  return p;
}

bool is_fact(const Model& m, const std::optional<CommandFact>& f, uint16_t address, uint16_t value) {
  if (!f) return false;
  const Register* r = m.view->spec().find_by_key(f->key);
  return r && r->address == address && r->words == 1 && value == uint16_t(f->value);
}

// Address checks in the standard's order (MBAP v1.1b3 §6.3/§6.12 figures:
// quantity, then address, then value), with the spec language's kinds.
std::optional<Violation> check_addresses(const Model& m, Table table, uint32_t start, uint32_t qty, bool reading) {
  const spec::Spec& s = m.view->spec();
  auto last = s.last_address(table);
  for (uint32_t a = start; a < start + qty; ++a) {
    if (a > 0xFFFF || !last || a > *last) return Violation::address_past_map;
    const Register* r = s.register_covering(uint16_t(a), table);
    if (!r) return Violation::unmapped_address;
    if (reading && r->access == Access::wo) return Violation::read_write_only;
    if (!reading && r->access == Access::ro) return Violation::write_read_only;
  }
  return std::nullopt;
}

// A write of `values` at `start` to holding registers.
Prediction predict_write(const Model& m, uint16_t start, std::span<const uint16_t> values, Bytes echo) {
  const SpecView& v = *m.view;
  const spec::Spec& s = v.spec();
  Prediction p;
  p.kind = Prediction::Kind::normal;
  p.exact = std::move(echo);
  // Every register the write touches, with its new words (other words as modelled).
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
    std::vector<uint16_t> w;
    bool known = true;
    for (int k = 0; k < r->words; ++k) {
      uint16_t a = uint16_t(r->address + k);
      if (a >= start && a < start + values.size()) {
        w.push_back(values[a - start]);
      } else if (auto it = m.words.find(a); it != m.words.end() && it->second) {
        w.push_back(*it->second);
      } else {
        known = false;
      }
    }
    if (!known) {
      p.or_refused = true;  // the range of a half-written 2-word value depends on a word the model does not know
    } else if (!v.in_range(*r, v.raw_of(*r, w))) {
      return refused(m, Violation::value_out_of_range,
                     fmt::format("0x{:X} is outside the range of 0x{:04X} (spec range/enum)", v.raw_of(*r, w), r->address));
    }
  }
  for (size_t i = 0; i < values.size(); ++i) {
    uint16_t a = uint16_t(start + i);
    if (m.words.count(a)) p.updates[a] = p.or_refused ? std::nullopt : std::optional<uint16_t>(values[i]);
  }
  p.refusal = v.expected(Violation::value_out_of_range);
  p.why = "a valid write: echoed (MBAP v1.1b3 §6.6, §6.12)";
  return p;
}

Prediction predict_pdu(const Model& m, std::span<const uint8_t> pdu) {
  const SpecView& v = *m.view;
  uint8_t fc = pdu[0];
  if ((fc & 0x80) || !v.in_profile(fc))
    return refused(m, Violation::unsupported_function, fmt::format("FC {:02} is not in the profile", fc & 0x7F));
  switch (fc) {
    case 3:
    case 4: {
      if (pdu.size() != 5) return refused(m, Violation::wrong_byte_count, "a read PDU is 5 bytes");
      uint16_t start = be16(pdu, 1), qty = be16(pdu, 3);
      if (qty == 0) return refused(m, Violation::quantity_zero, "quantity 0");
      if (qty > v.quantity_limit(fc)) return refused(m, Violation::quantity_over_limit, fmt::format("quantity {} over the limit {}", qty, v.quantity_limit(fc)));
      if (auto bad = check_addresses(m, fc == 3 ? Table::holding : Table::input, start, qty, true))
        return refused(m, *bad, fmt::format("0x{:04X} x{}", start, qty));
      Prediction p;
      p.kind = Prediction::Kind::normal;
      if (fc == 3) p.read = std::make_pair(start, qty);
      p.why = "a valid read";
      return p;
    }
    case 6: {
      if (pdu.size() != 5) return refused(m, Violation::wrong_byte_count, "an FC 06 PDU is 5 bytes");
      uint16_t a = be16(pdu, 1), value = be16(pdu, 3);
      if (auto bad = check_addresses(m, Table::holding, a, 1, false)) return refused(m, *bad, fmt::format("0x{:04X}", a));
      return predict_write(m, a, std::span<const uint16_t>(&value, 1), Bytes(pdu.begin(), pdu.end()));
    }
    case 16: {
      if (pdu.size() < 6) return refused(m, Violation::wrong_byte_count, "an FC 16 PDU is at least 6 bytes");
      uint16_t start = be16(pdu, 1), qty = be16(pdu, 3);
      if (qty == 0) return refused(m, Violation::quantity_zero, "quantity 0");
      if (qty > v.quantity_limit(16)) return refused(m, Violation::quantity_over_limit, fmt::format("quantity {} over the limit {}", qty, v.quantity_limit(16)));
      if (pdu[5] != qty * 2 || pdu.size() != size_t(6 + pdu[5]))
        return refused(m, Violation::wrong_byte_count, "byte count != 2 x quantity, or != the data sent");
      if (auto bad = check_addresses(m, Table::holding, start, qty, false))
        return refused(m, *bad, fmt::format("0x{:04X} x{}", start, qty));
      std::vector<uint16_t> values(qty);
      for (uint16_t i = 0; i < qty; ++i) values[i] = be16(pdu, 6 + 2 * i);
      return predict_write(m, start, values, Bytes(pdu.begin(), pdu.begin() + 5));
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

// What the model predicts for a frame, as a frame-script expectation
// (written into counterexamples and regressions).
check::Expect expectation(const Model& m, const Prediction& p, std::span<const uint8_t> adu) {
  using K = check::Expect::Kind;
  switch (p.kind) {
    case Prediction::Kind::silence: return {.kind = K::silence};
    case Prediction::Kind::any: return {.kind = K::any_or_silence};
    case Prediction::Kind::refused:
      if (p.refusal.kind == Expected::Kind::exception) return {.kind = K::exception, .code = uint8_t(p.refusal.code)};
      if (p.refusal.kind == Expected::Kind::silence) return {.kind = K::silence};
      return {.kind = K::any_or_silence};  // an exception or silence: the policy is unspecified
    case Prediction::Kind::normal: break;
  }
  if (p.or_refused) return {.kind = K::any};
  if (p.exact) return {.kind = K::reply, .pdu = *p.exact};
  if (p.read && adu.size() >= 4) {
    // Every word read known to the model: the reply is exact (MBAP v1.1b3 §6.3).
    Bytes r{adu[1], uint8_t(2 * p.read->second)};
    for (uint16_t i = 0; i < p.read->second; ++i) {
      auto it = m.words.find(uint16_t(p.read->first + i));
      if (it == m.words.end() || !it->second) return {.kind = K::normal};
      r.insert(r.end(), {uint8_t(*it->second >> 8), uint8_t(*it->second)});
    }
    return {.kind = K::reply, .pdu = r};
  }
  return {.kind = K::normal};
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
      return rep.silent() ? "" : fmt::format("expected silence ({}), got {}", p.why, reply_text(rep));
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
    sut.session.expect_last(expectation(m, p, step.frame));
    std::string why = judge(m, p, step.frame, rep);
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
    s.expect_last(expectation(*m, p, st.frame));
    if (std::string why = judge(*m, p, st.frame, rep); !why.empty())
      return fmt::format("step {} ({}): {}", i + 1, st.line(), why);
    // The expectation written in the file holds too.
    if (auto miss = check::judge(st.script(), rep, check::JudgeContext{m->unit, &mbc::kRtu, &s.spec(), {}}))
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
