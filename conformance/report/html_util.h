// Small helpers shared by the HTML writers (html.cpp, html_summary.cpp).
#pragma once

#include <optional>
#include <string>

#include "report/result.h"

namespace mbc::conf::html {

inline std::string esc(const std::string& s) {
  std::string out;
  for (char c : s) {
    switch (c) {
      case '&': out += "&amp;"; break;
      case '<': out += "&lt;"; break;
      case '>': out += "&gt;"; break;
      case '"': out += "&quot;"; break;
      default: out += c;
    }
  }
  return out;
}

// The qualification summary that opens report.html (html_summary.cpp).
std::string summary(const RunReport& rep);

// `expected` and `actual` as hex, the bytes that differ marked (<mark>).
std::string byte_diff(const Bytes& expected, const std::optional<Bytes>& actual);

}  // namespace mbc::conf::html
