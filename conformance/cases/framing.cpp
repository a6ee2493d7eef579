// Family "framing": addressing and the RTU frame (MB-SL v1.02 §2.1, §2.2,
// §2.5.1). Frames for another slave get silence; broadcast writes get no
// reply and take effect; corrupted frames (bad CRC, truncated, over-long,
// split by an inter-character gap) get the crc_error policy's answer and the
// device keeps answering the next good frame; a byte count that contradicts
// the quantity gets the wrong_byte_count policy's answer.
#include <fmt/core.h>

#include "cases/common.h"
#include "cases/facts.h"
#include "erratum_extra.h"
#include "modbus/crc16.h"
#include "modbus/pdu.h"
#include "modbus/rtu.h"

namespace mbc::conf {
namespace {

using cases::clause;
using cases::hex16;
using spec::Violation;

struct Gen {
  const GenContext& g;
  std::vector<Case>& out;
  const spec::Register* probe = nullptr;  // a readable register for probe reads

  Case base(const std::string& group, const std::string& what, const std::string& cl) {
    Case c;
    c.family = "framing";
    c.id = fmt::format("{}/framing/{}/{}", g.spec.device.id, group, what);
    c.clause = cl;
    return c;
  }

  Bytes probe_pdu() const { return read_request(3, probe->address, uint16_t(probe->words)); }

  Step good_request(const std::string& why) const {
    Step s;
    s.unit = g.target.unit;
    s.pdu = probe_pdu();
    s.note = fmt::format("read {} with a good frame ({})", hex16(probe->address), why);
    s.expect = cases::normal("a normal reply: the device still answers good frames");
    facts::readable(s.expect.relies, *probe);  // a drive that reads the probe otherwise answers it otherwise
    return s;
  }

  Step raw(Bytes adu, std::string what, Expect e, std::optional<size_t> gap = std::nullopt) const {
    Step s;
    s.kind = Step::Kind::raw;
    s.bytes = std::move(adu);
    s.gap = gap;
    s.note = std::move(what);
    s.expect = std::move(e);
    return s;
  }

  bool needs_raw(Case& c) {
    if (g.target.framing != &mbc::kRtu) {
      c.skip_reason = "RTU framing case; the target frames MBAP";
      return false;
    }
    if (!g.target.raw) {
      c.skip_reason = "the target cannot send raw frames";
      return false;
    }
    return true;
  }

  // A corrupted RTU frame: the crc_error policy applies (the CRC cannot check).
  void corrupted(const std::string& what, const std::string& title, const std::string& req, Bytes adu,
                 std::optional<size_t> gap = std::nullopt) {
    auto pe = cases::policy_expect(g, Violation::crc_error);
    Case c = base("rtu", what, pe.level == Level::observed ? "MB-SL v1.02 §2.5.1.1; " + pe.clause : pe.clause + "; MB-SL v1.02 §2.5.1.1");
    c.level = pe.level;
    if (!pe.erratum.empty()) c.errata.push_back(pe.erratum);
    c.title = title;
    c.requirement = req + " The frame's CRC cannot check: " + pe.expect.text + ".";
    if (needs_raw(c)) {
      c.steps.push_back(raw(std::move(adu), title, pe.expect, gap));
      c.steps.push_back(good_request("after the corrupted frame"));
    }
    out.push_back(std::move(c));
  }

  void addressing() {
    {
      Case c = base("address", "wrong-slave", "MB-SL v1.02 §2.2");
      uint8_t other = g.target.unit == 247 ? 246 : 247;
      c.title = fmt::format("a request for slave {} gets no reply from slave {}", other, g.target.unit);
      c.requirement = "Only the addressed slave answers (MB-SL v1.02 §2.2: the master addresses one slave; others ignore the request).";
      if (g.target.framing != &mbc::kRtu) {
        c.skip_reason = "RTU addressing; an MBAP unit id is routed by the gateway";
      } else {
        Step s;
        s.unit = other;
        s.pdu = probe_pdu();
        s.note = fmt::format("read {} addressed to slave {}", hex16(probe->address), other);
        s.expect = cases::silence("silence (not addressed)");
        c.steps.push_back(std::move(s));
        c.steps.push_back(good_request("addressed to the target"));
      }
      out.push_back(std::move(c));
    }
    const spec::Register* r = cases::plain_register(g);
    if (!r) return;
    const auto& ser = g.spec.serial;
    std::string cl = ser.broadcast_section.empty() ? "MB-SL v1.02 §2.1" : clause(g.spec, ser.broadcast_section);
    uint8_t bcast = uint8_t(ser.broadcast_address.value_or(0));
    auto [lo_v, hi_v] = cases::plain_values(*r);
    auto lo = cases::encode(*r, lo_v), hi = cases::encode(*r, hi_v);
    for (bool effect : {false, true}) {
      bool stated = effect ? ser.broadcast_writes == "applied" : ser.broadcast_reply == "none";
      Case c = base("broadcast", effect ? "write-applied" : "no-reply", stated ? cl : "MB-SL v1.02 §2.1");
      cases::plain_relies(c.relies, *r);
      c.level = stated ? Level::must : Level::observed;
      c.register_address = r->address;
      c.title = effect ? fmt::format("a broadcast write of {} takes effect", hex16(r->address))
                       : fmt::format("a broadcast write of {} gets no reply", hex16(r->address));
      c.requirement = effect ? "Broadcast writes are executed by every slave (MB-SL v1.02 §2.1)."
                             : "Broadcast requests get no reply (MB-SL v1.02 §2.1).";
      if (!stated) c.requirement += " The manual does not say; recorded against the standard.";
      c.touches.push_back({r->address, 1});
      if (auto tcp = broadcast_not_applicable(g.target); !tcp.empty()) {
        c.skip_reason = tcp;
      } else if (auto why = cases::write_forbidden(g, *r); !why.empty()) {
        c.skip_reason = why;
      } else if (!cases::has_fc(g.spec, 3)) {
        c.skip_reason = "the profile has no FC 03 to read the value the target holds";
      } else {
        // Every drive on the line takes a broadcast and only the target is
        // restored: "no reply" writes what the target already holds; "applied"
        // writes a new value, then broadcasts the held value back.
        auto broadcast = [&](uint16_t value, const std::string& what, Expect e) {
          Step b;
          b.unit = bcast;
          b.pdu = write_single_register(r->address, value);
          b.note = fmt::format("broadcast write {} = {}", hex16(r->address), what);
          b.expect = std::move(e);
          return b;
        };
        Expect unchanged;  // for the no-reply case
        unchanged.kind = Expect::Kind::same;
        unchanged.memo = 0;
        unchanged.text = "the value the target held before";
        c.steps.push_back(*cases::read_step(g, *r, cases::normal("the value the target holds")));
        if (!effect) {
          Step b = broadcast(0, "the value the target holds", cases::silence("silence (broadcast)"));
          b.words_from = 0;
          c.steps.push_back(std::move(b));
          c.steps.push_back(*cases::read_step(g, *r, unchanged));
        } else {
          auto set = cases::write_step(g, *r, lo);
          set->setup = true;
          set->note = "first: " + set->note;
          c.steps.push_back(std::move(*set));
          Expect none;
          none.text = "no check (the no-reply case checks silence)";
          c.steps.push_back(broadcast(hi[0], fmt::format("{:04X}", hi[0]), none));
          Expect want;
          want.kind = Expect::Kind::registers;
          want.words = hi;
          want.text = fmt::format("{:04X} (the broadcast value)", hi[0]);
          c.steps.push_back(*cases::read_step(g, *r, want));
          Step back = broadcast(0, "the value the target held (put back on every drive)", none);
          back.words_from = 0;
          c.steps.push_back(std::move(back));
        }
      }
      out.push_back(std::move(c));
    }
  }

  void rtu() {
    Bytes good = rtu_frame(g.target.unit, probe_pdu());
    Bytes bad_crc = good;
    bad_crc.back() ^= 0xFF;
    {
      auto pe = cases::policy_expect(g, Violation::crc_error);
      Case c = base("rtu", "crc-error", pe.clause);
      c.level = pe.level;
      if (!pe.erratum.empty()) c.errata.push_back(pe.erratum);
      c.title = "a request with a wrong CRC";
      c.requirement = "A frame whose CRC does not check (MB-SL v1.02 §2.4.2): " + pe.expect.text + ".";
      if (needs_raw(c)) {
        c.steps.push_back(raw(bad_crc, "read with the CRC's high byte inverted", pe.expect));
        c.steps.push_back(good_request("after the CRC error"));
      }
      out.push_back(std::move(c));
    }
    Bytes truncated(good.begin(), good.end() - 1);
    corrupted("truncated", "a request missing its last byte", "A frame cut short.", truncated);
    // Not 0x00: a CRC-16 register at zero (a frame followed by its own CRC)
    // stays zero on a 0x00 byte, so "frame + 00" is itself a frame whose CRC
    // checks (its PDU swallows the old CRC). Any other byte breaks the check.
    Bytes longer = good;
    longer.push_back(0x55);
    corrupted("over-long", "a request with one extra byte after its CRC",
              "A frame with a byte after the CRC: the last two bytes are no longer the CRC.", longer);
    corrupted("split-by-gap", "a request split by an inter-character gap",
              "A silence of more than 1.5 character times inside a frame ends it: both halves are incomplete frames (MB-SL v1.02 §2.5.1.1).",
              good, size_t(3));
    {
      // Well-framed (CRC good) but the PDU is short or long: the standard does not say.
      for (bool shorter : {true, false}) {
        Case c = base("rtu", shorter ? "short-pdu" : "long-pdu", "MB-SL v1.02 §2.5.1; MBAP v1.1b3 §6.3");
        c.level = Level::observed;
        Bytes pdu = probe_pdu();
        if (shorter) pdu.resize(3);
        else pdu.push_back(0x00);
        c.title = shorter ? "FC 03 without its quantity field, CRC right" : "FC 03 with an extra data byte, CRC right";
        c.requirement = "A well-framed request whose PDU length does not match its function code; the standard does not state the answer: recorded.";
        if (needs_raw(c)) {
          c.steps.push_back(raw(rtu_frame(g.target.unit, pdu), c.title, Expect{}));
          c.steps.push_back(good_request("after it"));
        }
        out.push_back(std::move(c));
      }
    }
  }

  void byte_count() {
    if (!cases::has_fc(g.spec, 16)) return;
    const spec::Register* r = cases::plain_register(g);
    if (!r) return;
    auto pe = cases::policy_expect(g, Violation::wrong_byte_count);
    Case c = base("pdu", "byte-count-mismatch", pe.clause);
    c.level = pe.level;
    c.register_address = r->address;
    cases::plain_relies(c.relies, *r);
    if (!pe.erratum.empty()) c.errata.push_back(pe.erratum);
    c.title = fmt::format("FC 16 to {}: quantity 2 but byte count 2", hex16(r->address));
    c.requirement = "The byte count must be 2 x quantity (MBAP v1.1b3 §6.12): " + pe.expect.text + "; nothing is written.";
    c.touches.push_back({r->address, 2});
    if (auto why = cases::write_forbidden(g, *r); !why.empty()) {
      c.skip_reason = why;
    } else {
      Step before = *cases::read_step(g, *r, Expect{});
      before.setup = true;
      before.note = "before: " + before.note;
      c.steps.push_back(before);
      Step s;
      s.unit = g.target.unit;
      auto w = cases::encode(*r, cases::plain_values(*r).second);
      s.pdu = {16, uint8_t(r->address >> 8), uint8_t(r->address & 0xFF), 0, 2, 2, uint8_t(w[0] >> 8), uint8_t(w[0] & 0xFF)};
      s.note = "write multiple registers, quantity 2, byte count 2";
      s.expect = pe.expect;
      c.steps.push_back(std::move(s));
      Expect same;
      same.kind = Expect::Kind::same;
      same.memo = 0;
      same.text = "the value read before (unchanged)";
      c.steps.push_back(*cases::read_step(g, *r, same));
    }
    out.push_back(std::move(c));
  }

  void run() {
    // The first holding register stated readable, else the first readable at all.
    for (bool stated_only : {true, false}) {
      for (const auto& r : g.spec.registers)
        if (r.table == spec::Table::holding && r.access != spec::Access::wo && r.access != spec::Access::command &&
            (!stated_only || !spec::demotes(r.basis_of(spec::Fact::read)))) {
          probe = &r;
          break;
        }
      if (probe) break;
    }
    if (!probe || !cases::has_fc(g.spec, 3)) return;
    addressing();
    rtu();
    byte_count();
  }
};

}  // namespace

std::vector<Case> framing_cases(const GenContext& g) {
  std::vector<Case> out;
  Gen{g, out}.run();
  return out;
}

}  // namespace mbc::conf
