#include "csv.h"

#include <cstdlib>
#include <stdexcept>

namespace mbc::exchange {

std::vector<CsvRecord> parse_csv(std::string_view text) {
  if (text.substr(0, 3) == "\xEF\xBB\xBF") text.remove_prefix(3);
  std::string_view first = text.substr(0, text.find('\n'));
  const char sep = first.find(',') == std::string_view::npos && first.find(';') != std::string_view::npos ? ';' : ',';

  std::vector<CsvRecord> out;
  CsvRecord rec{1, {}};
  std::string field;
  bool quoted = false, was_quoted = false, any = false;
  int line = 1, quote_line = 0;
  auto end_record = [&] {
    if (any || !field.empty() || was_quoted) rec.fields.push_back(field);
    bool blank = rec.fields.empty() || (rec.fields.size() == 1 && rec.fields[0].empty() && !was_quoted);
    if (!blank) out.push_back(std::move(rec));
    rec = CsvRecord{line, {}};
    field.clear();
    any = was_quoted = false;
  };
  for (size_t i = 0; i < text.size(); ++i) {
    char c = text[i];
    if (quoted) {
      if (c == '"') {
        if (i + 1 < text.size() && text[i + 1] == '"') {
          field += '"';
          ++i;
        } else {
          quoted = false;
        }
      } else {
        if (c == '\n') ++line;
        field += c;
      }
      continue;
    }
    if (c == '"' && field.empty() && !was_quoted) {
      quoted = was_quoted = true;
      quote_line = line;
    } else if (c == sep) {
      rec.fields.push_back(field);
      field.clear();
      any = true;
      was_quoted = false;
    } else if (c == '\n') {
      ++line;
      end_record();
    } else if (c != '\r') {
      field += c;
    }
  }
  if (quoted) throw std::runtime_error(std::to_string(quote_line) + ": error: a quoted field is not closed");
  end_record();
  return out;
}

namespace {
bool formula_start(char c) { return c == '=' || c == '+' || c == '-' || c == '@' || c == '\t' || c == '\r'; }

// A plain decimal number ("-10", "-0.5", "-1e-05"): a spreadsheet reads it
// as a number, not a formula, so it stays as it is.
bool plain_number(std::string_view s) {
  std::string t(s);
  char* end = nullptr;
  std::strtod(t.c_str(), &end);
  return !t.empty() && end == t.c_str() + t.size() && t.find_first_of("xXnNiI \t") == std::string::npos;
}

// "'=x", "''=x": apostrophes, then a formula character.
bool escaped_formula(std::string_view s) {
  size_t i = s.find_first_not_of('\'');
  return i != 0 && i != std::string_view::npos && formula_start(s[i]);
}
}  // namespace

std::string csv_text(std::string_view s) { return std::string(escaped_formula(s) ? s.substr(1) : s); }

std::string csv_field(std::string_view s) {
  bool formula = !s.empty() && ((formula_start(s[0]) && !plain_number(s)) || escaped_formula(s));
  if (formula) {
    std::string q = "\"'";
    for (char c : s) {
      if (c == '"') q += '"';
      q += c;
    }
    return q + "\"";
  }
  if (s.find_first_of(",;\"\r\n") == std::string_view::npos) return std::string(s);
  std::string q = "\"";
  for (char c : s) {
    if (c == '"') q += '"';
    q += c;
  }
  return q + "\"";
}

}  // namespace mbc::exchange
