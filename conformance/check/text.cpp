#include "check/text.h"

#include <fmt/core.h>

#include <algorithm>
#include <fstream>
#include <sstream>

#include "check/judge.h"
#include "modbus/bytes.h"
#include "modbus/crc16.h"
#include "modbus/limits.h"
#include "modbus/mbap.h"
#include "modbus/rtu.h"

namespace mbc::conf::check {

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
      uint64_t v = std::stoull(w.text, &used, 0);
      if (used == w.text.size() && w.text[0] != '-') return v;
    } catch (const std::exception&) {
    }
    fail(w.col, "number", what + " takes a whole number, not '" + w.text + "'");
  }
  // One expectation from words[from, to).
  Expect expect(const std::vector<Word>& w, size_t from, size_t to) const {
    constexpr const char* kinds =
        "reply HEX [frame HEX], exception XX, silence, normal, registers WWWW[/MMMM]..., same-as N, answered, any, any-or-silence, "
        "anything";
    Expect e;
    if (from >= to) fail(w[from - 1].col, "expect", std::string("an expectation is one of: ") + kinds);
    const Word& k = w[from];
    auto nothing_after = [&] {
      if (from + 1 != to) fail(w[from + 1].col, "expect", k.text + " takes nothing after it");
    };
    if (k.text == "reply") {
      e.kind = Expect::Kind::reply;
      size_t f = from + 1;
      while (f < to && w[f].text != "frame") ++f;
      e.pdu = hex(w, from + 1, f);
      if (e.pdu.empty()) fail(k.col, "expect", "reply needs the reply PDU as hex");
      if (f < to) {
        e.adu = hex(w, f + 1, to);
        if (e.adu->empty()) fail(w[f].col, "expect", "frame needs the reply ADU as hex");
      }
    } else if (k.text == "exception") {
      e.kind = Expect::Kind::exception;
      Bytes c = from + 2 == to ? hex(w, from + 1, to) : Bytes{};
      if (c.size() != 1) fail(k.col, "expect", "exception takes one code byte (e.g. exception 02)");
      e.code = c[0];
    } else if (k.text == "registers") {
      e.kind = Expect::Kind::registers;
      for (size_t i = from + 1; i < to; ++i) {
        // WWWW, or WWWW/MMMM: only the bits of the mask are compared.
        std::string word = w[i].text, mask;
        if (auto slash = word.find('/'); slash != std::string::npos) {
          mask = word.substr(slash + 1);
          word = word.substr(0, slash);
        }
        auto v = parse_hex(word);
        if (!v || word.size() != 4) fail(w[i].col, "expect", "'" + w[i].text + "' is not a register (four hex digits, or WWWW/MMMM)");
        e.words.push_back(uint16_t((*v)[0] << 8 | (*v)[1]));
        uint16_t m = 0xFFFF;
        if (!mask.empty()) {
          auto mv = parse_hex(mask);
          if (!mv || mask.size() != 4) fail(w[i].col, "expect", "'" + w[i].text + "': the mask after / is four hex digits");
          m = uint16_t((*mv)[0] << 8 | (*mv)[1]);
        }
        e.masks.push_back(m);
      }
      if (std::all_of(e.masks.begin(), e.masks.end(), [](uint16_t m) { return m == 0xFFFF; })) e.masks.clear();
    } else if (k.text == "same-as") {
      e.kind = Expect::Kind::same;
      if (from + 2 != to) fail(k.col, "expect", "same-as takes the number of an earlier step of the case (1 is its first)");
      uint64_t n = number(w[from + 1], "same-as");
      if (n < 1) fail(w[from + 1].col, "expect", "steps are numbered from 1");
      e.memo = int(n) - 1;
    } else if (k.text == "silence" || k.text == "normal" || k.text == "any" || k.text == "any-or-silence" ||
               k.text == "answered" || k.text == "anything") {
      nothing_after();
      e.kind = k.text == "anything"   ? Expect::Kind::none
               : k.text == "silence"  ? Expect::Kind::silence
               : k.text == "normal"   ? Expect::Kind::normal
               : k.text == "any"      ? Expect::Kind::any
               : k.text == "answered" ? Expect::Kind::answered
                                      : Expect::Kind::any_or_silence;
    } else {
      fail(k.col, "expect", "'" + k.text + "' is not an expectation (" + kinds + ")");
    }
    return e;
  }
};

std::string rest_of(const std::string& raw, const Word& w) {
  std::string r = raw.substr(size_t(w.col - 1) + w.text.size());
  while (!r.empty() && isspace(uint8_t(r.front()))) r.erase(r.begin());
  while (!r.empty() && isspace(uint8_t(r.back()))) r.pop_back();
  return r;
}

}  // namespace

// ---- writing ---------------------------------------------------------------

namespace {
std::string one_expect(const Expect& e) {
  switch (e.kind) {
    case Expect::Kind::none: return "anything";
    case Expect::Kind::reply: return "reply " + to_hex(e.pdu) + (e.adu ? " frame " + to_hex(*e.adu) : "");
    case Expect::Kind::exception: return fmt::format("exception {:02X}", e.code);
    case Expect::Kind::silence: return "silence";
    case Expect::Kind::normal: return "normal";
    case Expect::Kind::registers: {
      std::string s = "registers";
      for (size_t i = 0; i < e.words.size(); ++i) {
        s += fmt::format(" {:04X}", e.words[i]);
        if (i < e.masks.size() && e.masks[i] != 0xFFFF) s += fmt::format("/{:04X}", e.masks[i]);
      }
      return s;
    }
    case Expect::Kind::same: return fmt::format("same-as {}", e.memo + 1);
    case Expect::Kind::answered: return "answered";
    case Expect::Kind::any: return "any";
    case Expect::Kind::any_or_silence: return "any-or-silence";
  }
  return "";
}
}  // namespace

std::string expect_text(const Expect& e) {
  std::string s = one_expect(e);
  for (const auto& alt : e.either) s += " or " + one_expect(alt);
  return s;
}

std::string line(const Step& s, std::optional<Framing> framing) {
  std::string l;
  switch (s.kind) {
    case Step::Kind::frame:
      if (framing.value_or(s.framing) == &mbc::kRtu) {
        l = "rtu " + to_hex(rtu_frame(s.unit, s.pdu));
      } else {
        Bytes adu = mbap_frame(s.tid.value_or(0), s.unit, s.pdu);
        l = "mbap " + (s.tid ? to_hex(adu) : "* " + to_hex(std::span(adu).subspan(2)));
      }
      break;
    case Step::Kind::raw: {
      l = s.framing == &mbc::kRtu ? "raw-rtu" : "raw-mbap";
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
  if (s.setup) l += " +setup";
  if (s.may_go_unanswered) l += " +may-go-unanswered";
  if (s.words_from >= 0) l += fmt::format(" +words-from={}", s.words_from + 1);
  if (s.expect.kind != Expect::Kind::none || !s.expect.either.empty()) l += "  -> " + expect_text(s.expect);
  std::string note = s.note;
  if (!s.expect.text.empty()) note += " | " + s.expect.text;
  for (char& c : note)
    if (c == '\n') c = ' ';
  if (!note.empty()) l += "   # " + note;
  return l;
}

std::vector<std::string> case_lines(const Case& c, Framing framing) {
  std::vector<std::string> out;
  out.push_back(fmt::format("case {} {} {}", c.id, to_string(c.level), c.clause));
  if (!c.title.empty()) out.push_back("title " + c.title);
  for (auto [a, n] : c.touches) out.push_back(fmt::format("touches 0x{:04X} {}", a, n));
  if (c.functions_optional) out.push_back("functions-optional");
  if (!c.incomparable.empty()) out.push_back("incomparable " + c.incomparable);
  if (!c.skip_reason.empty()) out.push_back("skip " + c.skip_reason);
  for (const auto& st : c.steps) out.push_back((c.skip_reason.empty() ? "" : "# ") + line(st, framing));
  return out;
}

std::string format(const Script& s) {
  std::string out = std::string(kHeader) + "\n";
  std::istringstream c(s.comment);
  for (std::string l; std::getline(c, l);) out += l.empty() ? "#\n" : "# " + l + "\n";
  if (!s.device.empty()) out += "device " + s.device + "\n";
  if (!s.fault.empty()) out += "fault " + s.fault + "\n";
  for (const auto& st : s.steps) out += line(st) + "\n";
  for (const auto& cs : s.cases)
    for (const auto& l : case_lines(cs, &mbc::kRtu)) out += l + "\n";
  return out;
}

// ---- reading ---------------------------------------------------------------

Script parse(const std::string& text, const std::string& file) {
  Script sc;
  std::istringstream in(text);
  std::string raw_line;
  bool header = false, in_comment = true, v2 = false;
  std::optional<size_t> open_at;  // the case the next steps belong to
  auto open = [&]() -> Case* { return open_at ? &sc.cases[*open_at] : nullptr; };
  for (int n = 1; std::getline(in, raw_line); ++n) {
    LineParser p{file, n};
    if (!raw_line.empty() && raw_line.back() == '\r') raw_line.pop_back();
    if (!header) {
      if (raw_line != kHeader && raw_line != kHeaderV1)
        p.fail(1, "header", fmt::format("the first line must be '{}' (a frame script of this version)", kHeader));
      header = true;
      v2 = raw_line == kHeader;
      continue;
    }
    // Lines whose text runs to the end of the line ('#' included).
    if (auto lw = words_of(raw_line); !lw.empty() && v2 &&
                                      (lw[0].text == "case" || lw[0].text == "title" || lw[0].text == "skip" ||
                                       lw[0].text == "incomparable")) {
      in_comment = false;
      const std::string& kw = lw[0].text;
      if (kw == "case") {
        if (lw.size() < 3) p.fail(lw[0].col, "case", "case takes an id, a level (MUST, SHOULD, OBSERVED) and the clause");
        Case c;
        c.id = lw[1].text;
        c.line = n;
        if (auto a = c.id.find('/'); a != std::string::npos) c.family = c.id.substr(a + 1, c.id.find('/', a + 1) - a - 1);
        bool known = false;
        for (Level l : {Level::must, Level::should, Level::observed})
          if (lw[2].text == to_string(l)) {
            c.level = l;
            known = true;
          }
        if (!known) p.fail(lw[2].col, "case", "'" + lw[2].text + "' is not a level (MUST, SHOULD, OBSERVED)");
        c.clause = rest_of(raw_line, lw[2]);
        sc.cases.push_back(std::move(c));
        open_at = sc.cases.size() - 1;
        continue;
      }
      if (!open()) p.fail(lw[0].col, kw, kw + " belongs to a case: write it after a 'case' line");
      if (!open()->steps.empty()) p.fail(lw[0].col, kw, kw + " comes before the case's first step");
      std::string& field = kw == "title" ? open()->title : kw == "skip" ? open()->skip_reason : open()->incomparable;
      field = rest_of(raw_line, lw[0]);
      if (kw != "title" && field.empty()) p.fail(lw[0].col, kw, kw + " takes the reason");
      continue;
    }
    auto hash = raw_line.find('#');
    std::string note = hash == std::string::npos ? "" : raw_line.substr(hash + 1);
    while (!note.empty() && isspace(uint8_t(note.front()))) note.erase(note.begin());
    auto all = words_of(raw_line.substr(0, hash));
    if (all.empty()) {
      if (in_comment && hash != std::string::npos) sc.comment += note + "\n";
      continue;
    }
    in_comment = false;
    // Flags ("+setup") may stand anywhere before the expectation.
    Step st;
    std::vector<Word> w;
    for (const auto& x : all) {
      if (x.text.size() < 2 || x.text[0] != '+') {
        w.push_back(x);
        continue;
      }
      if (!v2) p.fail(x.col, "flag", "flags are version 2 (" + std::string(kHeader) + ")");
      if (x.text == "+setup") st.setup = true;
      else if (x.text == "+may-go-unanswered") st.may_go_unanswered = true;
      else if (x.text.rfind("+words-from=", 0) == 0) {
        uint64_t k = p.number(Word{x.text.substr(12), x.col}, "+words-from=");
        if (k < 1) p.fail(x.col, "flag", "steps are numbered from 1");
        st.words_from = int(k) - 1;
      } else {
        p.fail(x.col, "flag", "'" + x.text + "' is not a flag (+setup, +may-go-unanswered, +words-from=N)");
      }
    }
    if (w.empty()) p.fail(all[0].col, "step", "a flag needs a step");
    const std::string& kw = w[0].text;
    if (kw == "device" || kw == "fault") {
      if (w.size() != 2) p.fail(w[0].col, "header", kw + " takes one name");
      (kw == "device" ? sc.device : sc.fault) = w[1].text;
      continue;
    }
    if (v2 && (kw == "touches" || kw == "functions-optional")) {
      if (!open()) p.fail(w[0].col, kw, kw + " belongs to a case: write it after a 'case' line");
      if (kw == "functions-optional") {
        if (w.size() != 1) p.fail(w[1].col, kw, "functions-optional takes nothing after it");
        open()->functions_optional = true;
      } else {
        if (w.size() != 3) p.fail(w[0].col, kw, "touches takes a register address and a count of words");
        open()->touches.emplace_back(uint16_t(p.number(w[1], "touches")), int(p.number(w[2], "touches")));
      }
      continue;
    }
    // The expectation follows "->"; readings are separated by "or".
    size_t arrow = w.size();
    for (size_t i = 0; i < w.size(); ++i)
      if (w[i].text == "->") arrow = i;
    if (auto bar = note.find(" | "); v2 && bar != std::string::npos) {
      st.expect.text = note.substr(bar + 3);
      note.resize(bar);
    }
    st.note = note;
    st.line = n;
    if (arrow < w.size()) {
      std::string text = st.expect.text;
      size_t from = arrow + 1;
      for (size_t i = arrow + 1; i <= w.size(); ++i) {
        if (i < w.size() && w[i].text != "or") continue;
        if (!v2 && i < w.size()) p.fail(w[i].col, "expect", "readings ('or') are version 2 (" + std::string(kHeader) + ")");
        Expect e = p.expect(w, from, i);
        if (from == arrow + 1) st.expect = std::move(e);
        else st.expect.either.push_back(std::move(e));
        from = i + 1;
      }
      st.expect.text = text;
    }
    auto no_args = [&](size_t want) {
      if (arrow != want) p.fail(w[want].col, "step", kw + ": unexpected '" + w[want].text + "'");
    };
    if (kw == "rtu") {
      Bytes adu = p.hex(w, 1, arrow);
      if (adu.size() < 4) p.fail(w[0].col, "rtu", "an RTU frame is at least unit, function code and CRC (4 bytes)");
      if (!crc_ok(adu)) p.fail(w[0].col, "crc", "the CRC is wrong; a frame that must go out with a bad CRC is written raw-rtu");
      Unframed u = rtu_unframe(adu);
      st.framing = &mbc::kRtu;
      st.unit = u.unit;
      st.pdu = std::move(u.pdu);
    } else if (kw == "mbap") {
      bool star = w.size() > 1 && w[1].text == "*";
      Bytes adu = p.hex(w, star ? 2 : 1, arrow);
      if (star) adu.insert(adu.begin(), 2, 0);
      if (adu.size() < kMbapHeader + 1) p.fail(w[0].col, "mbap", "an MBAP frame is the 7-byte header and a PDU");
      Unframed u = mbap_unframe(adu);
      if (adu[2] != 0 || adu[3] != 0) p.fail(w[0].col, "mbap", "protocol id is not 0; such a frame is written raw-mbap");
      if (!u.ok()) p.fail(w[0].col, "mbap", "the length field does not count unit id and PDU; such a frame is written raw-mbap");
      if (!star) st.tid = u.transaction;
      st.framing = &mbc::kTcp;
      st.unit = u.unit;
      st.pdu = std::move(u.pdu);
    } else if (kw == "raw-rtu" || kw == "raw-mbap") {
      st.kind = Step::Kind::raw;
      st.framing = kw == "raw-rtu" ? &mbc::kRtu : &mbc::kTcp;
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
             "'" + kw + "' is not a step (rtu, mbap, raw-rtu, raw-mbap, advance, power-cycle, wait, device, fault" +
                 (v2 ? ", case, title, skip, touches, functions-optional)" : ")"));
    }
    if (arrow < w.size() && (st.kind != Step::Kind::frame && st.kind != Step::Kind::raw))
      p.fail(w[arrow].col, "expect", kw + " sends no frame, so it expects nothing");
    if (st.expect.kind == Expect::Kind::same || st.words_from >= 0) {
      int k = st.expect.kind == Expect::Kind::same ? st.expect.memo : st.words_from;
      size_t have = open() ? open()->steps.size() : sc.steps.size();
      if (size_t(k) >= have) p.fail(w[0].col, "step", fmt::format("step {} is not an earlier step of this case", k + 1));
    }
    (open() ? open()->steps : sc.steps).push_back(std::move(st));
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

}  // namespace mbc::conf::check
