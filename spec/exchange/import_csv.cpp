// `mbconform spec import --csv`: a CSV register map -> a spec skeleton.
#include <iconv.h>

#include <algorithm>
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

const std::vector<std::string> kCsvColumns = {"table", "address", "name", "access",  "role",  "type", "words",
                                              "word_order", "min", "max", "default", "unit", "scale", "description"};

namespace {

using spec::Access;
using spec::DataType;
using spec::Table;
using spec::WordOrder;

// Lower case, letters and digits only: "Word Order" == "word_order" ==
// "WORD-ORDER". Bytes of UTF-8 characters past ASCII are kept as they are
// (地址 stays 地址), but full-width brackets and spaces, which vendor
// sheets put around units (名称（中文）), are dropped like ASCII punctuation.
std::string norm(std::string_view s) {
  std::string n;
  for (size_t i = 0; i < s.size(); ++i) {
    unsigned char c = static_cast<unsigned char>(s[i]);
    if (c < 0x80) {
      if (std::isalnum(c)) n += char(std::tolower(c));
      continue;
    }
    // U+3000 ideographic space (E3 80 80), U+FF08/U+FF09 full-width parentheses (EF BC 88/89).
    std::string_view rest = s.substr(i);
    if (rest.starts_with("\xE3\x80\x80") || rest.starts_with("\xEF\xBC\x88") || rest.starts_with("\xEF\xBC\x89")) {
      i += 2;
      continue;
    }
    n += char(c);
  }
  return n;
}

std::string trim(std::string_view s) {
  size_t b = s.find_first_not_of(" \t"), e = s.find_last_not_of(" \t");
  return b == std::string_view::npos ? "" : std::string(s.substr(b, e - b + 1));
}

// Header names and their aliases (normalised), by canonical column.
// Chinese aliases are those of vendor sheets (Simplified Chinese, as the
// drives' manuals print them: 地址, 名称, 读写, 范围, 单位, 默认值, 倍率, ...).
const std::map<std::string, std::vector<std::string>>& column_aliases() {
  static const std::map<std::string, std::vector<std::string>> m = {
      {"table", {"table", "registertype", "regtype", "objecttype", "area", "datatable", "space", "寄存器类型", "数据区",
                 "功能区", "区域"}},
      {"address", {"address", "addr", "register", "reg", "registeraddress", "regaddress", "offset", "reference", "ref",
                   "startaddress", "startingaddress", "地址", "寄存器地址", "通讯地址", "通信地址", "参数地址",
                   "modbus地址", "起始地址", "地址hex", "地址十六进制", "地址十进制"}},
      {"name", {"name", "tag", "label", "parameter", "param", "signal", "point", "parametername", "名称", "参数名称",
                "参数名", "参数", "变量名", "变量名称", "功能", "功能名称"}},
      {"access", {"access", "rw", "readwrite", "mode", "permission", "permissions", "attribute", "property", "读写",
                  "读写属性", "属性", "访问", "访问权限", "权限", "操作"}},
      {"role", {"role", "registerrole", "角色", "用途"}},
      {"type", {"type", "datatype", "format", "valuetype", "dtype", "数据类型", "类型", "数据格式", "格式"}},
      {"words", {"words", "wordcount", "registers", "length", "len", "size", "count", "quantity",
                 "numberofregisters", "registercount", "长度", "字数", "寄存器数", "寄存器个数", "数据长度"}},
      {"word_order", {"wordorder", "wordswap", "swap", "order", "endianness", "endian", "byteorder", "字节序",
                      "字序", "字节顺序", "高低字", "大小端"}},
      {"range", {"range", "valuerange", "settingrange", "setrange", "limits", "范围", "取值范围", "设定范围",
                 "数据范围", "参数范围", "设置范围"}},
      {"min", {"min", "minimum", "minvalue", "low", "lowerlimit", "rangemin", "最小值", "下限", "最小"}},
      {"max", {"max", "maximum", "maxvalue", "high", "upperlimit", "rangemax", "最大值", "上限", "最大"}},
      {"default", {"default", "defaultvalue", "initial", "initialvalue", "factory", "factorydefault", "factorysetting",
                   "默认值", "默认", "出厂值", "出厂设定", "出厂设置", "缺省值", "初始值"}},
      {"unit", {"unit", "units", "uom", "engineeringunit", "单位"}},
      {"scale", {"scale", "factor", "scalefactor", "multiplier", "gain", "resolution", "倍率", "系数", "比例",
                 "比例系数", "分辨率"}},
      {"description", {"description", "desc", "comment", "comments", "note", "notes", "remark", "remarks", "描述",
                       "说明", "备注", "注释", "参数说明"}},
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
      {{"ro", "r", "read", "readonly", "只读", "读"}, Access::ro},
      {{"rw", "readwrite", "wr", "读写", "可读写", "可读可写", "读写"}, Access::rw},
      {{"wo", "w", "write", "writeonly", "只写", "写"}, Access::wo},
      {{"command", "cmd", "action", "trigger", "命令", "指令"}, Access::command}};
  return lookup(t, v);
}

std::optional<DataType> parse_type(const std::string& v) {
  static const std::vector<std::pair<std::vector<const char*>, DataType>> t = {
      {{"u16", "uint16", "uint", "unsigned", "word", "ushort", "unsigned16", "uint16t", "无符号16位", "16位无符号"}, DataType::u16},
      {{"s16", "int16", "int", "signed", "short", "i16", "sint16", "signed16", "int16t", "integer", "整数", "整型", "有符号16位",
        "16位有符号"}, DataType::s16},
      {{"u32", "uint32", "udint", "dword", "ulong", "unsigned32", "uint32t", "无符号32位", "32位无符号"}, DataType::u32},
      {{"s32", "int32", "dint", "long", "i32", "sint32", "signed32", "int32t", "有符号32位", "32位有符号", "长整型"}, DataType::s32},
      {{"f32", "float", "float32", "real", "single", "ieee754", "浮点", "浮点数", "浮点型", "单精度"}, DataType::f32},
      {{"bit", "bool", "boolean", "coil"}, DataType::bit}};
  return lookup(t, v);
}

std::optional<WordOrder> parse_word_order(const std::string& v) {
  static const std::vector<std::pair<std::vector<const char*>, WordOrder>> t = {
      {{"highfirst", "high", "msw", "mswfirst", "big", "bigendian", "be", "abcd", "hilo", "高字在前", "大端"},
       WordOrder::high_first},
      {{"lowfirst", "low", "lsw", "lswfirst", "little", "littleendian", "le", "cdab", "lohi", "swapped", "低字在前",
        "小端"},
       WordOrder::low_first}};
  return lookup(t, v);
}

// A number as a sheet writes it: decimal, 0x..., or with a decimal comma
// (0,1: one comma and no point, as spreadsheets in most of Europe write it).
std::optional<double> parse_number(std::string v) {
  if (v.empty()) return std::nullopt;
  if (std::count(v.begin(), v.end(), ',') == 1 && v.find('.') == std::string::npos) v[v.find(',')] = '.';
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

// Byte orders that swap the two bytes of each word: the spec language
// states word order only, because Modbus sends each register high byte
// first (MBAP v1.1b3 §4.2).
bool swaps_bytes(const std::string& v) {
  std::string n = norm(v);
  return n == "badc" || n == "dcba" || n == "byteswap" || n == "byteswapped";
}

// "0~3000", "0～3000", "-10~10", "0..3000", "0 to 3000", "0-3000": a range
// as vendor sheets print one.
std::optional<std::pair<double, double>> parse_range(std::string v) {
  for (size_t at; (at = v.find("\xEF\xBD\x9E")) != std::string::npos;) v.replace(at, 3, "~");  // full-width tilde
  size_t cut = std::string::npos, len = 1;
  if ((cut = v.find('~')) == std::string::npos) {
    if ((cut = v.find("..")) != std::string::npos) len = 2;
    else if ((cut = v.find(" to ")) != std::string::npos) len = 4;
    else if ((cut = v.find('-', 1)) != std::string::npos && v[cut - 1] != 'e' && v[cut - 1] != 'E') len = 1;
  }
  if (cut == std::string::npos) return std::nullopt;
  auto lo = parse_number(trim(v.substr(0, cut))), hi = parse_number(trim(v.substr(cut + len)));
  if (!lo || !hi) return std::nullopt;
  return std::pair(*lo, *hi);
}

struct Row {
  int line = 0;
  int count = 1;  // an address range "a~b": a block of b - a + 1 registers
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
  bool byte_swapped = false;  // BADC / DCBA: imported without values
  spec::Role role = spec::Role::none;
  std::string role_word;  // the lexicon's word, or "role column"
};

// "int", "uint", "integer": 16 bits to a PLC (IEC 61131-3), 32 to C.
bool ambiguous_width(const std::string& t) {
  std::string n = norm(t);
  return n == "int" || n == "uint" || n == "integer" || n == "signed" || n == "unsigned" || n == "整数" || n == "整型";
}

// A write to a register of this role is an action, not a setting: the spec
// says `access: command` with what it does.
bool command_role(spec::Role r) { return r == spec::Role::motion || r == spec::Role::save || r == spec::Role::factory_reset; }

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
      return {"", {file_ + ":" + e.what()}, 0, {}, 1, {}};
    }
    if (records.empty()) return {"", {file_ + ":1: error: the file has no header row"}, 0, {}, 1, {}};
    header(records[0]);
    if (!failed())
      for (size_t i = 1; i < records.size(); ++i) row(records[i]);
    if (!failed() && rows_.empty()) error(records[0].line, "the file has a header but no registers");
    if (failed()) return {"", errors(), 0, warnings(), error_count_, {}};
    overlaps();
    if (failed()) return {"", errors(), 0, warnings(), error_count_, {}};
    auto lines = settings();
    if (lines.size() > 64) {
      error(rows_.front().line, fmt::format("{} line-setting registers (slave address, baud, parity, frame format): the "
                                            "spec language lists at most 64", lines.size()));
      return {"", errors(), 0, warnings(), error_count_, {}};
    }
    std::string yaml = emit(lines);
    // The skeleton must pass `spec check`; anything the rows did not catch
    // is reported here, against the generated text.
    auto r = spec::load_spec_text(yaml, id_ + ".yaml");
    for (const auto& d : r.diagnostics) {
      ++error_count_;
      errors_.push_back(file_ + ": error: the skeleton does not pass spec check: " + d.str());
    }
    if (failed()) return {"", errors(), 0, warnings(), error_count_, {}};
    return {yaml, {}, rows_.size(), warnings(), 0, classified()};
  }

 private:
  // At most kShownLines errors and warnings are kept; the rest are counted.
  static constexpr size_t kShownErrors = kShownLines;
  void error(int line, const std::string& what) {
    if (++error_count_ <= kShownErrors) errors_.push_back(fmt::format("{}:{}: error: {}", file_, line, what));
  }
  std::vector<std::string> warnings() const {
    std::vector<std::string> out = warnings_;
    if (warning_count_ > kShownLines)
      out.push_back(fmt::format("{}: {} more warnings not shown ({} in all)", file_, warning_count_ - kShownLines, warning_count_));
    return out;
  }
  bool failed() const { return error_count_ > 0; }
  std::vector<std::string> errors() const {
    std::vector<std::string> out = errors_;
    if (error_count_ > kShownErrors)
      out.push_back(fmt::format("{}: {} more errors not shown ({} in all)", file_, error_count_ - kShownErrors, error_count_));
    return out;
  }
  void warning(int line, const std::string& what) {
    if (++warning_count_ <= kShownLines) warnings_.push_back(fmt::format("{}:{}: warning: {}", file_, line, what));
  }

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
        // A vendor sheet's own column (序号, No., 备注2): said once, then ignored.
        std::string known;
        for (const auto& c : kCsvColumns) known += (known.empty() ? "" : ", ") + c;
        warning(h.line, fmt::format("column '{}' is not one of the register map's ({}, range; spec/README.md lists the "
                                    "aliases): ignored", trim(h.fields[i]), known));
        continue;
      }
      if (!seen.insert(canon).second) error(h.line, fmt::format("two columns mean '{}' ('{}' is the second)", canon, trim(h.fields[i])));
      col_[canon] = i;
    }
    for (const char* required : {"address", "name"})
      if (!col_.count(required)) error(h.line, fmt::format("the header names no '{}' column", required));
  }

  // A cell, trimmed, as text (an export's "'=..." escape undone: csv.h).
  std::string cell(const CsvRecord& r, const std::string& c) const {
    auto it = col_.find(c);
    return it == col_.end() || it->second >= r.fields.size() ? "" : csv_text(trim(r.fields[it->second]));
  }

  // The register's role: the `role` column's, else its name's through the
  // lexicon (spec/roles/roles.h).
  void classify(const CsvRecord& rec, Row& r) {
    if (std::string v = cell(rec, "role"); !v.empty()) {
      if (auto role = spec::role_from_string(v)) {
        r.role = *role;
        r.role_word = "role column";
      } else {
        error(rec.line, fmt::format("role '{}' is not none, slave-address, baud, parity, frame-format, motion, save or "
                                    "factory-reset", v));
      }
      return;
    }
    auto m = spec::role_of_name(r.name);
    r.role = m.role;
    r.role_word = m.word;
  }

  void row(const CsvRecord& rec) {
    const int line = rec.line;
    size_t before = error_count_;
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
    } else if (auto block = parse_range(addr); block && block->first >= 0 && block->second <= 65535 &&
                                               block->first == std::floor(block->first) && block->second == std::floor(block->second) &&
                                               block->first < block->second) {
      // "92~150": a block of registers under one name (the manual's reserved ranges).
      r.table = table.value_or(Table::holding);
      r.address = uint32_t(block->first);
      r.count = int(block->second - block->first) + 1;
      r.hex = addr.size() > 2 && (addr[1] == 'x' || addr[1] == 'X');
    } else {
      error(line, addr.empty() ? std::string("no address")
                               : fmt::format("address '{}' is not 0..65535 (decimal or 0x...) or a 0x/1x/3x/4x reference", addr));
    }
    r.name = cell(rec, "name");
    if (r.name.empty()) error(line, "no name");
    bool bits = r.table == Table::coil || r.table == Table::discrete_input;
    bool read_only_table = r.table == Table::input || r.table == Table::discrete_input;

    // The range first: with no type column, it and the byte order give the width.
    auto number = [&](const char* c, std::optional<double>& out) {
      std::string v = cell(rec, c);
      if (v.empty()) return;
      if (!(out = parse_number(v))) error(line, fmt::format("{} '{}' is not a number", c, v));
    };
    number("min", r.min);
    number("max", r.max);
    if (std::string range = cell(rec, "range"); !range.empty()) {
      if (r.min || r.max) error(line, fmt::format("range '{}' and min/max both given", range));
      else if (auto rg = parse_range(range)) {
        r.min = rg->first;
        r.max = rg->second;
      } else if (auto one = parse_number(range)) {
        r.min = r.max = *one;
      } else {
        error(line, fmt::format("range '{}' is not MIN~MAX (0~3000, -10~10, 0..3000)", range));
      }
    }
    number("default", r.def);
    const bool negative = (r.min && *r.min < 0) || (r.def && *r.def < 0);
    const bool beyond_16 = (r.min && *r.min < -32768) || (r.max && *r.max > 65535) || (r.def && (*r.def < -32768 || *r.def > 65535));
    std::string wo = cell(rec, "word_order");
    const std::string wo_n = norm(wo);
    const bool four_bytes = wo_n == "abcd" || wo_n == "cdab" || wo_n == "badc" || wo_n == "dcba";
    std::string w = cell(rec, "words");
    const bool two_words_given = !w.empty() && parse_number(w) == 2.0;

    std::string t = cell(rec, "type");
    if (t.empty() && !bits) {
      // No type: a 4-byte order (ABCD, CDAB), a word count of 2 or a range
      // beyond 16 bits makes a 32-bit row; a negative bound a signed one.
      bool wide = four_bytes || two_words_given || beyond_16;
      r.type = wide ? (negative ? DataType::s32 : DataType::u32) : (negative ? DataType::s16 : DataType::u16);
    } else if (t.empty()) {
      r.type = DataType::bit;
    } else if (auto ty = parse_type(t)) {
      r.type = *ty;
      // "int", "uint": 16 bits to a PLC, 32 to C; a range beyond 16 bits settles it.
      if (beyond_16 && (r.type == DataType::u16 || r.type == DataType::s16) && ambiguous_width(t)) {
        r.type = r.type == DataType::s16 ? DataType::s32 : DataType::u32;
        warning(line, fmt::format("type '{}' with range {}..{}: read as {} (the range needs 32 bits)", t, num(r.min.value_or(0)),
                                  num(r.max.value_or(0)), spec::to_string(r.type)));
      }
    } else if (norm(t) == "enum" || norm(t) == "bitfield") {
      error(line, fmt::format("type '{}': the CSV carries no value list; write the integer type (u16) and describe the "
                              "values, then declare the {} in the spec", t, norm(t)));
    } else {
      error(line, fmt::format("type '{}' is not u16, s16, u32, s32, f32 or bit", t));
    }
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
    if (!w.empty()) {
      auto n = parse_number(w);
      if (!n || (*n != 1 && *n != 2)) error(line, fmt::format("words '{}' is not 1 or 2", w));
      else if (int(*n) != r.words) error(line, fmt::format("{} words, but type {} takes {}", w, spec::to_string(r.type), r.words));
    }
    if (!wo.empty() && swaps_bytes(wo)) {
      // Bytes swapped inside each word: Modbus sends every register high byte
      // first (MBAP v1.1b3 §4.2) and the spec language states word order
      // only. The registers are imported, their values are not.
      r.byte_swapped = true;
      if (r.words == 2) r.word_order = wo_n == "dcba" ? WordOrder::low_first : WordOrder::high_first;
      warning(line, fmt::format("byte order '{}' swaps the bytes inside each word, which the spec language cannot state "
                                "(Modbus sends each register high byte first, MBAP v1.1b3 §4.2): imported as {} {}-word "
                                "register{} with no range or default", wo, r.words == 2 ? "a" : "a", r.words,
                                r.words == 2 ? fmt::format(" ({})", spec::to_string(r.word_order)) : ""));
      r.min.reset();
      r.max.reset();
      r.def.reset();
    } else if (!wo.empty() && r.words == 1) {
      // A sheet's byte-order column is filled for every row; a 1-word
      // register has no word order, and AB (high byte first) is the wire's.
      if (!parse_word_order(wo)) error(line, fmt::format("word order '{}' is not high_first or low_first (ABCD, CDAB)", wo));
    } else if (!wo.empty()) {
      if (auto o = parse_word_order(wo)) r.word_order = *o;
      else error(line, fmt::format("word order '{}' is not high_first or low_first (ABCD, CDAB)", wo));
    } else if (r.words == 2) {
      error(line, "a 2-word register needs a word order (high_first: the high word at the lower address, or low_first)");
    }
    if (r.address + uint32_t(r.words * r.count) - 1 > 65535) error(line, "the register runs past address 0xFFFF");

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
    classify(rec, r);
    if (error_count_ == before) rows_.push_back(r);
  }

  void overlaps() {
    std::map<std::pair<Table, uint32_t>, int> used;  // (table, word address) -> line
    for (const auto& r : rows_)
      for (int k = 0; k < r.words * r.count; ++k) {
        auto [it, fresh] = used.emplace(std::pair(r.table, r.address + k), r.line);
        if (!fresh)
          error(r.line, fmt::format("{} 0x{:04X} is also on line {}", csv_table_name(r.table), r.address + k, it->second));
      }
  }

  // The access the spec states: a read-write register of a motion, save or
  // factory-reset role is a command (a write is an action); a write-only one
  // stays write-only, with the same `command:` (what a write does).
  static Access access_of(const Row& r) { return r.access == Access::rw && command_role(r.role) ? Access::command : r.access; }
  static bool has_command(const Row& r) { return access_of(r) == Access::command || (r.access == Access::wo && command_role(r.role)); }

  // What the import made of each register's role, in the spec's order.
  std::vector<Classified> classified() const {
    std::vector<Classified> out;
    for (const auto& r : rows_) out.push_back({r.table, r.address, r.name, r.role, r.role_word, access_of(r)});
    return out;
  }

  // The line settings (serial.settings): a holding register whose role is
  // the slave address, the baud rate, the parity or the frame format.
  std::vector<std::string> settings() {
    std::vector<std::string> out;
    for (const auto& r : rows_) {
      if (!spec::is_line_setting(r.role)) continue;
      if (r.table != Table::holding) {
        if (r.table == Table::coil)
          warning(r.line, fmt::format("a coil of role {}: serial.settings names holding registers only; the coil is "
                                      "imported as it is", spec::to_string(r.role)));
        continue;
      }
      const char* setting = r.role == spec::Role::slave_address ? "slave_id"
                            : r.role == spec::Role::baud        ? "baud_rate"
                                                                : "frame_format";  // parity is part of the frame format (8E1)
      for (int k = 0; k < r.count; ++k)
        out.push_back(fmt::format("{{register: 0x{:04X}, setting: {}, section: {}, note: {}}}", r.address + uint32_t(k), setting,
                                  yaml_str(fmt::format("{}:{}", name_, r.line)),
                                  yaml_str(fmt::format("role {} ({}); the encoding is not stated in {}", spec::to_string(r.role),
                                                       why(r), name_))));
    }
    return out;
  }

  std::string why(const Row& r) const {
    return r.role_word == "role column" ? "the role column" : fmt::format("the name's word '{}'", r.role_word);
  }

  std::string emit(const std::vector<std::string>& settings) const {
    bool hex = true;
    std::set<Table> tables;
    bool writable_holding = false, writable_coil = false;
    for (const auto& r : rows_) {
      tables.insert(r.table);
      hex = hex && r.hex;
      if (access_of(r) != Access::ro) (r.table == Table::coil ? writable_coil : writable_holding) = true;
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
    // source: csv: the facts are the sheet's, the user's claim and not a
    // manual's: each is inferred, so a live run writes only with --allow-writes (spec/README.md).
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
    y += "  frame_formats: {values: [8E1], default: 8E1, section: \"MB-SL 2.5.1\"}\n";
    // The registers that set the line: never written by a run (conformance/policy/).
    if (!settings.empty()) y += "  settings:\n";
    for (const auto& st : settings) y += "    - " + st + "\n";
    y += "\n";

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
      if (r.count > 1) m += fmt::format(", count: {}", r.count);
      if (r.table != Table::holding) m += fmt::format(", table: {}", spec::to_string(r.table));
      // A name in Chinese is the manual's (zh); `en` is required, and stays the same until someone translates it.
      bool ascii = std::all_of(r.name.begin(), r.name.end(), [](char c) { return static_cast<unsigned char>(c) < 0x80; });
      m += fmt::format(", name: {{{}en: {}}}, access: {}, type: {}", ascii ? "" : "zh: " + yaml_str(r.name) + ", ", yaml_str(r.name),
                       spec::to_string(access_of(r)), spec::to_string(r.type));
      if (r.words == 2) m += fmt::format(", words: 2, word_order: {}", spec::to_string(r.word_order));
      if (r.min) m += fmt::format(", range: {{min: {}, max: {}}}", num(*r.min), num(*r.max));
      if (r.def) m += fmt::format(", default: {}", num(*r.def));
      if (!r.unit.empty()) m += fmt::format(", unit: {}", yaml_str(r.unit));
      if (r.scale != 1) m += fmt::format(", scale: {}", num(r.scale));
      if (has_command(r)) {
        std::string effect = !r.description.empty() ? r.description
                             : command_role(r.role) ? fmt::format("{} (role {}, from {})", r.name, spec::to_string(r.role), why(r))
                                                    : "as stated in " + name_;
        // motion: a write may move the drive (--allow-motion); eeprom: a
        // write stores or resets the parameters (the EEPROM opt-in).
        m += fmt::format(", command: {{effect: {}{}}}", yaml_str(effect),
                         r.role == spec::Role::motion                                       ? ", motion: true"
                         : r.role == spec::Role::save || r.role == spec::Role::factory_reset ? ", eeprom: true"
                                                                                              : "");
      }
      std::string note = r.description;
      if (r.byte_swapped)
        note += std::string(note.empty() ? "" : "; ") + "the sheet's byte order swaps the bytes inside each word: "
                "the spec states no range or default for it";
      if (!note.empty()) m += fmt::format(", note: {}", yaml_str(note));
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
  std::vector<std::string> errors_, warnings_;
  size_t error_count_ = 0, warning_count_ = 0;
};

}  // namespace

namespace {
// The offset of the first byte that breaks UTF-8 (RFC 3629), or npos.
size_t first_bad_utf8(const std::string& s) {
  for (size_t i = 0; i < s.size();) {
    unsigned char c = static_cast<unsigned char>(s[i]);
    size_t n = c < 0x80 ? 1 : (c >> 5) == 0x6 && c >= 0xC2 ? 2 : (c >> 4) == 0xE ? 3 : (c >> 3) == 0x1E && c <= 0xF4 ? 4 : 0;
    if (n == 0 || i + n > s.size()) return i;
    for (size_t k = 1; k < n; ++k)
      if ((static_cast<unsigned char>(s[i + k]) & 0xC0) != 0x80) return i;
    i += n;
  }
  return std::string::npos;
}
}  // namespace

std::optional<std::string> to_utf8(const std::string& text, int& line) {
  size_t bad = first_bad_utf8(text);
  if (bad == std::string::npos) return text;
  line = 1 + int(std::count(text.begin(), text.begin() + long(bad), '\n'));
  iconv_t cd = iconv_open("UTF-8", "GB18030");
  if (cd == iconv_t(-1)) return std::nullopt;
  std::string out(text.size() * 2 + 16, '\0');
  char* in = const_cast<char*>(text.data());
  size_t in_left = text.size();
  char* o = out.data();
  size_t out_left = out.size();
  size_t rc = iconv(cd, &in, &in_left, &o, &out_left);
  iconv_close(cd);
  if (rc == size_t(-1) || in_left != 0) return std::nullopt;
  out.resize(out.size() - out_left);
  if (first_bad_utf8(out) != std::string::npos) return std::nullopt;
  return out;
}

ImportResult import_csv(const std::string& text, const std::string& file, const std::string& id) {
  if (text.size() > kMaxImportBytes)
    return {"", {fmt::format("{}:1: error: {} bytes: a register sheet is read up to {} MiB (every address of the four tables "
                             "fits in less); split the sheet", file, text.size(), kMaxImportBytes >> 20)}, 0, {}, 1, {}};
  int line = 0;
  auto utf8 = to_utf8(text, line);
  if (!utf8) {
    size_t bad = first_bad_utf8(text);
    return {"",
            {fmt::format("{}:{}: error: the file is neither UTF-8 nor GB18030/GBK (byte 0x{:02X}); save it as CSV UTF-8", file,
                         line, static_cast<unsigned char>(text[bad]))},
            0,
            {},
            1,
            {}};
  }
  ImportResult r = Importer(file, id).run(*utf8);
  if (utf8->size() != text.size() || *utf8 != text)
    r.warnings.insert(r.warnings.begin(), fmt::format("{}:{}: warning: not UTF-8: read as GB18030 (GBK, the default of "
                                                      "Chinese Excel) and converted", file, line));
  return r;
}

}  // namespace mbc::exchange

namespace mbc::exchange {

std::string classification_table(const ImportResult& r) {
  std::string out = fmt::format("{:<22} {:<30} {:<14} {:<26} {}\n", "register", "name", "role", "written as", "from");
  size_t with_role = 0, by_column = 0;
  for (const auto& c : r.classified) {
    with_role += c.role != spec::Role::none;
    by_column += c.word == "role column";
    if (c.role == spec::Role::none && c.word.empty()) continue;
    std::string as = spec::is_line_setting(c.role) && c.table == spec::Table::holding ? "serial.settings"
                     : c.access == spec::Access::ro && command_role(c.role)              ? "ro: never written"
                     : c.role == spec::Role::motion                                       ? std::string(spec::to_string(c.access)) + ", motion"
                     : command_role(c.role)                                               ? std::string(spec::to_string(c.access)) + ", eeprom"
                                                                                          : spec::to_string(c.access);
    std::string name = c.name;
    if (name.size() > 60) {  // cut at a character boundary
      size_t cut = 57;
      while (cut > 0 && (static_cast<unsigned char>(name[cut]) & 0xC0) == 0x80) --cut;
      name = name.substr(0, cut) + "...";
    }
    out += fmt::format("{:<22} {:<30} {:<14} {:<26} {}\n", fmt::format("{} 0x{:04X}", csv_table_name(c.table), c.address), name,
                       spec::to_string(c.role), as, c.word == "role column" ? c.word : "'" + c.word + "'");
  }
  out += fmt::format("{} of {} registers have a role ({} from the role column); {} have none (no word of spec/README.md "
                     "\"Roles\" in their name)\n",
                     with_role, r.classified.size(), by_column, r.classified.size() - with_role);
  return out;
}

}  // namespace mbc::exchange
