// The profile invariants, each stated once. Expected outcomes come from the
// spec (ranges, access, word order, exception policy, persistence) and the
// Modbus standard; none from the reference implementation.
#include <fmt/core.h>
#include <rapidcheck.h>

#include <algorithm>
#include <map>
#include <set>

#include "modbus/judge.h"
#include "modbus/rtu.h"
#include "properties/control.h"
#include "properties/generators.h"
#include "properties/motion.h"
#include "properties/properties.h"
#include "properties/stateful.h"

namespace mbc::conf::props {

using spec::Access;
using spec::Register;
using spec::Violation;

namespace {

[[noreturn]] void fail(const std::string& message) {
  RC_FAIL(message);
  throw std::logic_error("unreachable");
}

std::string reply_text(const Reply& r) {
  if (r.silent()) return "silence";
  if (!r.pdu) return fmt::format("{} ({})", to_hex(r.frame), r.framing_error);
  return fmt::format("{} ({})", to_hex(r.frame), describe_pdu(*r.pdu, false));
}

// A normal, well-formed reply to `req`, or the case fails saying what came.
Judged expect_normal(const Reply& rep, std::span<const uint8_t> req, const std::string& what) {
  if (rep.silent()) fail(what + ": no reply");
  if (!rep.pdu) fail(fmt::format("{}: bad reply frame {}: {}", what, to_hex(rep.frame), rep.framing_error));
  Judged j = judge_reply(req, *rep.pdu);
  if (j.kind == Judged::Kind::exception) fail(fmt::format("{}: refused with exception {:02X}", what, j.exception_code));
  if (!j.ok()) fail(fmt::format("{}: malformed reply {}: {}", what, to_hex(rep.frame), j.problems.front()));
  return j;
}

Image image_or_fail(Session& s, const char* when) {
  Image img = read_image(s.transact(), s.view());
  if (!img.error.empty()) fail(fmt::format("{}: {}", when, img.error));
  return img;
}

void expect_unchanged(const Image& before, const Image& after, const std::string& what) {
  auto diff = before.differences(after);
  if (diff.empty()) return;
  std::string list;
  for (const auto& d : diff) list += "\n    " + d;
  fail(fmt::format("{} changed the register image:{}", what, list));
}

uint32_t read_or_fail(Session& s, const Register& r, const std::string& what) {
  ReadResult rr = read_register(s.transact(), s.view(), r);
  if (!rr.raw) fail(fmt::format("{}: reading {}: {}", what, describe(r), rr.error));
  return *rr.raw;
}

std::string needs_writable(const SpecView& v, const TargetInfo&, const DeviceFacts*) {
  if (!v.supports(3)) return "the profile has no FC 03 to read back with";
  if (!v.supports(6) && !v.supports(16)) return "the profile has no register write (FC 06/16)";
  if (v.writable().empty()) return "no writable (rw) holding register may be written on this target";
  return "";
}

// ---- read-after-write ----------------------------------------------------

void read_after_write(Session& s) {
  const SpecView& v = s.view();
  const Register& r = pick_writable(v);
  uint32_t raw = pick_in_range(v, r);
  bool fc16 = pick_bool();
  Bytes req = v.write_request(r, raw, fc16);
  std::string what = fmt::format("write {} = 0x{:X} (FC {:02})", describe(r), raw, req[0]);
  expect_normal(s.send(req, what), req, what);
  uint32_t got = read_or_fail(s, r, what);
  if (got != raw)
    fail(fmt::format("{}: read back 0x{:X}{}", what, got,
                     r.words == 2 ? fmt::format(" (word order {})", spec::to_string(r.word_order)) : ""));
}

// ---- rejection changes nothing -----------------------------------------

void rejection_changes_nothing(Session& s) {
  const SpecView& v = s.view();
  auto kinds = rejection_kinds(v);
  Bad bad = kinds[pick<size_t>(0, kinds.size())]();
  // What the request breaks is the classifier's to say (cases/facts.h), not the generator's label.
  facts::Classified c = facts::classify(v.spec(), bad.pdu);
  if (c.valid()) RC_DISCARD(fmt::format("{}: the spec finds nothing wrong with it", bad.note));
  Expected want = refusal_of(c.breaches);
  Image before = image_or_fail(s, "before");
  Reply rep = s.send(bad.pdu, bad.note);
  if (!rep.silent() && !rep.pdu) fail(fmt::format("{}: bad reply frame: {}", bad.note, rep.framing_error));
  if (!want.allows(rep))
    fail(fmt::format("{} ({}): expected {} (policy {}), got {}", bad.note, spec::to_string(bad.violation), want.text(),
                     spec::to_string(c.breaches.front().violation), reply_text(rep)));
  expect_unchanged(before, image_or_fail(s, "after"), bad.note);
}

// ---- foreign and corrupted frames --------------------------------------

// Whether a reply to a frame for unit `to` is the target's (check/judge.h).
bool reply_is_targets(Session& s, uint8_t to, const Reply& rep) {
  check::JudgeContext ctx{s.unit(), s.target().info().framing, &s.spec(), {}};
  ctx.shared_line = s.target().info().live;
  return check::reply_is_targets(to, rep.frame, ctx);
}

void foreign_or_corrupt_ignored(Session& s) {
  const SpecView& v = s.view();
  bool corrupt = s.target().info().raw && pick_bool();
  // A valid frame to another slave is a read: a write would change a drive
  // on the line that nothing restores (the session's gate refuses it). A
  // write goes out only corrupted, which no receiver takes.
  Request req = !corrupt || pick_bool() || v.writable().empty() ? pick_valid_read(v) : pick_valid_write(v);
  Image before = image_or_fail(s, "before");
  if (corrupt) {
    Bytes frame = rtu_frame(s.unit(), req.pdu);
    size_t at = pick<size_t>(0, frame.size());
    uint8_t mask = pick<int>(1, 256);
    frame[at] ^= mask;
    // Any one corrupted byte fails the CRC (MB-SL v1.02 §2.5.1.2: CRC-16 catches every burst up to 16 bits).
    std::string note = fmt::format("{}, byte {} XOR {:02X}", req.note, at, mask);
    Reply rep = s.send_raw(frame, note);
    Expected want = frame[0] == s.unit() ? v.expected(Violation::crc_error) : Expected{Expected::Kind::silence, 0};
    if (!want.allows(rep) && reply_is_targets(s, frame[0], rep))
      fail(fmt::format("{}: expected {} (CRC error), got {}", note, want.text(), reply_text(rep)));
  } else {
    uint8_t other = uint8_t(pick<int>(1, 247));
    if (other >= s.unit()) ++other;  // 1..247 without the unit
    std::string note = fmt::format("{} to slave {}", req.note, other);
    Reply rep = s.send_to(other, req.pdu, note);
    // MB-SL v1.02 §2.2: only the addressed slave answers; on a multi-drop
    // line slave `other` may be there, and its reply is its own.
    if (!rep.silent() && reply_is_targets(s, other, rep))
      fail(fmt::format("{}: a frame for slave {} was answered{}: {}", note, other,
                       s.target().info().live ? fmt::format(" with the address of slave {}, the target", s.unit())
                                              : " (in process the target is alone on its line)",
                       to_hex(rep.frame)));
  }
  expect_unchanged(before, image_or_fail(s, "after"), req.note + (corrupt ? " (corrupted)" : " (other slave)"));
}

// ---- broadcast -----------------------------------------------------------

void broadcast_unanswered(Session& s) {
  const SpecView& v = s.view();
  const auto& serial = s.spec().serial;
  uint8_t bcast = uint8_t(*serial.broadcast_address);
  if (pick<int>(0, 4) == 0) {
    Request req = pick_valid_read(v);
    Reply rep = s.send_to(bcast, req.pdu, req.note + " (broadcast)");
    if (!rep.silent()) fail(fmt::format("broadcast {}: answered {} (MB-SL v1.02 §2.1: no reply)", req.note, to_hex(rep.frame)));
    return;
  }
  const Register& r = pick_writable(v);
  uint32_t old = read_or_fail(s, r, "before");
  uint32_t raw = pick_in_range(v, r);
  Bytes req = v.write_request(r, raw, pick_bool());
  std::string what = fmt::format("broadcast write {} = 0x{:X}", describe(r), raw);
  Reply rep = s.send_to(bcast, req, what);
  if (!rep.silent()) fail(fmt::format("{}: answered {} (MB-SL v1.02 §2.1: no reply to broadcast)", what, to_hex(rep.frame)));
  uint32_t got = read_or_fail(s, r, what);
  if (serial.broadcast_writes == "applied" && got != raw)
    fail(fmt::format("{}: read back 0x{:X}; the spec says broadcast writes are applied", what, got));
  if (serial.broadcast_writes == "ignored" && got != old)
    fail(fmt::format("{}: read back 0x{:X}; the spec says broadcast writes are ignored", what, got));
  if (got != raw && got != old) fail(fmt::format("{}: read back 0x{:X}, neither the old 0x{:X} nor the new value", what, got, old));
  // Every drive on the line took the write; the snapshot restores only the
  // target, so the value it held goes back out the same way.
  if (got != old) s.send_to(bcast, v.write_request(r, old), fmt::format("broadcast back {} = 0x{:X}", describe(r), old));
}

// ---- responses well formed ------------------------------------------------

void responses_well_formed(Session& s) {
  const SpecView& v = s.view();
  int choice = pick<int>(0, 10);
  Bytes pdu;
  std::string note;
  bool valid = false;
  if (choice < 4) {
    auto r = pick_valid_read(v);
    pdu = r.pdu, note = r.note, valid = true;
  } else if (choice < 7 && !v.writable().empty()) {
    auto r = pick_valid_write(v);
    pdu = r.pdu, note = r.note, valid = true;
  } else if (choice < 9) {
    auto kinds = rejection_kinds(v);
    Bad b = kinds[pick<size_t>(0, kinds.size())]();
    pdu = b.pdu, note = b.note;
  } else {
    // A short PDU of a supported function code with arbitrary bytes.
    std::vector<int> fcs;
    for (const auto& f : s.spec().profile.function_codes) fcs.push_back(f.code);
    pdu = {uint8_t(pick_of(fcs))};
    int n = pick<int>(0, 12);
    for (int i = 0; i < n; ++i) pdu.push_back(uint8_t(pick<int>(0, 256)));
    note = fmt::format("FC {:02} with {} arbitrary bytes", pdu[0], n);
  }
  Reply rep = s.send(pdu, note);
  if (rep.silent()) {
    if (valid) fail(note + ": a valid request got no reply");
    return;
  }
  // MB-SL v1.02 §2.5.1: CRC, the addressed slave, at most 256 bytes (decode_rtu_reply checks each).
  if (!rep.pdu) fail(fmt::format("{}: reply {}: {}", note, to_hex(rep.frame), rep.framing_error));
  Judged j = judge_reply(pdu, *rep.pdu);
  if (!j.problems.empty()) fail(fmt::format("{}: reply {}: {}", note, to_hex(rep.frame), j.problems.front()));
  if (valid && j.kind != Judged::Kind::normal)
    fail(fmt::format("{}: a valid request was refused: {}", note, reply_text(rep)));
}

// ---- persistence -----------------------------------------------------------

std::string needs_power_cycle(const SpecView& v, const TargetInfo& t, const DeviceFacts* f) {
  if (std::string w = needs_writable(v, t, f); !w.empty()) return w;
  if (!t.power_cycle) return "the target cannot be power-cycled";
  return "";
}

void write_command(Session& s, const CommandFact& c, const char* what) {
  const Register* r = s.spec().find_by_key(c.key);
  if (!r) fail(fmt::format("the spec's operations name register key '{}', which the spec does not have", c.key));
  Bytes req = s.view().write_request(*r, uint32_t(c.value));
  expect_normal(s.send(req, fmt::format("{}: {} = {} ({})", what, c.key, c.value, c.section)), req, what);
  if (c.settle_us) s.advance(c.settle_us);
}

void persistence(Session& s) {
  const SpecView& v = s.view();
  const DeviceFacts* facts = s.facts();
  std::map<uint16_t, uint32_t> initial, last;  // register address -> raw
  std::map<uint16_t, std::optional<uint32_t>> stored;  // what the store holds, per register, when known
  std::set<uint16_t> held_back;  // on_write registers whose last write the do-not-persist switch held back
  auto value_of = [&](const Register& r) -> uint32_t {
    if (auto it = last.find(r.address); it != last.end()) return it->second;
    if (!initial.count(r.address)) initial[r.address] = read_or_fail(s, r, "reading the value before the writes");
    return initial[r.address];
  };
  int n = pick<int>(1, 5);
  for (int i = 0; i < n; ++i) {
    const Register& r = pick_writable(v);
    if (r.persistence.store != spec::Store::none) (void)value_of(r);  // the stored value, as of power-on
    uint32_t raw = pick_in_range(v, r);
    Bytes req = v.write_request(r, raw);
    std::string what = fmt::format("write {} = 0x{:X}", describe(r), raw);
    // The "do not persist" switch, as it stands at the time of this write.
    bool suppressed = false;
    if (r.persistence.unless_register)
      if (const Register* u = s.spec().find_register(*r.persistence.unless_register))
        suppressed = int64_t(value_of(*u)) == r.persistence.unless_value;
    expect_normal(s.send(req, what), req, what);
    last[r.address] = raw;
    if (r.persistence.by == spec::PersistBy::on_write && !suppressed) stored[r.address] = raw, held_back.erase(r.address);
    if (r.persistence.by == spec::PersistBy::on_write && suppressed) held_back.insert(r.address);
  }
  bool saved = false;
  if (facts && facts->save && pick_bool()) {
    write_command(s, *facts->save, "save");
    saved = true;
    for (const auto& [a, raw] : last)
      if (const Register* r = s.spec().find_register(a); r && r->persistence.by == spec::PersistBy::save_command)
        stored[a] = raw;
  }
  s.power_cycle();
  // After a power cycle (the spec's persistence): a stored value comes back;
  // a register never stored comes back as it was at power-on; a volatile
  // register returns to its default.
  for (const auto& [a, raw] : last) {
    const Register& r = *s.spec().find_register(a);
    std::optional<uint32_t> want;
    std::string why;
    if (saved && held_back.count(a)) {
      continue;  // whether a save stores what the do-not-persist switch held back is not stated (57HS-R §6.1)
    } else if (r.basis_of(spec::Fact::persistence).basis != spec::Basis::stated) {
      continue;  // an inferred persistence is not held against the device (spec/README.md)
    } else if (held_back.count(a) && r.basis_of(spec::Fact::persistence_unless).basis != spec::Basis::stated) {
      continue;  // that the switch held the write back is inferred (57HS-R 0x00E0, erratum pv-autosave)
    } else if (r.persistence.store == spec::Store::none) {
      want = v.default_raw(r), why = "volatile: its default";
    } else if (stored.count(a)) {
      want = stored[a], why = "persistent: the stored value";
    } else if (r.persistence.by == spec::PersistBy::save_command && !saved) {
      want = initial[a], why = "persistent, not saved: the value it had at power-on";
    } else if (r.persistence.by == spec::PersistBy::on_write) {
      want = initial[a], why = "persistent, write not stored (do-not-persist switch): the value it had at power-on";
    }
    if (!want) continue;
    uint32_t got = read_or_fail(s, r, "after the power cycle");
    if (got != *want)
      fail(fmt::format("after the power cycle {} reads 0x{:X}, expected 0x{:X} ({}, {})", describe(r), got, *want, why,
                       r.persistence.section.empty() ? r.section : r.persistence.section));
  }
  // Factory reset restores the spec's defaults, and they survive a power cycle.
  if (facts && facts->factory_reset && pick_bool()) {
    write_command(s, *facts->factory_reset, "factory reset");
    for (int round = 0; round < 2; ++round) {
      for (const Register* r : v.writable()) {
        if (round == 1 && r->persistence.store == spec::Store::none) continue;
        auto d = v.default_raw(*r);
        if (!d) continue;
        uint32_t got = read_or_fail(s, *r, round ? "after factory reset and a power cycle" : "after factory reset");
        if (got != *d)
          fail(fmt::format("{} {} reads 0x{:X}, the spec's default is 0x{:X} ({})",
                           round ? "after factory reset and a power cycle" : "after factory reset", describe(*r), got,
                           *d, facts->factory_reset->section));
      }
      if (round == 0) s.power_cycle();
    }
  }
}

std::vector<Invariant> make_invariants() {
  std::vector<Invariant> v;
  v.push_back({"read-after-write", "MBAP v1.1b3 §6.3, §6.6, §6.12; spec registers (access, range, word_order)",
               "For every writable register and every in-range value, a write then a read returns the value "
               "(2-word values through the spec's word order, float32 bit-exact).",
               needs_writable, read_after_write});
  v.push_back({"rejection-changes-nothing", "MBAP v1.1b3 §7; spec profile.exception_policy",
               "An out-of-range value, a write to a read-only register, a quantity over the limit or zero, and an "
               "unsupported function code get the policy's answer, and the whole readable register image is unchanged.",
               [](const SpecView& v, const TargetInfo&, const DeviceFacts*) {
                 if (!v.supports(3) || v.image_reads().empty()) return std::string("no FC 03 image to compare");
                 return rejection_kinds(v).empty() ? std::string("the spec gives nothing to reject") : std::string();
               },
               rejection_changes_nothing});
  v.push_back({"foreign-or-corrupt-ignored", "MB-SL v1.02 §2.2, §2.4.2, §2.5.1.2; spec exception_policy.crc_error",
               "Frames for another slave id, and frames with any corrupted byte, never change state and never get a "
               "reply other than what the policy allows.",
               [](const SpecView& v, const TargetInfo& t, const DeviceFacts*) {
                 if (t.framing != &mbc::kRtu) return std::string("not an RTU target");
                 return v.image_reads().empty() ? std::string("no FC 03 image to compare") : std::string();
               },
               foreign_or_corrupt_ignored});
  v.push_back({"broadcast-unanswered", "MB-SL v1.02 §2.1; spec serial.broadcast",
               "Broadcast requests are never answered; broadcast writes are applied when the spec says so.",
               [](const SpecView& v, const TargetInfo& t, const DeviceFacts* f) {
                 if (!v.spec().serial.broadcast_address) return std::string("the spec has no broadcast address");
                 if (!v.broadcast_unavailable().empty()) return v.broadcast_unavailable();
                 return needs_writable(v, t, f);
               },
               broadcast_unanswered});
  v.push_back({"responses-well-formed", "MB-SL v1.02 §2.5.1; MBAP v1.1b3 §4.1, §6, §7",
               "Every reply has a correct CRC and the addressed slave, echoes FC 06/16 requests, has byte count = 2 x "
               "quantity, is at most 256 bytes; valid requests get a normal reply.",
               [](const SpecView& v, const TargetInfo&, const DeviceFacts*) {
                 return v.image_reads().empty() ? std::string("no readable registers") : std::string();
               },
               responses_well_formed});
  v.push_back({"persistence", "spec registers[].persistence, default; operations (save, factory reset)",
               "After a power cycle persistent registers keep their stored values and volatile ones return to their "
               "defaults; a factory reset restores the spec's defaults.",
               needs_power_cycle, persistence});
  for (auto& m : motion_invariants()) v.push_back(std::move(m));
  for (auto& c : control_invariants()) v.push_back(std::move(c));
  v.push_back(stateful_invariant());
  return v;
}

}  // namespace

const std::vector<Invariant>& invariants() {
  static const std::vector<Invariant> list = make_invariants();
  return list;
}

}  // namespace mbc::conf::props
