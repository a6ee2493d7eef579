#include "check/judge.h"

#include <fmt/core.h>

#include <cctype>

#include "modbus/crc16.h"
#include "modbus/judge.h"
#include "modbus/limits.h"
#include "modbus/mbap.h"
#include "modbus/rtu.h"

namespace mbc::conf::check {

std::optional<Bytes> request_pdu(const Step& s, uint8_t unit) {
  if (s.kind == Step::Kind::frame) return s.pdu;
  if (s.kind != Step::Kind::raw) return std::nullopt;
  std::span<const uint8_t> all(s.bytes);
  if (s.framing == &mbc::kTcp) {
    // The receiver frames by the MBAP header (TCP IG v1.0b §3.1.3): a PDU only
    // when the header is whole, protocol 0, and its length counts the bytes.
    Unframed u = mbap_unframe(all);
    if (!u.ok() || u.unit != unit) return std::nullopt;
    return u.pdu;
  }
  // A gap splits the bytes into two frames for the receiver (MB-SL v1.02
  // §2.5.1.1); either part may happen to be a valid frame of its own.
  std::vector<std::span<const uint8_t>> parts{all};
  if (s.gap && *s.gap < all.size()) parts = {all.first(*s.gap), all.subspan(*s.gap)};
  for (auto a : parts) {
    Unframed u = rtu_unframe(a);
    if (u.ok() && u.unit == unit) return u.pdu;
  }
  return std::nullopt;
}

bool exception_code_known(const spec::Spec* s, uint8_t code) {
  if (code >= 1 && code <= 4) return true;  // MBAP v1.1b3 §7
  if (!s) return false;
  for (const auto& e : s->profile.exception_codes)
    if (e.code == code) return true;
  for (const auto& [k, pe] : s->profile.exception_policy)
    if (pe.kind == spec::PolicyEntry::Kind::exception && pe.code == code) return true;
  return false;
}

std::string describe(const Expect& e) {
  if (!e.text.empty()) return e.text;
  switch (e.kind) {
    case Expect::Kind::none: return "anything (recorded)";
    case Expect::Kind::reply: return "exactly " + to_hex(e.pdu);
    case Expect::Kind::exception: return fmt::format("exception {:02X}", e.code);
    case Expect::Kind::silence: return "silence";
    case Expect::Kind::normal: return "a well-formed normal reply";
    case Expect::Kind::registers: {
      std::string s;
      for (size_t i = 0; i < e.words.size(); ++i) {
        s += fmt::format("{}{:04X}", s.empty() ? "" : " ", e.words[i]);
        if (i < e.masks.size() && e.masks[i] != 0xFFFF) s += fmt::format(" under mask {:04X}", e.masks[i]);
      }
      return "registers [" + s + "]";
    }
    case Expect::Kind::same: return "the value read before the write (unchanged)";
    case Expect::Kind::answered: return "a reply: a normal one or an exception";
    case Expect::Kind::any: return "any well-formed reply";
    case Expect::Kind::any_or_silence: return "any well-formed reply, or silence";
  }
  return "";
}

bool reply_is_targets(uint8_t to, std::span<const uint8_t> reply, const JudgeContext& ctx) {
  if (to == ctx.unit || !ctx.shared_line || ctx.framing != &mbc::kRtu) return true;
  bool told = reply.size() >= kRtuAddress + kRtuCrc + 1 && crc_ok(reply);  // its address can be read
  // A broadcast reaches the target too: its reply is the target's unless it names another drive.
  if (to == 0) return !told || reply[0] == 0 || reply[0] == ctx.unit;
  return told && reply[0] == ctx.unit;
}

std::string due_words(const Expect& e) {
  switch (e.kind) {
    case Expect::Kind::none: return "anything";
    case Expect::Kind::reply:
      return !e.pdu.empty() && (e.pdu[0] & 0x80) && e.pdu.size() == 2 ? fmt::format("exception {:02X}", e.pdu[1])
                                                                       : "the stated reply";
    case Expect::Kind::exception: return fmt::format("exception {:02X}", e.code);
    case Expect::Kind::silence: return "silence";
    case Expect::Kind::normal: return "a normal reply";
    case Expect::Kind::registers: return "the stated value";
    case Expect::Kind::same: return "the value unchanged";
    case Expect::Kind::answered: return "a reply to the request's function";
    case Expect::Kind::any: return "a well-formed reply";
    case Expect::Kind::any_or_silence: return "a well-formed reply or silence";
  }
  return "";
}

namespace {

// The digits of a sentence taken out ("byte count 4, expected 2" ->
// "byte count #, expected #"): a problem at every address is one cause.
std::string without_numbers(const std::string& s) {
  std::string out;
  bool in_number = false;
  for (size_t i = 0; i < s.size(); ++i) {
    char c = s[i];
    bool hexish = std::isxdigit(static_cast<unsigned char>(c)) && in_number;
    if (std::isdigit(static_cast<unsigned char>(c)) || hexish ||
        (c == 'x' && in_number && i > 0 && s[i - 1] == '0')) {
      if (!in_number) out += '#';
      in_number = true;
      continue;
    }
    in_number = false;
    out += c;
  }
  return out;
}

// What a reply was, in cause words: "exception 02", "a normal reply".
std::string did_words(const Bytes& pdu) {
  if (!pdu.empty() && (pdu[0] & 0x80) && pdu.size() == 2) return fmt::format("exception {:02X}", pdu[1]);
  if (!pdu.empty() && (pdu[0] & 0x80)) return fmt::format("an exception reply of {} bytes", pdu.size());
  return "a normal reply";
}

// MBAP v1.1b3 §7: an exception reply is the function code with its high bit
// set and one exception code.
std::string exception_shape(const Bytes& pdu) {
  if (pdu.size() < 2) return fmt::format("exception reply of {} byte: an exception reply is the function code and one exception code (MBAP v1.1b3 §7)", pdu.size());
  if (pdu.size() > 2) return "exception reply longer than 2 bytes";
  return "";
}

}  // namespace

namespace {

std::optional<Mismatch> judge_core(const Expect& e, const Step& s, const Reply& r, const JudgeContext& ctx) {
  using K = Expect::Kind;
  using M = Mismatch::Kind;
  if (e.kind == K::none) return std::nullopt;
  if (e.kind == K::silence) {
    if (r.silent()) return std::nullopt;
    // A frame for another unit answered by another drive of the line.
    uint8_t to = s.kind == Step::Kind::frame ? s.unit : s.bytes.empty() ? ctx.unit : s.bytes[0];
    if ((s.kind == Step::Kind::frame || s.framing == &mbc::kRtu) && !reply_is_targets(to, r.frame, ctx)) return std::nullopt;
    return Mismatch{M::answered, "a reply came"};
  }
  if (r.silent()) {
    if (e.kind == K::any_or_silence) return std::nullopt;  // a dropped request, or a closed connection
    return Mismatch{M::silent, r.closed ? "the server closed the connection" : "no reply"};
  }
  if (!r.pdu) return Mismatch{M::malformed_framing, "unusable reply: " + r.framing_error};
  const Bytes& pdu = *r.pdu;
  auto req = request_pdu(s, ctx.unit);
  auto well_formed = [&]() -> std::optional<Mismatch> {
    if (!req || req->empty()) return std::nullopt;
    Judged j = judge_reply(*req, pdu);
    if (j.ok()) return std::nullopt;
    if (j.kind == Judged::Kind::exception) return std::nullopt;  // the callers name a bad exception themselves
    return Mismatch{M::malformed_reply, j.problems.empty() ? "malformed reply" : j.problems.front()};
  };
  switch (e.kind) {
    case K::reply: {
      bool exc = !pdu.empty() && (pdu[0] & 0x80);
      if (pdu != e.pdu) return Mismatch{exc ? M::refused : M::different, fmt::format("PDU differs (expected {})", to_hex(e.pdu))};
      if (e.adu && ctx.framing == &mbc::kRtu && r.frame != *e.adu)
        return Mismatch{M::different, fmt::format("frame differs (expected {})", to_hex(*e.adu))};
      return std::nullopt;
    }
    case K::exception: {
      if (pdu.empty() || !(pdu[0] & 0x80)) return Mismatch{M::refused, "not an exception reply"};
      if (req && !req->empty() && pdu[0] != ((*req)[0] | 0x80))
        return Mismatch{M::malformed_reply, fmt::format("exception to FC {:02X}, request was FC {:02X}", pdu[0] & 0x7F, (*req)[0])};
      if (pdu.size() < 2) return Mismatch{M::malformed_reply, exception_shape(pdu)};
      if (pdu[1] != e.code) return Mismatch{M::different, fmt::format("exception {:02X} instead of {:02X}", pdu[1], e.code)};
      if (pdu.size() != 2) return Mismatch{M::malformed_reply, exception_shape(pdu)};
      return std::nullopt;
    }
    case K::normal:
    case K::registers: {
      Bytes request = req.value_or(Bytes{});
      Judged j = judge_reply(request, pdu);
      if (j.kind == Judged::Kind::exception) return Mismatch{M::refused, fmt::format("exception {:02X}", j.exception_code)};
      if (!j.ok()) return Mismatch{M::malformed_reply, j.problems.empty() ? "malformed reply" : j.problems.front()};
      if (e.kind == K::registers) {
        std::vector<uint16_t> got = j.registers;
        if (got.empty() && !j.bits.empty())
          for (bool b : j.bits) got.push_back(b ? 1 : 0);
        bool differs = got.size() != e.words.size();
        for (size_t i = 0; !differs && i < got.size(); ++i) {
          const uint16_t m = i < e.masks.size() ? e.masks[i] : 0xFFFF;
          differs = (got[i] & m) != (e.words[i] & m);
        }
        if (differs) {
          std::string g;
          for (auto w : got) g += fmt::format("{}{:04X}", g.empty() ? "" : " ", w);
          return Mismatch{M::different, fmt::format("read [{}]", g)};
        }
      }
      return std::nullopt;
    }
    case K::answered: {
      uint8_t fc = req && !req->empty() ? (*req)[0] : 0;
      if (pdu.empty() || (pdu[0] & 0x7F) != fc)
        return Mismatch{M::malformed_reply, fmt::format("reply to FC {:02X}, request was FC {:02X}", pdu.empty() ? 0 : pdu[0] & 0x7F, fc)};
      if (pdu[0] & 0x80)
        if (std::string why = exception_shape(pdu); !why.empty()) return Mismatch{M::malformed_reply, why};
      return std::nullopt;
    }
    case K::same: {
      if (e.memo < 0 || size_t(e.memo) >= ctx.earlier.size() || !ctx.earlier[size_t(e.memo)])
        return Mismatch{M::different, "no earlier value to compare"};
      const Bytes& before = *ctx.earlier[size_t(e.memo)];
      if (pdu != before) return Mismatch{M::different, fmt::format("value changed (before: {})", to_hex(before))};
      return std::nullopt;
    }
    case K::any:
    case K::any_or_silence: {
      if (auto m = well_formed()) return m;
      bool exc = !pdu.empty() && (pdu[0] & 0x80);
      if (exc && (!req || req->empty()))
        if (std::string why = exception_shape(pdu); !why.empty()) return Mismatch{M::malformed_reply, why};
      if (exc && pdu.size() == 2 && !exception_code_known(ctx.spec, pdu[1]))
        return Mismatch{M::unknown_exception,
                        fmt::format("exception code {:02X} is neither in MBAP v1.1b3 §7 nor in the spec", pdu[1])};
      return std::nullopt;
    }
    default: return std::nullopt;
  }
}

}  // namespace

std::optional<Mismatch> judge_expect(const Expect& e, const Step& s, const Reply& r, const JudgeContext& ctx) {
  auto m = judge_core(e, s, r, ctx);
  if (!m) return m;
  // What was due and what the device did, in words free of values.
  if (m->due.empty()) m->due = due_words(e);
  if (m->did.empty()) {
    const Bytes empty;
    const Bytes& pdu = r.pdu ? *r.pdu : empty;
    switch (m->kind) {
      case Mismatch::Kind::answered: m->did = "a reply"; break;
      case Mismatch::Kind::silent: m->did = r.closed ? "a closed connection" : "silence"; break;
      case Mismatch::Kind::malformed_framing: m->did = "an unusable frame"; break;
      case Mismatch::Kind::malformed_reply: m->did = "a malformed reply (" + without_numbers(m->why) + ")"; break;
      case Mismatch::Kind::unknown_exception:
      case Mismatch::Kind::refused: m->did = did_words(pdu); break;
      case Mismatch::Kind::different:
        if (e.kind == Expect::Kind::registers || e.kind == Expect::Kind::same) m->did = "another value";
        else if (!pdu.empty() && (pdu[0] & 0x80)) m->did = did_words(pdu);
        else if (e.kind == Expect::Kind::reply && pdu.size() != e.pdu.size())
          m->did = fmt::format("a reply {} bytes {}", pdu.size() > e.pdu.size() ? pdu.size() - e.pdu.size() : e.pdu.size() - pdu.size(),
                               pdu.size() > e.pdu.size() ? "longer" : "shorter");
        else if (e.kind == Expect::Kind::reply && r.pdu && *r.pdu == e.pdu) m->did = "another frame around the stated reply";
        else m->did = "another reply of the stated length";
        break;
    }
  }
  return m;
}

std::optional<Mismatch> judge(const Step& s, const Reply& r, const JudgeContext& ctx) {
  auto m = judge_expect(s.expect, s, r, ctx);
  if (!m) return m;
  for (const auto& alt : s.expect.either)
    if (!judge_expect(alt, s, r, ctx)) return std::nullopt;
  return m;
}

std::string judge_reading(const Step& s, const Reply& r, const JudgeContext& ctx) {
  if (!judge_expect(s.expect, s, r, ctx)) return s.expect.reading.empty() ? describe(s.expect) : s.expect.reading;
  for (const auto& alt : s.expect.either)
    if (!judge_expect(alt, s, r, ctx)) return alt.reading.empty() ? describe(alt) : alt.reading;
  return "";
}

std::optional<Bytes> expected_bytes(const Step& st, const JudgeContext& ctx) {
  const Expect& e = st.expect;
  auto req = request_pdu(st, ctx.unit);
  bool rtu_frame_step = ctx.framing == &mbc::kRtu && st.kind == Step::Kind::frame;
  auto framed = [&](Bytes pdu) { return rtu_frame_step ? rtu_frame(st.unit, pdu) : pdu; };
  switch (e.kind) {
    case Expect::Kind::reply: return e.adu && ctx.framing == &mbc::kRtu ? *e.adu : e.pdu;
    case Expect::Kind::exception:
      if (!req || req->empty()) return std::nullopt;
      return framed(Bytes{uint8_t((*req)[0] | 0x80), e.code});
    case Expect::Kind::registers: {
      if (!req || req->empty() || ((*req)[0] != 3 && (*req)[0] != 4)) return std::nullopt;
      if (!e.masks.empty()) return std::nullopt;  // only some bits are known
      // MBAP v1.1b3 §6.3/§6.4: FC, byte count, the registers high byte first.
      Bytes b{(*req)[0], uint8_t(2 * e.words.size())};
      for (uint16_t w : e.words) b.insert(b.end(), {uint8_t(w >> 8), uint8_t(w & 0xFF)});
      return framed(b);
    }
    case Expect::Kind::same:
      if (e.memo < 0 || size_t(e.memo) >= ctx.earlier.size() || !ctx.earlier[size_t(e.memo)]) return std::nullopt;
      return framed(*ctx.earlier[size_t(e.memo)]);
    default: return std::nullopt;
  }
}

}  // namespace mbc::conf::check
