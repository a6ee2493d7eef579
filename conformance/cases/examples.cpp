// Family "examples": every frame the manual prints, replayed in the state the
// manual implies (given:), with the effect it states checked (after:), worked
// sequences in step order. The expected bytes are the printed response (or an
// erratum's resolved reading, whose id the case records); where no response is
// printed the standard's (MBAP v1.1b3 §6) echo or a well-formed reply is
// expected. A printed frame addressed to another slave id is re-framed for the
// target's unit; a deliberately corrupted CRC keeps its corruption.
#include <fmt/core.h>

#include <algorithm>
#include <map>

#include "cases/common.h"
#include "cases/facts.h"
#include "modbus/crc16.h"
#include "modbus/limits.h"
#include "modbus/rtu.h"

namespace mbc::conf {
namespace {

using cases::clause;
using cases::hex16;

std::string slug(const std::string& s) {
  std::string out;
  for (char c : s) out += (c == ' ' || c == '/' || c == ';' || c == ',') ? '_' : c;
  while (out.find("__") != std::string::npos) out.replace(out.find("__"), 2, "_");
  return out.empty() ? "-" : out;
}

// The registers a write request PDU covers (FC 05/06/15/16/22/23), for
// per-case restore and the safety check.
std::vector<std::pair<uint16_t, int>> written_by(const Bytes& pdu) {
  if (pdu.size() < 5) return {};
  switch (pdu[0]) {
    case 6: case 22: return {{be16(pdu, 1), 1}};
    case 16: return {{be16(pdu, 1), std::min<int>(be16(pdu, 3), standard_max_quantity(3))}};
    case 23: return pdu.size() >= 9 ? std::vector<std::pair<uint16_t, int>>{{be16(pdu, 5), std::min<int>(be16(pdu, 7), standard_max_quantity(3))}}
                                    : std::vector<std::pair<uint16_t, int>>{};
    default: return {};
  }
}

struct Built {
  std::vector<Step> steps;
  std::string skip;
  bool given_unsettable = false;
  std::string note;
};

// Steps that set `given` values through the bus (setup).
void add_given(const GenContext& g, const spec::Example& ex, Built& b, std::vector<std::pair<uint16_t, int>>& touches) {
  for (const auto& v : ex.given) {
    const spec::Register* r = g.spec.find_register(v.address, v.table);
    if (!r) r = g.spec.register_covering(v.address, v.table);
    if (!r || (r->access != spec::Access::rw)) {
      // Status the manual prints but the bus cannot set: the reply is recorded, not failed.
      b.given_unsettable = true;
      b.note += fmt::format("given {} = {} cannot be set through the bus; ", hex16(v.address), v.value);
      continue;
    }
    if (auto why = cases::write_forbidden(g, *r); !why.empty()) {
      if (b.skip.empty()) b.skip = "given state: " + why;
    }
    auto st = cases::write_step(g, *r, cases::encode(*r, int64_t(v.value)));
    if (!st) {
      b.given_unsettable = true;
      b.note += fmt::format("given {}: the profile has no function to write it; ", hex16(v.address));
      continue;
    }
    st->setup = true;
    st->note = "given: " + st->note;
    if (r->table == spec::Table::holding) touches.push_back({r->address, r->words});
    b.steps.push_back(std::move(*st));
  }
}

void add_example(const GenContext& g, const spec::Example& ex, Built& b, std::vector<std::pair<uint16_t, int>>& touches,
                 std::vector<std::string>& errata) {
  for (const auto& e : ex.errata)
    if (std::find(errata.begin(), errata.end(), e) == errata.end()) errata.push_back(e);
  auto req = parse_hex(ex.resolved_request.value_or(ex.request));
  if (!req || req->size() < 2) {
    b.skip = "the printed request is not a frame (erratum without a resolved reading)";
    return;
  }
  uint8_t printed_slave = (*req)[0];
  bool broadcast = printed_slave == 0;
  uint8_t unit = broadcast ? 0 : g.target.unit;
  bool crc_valid = req->size() >= 4 && crc_ok(*req);
  // A broadcast write reaches every drive on the line: what the target holds
  // is read first and broadcast back after the example (the runner restores
  // only the target).
  std::vector<std::pair<size_t, std::pair<uint16_t, int>>> held;
  if (broadcast) {
    if (auto tcp = broadcast_not_applicable(g.target); !tcp.empty()) {
      b.skip = tcp;
      return;
    }
    if (crc_valid && cases::has_fc(g.spec, 3))
      for (auto range : written_by(rtu_unframe(*req).pdu)) {
        held.push_back({b.steps.size(), range});
        auto rd = cases::read_range_step(g, spec::Table::holding, range.first, uint16_t(range.second),
                                         cases::normal("what the target holds, broadcast back at the end"));
        rd->note = "first: " + rd->note;
        b.steps.push_back(std::move(*rd));
      }
  }
  add_given(g, ex, b, touches);

  // Expected reply.
  Expect e;
  std::optional<std::string> resp_hex = ex.resolved_response ? ex.resolved_response : ex.response;
  if (ex.resolved_silent || ex.no_reply || broadcast) {
    e = cases::silence(ex.resolved_silent ? "silence (resolved reading of the erratum)"
                                          : broadcast ? "silence (broadcast: MB-SL v1.02 §2.1)" : "silence (the source says no reply)");
  } else if (resp_hex) {
    auto resp = parse_hex(*resp_hex);
    if (!resp || resp->size() < 4) {
      b.skip = "the printed response is not a frame";
      return;
    }
    Bytes pdu = rtu_unframe(*resp).pdu;
    e = cases::exact(pdu, "the printed response");
    if (crc_ok(*resp)) e.adu = rtu_frame(unit, pdu);
    else b.note += "printed response CRC is wrong; the PDU is compared; ";
  } else {
    Bytes pdu(req->begin() + 1, req->end() - (crc_valid ? 2 : 0));
    uint8_t fc = pdu.empty() ? 0 : pdu[0];
    if (fc == 5 || fc == 6 || fc == 15 || fc == 16) e = cases::write_echo(pdu);
    else e = cases::normal("a well-formed normal reply (no response printed)");
  }

  facts::example(e.relies, ex);
  if (ex.exercises && !g.spec.profile.policy(*ex.exercises).readings.empty()) {
    // An example inherits the `either` of the policy it exercises: each of
    // the policy's other readings is accepted too.
    spec::PolicyEntry p = facts::policy(e.relies, g.spec, *ex.exercises);
    for (const auto& r : p.readings) {
      bool same = (r.kind == spec::PolicyEntry::Kind::silent && e.kind == Expect::Kind::silence) ||
                  (r.kind == spec::PolicyEntry::Kind::exception && e.kind == Expect::Kind::reply && e.pdu.size() == 2 &&
                   (e.pdu[0] & 0x80) && e.pdu[1] == r.code) ||
                  (r.kind == spec::PolicyEntry::Kind::exception && e.kind == Expect::Kind::exception && e.code == r.code);
      if (same || r.kind == spec::PolicyEntry::Kind::unspecified) continue;
      if (e.reading.empty()) e.reading = e.text;
      Expect alt = r.kind == spec::PolicyEntry::Kind::silent
                       ? cases::silence(fmt::format("silence (the other reading of exception_policy.{})", spec::to_string(*ex.exercises)))
                       : cases::exception(uint8_t(r.code), fmt::format("exception {:02X} (the other reading of exception_policy.{})", r.code,
                                                                      spec::to_string(*ex.exercises)));
      alt.reading = alt.text;
      e.text += " or " + alt.text;
      e.either.push_back(std::move(alt));
    }
  }
  if (ex.basis.basis == spec::Basis::either && ex.response && ex.has_resolution()) {
    // The manual prints two readings: the resolved one above, or the frame as printed.
    if (auto printed = parse_hex(*ex.response); printed && printed->size() >= 4) {
      e.reading = e.text;
      Expect alt = cases::exact(rtu_unframe(*printed).pdu, "the printed response");
      alt.reading = alt.text;
      e.text += " or the printed response (printed two ways)";
      e.either.push_back(std::move(alt));
    }
  }
  Step s;
  s.note = fmt::format("{} ({})", ex.id, ex.does.empty() ? "printed frame" : ex.does.substr(0, 80));
  if (crc_valid) {
    s.kind = Step::Kind::frame;
    s.unit = unit;
    s.pdu = rtu_unframe(*req).pdu;
  } else {
    // A frame the manual corrupts on purpose: it goes out raw, re-addressed to
    // the target with the same CRC error (the XOR from the correct CRC is kept).
    if (!g.target.raw || g.target.framing != &mbc::kRtu) {
      b.skip = "the printed request has a wrong CRC and the target cannot send raw RTU frames";
      return;
    }
    Bytes adu = *req;
    if (adu.size() >= 4) {
      uint16_t printed = uint16_t(adu[adu.size() - 2] | adu.back() << 8);
      uint16_t right = crc16(std::span(adu).first(adu.size() - 2));
      adu[0] = unit;
      uint16_t now = crc16(std::span(adu).first(adu.size() - 2)) ^ uint16_t(printed ^ right);
      adu[adu.size() - 2] = uint8_t(now & 0xFF);
      adu.back() = uint8_t(now >> 8);
    }
    s.kind = Step::Kind::raw;
    s.bytes = std::move(adu);
  }
  s.expect = std::move(e);
  // A write of part of a multi-word value (FC 06 to one word of a u32): the
  // words it does not write are read first and expected unchanged after, so
  // the case does not assume what a live drive holds there.
  std::map<uint16_t, size_t> untouched;  // word address -> the step that read it before
  if (s.kind == Step::Kind::frame) {
    for (auto [addr, n] : written_by(s.pdu)) {
      touches.push_back({addr, n});
      if (const spec::Register* r = g.spec.register_covering(addr))
        if (auto why = cases::write_forbidden(g, *r); !why.empty() && g.target.live && b.skip.empty()) b.skip = why;
      for (uint32_t a = addr; a < uint32_t(addr) + uint32_t(n); ++a) {
        const spec::Register* r = g.spec.register_covering(uint16_t(a));
        if (!r || r->words < 2) continue;
        for (uint32_t w = r->address; w <= r->last_address(); ++w) {
          if ((w >= addr && w < uint32_t(addr) + uint32_t(n)) || untouched.count(uint16_t(w))) continue;
          auto rd = cases::read_range_step(g, spec::Table::holding, uint16_t(w), 1,
                                           cases::normal("the word the write leaves alone"));
          if (!rd) continue;
          rd->note = fmt::format("first: {} (the other word of {})", rd->note, hex16(r->address));
          untouched[uint16_t(w)] = b.steps.size();
          b.steps.push_back(std::move(*rd));
        }
      }
    }
  }
  b.steps.push_back(std::move(s));

  for (const auto& v : ex.after) {
    const spec::Register* r = g.spec.find_register(v.address, v.table);
    if (!r) continue;
    Expect want;
    want.kind = Expect::Kind::registers;
    want.words = cases::encode(*r, int64_t(v.value));
    want.text = fmt::format("{} = {} (after: the effect the manual states)", hex16(v.address), v.value);
    if (r->table == spec::Table::coil || r->table == spec::Table::discrete_input) want.words = {uint16_t(v.value != 0)};
    bool partial = r->table == spec::Table::holding && r->words > 1 && untouched.count(r->address) + untouched.count(uint16_t(r->address + 1));
    if (!partial) {
      if (auto rd = cases::read_step(g, *r, want)) b.steps.push_back(std::move(*rd));
      continue;
    }
    // Word by word: the written ones hold the stated value's words, the others what they held.
    for (int i = 0; i < r->words; ++i) {
      uint16_t at = uint16_t(r->address + i);
      Expect one;
      if (auto it = untouched.find(at); it != untouched.end()) {
        one.kind = Expect::Kind::same;
        one.memo = int(it->second);
        one.text = fmt::format("{} unchanged (the write covers only part of {})", hex16(at), hex16(r->address));
      } else {
        one.kind = Expect::Kind::registers;
        one.words = {want.words[size_t(i)]};
        one.text = fmt::format("{:04X} (word {} of {} = {}: the effect the manual states)", want.words[size_t(i)], i,
                               hex16(v.address), v.value);
      }
      if (auto rd = cases::read_range_step(g, spec::Table::holding, at, 1, one)) b.steps.push_back(std::move(*rd));
    }
  }
  for (auto [at, range] : held) {
    Step back;
    back.unit = 0;
    std::vector<uint16_t> placeholder(size_t(range.second), 0);
    back.pdu = range.second == 1 && cases::has_fc(g.spec, 6) ? write_single_register(range.first, 0)
                                                             : write_multiple_registers(range.first, placeholder);
    back.words_from = int(at);
    back.note = fmt::format("broadcast back what the target held at {} (every drive on the line)", hex16(range.first));
    back.expect.text = "no check (put back)";
    b.steps.push_back(std::move(back));
  }
}

}  // namespace

std::vector<Case> examples_cases(const GenContext& g) {
  std::vector<Case> out;
  std::map<std::string, std::vector<const spec::Example*>> sequences;
  std::vector<std::vector<const spec::Example*>> groups;
  std::map<std::string, size_t> seq_group;
  for (const auto& ex : g.spec.examples) {
    if (ex.sequence.empty()) {
      groups.push_back({&ex});
    } else {
      auto [it, fresh] = seq_group.emplace(ex.sequence, groups.size());
      if (fresh) groups.push_back({});
      groups[it->second].push_back(&ex);
    }
  }
  for (auto& grp : groups) {
    std::stable_sort(grp.begin(), grp.end(), [](auto* a, auto* b) { return a->step < b->step; });
    const spec::Example& first = *grp.front();
    Case c;
    c.family = "examples";
    bool seq = !first.sequence.empty();
    c.id = fmt::format("{}/examples/{}/{}", g.spec.device.id, slug(first.section), seq ? first.sequence : first.id);
    c.clause = clause(g.spec, first.section);
    c.level = Level::must;
    c.title = seq ? fmt::format("sequence {} ({} steps) as printed", first.sequence, grp.size())
                  : fmt::format("printed frame {}", first.id);
    c.requirement = seq ? fmt::format("The worked sequence of §{} gives these replies in step order.", first.section)
                        : (first.does.empty() ? "The device answers the printed request with the printed response." : first.does);
    Built b;
    for (const auto* ex : grp) add_example(g, *ex, b, c.touches, c.errata);
    c.steps = std::move(b.steps);
    c.skip_reason = b.skip;
    if (b.given_unsettable) {
      // The manual's state cannot be reached through the bus: what the device
      // answers is recorded, not judged.
      c.level = Level::observed;
      c.requirement += " [" + b.note + "reply recorded]";
      c.incomparable = b.note.substr(0, b.note.size() - 2);
      if (size_t n = size_t(std::count(b.note.begin(), b.note.end(), ';')); n > 2)
        c.incomparable = fmt::format("the given state ({} values, {}) cannot be set through the bus", n,
                                     b.note.substr(0, b.note.find(" cannot")));
    } else if (!b.note.empty()) {
      c.requirement += " [" + b.note.substr(0, b.note.size() - 2) + "]";
    }
    if (auto req = parse_hex(first.request); req && req->size() >= 6 && crc_ok(*req) &&
                                             (req->at(1) == 3 || req->at(1) == 6 || req->at(1) == 4))
      c.register_address = be16(*req, 2);
    out.push_back(std::move(c));
  }
  return out;
}

}  // namespace mbc::conf
