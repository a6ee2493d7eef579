// printf into a std::string, for this floor's messages (modbus/ uses the
// standard library only, so no fmt here).
#pragma once

#include <cstdarg>
#include <cstdio>
#include <string>

namespace mbc {

[[gnu::format(printf, 1, 2)]] inline std::string strf(const char* format, ...) {
  va_list args;
  va_start(args, format);
  va_list again;
  va_copy(again, args);
  int n = std::vsnprintf(nullptr, 0, format, args);
  va_end(args);
  std::string s(n > 0 ? size_t(n) : 0, '\0');
  if (n > 0) std::vsnprintf(s.data(), s.size() + 1, format, again);
  va_end(again);
  return s;
}

}  // namespace mbc
