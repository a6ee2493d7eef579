#include "faults/faults.h"

#include <algorithm>
#include <bit>
#include <map>
#include <cmath>
#include <stdexcept>

#include "modbus/bytes.h"
#include "modbus/crc16.h"
#include "modbus/limits.h"
#include "modbus/rtu.h"
#include "engine/control.h"

namespace mbc::faults {

using spec::Access;
using spec::Table;

const std::vector<FaultInfo>& all_faults() {
  static const std::vector<FaultInfo> list = {
      {Fault::wrong_exception_code, "wrong-exception-code",
       "answers every exception with another code than the policy's (1->2->3->4->1)"},
      {Fault::off_by_one_limit, "off-by-one-limit",
       "accepts FC 03/04/16 with quantity limit+1 (the spec's max_quantity, else the standard's)"},
      {Fault::refuse_limit, "refuse-limit", "refuses FC 03/04/16 at exactly the quantity limit, as if over it"},
      {Fault::swapped_words, "swapped-words",
       "stores 2-word values written whole (FC 16/23) in the other word order than the spec's word_order"},
      {Fault::accept_out_of_range, "accept-out-of-range",
       "a refused write (FC 06/16) to writable registers is stored anyway and echoed as success"},
      {Fault::accept_read_only, "accept-read-only",
       "a write (FC 06/16) to read-only registers is stored and echoed as success"},
      {Fault::lost_write, "lost-write", "acknowledges FC 06/16 writes but keeps the old register values"},
      {Fault::reply_other_slave, "reply-other-slave",
       "acts on and answers frames for slave ids nobody on the bus has (as the first device)"},
      {Fault::accept_bad_crc, "accept-bad-crc", "acts on and answers frames with a bad CRC"},
      {Fault::answer_broadcast, "answer-broadcast", "applies broadcast writes and answers them (from address 0)"},
      {Fault::ignore_broadcast, "ignore-broadcast", "drops broadcast writes the spec says are applied"},
      {Fault::bad_reply_crc, "bad-reply-crc", "every RTU reply carries a wrong CRC"},
      {Fault::wrong_byte_count, "wrong-byte-count", "FC 01-04/23 replies state a byte count 2 higher than sent"},
      {Fault::read_before_write, "read-before-write",
       "FC 23 reads its read range before it writes its write range (MBAP v1.1b3 §6.17: the write is performed first), "
       "so an overlapping read returns the old values"},
      {Fault::forget_persistent, "forget-persistent",
       "a power cycle loses the stored (EEPROM/flash) values: persistent registers come back at their defaults"},
      {Fault::keep_volatile, "keep-volatile",
       "a power cycle keeps the last written values of volatile registers instead of their defaults"},
      {Fault::overshoot, "overshoot", "a position move ends 3 pulses past its target"},
      {Fault::overspeed, "overspeed", "while the axis moves, it travels 1.5x the distance its speed allows"},
      {Fault::homing_gate_open, "homing-gate-open",
       "7TRSM5740Q: a position command (position_command) moves the axis before a homing"},
      {Fault::slow_estop, "slow-estop", "an emergency stop decelerates over 0.5 s instead of stopping at once"},
      {Fault::creep, "creep", "after a move ends the position creeps on by 1 pulse per clock step, 5 times, while the status says stopped"},
      {Fault::silent_unstated_reads, "silent-unstated-reads",
       "answers no FC 03/04 read of a register whose readability the spec only infers (a Hanstar that answers FC 03 "
       "only where its table 12 prints it); within what the manual states"},
      {Fault::refuse_reserved, "refuse-reserved",
       "answers exception 02 to FC 03/04 reads of registers named reserved (an HSC60 whose reserved 92-150 is not "
       "implemented)"},
      {Fault::silent_command_reads, "silent-command-reads",
       "never answers a read (FC 03/04) that covers an `access: command` register; Hanstar and Rieding print no "
       "exception reply for it, so a drive may stay silent (the printed examples write those registers without reading them)"},
      {Fault::undefined_command_accepted, "undefined-command-accepted",
       "control: a command not defined in the current state is taken as in the first state that defines it "
       "(CiA 402: Switch on from Switch on disabled goes to Switched on) instead of what `undefined` says"},
      {Fault::status_bit_wrong, "status-bit-wrong",
       "control: in the first state with motion whose status reading sets a bit, the highest bit it sets reads 0 "
       "(CiA 402: quick stop bit 5 clear in Operation enabled)"},
      {Fault::transition_missing, "transition-missing",
       "control: the first command (in the model's order) that leaves the first state with motion is ignored there "
       "(CiA 402: Shutdown ignored in Operation enabled, transition 8)"},
      {Fault::transition_wrong_target, "transition-wrong-target",
       "control: the first level command whose every transition goes to the safe state goes instead to the state "
       "one command past it (CiA 402: Disable voltage goes to Ready to switch on)"},
      {Fault::edge_as_level, "edge-as-level",
       "control: an edge-triggered command of the state machine acts on every write that holds its bits, not on "
       "their rising edge only (CiA 402: Fault reset by bit 7 written high again)"},
      {Fault::stop_ignored, "stop-ignored",
       "control: a stopping command (quick stop, emergency stop) is ignored while the axis moves"},
  };
  return list;
}

const char* to_string(Fault f) {
  for (const auto& i : all_faults())
    if (i.fault == f) return i.name;
  return "?";
}

std::vector<Fault> FaultSet::list() const {
  std::vector<Fault> out;
  for (const auto& i : all_faults())
    if (has(i.fault)) out.push_back(i.fault);
  return out;
}

std::string FaultSet::names() const {
  std::string out;
  for (Fault f : list()) out += (out.empty() ? "" : ",") + std::string(to_string(f));
  return out;
}

FaultSet parse_faults(const std::string& text) {
  FaultSet set;
  size_t at = 0;
  while (at <= text.size()) {
    size_t comma = text.find(',', at);
    std::string name = text.substr(at, comma == std::string::npos ? std::string::npos : comma - at);
    at = comma == std::string::npos ? text.size() + 1 : comma + 1;
    if (name.empty()) continue;
    auto it = std::find_if(all_faults().begin(), all_faults().end(), [&](const FaultInfo& i) { return name == i.name; });
    if (it == all_faults().end()) {
      std::string known;
      for (const auto& i : all_faults()) known += (known.empty() ? "" : ", ") + std::string(i.name);
      throw std::invalid_argument("unknown fault '" + name + "' (known: " + known + ")");
    }
    set.add(it->fault);
  }
  return set;
}

namespace {

constexpr double kOvershootPulses = 3;
constexpr double kOverspeedFactor = 1.5;
constexpr double kSlowEstopSeconds = 0.5;
constexpr int kCreepSteps = 5;

bool control_level(const FaultSet& f) {
  for (Fault x : {Fault::undefined_command_accepted, Fault::status_bit_wrong, Fault::transition_missing,
                  Fault::transition_wrong_target, Fault::edge_as_level, Fault::stop_ignored})
    if (f.has(x)) return true;
  return false;
}

bool device_level(const FaultSet& f) {
  if (control_level(f)) return true;
  for (Fault x : {Fault::forget_persistent, Fault::keep_volatile, Fault::overshoot, Fault::overspeed,
                  Fault::homing_gate_open, Fault::slow_estop, Fault::creep})
    if (f.has(x)) return true;
  return false;
}

bool pdu_level(const FaultSet& f) {
  for (Fault x : {Fault::wrong_exception_code, Fault::off_by_one_limit, Fault::refuse_limit, Fault::swapped_words,
                  Fault::accept_out_of_range, Fault::accept_read_only, Fault::lost_write, Fault::wrong_byte_count,
                  Fault::read_before_write, Fault::silent_unstated_reads, Fault::refuse_reserved,
                  Fault::silent_command_reads})
    if (f.has(x)) return true;
  return false;
}

Bytes with_crc(Bytes frame) {
  append_crc(frame);
  return frame;
}

// The quantity limit the engine applies to FC 03/04/16: the spec's, capped by
// the standard's (MBAP v1.1b3 §6.3, §6.4, §6.12).
int quantity_limit(const ref::Device& d, uint8_t fc) {
  int standard = standard_max_quantity(fc);
  const spec::FunctionCode* f = d.spec().profile.function(fc);
  return f && f->max_quantity ? std::min(*f->max_quantity, standard) : standard;
}

// ---- state-machine faults: the control executor bent (ref::ControlTweak) ----
// Each is chosen on the model, not on a profile's names, so that it applies
// to every device with a control section; CiA 402 is the worked case in each
// description.

class ControlFaults final : public ref::ControlTweak {
 public:
  ControlFaults(FaultSet faults, const spec::Control& c) : faults_(faults) {
    // The first state with motion that is not a fault state (CiA 402: Operation enabled).
    for (const auto& s : c.states)
      if (s.motion && !s.fault) {
        motion_state_ = s.id;
        break;
      }
    // status-bit-wrong: the first such state whose reading sets a bit (a
    // standstill that reads all zeros has none to clear: 57HS-R moving).
    for (const auto& s : c.states) {
      if (!s.motion || s.fault) continue;
      for (const spec::StatusMatch& m : s.status)
        if (uint16_t set = m.value & m.mask) {
          wrong_state_ = s.id;
          wrong_key_ = m.register_key;
          wrong_bit_ = uint16_t(1u << (15 - std::countl_zero(set)));
          break;
        }
      if (!wrong_state_.empty()) break;
    }
    // transition-missing: the first command that leaves that state (CiA 402: Shutdown, 8).
    for (const auto& cmd : c.commands) {
      if (cmd.stops) continue;
      bool leaves = std::any_of(c.transitions.begin(), c.transitions.end(), [&](const spec::ControlTransition& t) {
        return t.command == cmd.id && t.from == motion_state_ && t.to != motion_state_;
      });
      if (leaves) {
        missing_command_ = cmd.id;
        break;
      }
    }
    // transition-wrong-target: the first level command that only ever goes
    // to the safe state (CiA 402: Disable voltage), sent instead to where the
    // safe state's first command leads (Ready to switch on).
    for (const auto& t : c.transitions)
      if (t.from == c.safe && !t.automatic() && t.to != c.safe) {
        wrong_target_ = t.to;
        break;
      }
    for (const auto& cmd : c.commands) {
      if (cmd.stops || cmd.trigger == spec::Trigger::edge || wrong_target_.empty()) continue;
      bool any = false, all_safe = true;
      for (const auto& t : c.transitions)
        if (t.command == cmd.id) any = true, all_safe = all_safe && t.to == c.safe;
      if (any && all_safe) {
        for (const auto& t : c.transitions)
          if (t.command == cmd.id) {
            redirected_.push_back(t);
            redirected_.back().to = wrong_target_;
          }
        break;
      }
    }
    for (const auto& t : c.transitions) has_transition_.push_back(t.command);
  }

  const spec::ControlTransition* take(const ref::ControlExecutor& x, const spec::ControlCommand& c,
                                      const spec::ControlTransition* model) const override {
    if (ignores(x, c)) return nullptr;  // the model's side of what the drive does not act on
    if (faults_.has(Fault::transition_wrong_target) && model)
      for (const auto& t : redirected_)
        if (t.id == model->id) return &t;
    if (faults_.has(Fault::undefined_command_accepted) && !model)
      for (const auto& t : x.control().transitions)
        if (t.command == c.id && t.from != "*") return &t;
    return model;
  }

  bool ignores(const ref::ControlExecutor& x, const spec::ControlCommand& c) const override {
    if (faults_.has(Fault::stop_ignored) && c.stops && x.axis_moving()) return true;
    return faults_.has(Fault::transition_missing) && c.id == missing_command_ && x.state() == motion_state_;
  }

  bool selected(const ref::ControlExecutor&, const spec::ControlCommand& c, uint16_t, uint16_t word,
                bool model) const override {
    if (faults_.has(Fault::edge_as_level) && c.trigger == spec::Trigger::edge &&
        std::find(has_transition_.begin(), has_transition_.end(), c.id) != has_transition_.end())
      return c.selected_by(word);
    return model;
  }

  uint16_t status(const ref::ControlExecutor& x, const std::string& key, uint16_t word) const override {
    if (faults_.has(Fault::status_bit_wrong) && key == wrong_key_ && x.state() == wrong_state_)
      return uint16_t(word & ~wrong_bit_);
    return word;
  }

 private:
  FaultSet faults_;
  std::string motion_state_, wrong_state_, wrong_key_, missing_command_, wrong_target_;
  uint16_t wrong_bit_ = 0;
  std::vector<spec::ControlTransition> redirected_;  // not resized after construction
  std::vector<std::string> has_transition_;          // commands some transition names
};

// ---- device-level faults: a Behaviour around the device's own ----

class FaultyBehaviour final : public ref::Behaviour {
 public:
  FaultyBehaviour(std::unique_ptr<ref::Behaviour> inner, FaultSet faults) : inner_(std::move(inner)), faults_(faults) {}

  std::optional<uint8_t> check_write(const ref::Device& d, uint16_t address, std::span<const uint16_t> values) override {
    return inner_->check_write(d, address, values);
  }

  void on_write(ref::Device& d, uint16_t address, uint16_t count) override {
    ref::Axis before = d.axis();
    inner_->on_write(d, address, count);
    if (faults_.has(Fault::slow_estop) && before.moving() && !d.axis().moving() && !d.axis().in_position()) {
      // Stopped at once by this write: decelerate from where it was instead.
      double v = std::abs(before.speed());
      d.axis() = before;
      d.axis().stop(v > 0 ? v / kSlowEstopSeconds : 1);
      inner_->advance(d, 0);  // the behaviour publishes its status registers
    }
    if (faults_.has(Fault::homing_gate_open)) open_homing_gate(d, address, count);
    if (faults_.has(Fault::keep_volatile)) remember_volatile(d);
  }

  void before_read(ref::Device& d, uint16_t address, uint16_t count) override { inner_->before_read(d, address, count); }

  void advance(ref::Device& d, uint64_t dt_us) override {
    bool was_moving = d.axis().moving();
    if (faults_.has(Fault::overspeed) && was_moving) dt_us = uint64_t(double(dt_us) * kOverspeedFactor);
    inner_->advance(d, dt_us);
    if (faults_.has(Fault::overshoot) && was_moving && d.axis().in_position()) {
      d.axis().set_position(d.axis().position() + kOvershootPulses);
      inner_->advance(d, 0);
    }
    if (faults_.has(Fault::creep)) {
      if (was_moving && !d.axis().moving()) {
        creep_left_ = kCreepSteps;
      } else if (!d.axis().moving() && creep_left_ > 0 && dt_us > 0) {
        --creep_left_;
        d.axis().set_position(d.axis().position() + 1);
        inner_->advance(d, 0);
      }
    }
  }

  bool trip_fault(ref::Device& d) override { return inner_->trip_fault(d); }

  void power_on(ref::Device& d) override {
    if (faults_.has(Fault::forget_persistent)) {
      // The engine restored the stored image; this device lost it.
      for (const auto& r : d.spec().registers)
        if (r.table == Table::holding && r.persistence.store != spec::Store::none)
          d.set_value(r, r.default_value ? (r.type == spec::DataType::f32
                                                 ? int64_t(std::bit_cast<uint32_t>(float(*r.default_value)))
                                                 : int64_t(*r.default_value))
                                          : 0);
      d.load_stored_image({});
    }
    if (faults_.has(Fault::keep_volatile))
      for (const auto& [address, word] : volatile_) d.set_word(address, word);
    inner_->power_on(d);
  }

 private:
  void remember_volatile(const ref::Device& d) {
    volatile_.clear();
    for (const auto& r : d.spec().registers)
      if (r.table == Table::holding && r.access == Access::rw && r.persistence.store == spec::Store::none)
        for (int i = 0; i < r.words; ++i) volatile_.emplace_back(uint16_t(r.address + i), d.word(uint16_t(r.address + i)));
  }

  // 7TRSM5740Q §5.2 refuses 2002 before a homing; this one runs the same
  // distance as a forward/reverse move (2004/2006), which needs no homing.
  void open_homing_gate(ref::Device& d, uint16_t address, uint16_t count) {
    const spec::Register* pos = d.find_by_key("position_command");
    const spec::Register* now = d.find_by_key("current_position");
    const spec::Register* fwd = d.find_by_key("forward_command");
    const spec::Register* rev = d.find_by_key("reverse_command");
    if (!pos || !now || !fwd || !rev || d.axis().moving()) return;
    if (!(pos->address >= address && pos->last_address() < uint32_t(address) + count)) return;
    int64_t delta = d.value(*pos) - d.value(*now);
    if (delta == 0) return;
    const spec::Register& cmd = delta > 0 ? *fwd : *rev;
    int64_t kept = d.value(cmd);
    d.set_value(cmd, std::llabs(delta));
    inner_->on_write(d, cmd.address, uint16_t(cmd.words));
    d.set_value(cmd, kept);
  }

  std::unique_ptr<ref::Behaviour> inner_;
  FaultSet faults_;
  std::vector<std::pair<uint16_t, uint16_t>> volatile_;
  int creep_left_ = 0;
};

}  // namespace

FaultyBus::FaultyBus(ref::Bus bus, FaultSet faults) : faults_(faults) {
  if (!device_level(faults)) {
    bus_ = std::move(bus);
    return;
  }
  for (auto& d : bus.devices()) {
    std::shared_ptr<const ref::ControlTweak> tweak;
    if (control_level(faults) && d->spec().control && !d->spec().control->states.empty()) tweak = std::make_shared<ControlFaults>(faults, *d->spec().control);
    auto behaviour = std::make_unique<FaultyBehaviour>(ref::make_behaviour(d->spec(), tweak), faults);
    auto nd = std::make_unique<ref::Device>(d->spec(), d->slave_id(), std::move(behaviour));
    nd->load_stored_image(d->stored_image());
    nd->power_cycle();
    bus_.add(std::move(nd));
  }
}

std::optional<Bytes> FaultyBus::device_pdu(ref::Device& d, std::span<const uint8_t> pdu_in, bool broadcast) {
  if (!pdu_level(faults_) || pdu_in.empty()) return d.handle_pdu(pdu_in, broadcast);
  Bytes pdu(pdu_in.begin(), pdu_in.end());
  const uint8_t fc = pdu[0];
  // silent-unstated-reads, refuse-reserved: reads a drive leaves unanswered
  // or refuses where the manual does not say it answers them.
  if ((faults_.has(Fault::silent_unstated_reads) || faults_.has(Fault::refuse_reserved)) && (fc == 3 || fc == 4) &&
      pdu.size() == 5) {
    const Table t = fc == 4 ? Table::input : Table::holding;
    for (uint32_t a = be16(pdu, 1); a < uint32_t(be16(pdu, 1)) + be16(pdu, 3) && a <= 0xFFFF; ++a)
      if (const spec::Register* r = d.spec().register_covering(uint16_t(a), t)) {
        if (faults_.has(Fault::silent_unstated_reads) && r->basis_of(spec::Fact::read).basis != spec::Basis::stated)
          return std::nullopt;
        if (faults_.has(Fault::refuse_reserved) && r->name.en == "reserved") return Bytes{uint8_t(fc | 0x80), 0x02};
      }
  }
  // read-before-write: the FC 23 reply carries the read range as it was
  // before the write (the register image taken first), not after it.
  if (faults_.has(Fault::read_before_write) && fc == 23 && pdu.size() >= 5) {
    const uint16_t start = be16(pdu, 1), count = be16(pdu, 3);
    Bytes before;
    for (uint32_t a = start; a < uint32_t(start) + count && a <= 0xFFFF; ++a) put_be16(before, d.word(uint16_t(a)));
    auto reply = d.handle_pdu(pdu, broadcast);
    if (reply && reply->size() == 2 + before.size() && (*reply)[0] == 23)
      std::copy(before.begin(), before.end(), reply->begin() + 2);
    return reply;
  }
  const bool read_words = (fc == 3 || fc == 4) && pdu.size() == 5;
  // silent-command-reads: no reply at all to a read that reaches a command register.
  if (faults_.has(Fault::silent_command_reads) && read_words)
    for (uint32_t a = be16(pdu, 1); a < uint32_t(be16(pdu, 1)) + be16(pdu, 3) && a <= 0xFFFF; ++a)
      if (const spec::Register* r = d.spec().register_covering(uint16_t(a), fc == 4 ? Table::input : Table::holding);
          r && r->access == Access::command)
        return std::nullopt;
  const bool write_words = (fc == 6 && pdu.size() == 5) || (fc == 16 && pdu.size() >= 6 && pdu.size() == size_t(6 + pdu[5]));
  uint16_t start = pdu.size() >= 3 ? be16(pdu, 1) : 0;
  uint16_t qty = fc == 6 ? 1 : pdu.size() >= 5 ? be16(pdu, 3) : 0;
  if (write_words && fc == 16 && pdu[5] != qty * 2) return d.handle_pdu(pdu, broadcast);
  const int limit = (read_words || fc == 16) ? quantity_limit(d, fc) : 0;
  const Table table = fc == 4 ? Table::input : Table::holding;

  // refuse-limit: the limit itself is treated as over it.
  if (faults_.has(Fault::refuse_limit) && (read_words || write_words) && fc != 6 && qty == limit) {
    Bytes over = pdu;
    set_be16(over, 3, uint16_t(limit + 1));
    if (fc == 16) {
      over.push_back(0), over.push_back(0);
      over[5] = uint8_t(over[5] + 2);
    }
    return d.handle_pdu(over, broadcast);
  }

  // off-by-one-limit: limit+1 is served as limit, plus one more word.
  if (faults_.has(Fault::off_by_one_limit) && (read_words || (write_words && fc == 16)) && qty == limit + 1) {
    Bytes part = pdu;
    set_be16(part, 3, uint16_t(limit));
    if (fc == 16) {
      part.resize(part.size() - 2);
      part[5] = uint8_t(limit * 2);
    }
    auto reply = d.handle_pdu(part, broadcast);
    if (!reply || reply->empty() || (*reply)[0] != fc) return reply;
    uint16_t extra = uint16_t(start + limit);
    if (fc == 16) {
      d.set_word(extra, be16(pdu, pdu.size() - 2));
      set_be16(*reply, 3, qty);
    } else {
      uint16_t w = table == Table::input ? d.input_word(extra) : d.word(extra);
      reply->push_back(uint8_t(w >> 8)), reply->push_back(uint8_t(w));
      (*reply)[1] = uint8_t((*reply)[1] + 2);
    }
    return reply;
  }

  // swapped-words: a 2-word register written whole lands in the other order.
  if (faults_.has(Fault::swapped_words) && write_words && fc == 16)
    for (uint16_t i = 0; i + 1 < qty; ++i) {
      const spec::Register* r = d.spec().find_register(uint16_t(start + i));
      if (r && r->words == 2) {
        std::swap(pdu[6 + 2 * i], pdu[6 + 2 * (i + 1)]);
        std::swap(pdu[7 + 2 * i], pdu[7 + 2 * (i + 1)]);
        ++i;
      }
    }

  std::vector<uint16_t> before;
  std::map<uint16_t, uint16_t> stored_before;
  if (write_words) {
    for (uint16_t i = 0; i < qty; ++i) before.push_back(d.word(uint16_t(start + i)));
    stored_before = d.stored_image();
  }

  auto reply = d.handle_pdu(pdu, broadcast);

  if (write_words && reply && !reply->empty()) {
    bool refused = (*reply)[0] & 0x80;
    if (refused && (faults_.has(Fault::accept_out_of_range) || faults_.has(Fault::accept_read_only))) {
      bool all_mapped = true, any_read_only = false;
      for (uint16_t i = 0; i < qty; ++i) {
        const spec::Register* r = d.spec().register_covering(uint16_t(start + i));
        if (!r) all_mapped = false;
        else if (r->access == Access::ro) any_read_only = true;
      }
      bool accept = all_mapped && (any_read_only ? faults_.has(Fault::accept_read_only) : faults_.has(Fault::accept_out_of_range));
      if (accept) {
        for (uint16_t i = 0; i < qty; ++i) d.set_word(uint16_t(start + i), be16(pdu, fc == 6 ? 3 : 6 + 2 * i));
        reply = fc == 6 ? Bytes(pdu.begin(), pdu.end()) : Bytes(pdu.begin(), pdu.begin() + 5);
      }
    } else if (!refused && faults_.has(Fault::lost_write)) {
      for (uint16_t i = 0; i < qty; ++i) d.set_word(uint16_t(start + i), before[i]);
      d.load_stored_image(stored_before);
    }
  }

  if (reply && !reply->empty()) {
    Bytes& r = *reply;
    if (faults_.has(Fault::wrong_exception_code) && (r[0] & 0x80) && r.size() == 2)
      r[1] = uint8_t(r[1] >= 1 && r[1] <= 4 ? r[1] % 4 + 1 : r[1] + 1);
    if (faults_.has(Fault::wrong_byte_count) && !(r[0] & 0x80) && r.size() >= 2 &&
        (r[0] == 1 || r[0] == 2 || r[0] == 3 || r[0] == 4 || r[0] == 23))
      r[1] = uint8_t(r[1] + 2);
  }
  return reply;
}

std::optional<Bytes> FaultyBus::handle_rtu(std::span<const uint8_t> adu) {
  if (faults_.empty()) return bus_.handle_rtu(adu);
  if (adu.size() < 4 || adu.size() > kMaxRtuAdu || bus_.devices().empty()) return bus_.handle_rtu(adu);
  Bytes frame(adu.begin(), adu.end());
  const uint8_t address = frame[0];
  const bool crc_good = crc_ok(frame);
  ref::Device* d = address ? bus_.find(address) : nullptr;

  if (!crc_good) {
    if (!faults_.has(Fault::accept_bad_crc) || (!d && address != 0)) return bus_.handle_rtu(adu);
    frame.resize(frame.size() - 2);
    frame = with_crc(std::move(frame));
  }
  std::span<const uint8_t> pdu = kRtu.pdu_bytes(frame);

  if (address == 0) {
    if (faults_.has(Fault::ignore_broadcast)) return std::nullopt;
    if (!faults_.has(Fault::answer_broadcast)) {
      if (!pdu_level(faults_)) return bus_.handle_rtu(frame);
      for (auto& dev : bus_.devices()) device_pdu(*dev, pdu, true);
      return std::nullopt;
    }
    // Acts as if addressed individually, and answers from address 0.
    std::optional<Bytes> reply;
    for (auto& dev : bus_.devices()) {
      auto r = device_pdu(*dev, pdu, false);
      if (!reply) reply = r;
    }
    if (!reply) return std::nullopt;
    Bytes out = rtu_frame(0, *reply);
    if (faults_.has(Fault::bad_reply_crc)) out.back() ^= 0xFF;
    return out;
  }

  if (!d && faults_.has(Fault::reply_other_slave)) d = bus_.devices().front().get();
  if (!d) return std::nullopt;
  std::optional<Bytes> reply;
  if (pdu_level(faults_) || address != d->slave_id()) {
    reply = device_pdu(*d, pdu, false);
    if (!reply) return std::nullopt;
    reply = rtu_frame(address, *reply);
  } else {
    frame[0] = d->slave_id();
    reply = d->handle_rtu(with_crc(Bytes(frame.begin(), frame.end() - 2)));
  }
  if (reply && faults_.has(Fault::bad_reply_crc)) reply->back() ^= 0xFF;
  return reply;
}

std::optional<Bytes> FaultyBus::handle_pdu(uint8_t unit, std::span<const uint8_t> pdu) {
  if (faults_.empty() || bus_.devices().empty()) return bus_.handle_pdu(unit, pdu);
  if (ref::Device* d = bus_.direct(unit)) return device_pdu(*d, pdu, false);
  if (unit == 0) {
    if (faults_.has(Fault::ignore_broadcast)) return std::nullopt;
    if (faults_.has(Fault::answer_broadcast)) {
      std::optional<Bytes> reply;
      for (auto& dev : bus_.devices()) {
        auto r = device_pdu(*dev, pdu, false);
        if (!reply) reply = r;
      }
      return reply;
    }
    for (auto& dev : bus_.devices()) device_pdu(*dev, pdu, true);
    return std::nullopt;
  }
  ref::Device* d = bus_.find(unit);
  if (!d && faults_.has(Fault::reply_other_slave)) d = bus_.devices().front().get();
  if (!d) return std::nullopt;
  return device_pdu(*d, pdu, false);
}

namespace {

size_t copy_reply(const std::optional<Bytes>& r, std::span<uint8_t> out) {
  if (!r) return 0;
  if (r->size() > out.size()) throw std::length_error("FaultyBus: the reply buffer is shorter than the reply");
  std::copy(r->begin(), r->end(), out.begin());
  return r->size();
}

}  // namespace

size_t FaultyBus::handle_rtu_into(std::span<const uint8_t> adu, std::span<uint8_t> reply) {
  if (faults_.empty()) return bus_.handle_rtu_into(adu, reply);
  return copy_reply(handle_rtu(adu), reply);
}

size_t FaultyBus::handle_pdu_into(uint8_t unit, std::span<const uint8_t> pdu, std::span<uint8_t> reply) {
  if (faults_.empty()) return bus_.handle_pdu_into(unit, pdu, reply);
  return copy_reply(handle_pdu(unit, pdu), reply);
}

}  // namespace mbc::faults
