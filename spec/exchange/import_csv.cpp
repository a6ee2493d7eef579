// `mbconform spec import --csv`: a CSV register map -> a spec skeleton.
#include <cerrno>
#include <cmath>
#include <cstdlib>
#include <filesystem>
#include <map>
#include <optional>
#include <set>
#include <stdexcept>

#include <fmt/core.h>
#include <nlohmann/json.hpp>

#include "csv.h"
#include "exchange.h"
#include "loader.h"

namespace mbc::exchange {

const std::vector<std::string> kCsvColumns = {"table", "address", "name", "access", "type",  "words",      "word_order",
                                              "min",   "max",     "default", "unit", "scale", "description"};

namespace {

using spec::Access;
using spec::DataType;
using spec::Table;
using spec::WordOrder;

// Lower case, letters and digits only: "Word Order" == "word_order" == "WORD-ORDER".
std::string norm(std::string_view s) {
  std::string n;
  for (unsigned char c : s)
    if (std::isalnum(c)) n += char(std::tolower(c));
  return n;
}

std::string trim(std::string_view s) {
  size_t b = s.find_first_not_of(" \t"), e = s.find_last_not_of(" \t");
  return b == std::string_view::npos ? "" : std::string(s.substr(b, e - b + 1));
}

// Header names and their aliases (normalised), by canonical column.
const std::map<std::string, std::vector<std::string>>& column_aliases() {
  static const std::map<std::string, std::vector<std::string>> m = {
      {"table", {"table", "registertype", "regtype", "objecttype", "area", "datatable", "space"}},
      {"address", {"address", "addr", "register", "reg", "registeraddress", "regaddress", "offset", "reference", "ref",
                   "startaddress", "startingaddress"}},
      {"name", {"name", "tag", "label", "parameter", "param", "signal", "point"}},
      {"access", {"access", "rw", "readwrite", "mode", "permission", "permissions"}},
      {"type", {"type", "datatype", "format", "valuetype", "dtype"}},
      {"words", {"words", "wordcount", "registers", "length", "len", "size", "count", "quantity",
                 "numberofregisters", "registercount"}},
      {"word_order", {"wordorder", "wordswap", "swap", "order", "endianness", "endian"}},
      {"min", {"min", "minimum", "minvalue", "low", "lowerlimit", "rangemin"}},
      {"max", {"max", "maximum", "maxvalue", "high", "upperlimit", "rangemax"}},
      {"default", {"default", "defaultvalue", "initial", "initialvalue", "factory", "factorydefault"}},
      {"unit", {"unit", "units", "uom", "engineeringunit"}},
      {"scale", {"scale", "factor", "scalefactor", "multiplier", "gain", "resolution"}},
      {"description", {"description", "desc", "comment", "comments", "note", "notes", "remark", "remarks"}},
  };
  return m;
}

template <typename T>
std::optional<T> lookup(const std::vector<std::pair<std::vector<const char*>, T>>& table, const std::string& v) {
  std::string n = norm(v);
  for (const auto& [names, value] : table)
    for (const char* name : names)
      if (n == name) return value;
  return std::nullopt;
}

std::optional<Table> parse_table(const std::string& v) {
  static const std::vector<std::pair<std::vector<const char*>, Table>> t = {
      {{"coil", "coils", "0x", "do", "digitaloutput", "coilstatus"}, Table::coil},
      {{"discreteinput", "discreteinputs", "discrete", "di", "1x", "inputstatus", "digitalinput"}, Table::discrete_input},
      {{"inputregister", "inputregisters", "input", "ir", "3x"}, Table::input},
      {{"holdingregister", "holdingregisters", "holding", "hr", "4x"}, Table::holding}};
  return lookup(t, v);
}

std::optional<Access> parse_access(const std::string& v) {
  static const std::vector<std::pair<std::vector<const char*>, Access>> t = {
      {{"ro", "r", "read", "readonly"}, Access::ro},
      {{"rw", "readwrite", "wr"}, Access::rw},
      {{"wo", "w", "write", "writeonly"}, Access::wo},
      {{"command", "cmd", "action", "trigger"}, Access::command}};
  return lookup(t, v);
}

std::optional<DataType> parse_type(const std::string& v) {
  static const std::vector<std::pair<std::vector<const char*>, DataType>> t = {
      {{"u16", "uint16", "uint", "unsigned", "word", "ushort", "unsigned16", "uint16t"}, DataType::u16},
      {{"s16", "int16", "int", "signed", "short", "i16", "sint16", "signed16", "int16t"}, DataType::s16},
      {{"u32", "uint32", "udint", "dword", "ulong", "unsigned32", "uint32t"}, DataType::u32},
      {{"s32", "int32", "dint", "long", "i32", "sint32", "signed32", "int32t"}, DataType::s32},
      {{"f32", "float", "float32", "real", "single", "ieee754"}, DataType::f32},
      {{"bit", "bool", "boolean", "coil"}, DataType::bit}};
  return lookup(t, v);
}

std::optional<WordOrder> parse_word_order(const std::string& v) {
  static const std::vector<std::pair<std::vector<const char*>, WordOrder>> t = {
      {{"highfirst", "high", "msw", "mswfirst", "big", "bigendian", "be", "abcd", "hilo"}, WordOrder::high_first},
      {{"lowfirst", "low", "lsw", "lswfirst", "little", "littleendian", "le", "cdab", "lohi", "swapped"},
       WordOrder::low_first}};
  return lookup(t, v);
}

std::optional<double> parse_number(const std::string& v) {
  if (v.empty()) return std::nullopt;
  const char* b = v.c_str();
  char* end = nullptr;
  errno = 0;
  double d;
  if (v.size() > 2 && v[0] == '0' && (v[1] == 'x' || v[1] == 'X'))
    d = double(std::strtoull(b + 2, &end, 16));
  else
    d = std::strtod(b, &end);
  if (errno || end == b || *end != '\0' || !std::isfinite(d)) return std::nullopt;
  return d;
}

struct Row {
  int line = 0;
  Table table = Table::holding;
  uint32_t address = 0;
  std::string name, unit, description;
  Access access = Access::ro;
  DataType type = DataType::u16;
  int words = 1;
  WordOrder word_order = WordOrder::none;
  std::optional<double> min, max, def;
  double scale = 1;
  bool hex = false;  // the address was written 0x...
};

// A 1-based reference in the 0x/1x/3x/4x convention: 5 digits (00001..09999,
// 10001.., 30001.., 40001..) or 6 (000001..065536, ...). The first digit
// names the table; the rest, minus one, is the wire address.
struct Reference {
  Table table;
  uint32_t address;
};
std::optional<Reference> parse_reference(const std::string& v, std::string& error) {
  if ((v.size() != 5 && v.size() != 6) || v.find_first_not_of("0123456789") != std::string::npos) return std::nullopt;
  Table t;
  switch (v[0]) {
    case '0': t = Table::coil; break;
    case '1': t = Table::discrete_input; break;
    case '3': t = Table::input; break;
    case '4': t = Table::holding; break;
    default: return std::nullopt;
  }
  uint32_t n = uint32_t(std::stoul(v.substr(1)));
  if (n < 1 || n > 65536) {
    error = fmt::format("address {} is not a {}x reference ({}0001..{}9999, or 6 digits up to {}65536); write a wire "
                        "address above 9999 in hex (0x...)", v, v[0], v[0], v[0], v[0]);
    return std::nullopt;
  }
  return Reference{t, n - 1};
}

std::string yaml_str(const std::string& s) { return nlohmann::json(s).dump(); }
std::string num(double d) { return fmt::format("{}", d); }

std::pair<double, double> type_bounds(DataType t) {
  switch (t) {
    case DataType::s16: return {-32768, 32767};
    case DataType::u32: return {0, 4294967295.0};
    case DataType::s32: return {-2147483648.0, 2147483647.0};
    case DataType::f32: return {-3.4028234663852886e38, 3.4028234663852886e38};
    case DataType::bit: return {0, 1};
    default: return {0, 65535};
  }
}

class Importer {
 public:
  Importer(const std::string& file, const std::string& id) : file_(file), id_(id) {
    name_ = std::filesystem::path(file).filename().string();
  }

  ImportResult run(const std::string& text) {
    std::vector<CsvRecord> records;
    try {
      records = parse_csv(text);
    } catch (const std::runtime_error& e) {
      return {"", {file_ + ":" + e.what()}};
    }
    if (records.empty()) return {"", {file_ + ":1: error: the file has no header row"}};
    header(records[0]);
    if (errors_.empty())
      for (size_t i = 1; i < records.size(); ++i) row(records[i]);
    if (errors_.empty() && rows_.empty()) error(records[0].line, "the file has a header but no registers");
    if (!errors_.empty()) return {"", errors_};
    overlaps();
    if (!errors_.empty()) return {"", errors_};
    std::string yaml = emit();
    // The skeleton must pass `spec check`; anything the rows did not catch
    // is reported here, against the generated text.
    auto r = spec::load_spec_text(yaml, id_ + ".yaml");
    for (const auto& d : r.diagnostics) errors_.push_back(file_ + ": error: the skeleton does not pass spec check: " + d.str());
    if (!errors_.empty()) return {"", errors_};
    return {yaml, {}, rows_.size()};
  }

 private:
  void error(int line, const std::string& what) { errors_.push_back(fmt::format("{}:{}: error: {}", file_, line, what)); }

  void header(const CsvRecord& h) {
    width_ = h.fields.size();
    std::set<std::string> seen;
    for (size_t i = 0; i < h.fields.size(); ++i) {
      std::string n = norm(h.fields[i]);
      std::string canon;
      for (const auto& [c, aliases] : column_aliases())
        for (const auto& a : aliases)
          if (n == a) canon = c;
      if (canon.empty()) {
        std::string known;
        for (const auto& c : kCsvColumns) known += (known.empty() ? "" : ", ") + c;
        error(h.line, fmt::format("unknown column '{}' (columns: {}; spec/README.md lists the aliases)", trim(h.fields[i]), known));
        continue;
      }
      if (!seen.insert(canon).second) error(h.line, fmt::format("two columns mean '{}' ('{}' is the second)", canon, trim(h.fields[i])));
      col_[canon] = i;
    }
    for (const char* required : {"address", "name"})
      if (!col_.count(required)) error(h.line, fmt::format("the header names no '{}' column", required));
  }

  std::string cell(const CsvRecord& r, const std::string& c) const {
    auto it = col_.find(c);
    return it == col_.end() || it->second >= r.fields.size() ? "" : trim(r.fields[it->second]);
  }

  void row(const CsvRecord& rec) {
    const int line = rec.line;
    size_t before = errors_.size();
    if (rec.fields.size() > width_) error(line, fmt::format("{} fields, the header has {}", rec.fields.size(), width_));
    Row r;
    r.line = line;
    std::string table_text = cell(rec, "table"), addr = cell(rec, "address");
    std::optional<Table> table;
    if (!table_text.empty() && !(table = parse_table(table_text)))
      error(line, fmt::format("table '{}' is not coil, discrete input, input register or holding register", table_text));
    std::string ref_error;
    if (auto ref = parse_reference(addr, ref_error)) {
      if (table && *table != ref->table)
        error(line, fmt::format("address {} is a {} reference but the table column says {}", addr, csv_table_name(ref->table),
                                csv_table_name(*table)));
      r.table = ref->table;
      r.address = ref->address;
    } else if (!ref_error.empty()) {
      error(line, ref_error);
    } else if (auto a = parse_number(addr); a && *a >= 0 && *a <= 65535 && *a == std::floor(*a)) {
      r.table = table.value_or(Table::holding);
      r.address = uint32_t(*a);
      r.hex = addr.size() > 2 && (addr[1] == 'x' || addr[1] == 'X');
    } else {
      error(line, addr.empty() ? std::string("no address")
                               : fmt::format("address '{}' is not 0..65535 (decimal or 0x...) or a 0x/1x/3x/4x reference", addr));
    }
    r.name = cell(rec, "name");
    if (r.name.empty()) error(line, "no name");
    bool bits = r.table == Table::coil || r.table == Table::discrete_input;
    bool read_only_table = r.table == Table::input || r.table == Table::discrete_input;

    std::string t = cell(rec, "type");
    if (t.empty()) r.type = bits ? DataType::bit : DataType::u16;
    else if (auto ty = parse_type(t)) r.type = *ty;
    else if (norm(t) == "enum" || norm(t) == "bitfield")
      error(line, fmt::format("type '{}': the CSV carries no value list; write the integer type (u16) and describe the "
                              "values, then declare the {} in the spec", t, norm(t)));
    else error(line, fmt::format("type '{}' is not u16, s16, u32, s32, f32 or bit", t));
    if (bits != (r.type == DataType::bit))
      error(line, fmt::format("a {} has type {}: coils and discrete inputs are bits, registers are not",
                              csv_table_name(r.table), spec::to_string(r.type)));

    std::string acc = cell(rec, "access");
    if (acc.empty()) {
      if (read_only_table) r.access = Access::ro;
      else error(line, fmt::format("no access for a {} (ro, rw, wo or command)", csv_table_name(r.table)));
    } else if (auto a = parse_access(acc)) {
      r.access = *a;
      if (read_only_table && r.access != Access::ro)
        error(line, fmt::format("access '{}': {} {} is read-only", acc, r.table == Table::input ? "an" : "a", csv_table_name(r.table)));
    } else {
      error(line, fmt::format("access '{}' is not ro, rw, wo or command", acc));
    }

    bool wide = r.type == DataType::u32 || r.type == DataType::s32 || r.type == DataType::f32;
    r.words = wide ? 2 : 1;
    std::string w = cell(rec, "words");
    if (!w.empty()) {
      auto n = parse_number(w);
      if (!n || (*n != 1 && *n != 2)) error(line, fmt::format("words '{}' is not 1 or 2", w));
      else if (int(*n) != r.words) error(line, fmt::format("{} words, but type {} takes {}", w, spec::to_string(r.type), r.words));
    }
    std::string wo = cell(rec, "word_order");
    if (!wo.empty()) {
      if (auto o = parse_word_order(wo)) r.word_order = *o;
      else error(line, fmt::format("word order '{}' is not high_first or low_first", wo));
      if (r.words == 1) error(line, fmt::format("word order '{}' given for a 1-word register", wo));
    } else if (r.words == 2) {
      error(line, "a 2-word register needs a word order (high_first: the high word at the lower address, or low_first)");
    }
    if (r.address + uint32_t(r.words) - 1 > 65535) error(line, "the register runs past address 0xFFFF");

    auto number = [&](const char* c, std::optional<double>& out) {
      std::string v = cell(rec, c);
      if (v.empty()) return;
      if (!(out = parse_number(v))) error(line, fmt::format("{} '{}' is not a number", c, v));
    };
    number("min", r.min);
    number("max", r.max);
    number("default", r.def);
    std::optional<double> scale;
    number("scale", scale);
    if (scale) {
      if (*scale <= 0) error(line, fmt::format("scale {} is not positive", num(*scale)));
      else r.scale = *scale;
    }
    if (r.min.has_value() != r.max.has_value()) error(line, "min and max go together: give both or neither");
    auto [lo, hi] = type_bounds(r.type);
    if (r.min && r.max) {
      if (*r.min > *r.max) error(line, fmt::format("min {} is above max {}", num(*r.min), num(*r.max)));
      if (*r.min < lo || *r.max > hi)
        error(line, fmt::format("range {}..{} does not fit type {} ({}..{}); min and max are raw values", num(*r.min),
                                num(*r.max), spec::to_string(r.type), num(lo), num(hi)));
    }
    if (r.def) {
      double dlo = r.min.value_or(lo), dhi = r.max.value_or(hi);
      if (*r.def < dlo || *r.def > dhi)
        error(line, fmt::format("default {} is outside {}..{}", num(*r.def), num(dlo), num(dhi)));
    }
    r.unit = cell(rec, "unit");
    r.description = cell(rec, "description");
    if (errors_.size() == before) rows_.push_back(r);
  }

  void overlaps() {
    std::map<std::pair<Table, uint32_t>, int> used;  // (table, word address) -> line
    for (const auto& r : rows_)
      for (int k = 0; k < r.words; ++k) {
        auto [it, fresh] = used.emplace(std::pair(r.table, r.address + k), r.line);
        if (!fresh)
          error(r.line, fmt::format("{} 0x{:04X} is also on line {}", csv_table_name(r.table), r.address + k, it->second));
      }
  }

  std::string emit() const {
    bool hex = true;
    std::set<Table> tables;
    bool writable_holding = false, writable_coil = false;
    for (const auto& r : rows_) {
      tables.insert(r.table);
      hex = hex && r.hex;
      if (r.access != Access::ro) (r.table == Table::coil ? writable_coil : writable_holding) = true;
    }
    std::string y;
    y += fmt::format("# {}: a spec skeleton imported from {} by `mbconform spec import`.\n", id_, name_);
    y += fmt::format("# Every register cites the CSV row it came from (section: \"{}:<line>\").\n", name_);
    y += "# The CSV states only the register map: the serial line, the function codes\n"
         "# and the exception policy below are placeholders (each says so in a note);\n"
         "# replace them with what the manual states (spec/README.md).\n";
    y += "mbconform_spec: 1\n\ndevice:\n";
    y += fmt::format("  id: {}\n  vendor: {}\n  title: {}\n  models: [{}]\n", id_,
                     yaml_str("not stated in " + name_), yaml_str(id_ + " register map (from " + name_ + ")"), yaml_str(id_));
    // source: csv: the CSV is the register table, its facts are stated by it (spec/README.md).
    y += fmt::format("  manual:\n    file: {}\n    source: csv\n    address_notation: {}\n", yaml_str(name_),
                     hex ? "hex" : "decimal");
    y += fmt::format("    addressing_note: {}\n", yaml_str("Imported from " + name_ + ": addresses are wire (PDU) addresses; "
                                                           "1-based 0x/1x/3x/4x references in the CSV were converted (40001 -> 0)."));
    y += fmt::format("  section: {}\n\n", yaml_str(name_));

    const std::string placeholder = yaml_str("placeholder: not stated in " + name_ + "; the standard's value");
    y += "serial:\n";
    y += fmt::format("  note: {}\n", placeholder);
    y += "  slave_id: {min: 1, max: 247, section: \"MB-SL 2.2\"}\n";
    y += "  broadcast: {writes: unspecified, reply: unspecified}\n";
    y += "  baud_rates: {values: [9600, 19200], default: 19200, section: \"MB-SL 3.2\"}\n";
    y += "  frame_formats: {values: [8E1], default: 8E1, section: \"MB-SL 2.5.1\"}\n\n";

    y += "profile:\n";
    y += fmt::format("  note: {}\n", yaml_str("placeholder: the function codes of the tables " + name_ +
                                              " uses (MBAP 6); " + name_ + " states neither them nor the exception policy"));
    y += "  function_codes:\n";
    auto fc = [&](int code, const char* clause) { y += fmt::format("    - {{code: {}, section: \"MBAP {}\"}}\n", code, clause); };
    if (tables.count(Table::coil)) fc(1, "6.1");
    if (tables.count(Table::discrete_input)) fc(2, "6.2");
    if (tables.count(Table::holding)) fc(3, "6.3");
    if (tables.count(Table::input)) fc(4, "6.4");
    if (writable_coil) fc(5, "6.5");
    if (writable_holding) fc(6, "6.6");
    if (writable_coil) fc(15, "6.11");
    if (writable_holding) fc(16, "6.12");
    y += "  exception_policy:\n";
    for (auto v : spec::kAllViolations) y += fmt::format("    {}: unspecified\n", spec::to_string(v));

    y += "\nregisters:\n";
    for (const auto& r : rows_) {
      std::string m = fmt::format("address: 0x{:04X}", r.address);
      if (r.table != Table::holding) m += fmt::format(", table: {}", spec::to_string(r.table));
      m += fmt::format(", name: {{en: {}}}, access: {}, type: {}", yaml_str(r.name), spec::to_string(r.access),
                       spec::to_string(r.type));
      if (r.words == 2) m += fmt::format(", words: 2, word_order: {}", spec::to_string(r.word_order));
      if (r.min) m += fmt::format(", range: {{min: {}, max: {}}}", num(*r.min), num(*r.max));
      if (r.def) m += fmt::format(", default: {}", num(*r.def));
      if (!r.unit.empty()) m += fmt::format(", unit: {}", yaml_str(r.unit));
      if (r.scale != 1) m += fmt::format(", scale: {}", num(r.scale));
      if (r.access == Access::command)
        m += fmt::format(", command: {{effect: {}}}", yaml_str(r.description.empty() ? "as stated in " + name_ : r.description));
      if (!r.description.empty()) m += fmt::format(", note: {}", yaml_str(r.description));
      m += fmt::format(", section: {}", yaml_str(fmt::format("{}:{}", name_, r.line)));
      y += "  - {" + m + "}\n";
    }
    y += "\nexamples: []\nerrata: []\n";
    return y;
  }

  std::string file_, id_, name_;
  std::map<std::string, size_t> col_;
  size_t width_ = 0;
  std::vector<Row> rows_;
  std::vector<std::string> errors_;
};

}  // namespace

ImportResult import_csv(const std::string& text, const std::string& file, const std::string& id) {
  return Importer(file, id).run(text);
}

}  // namespace mbc::exchange
