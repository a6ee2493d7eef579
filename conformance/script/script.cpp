#include "script/script.h"

#include <fmt/core.h>

#include <fstream>
#include <sstream>
#include <thread>

#include "modbus/bytes.h"
#include "modbus/crc16.h"
#include "modbus/judge.h"
#include "modbus/limits.h"
#include "modbus/mbap.h"
#include "modbus/rtu.h"

namespace mbc::conf::script {

namespace {

// One line split into words, each with its column (1-based).
struct Word {
  std::string text;
  int col;
};
std::vector<Word> words_of(const std::string& body) {
  std::vector<Word> out;
  for (size_t i = 0; i < body.size();) {
    if (isspace(uint8_t(body[i]))) {
      ++i;
      continue;
    }
    size_t j = i;
    while (j < body.size() && !isspace(uint8_t(body[j]))) ++j;
    out.push_back({body.substr(i, j - i), int(i) + 1});
    i = j;
  }
  return out;
}

struct LineParser {
  const std::string& file;
  int n;
  [[noreturn]] void fail(int col, const std::string& rule, const std::string& what) const {
    throw ParseError(fmt::format("{}:{}:{}: error: {}: {}", file, n, col, rule, what));
  }
  // Hex bytes from words[from, to); a word "|" (when `gap`) marks a pause.
  Bytes hex(const std::vector<Word>& w, size_t from, size_t to, std::optional<size_t>* gap = nullptr) const {
    Bytes b;
    for (size_t i = from; i < to; ++i) {
      if (gap && w[i].text == "|") {
        if (*gap) fail(w[i].col, "gap", "one '|' (inter-character pause) per frame");
        *gap = b.size();
        continue;
      }
      auto v = parse_hex(w[i].text);
      if (!v || w[i].text.size() != 2) fail(w[i].col, "hex", "'" + w[i].text + "' is not a byte (two hex digits)");
      b.push_back((*v)[0]);
    }
    return b;
  }
  uint64_t number(const Word& w, const std::string& what) const {
    try {
      size_t used = 0;
      uint64_t v = std::stoull(w.text, &used);
      if (used == w.text.size() && w.text[0] != '-') return v;
    } catch (const std::exception&) {
    }
    fail(w.col, "number", what + " takes a whole number, not '" + w.text + "'");
  }
};

}  // namespace

// ---- writing ---------------------------------------------------------------

std::string expect_text(const Expect& e) {
  switch (e.kind) {
    case Expect::Kind::none: return "";
    case Expect::Kind::reply: return "reply " + to_hex(e.pdu);
    case Expect::Kind::exception: return fmt::format("exception {:02X}", e.code);
    case Expect::Kind::silence: return "silence";
    case Expect::Kind::normal: return "normal";
    case Expect::Kind::any: return "any";
    case Expect::Kind::any_or_silence: return "any-or-silence";
  }
  return "";
}

std::string line(const Step& s) {
  std::string l;
  switch (s.kind) {
    case Step::Kind::frame:
      if (s.framing == Framing::rtu) {
        l = "rtu " + to_hex(rtu_frame(s.unit, s.pdu));
      } else {
        Bytes adu = mbap_frame(s.tid.value_or(0), s.unit, s.pdu);
        l = "mbap " + (s.tid ? to_hex(adu) : "* " + to_hex(std::span(adu).subspan(2)));
      }
      break;
    case Step::Kind::raw: {
      l = s.framing == Framing::rtu ? "raw-rtu" : "raw-mbap";
      for (size_t i = 0; i < s.bytes.size(); ++i) {
        if (s.gap && *s.gap == i) l += " |";
        l += fmt::format(" {:02X}", s.bytes[i]);
      }
      if (s.gap && *s.gap >= s.bytes.size()) l += " |";
      break;
    }
    case Step::Kind::advance: l = fmt::format("advance {}", s.us); break;
    case Step::Kind::power_cycle: l = "power-cycle"; break;
    case Step::Kind::wait: l = fmt::format("wait {}", s.us / 1000); break;
  }
  if (s.expect.kind != Expect::Kind::none) l += "  -> " + expect_text(s.expect);
  if (!s.note.empty()) l += "   # " + s.note;
  return l;
}

std::string format(const Script& s) {
  std::string out = std::string(kHeader) + "\n";
  std::istringstream c(s.comment);
  for (std::string l; std::getline(c, l);) out += l.empty() ? "#\n" : "# " + l + "\n";
  if (!s.device.empty()) out += "device " + s.device + "\n";
  if (!s.fault.empty()) out += "fault " + s.fault + "\n";
  for (const auto& st : s.steps) out += line(st) + "\n";
  return out;
}

Step frame(Framing framing, uint8_t unit, Bytes pdu, Expect expect, std::string note) {
  Step s;
  s.framing = framing;
  s.unit = unit;
  s.pdu = std::move(pdu);
  s.expect = std::move(expect);
  s.note = std::move(note);
  return s;
}

Step raw_rtu(Bytes adu, std::optional<size_t> gap, Expect expect, std::string note) {
  Step s;
  s.kind = Step::Kind::raw;
  s.bytes = std::move(adu);
  s.gap = gap;
  s.expect = std::move(expect);
  s.note = std::move(note);
  return s;
}

Step advance(uint64_t us) {
  Step s;
  s.kind = Step::Kind::advance;
  s.us = us;
  return s;
}

Step power_cycle() {
  Step s;
  s.kind = Step::Kind::power_cycle;
  return s;
}

// ---- reading ---------------------------------------------------------------

Script parse(const std::string& text, const std::string& file) {
  Script sc;
  std::istringstream in(text);
  std::string raw_line;
  bool header = false, in_comment = true;
  for (int n = 1; std::getline(in, raw_line); ++n) {
    LineParser p{file, n};
    if (!raw_line.empty() && raw_line.back() == '\r') raw_line.pop_back();
    if (!header) {
      if (raw_line != kHeader)
        p.fail(1, "header", fmt::format("the first line must be '{}' (a frame script of this version)", kHeader));
      header = true;
      continue;
    }
    auto hash = raw_line.find('#');
    std::string note = hash == std::string::npos ? "" : raw_line.substr(hash + 1);
    while (!note.empty() && isspace(uint8_t(note.front()))) note.erase(note.begin());
    auto w = words_of(raw_line.substr(0, hash));
    if (w.empty()) {
      if (in_comment && hash != std::string::npos) sc.comment += note + "\n";
      continue;
    }
    in_comment = false;
    const std::string& kw = w[0].text;
    if (kw == "device" || kw == "fault") {
      if (w.size() != 2) p.fail(w[0].col, "header", kw + " takes one name");
      (kw == "device" ? sc.device : sc.fault) = w[1].text;
      continue;
    }
    // The expectation follows "->".
    size_t arrow = w.size();
    for (size_t i = 0; i < w.size(); ++i)
      if (w[i].text == "->") arrow = i;
    Step st;
    st.note = note;
    st.line = n;
    if (arrow < w.size()) {
      if (arrow + 1 >= w.size()) p.fail(w[arrow].col, "expect", "'->' needs an expectation: reply HEX, exception XX, silence, normal, any, any-or-silence");
      const Word& e = w[arrow + 1];
      if (e.text == "reply") {
        st.expect.kind = Expect::Kind::reply;
        st.expect.pdu = p.hex(w, arrow + 2, w.size());
        if (st.expect.pdu.empty()) p.fail(e.col, "expect", "reply needs the reply PDU as hex");
      } else if (e.text == "exception") {
        st.expect.kind = Expect::Kind::exception;
        Bytes c = arrow + 3 == w.size() ? p.hex(w, arrow + 2, w.size()) : Bytes{};
        if (c.size() != 1) p.fail(e.col, "expect", "exception takes one code byte (e.g. exception 02)");
        st.expect.code = c[0];
      } else if (e.text == "silence" || e.text == "normal" || e.text == "any" || e.text == "any-or-silence") {
        if (arrow + 2 != w.size()) p.fail(w[arrow + 2].col, "expect", e.text + " takes nothing after it");
        st.expect.kind = e.text == "silence"  ? Expect::Kind::silence
                         : e.text == "normal" ? Expect::Kind::normal
                         : e.text == "any"    ? Expect::Kind::any
                                              : Expect::Kind::any_or_silence;
      } else {
        p.fail(e.col, "expect", "'" + e.text + "' is not an expectation (reply HEX, exception XX, silence, normal, any, any-or-silence)");
      }
    }
    auto no_args = [&](size_t want) {
      if (arrow != want) p.fail(w[want].col, "step", kw + ": unexpected '" + w[want].text + "'");
    };
    if (kw == "rtu") {
      Bytes adu = p.hex(w, 1, arrow);
      if (adu.size() < 4) p.fail(w[0].col, "rtu", "an RTU frame is at least unit, function code and CRC (4 bytes)");
      if (!crc_ok(adu)) p.fail(w[0].col, "crc", "the CRC is wrong; a frame that must go out with a bad CRC is written raw-rtu");
      st.framing = Framing::rtu;
      st.unit = adu[0];
      st.pdu.assign(adu.begin() + 1, adu.end() - 2);
    } else if (kw == "mbap") {
      bool star = w.size() > 1 && w[1].text == "*";
      Bytes adu = p.hex(w, star ? 2 : 1, arrow);
      if (star) adu.insert(adu.begin(), 2, 0);
      if (adu.size() < kMbapHeader + 1) p.fail(w[0].col, "mbap", "an MBAP frame is the 7-byte header and a PDU");
      if (!star) st.tid = be16(adu, 0);
      if (adu[2] != 0 || adu[3] != 0) p.fail(w[0].col, "mbap", "protocol id is not 0; such a frame is written raw-mbap");
      if (size_t(be16(adu, 4)) != adu.size() - 6)
        p.fail(w[0].col, "mbap", "the length field does not count unit id and PDU; such a frame is written raw-mbap");
      st.framing = Framing::mbap;
      st.unit = adu[6];
      st.pdu.assign(adu.begin() + kMbapHeader, adu.end());
    } else if (kw == "raw-rtu" || kw == "raw-mbap") {
      st.kind = Step::Kind::raw;
      st.framing = kw == "raw-rtu" ? Framing::rtu : Framing::mbap;
      st.bytes = p.hex(w, 1, arrow, kw == "raw-rtu" ? &st.gap : nullptr);
      if (st.bytes.empty()) p.fail(w[0].col, "step", kw + " needs the bytes as hex");
    } else if (kw == "advance" || kw == "wait") {
      if (arrow < 2) p.fail(w[0].col, "step", kw + (kw == "wait" ? " takes milliseconds" : " takes microseconds"));
      no_args(2);
      st.kind = kw == "advance" ? Step::Kind::advance : Step::Kind::wait;
      st.us = p.number(w[1], kw) * (kw == "wait" ? 1000 : 1);
    } else if (kw == "power-cycle") {
      no_args(1);
      st.kind = Step::Kind::power_cycle;
    } else {
      p.fail(w[0].col, "step",
             "'" + kw + "' is not a step (rtu, mbap, raw-rtu, raw-mbap, advance, power-cycle, wait, device, fault)");
    }
    if (arrow < w.size() && (st.kind != Step::Kind::frame && st.kind != Step::Kind::raw))
      p.fail(w[arrow].col, "expect", kw + " sends no frame, so it expects nothing");
    sc.steps.push_back(std::move(st));
  }
  if (!header) throw ParseError(fmt::format("{}:1:1: error: header: empty; the first line must be '{}'", file, kHeader));
  return sc;
}

Script parse_file(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  if (!in) throw ParseError(path + ":1:1: error: file: cannot read");
  std::ostringstream text;
  text << in.rdbuf();
  return parse(text.str(), path);
}

// ---- sending and judging -----------------------------------------------------

Bytes wire_bytes(const Step& s, Framing framing) {
  if (s.kind == Step::Kind::raw) return s.bytes;
  if (s.kind != Step::Kind::frame) return {};
  return framing == Framing::rtu ? rtu_frame(s.unit, s.pdu) : mbap_frame(s.tid.value_or(0), s.unit, s.pdu);
}

std::optional<Bytes> request_pdu(const Step& s, uint8_t unit) {
  if (s.kind == Step::Kind::frame) return s.pdu;
  if (s.kind != Step::Kind::raw) return std::nullopt;
  std::span<const uint8_t> all(s.bytes);
  if (s.framing == Framing::mbap) {
    if (all.size() <= kMbapHeader) return std::nullopt;
    return Bytes(all.begin() + kMbapHeader, all.end());
  }
  // A gap splits the bytes into two frames for the receiver (MB-SL v1.02
  // §2.5.1.1); either part may happen to be a valid frame of its own.
  std::vector<std::span<const uint8_t>> parts{all};
  if (s.gap && *s.gap < all.size()) parts = {all.first(*s.gap), all.subspan(*s.gap)};
  for (auto a : parts)
    if (a.size() >= 4 && a.size() <= kMaxRtuAdu && crc_ok(a) && a[0] == unit) return Bytes(a.begin() + 1, a.end() - 2);
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

std::optional<Mismatch> check(const Step& s, uint8_t unit, const Reply& r, const spec::Spec* spec) {
  using K = Expect::Kind;
  const Expect& e = s.expect;
  if (e.kind == K::none) return std::nullopt;
  if (e.kind == K::silence) {
    if (r.silent()) return std::nullopt;
    return Mismatch{Mismatch::Kind::answered, "a reply where none may come"};
  }
  if (r.silent()) {
    if (e.kind == K::any_or_silence) return std::nullopt;
    return Mismatch{Mismatch::Kind::silent, "silence where a reply must come"};
  }
  if (!r.framing_error.empty() || !r.pdu) return Mismatch{Mismatch::Kind::malformed_framing, r.framing_error};
  const Bytes& got = *r.pdu;
  auto req = request_pdu(s, unit);
  Judged j;
  if (req && !req->empty()) {
    j = judge_reply(*req, got);
    if (!j.ok()) {
      std::string why = "reply malformed for the request:";
      for (const auto& pr : j.problems) why += " " + pr + ";";
      return Mismatch{Mismatch::Kind::malformed_reply, why};
    }
  } else if (got.size() == 2 && (got[0] & 0x80)) {
    j.kind = Judged::Kind::exception;
    j.exception_code = got[1];
  } else {
    j.kind = Judged::Kind::normal;
  }
  switch (e.kind) {
    case K::reply:
      if (got == e.pdu) return std::nullopt;
      return Mismatch{j.kind == Judged::Kind::exception ? Mismatch::Kind::refused : Mismatch::Kind::different,
                      "expected the reply " + to_hex(e.pdu)};
    case K::exception:
      if (j.kind == Judged::Kind::exception && j.exception_code == e.code) return std::nullopt;
      return Mismatch{Mismatch::Kind::different, fmt::format("expected exception {:02X}", e.code)};
    case K::normal:
      if (j.kind == Judged::Kind::normal) return std::nullopt;
      return Mismatch{Mismatch::Kind::refused, "an exception where a normal reply must come"};
    default:
      break;
  }
  if (j.kind == Judged::Kind::exception && !exception_code_known(spec, j.exception_code))
    return Mismatch{Mismatch::Kind::unknown_exception,
                    fmt::format("exception code {:02X} is neither in MBAP v1.1b3 §7 nor in the spec", j.exception_code)};
  return std::nullopt;
}

std::optional<std::pair<int, std::string>> unsupported(const Script& sc, const TargetInfo& info) {
  const char* kind = info.framing == Framing::rtu ? "RTU" : "MBAP";
  for (const auto& s : sc.steps) {
    switch (s.kind) {
      case Step::Kind::raw:
        if (s.framing != info.framing)
          return std::pair{s.line, fmt::format("raw {} bytes cannot go to {}, whose frames are {}",
                                               s.framing == Framing::rtu ? "RTU" : "MBAP", info.uri, kind)};
        if (!info.raw) return std::pair{s.line, info.uri + " cannot send raw bytes"};
        if (s.gap && info.framing != Framing::rtu) return std::pair{s.line, "a pause inside a frame needs an RTU target"};
        break;
      case Step::Kind::advance:
        if (!info.virtual_clock) return std::pair{s.line, info.uri + " has no virtual clock to advance (in-process targets only)"};
        break;
      case Step::Kind::power_cycle:
        if (!info.power_cycle) return std::pair{s.line, info.uri + " cannot be power-cycled from here (in-process targets only)"};
        break;
      default:
        break;
    }
  }
  return std::nullopt;
}

ReplayResult replay(Target& t, const Script& sc, const spec::Spec* spec) {
  ReplayResult res;
  const TargetInfo& info = t.info();
  if (auto u = unsupported(sc, info)) {
    res.outcome = ReplayResult::Outcome::cannot_run;
    res.line = u->first;
    res.message = u->second;
    return res;
  }
  for (const auto& s : sc.steps) {
    try {
      Reply r;
      switch (s.kind) {
        case Step::Kind::advance: t.advance(std::chrono::microseconds(s.us)); continue;
        case Step::Kind::power_cycle: t.power_cycle(); continue;
        case Step::Kind::wait:
          if (info.virtual_clock) t.advance(std::chrono::microseconds(s.us));
          else std::this_thread::sleep_for(std::chrono::microseconds(s.us));
          continue;
        case Step::Kind::raw: r = t.send_raw(s.bytes, s.gap); break;
        case Step::Kind::frame: r = t.transact(s.unit, s.pdu); break;
      }
      res.replies.push_back(r);
      if (auto m = check(s, info.unit, r, spec)) {
        res.outcome = ReplayResult::Outcome::failed;
        res.line = s.line;
        res.message = fmt::format("{}\n  sent:     {}\n  expected: {}\n  got:      {}", m->why, to_hex(r.request),
                                  expect_text(s.expect), r.silent() ? std::string("(silence)") : to_hex(r.frame));
        return res;
      }
    } catch (const std::logic_error& e) {
      res.outcome = ReplayResult::Outcome::cannot_run;
      res.line = s.line;
      res.message = e.what();
      return res;
    } catch (const std::exception& e) {
      // The target went away during the replay: the steps sent so far did it.
      res.outcome = ReplayResult::Outcome::failed;
      res.line = s.line;
      res.message = fmt::format("the target failed: {}", e.what());
      return res;
    }
  }
  return res;
}

}  // namespace mbc::conf::script
