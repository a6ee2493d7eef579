#include "capture/serial_log.h"

#include <charconv>
#include <cstring>
#include <ctime>
#include <map>
#include <string>
#include <vector>

#include "modbus/hex.h"
#include "modbus/crc16.h"
#include "modbus/mbap.h"
#include "modbus/text.h"

namespace mbc::conf::capture {
namespace {

constexpr size_t kMaxLine = 64 * 1024;
constexpr size_t kMaxLinks = 4096;

bool digits(std::string_view s, size_t at, size_t n, int& out) {
  if (s.size() < at + n) return false;
  out = 0;
  for (size_t i = at; i < at + n; ++i) {
    if (s[i] < '0' || s[i] > '9') return false;
    out = out * 10 + (s[i] - '0');
  }
  return true;
}

// "123", "123.456789": microseconds after the start of the log.
std::optional<uint64_t> parse_seconds(std::string_view t) {
  uint64_t whole = 0;
  auto [p, ec] = std::from_chars(t.data(), t.data() + t.size(), whole);
  if (ec != std::errc() || p == t.data() || whole > 100000000000ull) return std::nullopt;
  uint64_t us = whole * 1000000u;
  if (p != t.data() + t.size()) {
    if (*p != '.') return std::nullopt;
    ++p;
    uint64_t scale = 100000;
    const char* end = t.data() + t.size();
    if (p == end) return std::nullopt;
    for (; p != end; ++p) {
      if (*p < '0' || *p > '9') return std::nullopt;
      us += uint64_t(*p - '0') * scale;
      scale /= 10;
    }
  }
  return us;
}

}  // namespace

std::optional<uint64_t> parse_log_time(std::string_view t) {
  if (t.find('T') == std::string_view::npos) return parse_seconds(t);
  // YYYY-MM-DDTHH:MM:SS[.fffffffff]Z
  int y, mo, d, h, mi, s;
  if (!digits(t, 0, 4, y) || t.size() < 20 || t[4] != '-' || !digits(t, 5, 2, mo) || t[7] != '-' ||
      !digits(t, 8, 2, d) || t[10] != 'T' || !digits(t, 11, 2, h) || t[13] != ':' || !digits(t, 14, 2, mi) ||
      t[16] != ':' || !digits(t, 17, 2, s))
    return std::nullopt;
  if (mo < 1 || mo > 12 || d < 1 || d > 31 || h > 23 || mi > 59 || s > 60 || y < 1970) return std::nullopt;
  size_t at = 19;
  uint64_t us = 0;
  if (at < t.size() && t[at] == '.') {
    ++at;
    uint64_t scale = 100000;
    size_t start = at;
    while (at < t.size() && t[at] >= '0' && t[at] <= '9') {
      us += uint64_t(t[at] - '0') * scale;
      scale /= 10;
      ++at;
    }
    if (at == start) return std::nullopt;
  }
  if (at + 1 != t.size() || t[at] != 'Z') return std::nullopt;
  std::tm tm{};
  tm.tm_year = y - 1900;
  tm.tm_mon = mo - 1;
  tm.tm_mday = d;
  tm.tm_hour = h;
  tm.tm_min = mi;
  tm.tm_sec = s;
  time_t secs = timegm(&tm);
  if (secs < 0) return std::nullopt;
  return uint64_t(secs) * 1000000u + us;
}

ReadStats read_serial_log(FILE* f, FrameSink& sink) {
  ReadStats st;
  st.format = "serial log";
  std::map<std::string, uint32_t> links;
  std::vector<std::string> names;
  uint64_t bad_lines = 0;
  std::string line;
  std::vector<char> buf(kMaxLine + 2);
  bool skipping = false;  // the rest of a line over kMaxLine
  {
    // A log is text: a NUL byte in its first block means a binary file.
    char head[4096];
    size_t got = std::fread(head, 1, sizeof head, f);
    std::rewind(f);
    if (std::memchr(head, 0, got)) {
      st.error = "neither pcap, pcapng nor a serial log: binary data that no reader knows";
      return st;
    }
  }
  while (std::fgets(buf.data(), int(buf.size()), f)) {
    size_t n = std::strlen(buf.data());
    st.bytes += n;
    bool whole = n > 0 && buf[n - 1] == '\n';
    if (skipping) {
      skipping = !whole;
      continue;
    }
    ++st.packets;
    if (!whole && !std::feof(f)) {
      sink.finding({st.packets, strf("line longer than %zu bytes: skipped", kMaxLine)});
      skipping = true;
      continue;
    }
    std::string_view l(buf.data(), n);
    while (!l.empty() && (l.back() == '\n' || l.back() == '\r')) l.remove_suffix(1);
    size_t bar = l.find('|');
    std::string_view body = l.substr(0, bar);
    // Tokens split by blanks.
    std::vector<std::string_view> tok;
    for (size_t i = 0; i < body.size();) {
      while (i < body.size() && (body[i] == ' ' || body[i] == '\t')) ++i;
      size_t j = i;
      while (j < body.size() && body[j] != ' ' && body[j] != '\t') ++j;
      if (j > i) tok.push_back(body.substr(i, j - i));
      i = j;
    }
    if (tok.empty() || tok[0][0] == '#') continue;
    auto t = parse_log_time(tok[0]);
    if (!t) {
      if (++bad_lines <= 20)
        sink.finding({st.packets, strf("not 'TIME [LINK] rx|tx HEX': '%.60s'", std::string(l).c_str())});
      continue;
    }
    size_t dir = 1;
    while (dir < tok.size() && tok[dir] != "rx" && tok[dir] != "tx" && tok[dir] != "--") ++dir;
    if (dir == tok.size() || tok[dir] == "--") continue;  // an event (connected, closed, no reply)
    std::string link;
    for (size_t i = 1; i < dir; ++i) link += (i > 1 ? " " : "") + std::string(tok[i]);
    std::string hex;
    for (size_t i = dir + 1; i < tok.size(); ++i) hex += std::string(tok[i]) + " ";
    auto bytes = parse_hex(hex);
    if (!bytes || bytes->empty()) {
      sink.finding({st.packets, strf("%s: not hex bytes: '%.60s'", tok[dir] == "rx" ? "rx" : "tx", hex.c_str())});
      continue;
    }
    auto it = links.find(link);
    if (it == links.end()) {
      if (links.size() >= kMaxLinks) {
        sink.finding({st.packets, strf("more than %zu links in one log: '%s' skipped", kMaxLinks, link.c_str())});
        continue;
      }
      it = links.emplace(link, uint32_t(links.size())).first;
      names.push_back(link.empty() ? "serial line" : link);
      ++st.streams;
    }
    Frame fr;
    fr.time_us = *t;
    fr.packet = st.packets;
    fr.stream = it->second;
    fr.conversation = names[it->second];
    fr.to_server = tok[dir] == "rx";
    // A serve trace of a TCP link carries MBAP ADUs: a header whose length
    // matches the line's bytes; anything else is an RTU frame.
    // An RTU frame whose CRC checks is RTU even when it also reads as one
    // MBAP ADU ("01 03 00 00 00 02 C4 0B": protocol 0, length 2).
    auto h = parse_mbap(*bytes);
    bool mbap = !(bytes->size() >= 4 && crc_ok(*bytes)) && h && h->protocol == 0 && h->adu_size() == bytes->size() &&
                h->length_ok();
    fr.carrier = mbap ? Carrier::mbap : Carrier::rtu;
    fr.timed_line = !mbap;
    fr.adu = std::move(*bytes);
    ++st.frames;
    sink.frame(fr);
  }
  if (bad_lines > 20) sink.finding({st.packets, strf("%llu lines not in the format in all", (unsigned long long)bad_lines)});
  if (st.frames == 0 && bad_lines > 0)
    st.error = "neither pcap, pcapng nor a serial log: no line reads 'TIME [LINK] rx|tx HEX' (conformance/capture/README.md)";
  if (std::ferror(f)) st.error = strf("read error after line %llu", (unsigned long long)st.packets);
  for (uint32_t i = 0; i < names.size(); ++i) sink.stream_end(i);
  return st;
}

}  // namespace mbc::conf::capture
