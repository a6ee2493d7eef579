#include "policy/policy.h"

#include <fmt/core.h>
#include <fmt/ranges.h>

#include <algorithm>
#include <set>

#include "modbus/crc16.h"
#include "modbus/function_codes.h"
#include "modbus/pdu.h"
#include "modbus/rtu.h"

namespace mbc::conf {
namespace {

using spec::Register;
using spec::Role;
using spec::Table;

uint16_t be16(std::span<const uint8_t> p, size_t at) { return uint16_t(p[at] << 8 | p[at + 1]); }

// The quantity limits of the writes (MBAP v1.1b3 §6.11, §6.12, §6.17): a
// request claiming more is refused by a conforming server; the range kept
// covers the most a server could take from it. A quantity cut off (a frame
// a receiver completes with the bytes after it) is taken as the most.
constexpr int kMaxWriteRegisters = 123, kMaxWriteCoils = 1968, kMaxReadWriteRegisters = 121;

Refusal refuse(std::string reason, std::string opt_in) {
  reason += opt_in.empty() ? ": never sent to a live target" : ": needs " + opt_in;
  return Refusal{std::move(reason), std::move(opt_in)};
}
Decision no(std::string reason, std::string opt_in) { return Decision{refuse(std::move(reason), std::move(opt_in))}; }

std::string label(const Register& r) {
  const std::string& n = r.name.en.empty() ? r.name.zh : r.name.en;
  return fmt::format("{} 0x{:04X}{}{}", r.table == Table::coil ? "coil" : "register", r.address, n.empty() ? "" : " ", n);
}

// ---- by function code -------------------------------------------------------

// MB-SL v1.02 §6.1 (MBAP v1.1b3 §6.8.1): the sub-functions of FC 08 that
// change the server's state rather than return something: 01 Restart
// Communications Option (a restart, the event log cleared), 03 Change ASCII
// Input Delimiter, 04 Force Listen Only Mode (the drive answers nothing more
// until 08/01 or a power cycle), 0A Clear Counters and Diagnostic Register,
// 14 Clear Overrun Counter and Flag.
bool diagnostic_changes_state(uint16_t sub) { return sub == 0x01 || sub == 0x03 || sub == 0x04 || sub == 0x0A || sub == 0x14; }

// MBAP v1.1b3 §5 (Figure 10): 65-72 and 100-110 are user-defined function
// codes: what a drive does with one is its vendor's.
bool user_defined(uint8_t fc) { return (fc >= 65 && fc <= 72) || (fc >= 100 && fc <= 110); }

// Why a request of this function code changes what the spec does not state,
// or empty. Reads of the four tables (FC 01-04, MBAP v1.1b3 §6.1-§6.4)
// change nothing whatever the profile lists: the probe of a map sends them.
std::string disruptive(const spec::Spec* s, std::span<const uint8_t> pdu) {
  const uint8_t fc = pdu[0];
  if (user_defined(fc)) return fmt::format("FC {} is a user-defined function code (MBAP v1.1b3 §5): what it does is the vendor's", fc);
  if (fc == fc::write_file_record)
    return "FC 21 Write File Record writes the drive's file records, which no journal keeps (MBAP v1.1b3 §6.15)";
  if (fc >= 1 && fc <= 4) return "";
  const spec::FunctionCode* f = s ? s->profile.function(fc) : nullptr;
  if (!f)
    return fmt::format("FC {:02X} is not in the {} profile: what the drive does with it is not stated", fc,
                       s ? "spec's" : "(absent) spec's");
  if (fc == fc::diagnostics && pdu.size() >= 3) {
    const uint16_t sub = be16(pdu, 1);
    if (diagnostic_changes_state(sub))
      return fmt::format("FC 08/{:02X} changes the drive's line state (MB-SL v1.02 §6.1: {})", sub,
                         sub == 0x01   ? "restart communications"
                         : sub == 0x03 ? "change the ASCII delimiter"
                         : sub == 0x04 ? "listen only: the drive answers nothing more"
                                       : "clears counters");
    if (!f->subfunctions.empty() && std::find(f->subfunctions.begin(), f->subfunctions.end(), int(sub)) == f->subfunctions.end())
      return fmt::format("FC 08/{:04X} is a sub-function the spec's profile does not list: what it does is not stated", sub);
  }
  if (fc == fc::encapsulated_interface && pdu.size() >= 2) {
    const uint8_t mei = pdu[1];
    // §6.20: MEI 0x0D carries CANopen requests, writes among them.
    if (mei != kMeiReadDeviceId && (f->mei_types.empty() || std::find(f->mei_types.begin(), f->mei_types.end(), int(mei)) == f->mei_types.end()))
      return fmt::format("FC 43 MEI type {:02X} is not one the spec's profile lists: what it does is not stated", mei);
  }
  return "";
}

// ---- by register --------------------------------------------------------------

bool is_persist_switch(const spec::Spec& s, const Register& r) {
  if (r.table != Table::holding) return false;
  for (const auto& other : s.registers)
    if (other.persistence.unless_register && *other.persistence.unless_register >= r.address &&
        *other.persistence.unless_register <= r.last_address())
      return true;
  return false;
}

bool is_command(const Register& r) { return r.access == spec::Access::command || r.command; }

// Why the spec's facts about `r` are a claim rather than a manual's, or empty.
std::string claim(const spec::Spec& s, const Register& r) {
  if (!from_manual(s)) return fmt::format("the spec's facts come from {} (device.manual.source), not a manual", s.device.manual.source);
  for (spec::Fact f : {spec::Fact::write, spec::Fact::read}) {
    spec::FactBasis b = r.basis_of(f);
    if (b.is_inferred())
      return fmt::format("its {} access is {}, not stated ({})", f == spec::Fact::write ? "write" : "read", spec::to_string(b.basis),
                         b.why.size() > 80 ? b.why.substr(0, 77) + "..." : b.why);
  }
  return "";
}

const char* role_words(Role r) {
  switch (r) {
    case Role::slave_address: return "slave address";
    case Role::baud: return "baud rate";
    case Role::parity: return "parity";
    case Role::frame_format: return "frame format";
    case Role::motion: return "motion";
    case Role::save: return "save to EEPROM";
    case Role::factory_reset: return "factory reset";
    case Role::none: break;
  }
  return "none";
}

// The rules for one register a write reaches; nullopt when it may be written.
std::optional<Refusal> register_refusal(const PolicyFacts& p, const Register& r, uint8_t fc) {
  const spec::Spec& s = *p.spec;
  const WritePolicy& o = p.opt_ins;
  const std::string at = fmt::format("FC {:02X} to {}", fc, label(r));
  const Role role = role_of(s, r);
  // A line setting cuts the command off from the drive (at once or at the
  // next power-on, when the journal's restore could no longer reach it).
  if (spec::is_line_setting(role))
    return refuse(fmt::format("{}: sets the {}: a drive that takes it leaves the line, and no restore reaches it", at, role_words(role)), "");
  // The "do not persist" switch is held on by the session while it writes
  // (session/session.h); turned off, every later write would wear EEPROM.
  if (is_persist_switch(s, r))
    return refuse(fmt::format("{}: the \"do not persist\" switch, held on while the command writes", at), "");
  if ((is_command(r) || role == Role::motion) && !o.allow_motion)
    return refuse(fmt::format("{}: {}", at, r.command && r.command->motion ? "motion command register"
                                            : is_command(r)                 ? "command register"
                                                                            : "a motion register by its name"),
                  "--allow-motion");
  if ((r.command && r.command->eeprom) && !o.allow_eeprom_writes)
    return refuse(fmt::format("{}: the command stores to EEPROM", at), "--allow-eeprom-writes");
  if ((role == Role::save || role == Role::factory_reset) && !o.allow_eeprom_writes)
    return refuse(fmt::format("{}: {} register", at, role_words(role)), "--allow-eeprom-writes");
  const auto& ps = r.persistence;
  if (ps.store != spec::Store::none && ps.by == spec::PersistBy::on_write && !ps.unless_register && !o.allow_eeprom_writes)
    return refuse(fmt::format("{}: stored to {} on every write", at, ps.store == spec::Store::flash ? "flash" : "EEPROM"),
                  "--allow-eeprom-writes");
  if (!o.allow_writes)
    if (std::string why = claim(s, r); !why.empty()) return refuse(fmt::format("{}: {}", at, why), "--allow-writes");
  return std::nullopt;
}

// A write to an address no register of the spec covers: what the drive does
// there is stated only by the spec's exception policy (hsc60 四 1.4: "客户请不
// 要操作其他寄存器", other addresses may be live test registers).
std::optional<Refusal> unmapped_refusal(const PolicyFacts& p, Table t, uint16_t address, uint8_t fc) {
  if (p.opt_ins.allow_writes) return std::nullopt;
  const spec::Spec& s = *p.spec;
  const std::string at = fmt::format("FC {:02X} to {} 0x{:04X}", fc, t == Table::coil ? "coil" : "register", address);
  if (!from_manual(s))
    return refuse(fmt::format("{}: the spec's facts come from {} (device.manual.source), not a manual", at, s.device.manual.source),
                  "--allow-writes");
  auto last = s.last_address(t);
  const spec::Violation v = !last || address > *last ? spec::Violation::address_past_map : spec::Violation::unmapped_address;
  const spec::PolicyEntry e = s.profile.policy(v);
  if (e.kind == spec::PolicyEntry::Kind::unspecified || e.basis.basis != spec::Basis::stated)
    return refuse(fmt::format("{}: no register of the spec is there, and its exception policy does not state what the drive "
                              "does with a write there ({} is {})", at, spec::to_string(v),
                              e.kind == spec::PolicyEntry::Kind::unspecified ? "unspecified" : spec::to_string(e.basis.basis)),
                  "--allow-writes");
  return std::nullopt;
}

// One frame a receiver may take; `cut`: its PDU is shorter than its header says
// (MBAP), so the receiver completes it with whatever comes next.
struct Taken {
  uint8_t unit;
  Bytes pdu;
  bool cut = false;
};

std::vector<Taken> taken_from(Framing framing, std::span<const uint8_t> bytes, std::optional<size_t> gap_after) {
  std::vector<Taken> out;
  // Bounded: a receiver takes at most a frame per byte.
  const size_t most = bytes.size() + 4;
  auto scan_mbap = [&](std::span<const uint8_t> b) {
    // Every ADU by its length field (MBAP v1.1b3 §4.1), one after another.
    size_t at = 0;
    while (at + 7 <= b.size() && out.size() < most) {
      const size_t len = be16(b, at + 4);
      const size_t end = at + 6 + std::max<size_t>(len, 1);
      const size_t have = std::min(end, b.size());
      if (have > at + 7) out.push_back({b[at + 6], Bytes(b.begin() + long(at + 7), b.begin() + long(have)), have < end});
      at = end;
    }
  };
  auto scan_rtu = [&](std::span<const uint8_t> b) {
    // Every prefix whose CRC holds is a frame to a receiver that frames by
    // length; after it, the rest is read again as the next frame.
    std::vector<size_t> starts{0};
    std::set<size_t> seen{0};
    for (size_t k = 0; k < starts.size() && out.size() < most; ++k) {
      const size_t s = starts[k];
      for (size_t n = 4; s + n <= b.size() && out.size() < most; ++n) {
        auto f = b.subspan(s, n);
        if (!crc_ok(f)) continue;
        auto pdu = mbc::kRtu.pdu_bytes(f);
        out.push_back({f[0], Bytes(pdu.begin(), pdu.end()), false});
        if (seen.insert(s + n).second && s + n < b.size()) starts.push_back(s + n);
      }
    }
  };
  auto scan = [&](std::span<const uint8_t> b) { framing == &mbc::kTcp ? scan_mbap(b) : scan_rtu(b); };
  scan(bytes);
  if (gap_after && *gap_after > 0 && *gap_after < bytes.size()) {
    scan(bytes.first(*gap_after));
    scan(bytes.subspan(*gap_after));
  }
  return out;
}

// Whether a cut-off PDU still says everything it writes.
bool write_whole(std::span<const uint8_t> pdu) {
  switch (pdu[0]) {
    case 0x05: case 0x06: return pdu.size() >= 3;
    case 0x0F: case 0x10: return pdu.size() >= 5;
    case 0x16: return pdu.size() >= 3;
    case 0x17: return pdu.size() >= 9;
    default: return true;
  }
}

}  // namespace

bool from_manual(const spec::Spec& s) { return s.device.manual.source == "manual"; }

spec::Role role_of(const spec::Spec& s, const Register& r) {
  if (r.table == Table::holding)
    for (const auto& st : s.serial.settings)
      if (st.register_address >= r.address && st.register_address <= r.last_address()) {
        if (st.setting == "baud_rate") return Role::baud;
        if (st.setting == "slave_id") return Role::slave_address;
        if (st.setting == "parity") return Role::parity;
        return Role::frame_format;
      }
  const auto& ops = s.operations;
  if (ops.factory_reset && ops.factory_reset->key == r.key) return Role::factory_reset;
  if (ops.save && ops.save->key == r.key) return Role::save;
  if (s.control && s.control->motion) {
    const auto& m = *s.control->motion;
    for (const auto* w : {&m.start_forward, &m.start_reverse, &m.stop, &m.emergency_stop})
      if (*w && (*w)->key == r.key) return Role::motion;
    if (!m.position_command_key.empty() && m.position_command_key == r.key) return Role::motion;
    // No start write: the distance write starts the move.
    if (!m.start_forward && !m.distance_key.empty() && (m.distance_key == r.key || m.reverse_distance_key == r.key))
      return Role::motion;
  }
  if (r.command) return r.command->motion ? Role::motion : r.command->eeprom ? Role::save : Role::motion;
  if (r.access == spec::Access::command) return Role::motion;
  // A spec no manual states: its names are all there is to go by (a sheet's
  // row "运行命令" marked rw is still a motion command).
  if (!from_manual(s)) return spec::role_of_name(r.name.en, r.name.zh).role;
  return Role::none;
}

std::optional<WriteRange> writes_of(std::span<const uint8_t> pdu) {
  if (pdu.size() < 3) return std::nullopt;
  const uint16_t address = be16(pdu, 1);
  auto quantity = [&](int most) {
    if (pdu.size() < 5) return most;  // cut off: as many as a receiver could take
    return std::clamp(int(be16(pdu, 3)), 1, most);
  };
  switch (pdu[0]) {
    case 0x05: return WriteRange{Table::coil, address, 1};
    case 0x06: return WriteRange{Table::holding, address, 1};
    case 0x0F: return WriteRange{Table::coil, address, quantity(kMaxWriteCoils)};
    case 0x10: return WriteRange{Table::holding, address, quantity(kMaxWriteRegisters)};
    case 0x16: return WriteRange{Table::holding, address, 1};
    case 0x17:  // read/write multiple: the write part follows the read's address and quantity (§6.17)
      if (pdu.size() < 7) return std::nullopt;
      return WriteRange{Table::holding, be16(pdu, 5),
                        pdu.size() >= 9 ? std::clamp(int(be16(pdu, 7)), 1, kMaxReadWriteRegisters) : kMaxReadWriteRegisters};
    default: return std::nullopt;
  }
}

std::vector<std::pair<uint8_t, Bytes>> frames_in(Framing framing, std::span<const uint8_t> bytes, std::optional<size_t> gap_after) {
  std::vector<std::pair<uint8_t, Bytes>> out;
  for (auto& t : taken_from(framing, bytes, gap_after)) out.emplace_back(t.unit, std::move(t.pdu));
  return out;
}

std::set<uint16_t> control_setpoints(const spec::Spec& s) {
  std::set<uint16_t> out;
  if (!s.control) return out;
  auto add = [&](const std::vector<std::string>& keys) {
    for (const auto& key : keys)
      if (const Register* r = s.find_by_key(key))
        for (int k = 0; k < r->words; ++k) out.insert(uint16_t(r->address + k));
  };
  for (const auto& mode : s.control->modes) add(mode.setpoint_keys);
  for (const auto& cmd : s.control->commands)
    if (cmd.setpoint_keys) add(*cmd.setpoint_keys);
  return out;
}

void note_zeroed(const spec::Spec& s, std::span<const uint8_t> pdu, std::set<uint16_t>& zeroed) {
  if (!s.control || pdu.size() < 5 || (pdu[0] != 0x06 && pdu[0] != 0x10)) return;
  const std::set<uint16_t> setpoints = control_setpoints(s);
  const uint16_t start = be16(pdu, 1);
  const uint16_t qty = pdu[0] == 0x06 ? 1 : be16(pdu, 3);
  for (uint16_t k = 0; k < qty; ++k) {
    const size_t at = pdu[0] == 0x06 ? 3 : size_t(6 + 2 * k);
    if (at + 1 >= pdu.size() || !setpoints.count(uint16_t(start + k))) continue;
    if ((pdu[at] | pdu[at + 1]) == 0) zeroed.insert(uint16_t(start + k));
    else zeroed.erase(uint16_t(start + k));
  }
}

std::string control_motion(const PolicyFacts& p, std::span<const uint8_t> pdu) {
  if (!p.spec || !p.spec->control || pdu.empty()) return "";
  const spec::Spec& s = *p.spec;
  const spec::Control& c = *s.control;
  // The words a write puts where (FC 06, 16); another writer of holding registers is judged by its range alone.
  std::vector<std::pair<uint16_t, std::optional<uint16_t>>> words;
  if (pdu[0] == 0x06 && pdu.size() >= 5) {
    words.emplace_back(be16(pdu, 1), be16(pdu, 3));
  } else if (pdu[0] == 0x10 && pdu.size() >= 6) {
    const uint16_t start = be16(pdu, 1), qty = be16(pdu, 3);
    for (uint16_t k = 0; k < qty && size_t(6 + 2 * k + 1) < pdu.size(); ++k) words.emplace_back(uint16_t(start + k), be16(pdu, 6 + 2 * k));
  } else if (auto w = writes_of(pdu); w && w->table == Table::holding) {
    for (int k = 0; k < w->count && w->address + k <= 0xFFFF; ++k) words.emplace_back(uint16_t(w->address + k), std::nullopt);
  }
  const std::set<uint16_t> setpoints = control_setpoints(s);
  // A mode with no start command follows its set-points at once (CiA 402
  // profile velocity): a non-zero one moves. A mode with one moves on its start.
  std::set<uint16_t> followed;
  for (const auto& mode : c.modes)
    if (mode.start_command.empty())
      for (const auto& key : mode.setpoint_keys)
        if (const Register* r = s.find_by_key(key))
          for (int k = 0; k < r->words; ++k) followed.insert(uint16_t(r->address + k));
  const bool all_zero = std::all_of(setpoints.begin(), setpoints.end(), [&](uint16_t a) { return p.zeroed.count(a) > 0; });
  // A command that states its own set-points moves by those (spec control.commands
  // setpoints); one whose speed the manual leaves unsaid (setpoints: []) by none the run can make 0.
  auto zeroed_for = [&](const spec::ControlCommand& cmd) {
    if (!cmd.setpoint_keys) return all_zero;
    if (cmd.setpoint_keys->empty()) return false;
    for (const auto& key : *cmd.setpoint_keys) {
      const Register* r = s.find_by_key(key);
      if (!r) return false;
      for (int k = 0; k < r->words; ++k)
        if (!p.zeroed.count(uint16_t(r->address + k))) return false;
    }
    return true;
  };
  std::set<std::string> starts;
  for (const auto& mode : c.modes)
    if (!mode.start_command.empty()) starts.insert(mode.start_command);
  for (const auto& [address, word] : words) {
    const Register* r = s.register_covering(address);
    if (!r) continue;
    if (followed.count(address) && (!word || *word != 0))
      return fmt::format("FC {:02X} to {}: a non-zero set-point of the drive's control (spec control.modes)", pdu[0], label(*r));
    for (const auto& cmd : c.commands) {
      if (cmd.register_key != r->key) continue;
      if (word && (!cmd.selected_by(*word) || (cmd.trigger == spec::Trigger::edge && !(*word & cmd.edge_mask)))) continue;
      const std::string given = word ? fmt::format("0x{:04X} gives {}", *word, cmd.id) : fmt::format("may give {}", cmd.id);
      if (starts.count(cmd.id))
        return fmt::format("FC {:02X} to {}: {}, which starts a mode's motion (spec control.modes)", pdu[0], label(*r), given);
      if (cmd.motion && !zeroed_for(cmd))
        return fmt::format("FC {:02X} to {}: {}, a command that may move the axis (spec control.commands {}), and {}", pdu[0],
                           label(*r), given, cmd.section,
                           !cmd.setpoint_keys ? std::string("the set-points were not written 0 first")
                           : cmd.setpoint_keys->empty()
                               ? std::string("the manual does not say what sets its speed")
                               : fmt::format("its set-points ({}) were not written 0 first", fmt::join(*cmd.setpoint_keys, ", ")));
    }
  }
  return "";
}

Decision allowed(const PolicyFacts& p, uint8_t unit, std::span<const uint8_t> pdu) {
  if (!p.target.live || pdu.empty()) return {};
  const uint8_t fc = pdu[0];
  const auto w = writes_of(pdu);
  const std::string disrupts = disruptive(p.spec, pdu);
  const bool changes = w || !disrupts.empty();
  if (unit != 0 && unit != p.target.unit) {
    // Reads may go to another unit (a frame for another slave must stay
    // unanswered); nothing that changes a drive does: it could not be restored.
    if (!changes) return {};
    return no(fmt::format("FC {:02X} to unit {}: {} a drive other than the target's unit {}, which nothing could put back", fc, unit,
                          w ? "a write to" : "a request that changes", p.target.unit),
              "");
  }
  // MB-SL v1.02 §2.1: unit 0 reaches every drive on the line, and only the
  // addressed one can be restored; a tcp:// target may be a gateway that
  // forwards it as a broadcast. Reads are not executed in broadcast (§6.1.2).
  if (unit == 0 && !(fc >= 1 && fc <= 4) && !p.opt_ins.allow_broadcast)
    return no(fmt::format("FC {:02X} to unit 0: a broadcast reaches every drive on the line, and only unit {} can be restored", fc,
                          p.target.unit),
              "--allow-broadcast");
  if (!disrupts.empty() && !p.opt_ins.allow_disruptive) return no(disrupts, "--allow-disruptive");
  if (!w) return {};
  if (!p.spec) return no(fmt::format("FC {:02X}: no spec says what may be written on this target", fc), "");
  std::set<const Register*> seen;
  for (int k = 0; k < w->count; ++k) {
    const uint32_t a = uint32_t(w->address) + uint32_t(k);
    if (a > 0xFFFF) break;
    const Register* r = p.spec->register_covering(uint16_t(a), w->table);
    if (!r) {
      if (auto why = unmapped_refusal(p, w->table, uint16_t(a), fc)) return Decision{std::move(why)};
      continue;
    }
    if (!seen.insert(r).second) continue;
    if (auto why = register_refusal(p, *r, fc)) return Decision{std::move(why)};
  }
  // The drive's control (spec control:): a word that may move the axis.
  if (!p.opt_ins.allow_motion)
    if (std::string why = control_motion(p, pdu); !why.empty()) return no(why, "--allow-motion");
  return {};
}

Decision allowed_raw(const PolicyFacts& p, std::span<const uint8_t> bytes, std::optional<size_t> gap_after) {
  if (!p.target.live) return {};
  for (const auto& t : taken_from(p.target.framing, bytes, gap_after)) {
    if (t.cut && !t.pdu.empty() && is_write_function(t.pdu[0]) && !write_whole(t.pdu))
      return no(fmt::format("raw bytes: an MBAP ADU to unit {} cut off inside FC {:02X}: the receiver takes what it writes from "
                            "the bytes that come next", t.unit, t.pdu[0]),
                "");
    if (Decision d = allowed(p, t.unit, t.pdu); !d) {
      d.refused->reason = "raw bytes a receiver takes as a frame: " + d.refused->reason;
      return d;
    }
  }
  return {};
}

Decision allowed_write(const PolicyFacts& p, const Register& r) {
  const spec::Spec* s = p.spec;
  auto has = [&](int fc) { return s && s->profile.function(fc) != nullptr; };
  Bytes pdu;
  if (r.table == Table::holding) {
    std::vector<uint16_t> zeros(size_t(std::max(r.words, 1)), 0);
    pdu = r.words == 1 && (has(6) || !has(16)) ? write_single_register(r.address, 0) : write_multiple_registers(r.address, zeros);
  } else if (r.table == Table::coil) {
    bool off[1] = {false};
    pdu = has(5) || !has(15) ? write_single_coil(r.address, false) : write_multiple_coils(r.address, std::span<const bool>(off, 1));
  } else {
    return no(fmt::format("{}: no Modbus function writes {}", label(r), spec::to_string(r.table)), "");
  }
  return allowed(p, p.target.unit, pdu);
}

}  // namespace mbc::conf
