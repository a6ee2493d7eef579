// RFC 4180 CSV: records with the line each starts on, and quoting for output.
#pragma once

#include <string>
#include <string_view>
#include <vector>

namespace mbc::exchange {

struct CsvRecord {
  int line = 0;  // 1-based line the record starts on
  std::vector<std::string> fields;
};

// Splits `text` into records. Fields may be quoted ("a,b", "say ""hi"""),
// and a quoted field may span lines. The separator is ',' unless the first
// line has ';' and no ',' (spreadsheets in locales with a decimal comma).
// A UTF-8 byte order mark is skipped; blank lines are dropped.
// Throws std::runtime_error("LINE: what") on an unterminated quote.
std::vector<CsvRecord> parse_csv(std::string_view text);

// One field, quoted when it holds a separator, a quote or a line break. A
// field a spreadsheet would run as a formula (it starts with '=', '+', '-',
// '@', a tab or a carriage return, and is not a number: CSV injection,
// OWASP) is written as text: quoted, behind an apostrophe ("'=1+2"), which
// csv_text reads back.
std::string csv_field(std::string_view s);

// A field as csv_field wrote it: an apostrophe before a formula character
// is dropped ("'=1+2" -> "=1+2", "''=x" -> "'=x").
std::string csv_text(std::string_view s);

}  // namespace mbc::exchange
