#include "modbus/hex.h"

namespace mbc {
namespace {

int nibble(char c) {
  if (c >= '0' && c <= '9') return c - '0';
  if (c >= 'A' && c <= 'F') return c - 'A' + 10;
  if (c >= 'a' && c <= 'f') return c - 'a' + 10;
  return -1;
}

}  // namespace

std::optional<Bytes> parse_hex_strict(std::string_view s) {
  Bytes out;
  if (s.empty()) return std::nullopt;
  for (size_t i = 0; i < s.size(); i += 3) {
    if (i + 2 > s.size()) return std::nullopt;
    char a = s[i], b = s[i + 1];
    if ((a >= 'a' && a <= 'f') || (b >= 'a' && b <= 'f')) return std::nullopt;
    int hi = nibble(a), lo = nibble(b);
    if (hi < 0 || lo < 0) return std::nullopt;
    out.push_back(uint8_t(hi * 16 + lo));
    if (i + 2 < s.size() && s[i + 2] != ' ') return std::nullopt;
    if (i + 2 == s.size() - 1) return std::nullopt;  // trailing space
  }
  return out;
}

std::optional<Bytes> parse_hex(std::string_view s) {
  Bytes out;
  int pending = -1;
  for (char c : s) {
    if (c == ' ' || c == '\t' || c == '\n' || c == '\r') continue;
    int n = nibble(c);
    if (n < 0) return std::nullopt;
    if (pending < 0) pending = n;
    else {
      out.push_back(uint8_t(pending * 16 + n));
      pending = -1;
    }
  }
  if (pending >= 0) return std::nullopt;
  return out;
}

std::string to_hex(std::span<const uint8_t> bytes) {
  static const char* digits = "0123456789ABCDEF";
  std::string s;
  s.reserve(bytes.size() * 3);
  for (size_t i = 0; i < bytes.size(); ++i) {
    if (i) s += ' ';
    s += digits[bytes[i] >> 4];
    s += digits[bytes[i] & 15];
  }
  return s;
}

}  // namespace mbc
