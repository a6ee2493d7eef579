// `mbconform spec import --wb-template`: a wb-mqtt-serial device template
// (the public register maps of Wiren Board's wb-mqtt-serial, JSON; schema:
// wb-mqtt-serial-device-template.schema.json) -> a spec. What a template
// states becomes the spec's facts, each citing the template:
//   channels and parameters -> registers (reg_type, address, format, word
//     order, scale, units, readonly, enum/enum_titles, min/max);
//   bit channels ("50199:9:1": address, bit, width) -> the fields of a
//     bitfield register at that address;
//   setup -> operations.setup, register writes that pass the safety rules
//     like any other (a control word that starts a drive is a motion command);
//   response_timeout_ms, frame_timeout_ms, guard_interval_us -> timing;
//   max_read_registers -> FC 03/04's max_quantity.
#include <algorithm>
#include <cctype>
#include <cmath>
#include <filesystem>
#include <map>
#include <optional>
#include <set>

#include <fmt/core.h>
#include <nlohmann/json.hpp>

#include "exchange.h"
#include "loader.h"

namespace mbc::exchange {
namespace {

using nlohmann::json;
using spec::Access;
using spec::DataType;
using spec::Table;

std::string yaml_str(const std::string& s) { return json(s).dump(); }
std::string num(double d) { return fmt::format("{}", d); }

struct Field {
  int lo = 0, hi = 0;
  std::string name;
};

struct Reg {
  Table table = Table::holding;
  uint32_t address = 0;
  std::string key, name, unit, note, origin;
  DataType type = DataType::u16;
  int words = 1;
  bool low_first = false;
  bool writable = false;
  spec::Role role = spec::Role::none;  // from its channels' names (spec/roles/roles.h)
  std::string role_word;
  double scale = 1;
  std::optional<double> min, max;  // raw
  std::vector<std::pair<int64_t, std::string>> enum_values;
  std::vector<Field> fields;  // bit channels
  bool whole = false;         // a channel reads the whole register
};

// A template's words are often translation keys ("mst24_title"): the English translation, when there is one.
std::string english(const json& device, const std::string& s) {
  if (device.contains("translations") && device["translations"].contains("en") && device["translations"]["en"].contains(s) &&
      device["translations"]["en"][s].is_string())
    return device["translations"]["en"][s].get<std::string>();
  return s;
}

// Of two roles that a register's channels give it, the one a live run
// guards most: a line setting, then a factory reset, a save, motion.
int rank(spec::Role r) {
  switch (r) {
    case spec::Role::slave_address:
    case spec::Role::baud:
    case spec::Role::parity:
    case spec::Role::frame_format: return 0;
    case spec::Role::factory_reset: return 1;
    case spec::Role::save: return 2;
    case spec::Role::motion: return 3;
    case spec::Role::none: break;
  }
  return 4;
}

bool command_role(spec::Role r) { return r == spec::Role::motion || r == spec::Role::save || r == spec::Role::factory_reset; }

// The deepest nesting a template is read with: wb-mqtt-serial's own
// templates nest a handful of levels; 150,000 levels would exhaust the stack
// of anything that walks the tree.
constexpr int kMaxJsonDepth = 64;
struct TooDeep {};

// The template as JSON, with comments (wb-mqtt-serial allows them), refusing
// nesting deeper than kMaxJsonDepth while it parses.
json parse_template(const std::string& text) {
  json::parser_callback_t bound = [](int depth, json::parse_event_t, json&) {
    if (depth > kMaxJsonDepth) throw TooDeep{};
    return true;
  };
  return json::parse(text, bound, true, /*ignore_comments=*/true);
}

class WbImporter {
 public:
  WbImporter(const std::string& file, const std::string& id) : file_(file), id_(id) {
    name_ = std::filesystem::path(file).filename().string();
  }

  ImportResult run(const std::string& text) {
    if (text.size() > kMaxImportBytes)
      return fail(fmt::format("{}: error: {} bytes: a template is read up to {} MiB (wb-mqtt-serial's largest are a few "
                              "hundred KiB)", file_, text.size(), kMaxImportBytes >> 20));
    json t;
    try {
      t = parse_template(text);
    } catch (const json::parse_error& e) {
      return fail(fmt::format("{}: error: not JSON: {}", file_, e.what()));
    } catch (const TooDeep&) {
      return fail(fmt::format("{}: error: nesting deeper than {} levels: not a device template", file_, kMaxJsonDepth));
    }
    if (!t.is_object() || !t.contains("device") || !t["device"].is_object())
      return fail(file_ + ": error: not a wb-mqtt-serial device template (no \"device\" object)");
    const json& d = t["device"];
    device_ = &d;
    title_ = english(d, t.value("title", d.value("name", id_)));
    auto list = [&](const char* key) {
      std::vector<json> out;
      if (!d.contains(key)) return out;
      if (d[key].is_array())
        for (const auto& c : d[key]) out.push_back(c);
      else if (d[key].is_object())  // parameters may be an object keyed by id
        for (const auto& [k, c] : d[key].items()) {
          json x = c;
          if (!x.contains("id")) x["id"] = k;
          out.push_back(x);
        }
      return out;
    };
    auto channels = list("channels");
    for (size_t i = 0; i < channels.size(); ++i) channel(channels[i], fmt::format("channels[{}]", i), false);
    auto params = list("parameters");
    for (size_t i = 0; i < params.size(); ++i) channel(params[i], fmt::format("parameters[{}]", i), true);
    auto setups = list("setup");
    for (size_t i = 0; i < setups.size(); ++i) setup(setups[i], fmt::format("setup[{}]", i));
    if (regs_.empty() && errors_.empty()) error("", "the template has no channel this import can map");
    if (!errors_.empty()) return {"", errors(), 0, warnings(), error_count_, {}};
    std::vector<std::string> lines;
    for (const auto& r : regs_)
      if (spec::is_line_setting(r.role) && r.table == Table::holding) lines.push_back(r.key);
    if (lines.size() > 64) {
      error("", fmt::format("{} line-setting registers (slave address, baud, parity, frame format): the spec language lists at most 64",
                            lines.size()));
      return {"", errors(), 0, warnings(), error_count_, {}};
    }
    std::string yaml = emit(d);
    auto r = spec::load_spec_text(yaml, id_ + ".yaml");
    for (const auto& e : r.diagnostics) error("", "the imported spec does not pass spec check: " + e.str());
    if (!errors_.empty()) return {"", errors(), 0, warnings(), error_count_, {}};
    std::vector<Classified> classified;
    for (const auto& g : regs_) classified.push_back({g.table, g.address, g.name, g.role, g.role_word, access_of(g)});
    return {yaml, {}, regs_.size(), warnings(), 0, classified};
  }

 private:
  ImportResult fail(const std::string& e) { return {"", {e}, 0, {}, 1, {}}; }
  // At most kShownLines of each are kept, then a count (a 16 MiB template
  // of one repeated channel must not print 144,000 lines).
  void warn(const std::string& where, const std::string& what) {
    if (++warning_count_ <= kShownLines) warnings_.push_back(fmt::format("{}: {}: warning: {}", file_, where, what));
  }
  void error(const std::string& where, const std::string& what) {
    if (++error_count_ <= kShownLines)
      errors_.push_back(where.empty() ? fmt::format("{}: error: {}", file_, what) : fmt::format("{}: {}: error: {}", file_, where, what));
  }
  std::vector<std::string> warnings() const {
    std::vector<std::string> out = warnings_;
    if (warning_count_ > kShownLines)
      out.push_back(fmt::format("{}: {} more warnings not shown ({} in all)", file_, warning_count_ - kShownLines, warning_count_));
    return out;
  }
  std::vector<std::string> errors() const {
    std::vector<std::string> out = errors_;
    if (error_count_ > kShownLines)
      out.push_back(fmt::format("{}: {} more errors not shown ({} in all)", file_, error_count_ - kShownLines, error_count_));
    return out;
  }

  // A register's role from one of its channels' (or setup items') names.
  void take_role(Reg& r, const std::string& name) {
    auto m = spec::role_of_name(name);
    if (rank(m.role) < rank(r.role)) {
      r.role = m.role;
      r.role_word = m.word;
    }
  }
  // The access the spec states: a writable register of a motion, save or
  // factory-reset role is a command.
  static Access access_of(const Reg& r) { return r.writable ? (command_role(r.role) ? Access::command : Access::rw) : Access::ro; }

  std::optional<Table> table_of(const json& c, const std::string& where) {
    std::string rt = c.value("reg_type", "holding");
    if (rt == "holding" || rt == "holding_single" || rt == "holding_multi") return Table::holding;
    if (rt == "input") return Table::input;
    if (rt == "coil") return Table::coil;
    if (rt == "discrete") return Table::discrete_input;
    warn(where, fmt::format("reg_type '{}' is not a Modbus table (holding, input, coil, discrete): left out", rt));
    return std::nullopt;
  }

  struct Address {
    uint32_t address = 0;
    std::optional<int> bit, width;
  };
  // 16009, "16009", "0x3E89", "50199:9:1" (address:bit:width), "0x..:b:w".
  std::optional<Address> address_of(const json& a, const std::string& where) {
    Address out;
    if (a.is_number_integer()) {
      int64_t v = a.get<int64_t>();
      if (v < 0 || v > 0xFFFF) return error(where, fmt::format("address {} is not 0..65535", v)), std::nullopt;
      out.address = uint32_t(v);
      return out;
    }
    if (!a.is_string()) return error(where, "address is neither a number nor a string"), std::nullopt;
    std::string s = a.get<std::string>();
    std::vector<std::string> parts;
    for (size_t b = 0, e; b <= s.size(); b = e + 1) {
      e = s.find(':', b);
      if (e == std::string::npos) e = s.size();
      parts.push_back(s.substr(b, e - b));
    }
    auto number = [](const std::string& p) -> std::optional<int64_t> {
      if (p.empty()) return std::nullopt;
      size_t used = 0;
      try {
        int64_t v = std::stoll(p, &used, p.size() > 2 && p[0] == '0' && (p[1] == 'x' || p[1] == 'X') ? 16 : 10);
        if (used != p.size()) return std::nullopt;
        return v;
      } catch (...) {
        return std::nullopt;
      }
    };
    auto v = number(parts[0]);
    if (!v || *v < 0 || *v > 0xFFFF || parts.size() > 3)
      return error(where, fmt::format("address '{}' is not N, 0xN or N:BIT:WIDTH with N 0..65535", s)), std::nullopt;
    out.address = uint32_t(*v);
    if (parts.size() >= 2) {
      auto bit = number(parts[1]);
      auto width = parts.size() == 3 ? number(parts[2]) : std::optional<int64_t>(1);
      if (!bit || !width || *bit < 0 || *width < 1 || *bit + *width > 16)
        return error(where, fmt::format("address '{}': bit {} width {} is not inside a 16-bit register", s, parts[1],
                                        parts.size() == 3 ? parts[2] : "1")),
               std::nullopt;
      out.bit = int(*bit);
      out.width = int(*width);
    }
    return out;
  }

  // The spec's type and width of a template format; nullopt (with a warning) when the language has none.
  std::optional<std::pair<DataType, int>> format_of(const std::string& f, const std::string& where, bool bits) {
    if (bits) return std::pair(DataType::bit, 1);
    if (f == "u16" || f == "u8" || f == "bcd8" || f == "bcd16" || f == "char8") return std::pair(DataType::u16, 1);
    if (f == "s16" || f == "s8") return std::pair(DataType::s16, 1);
    if (f == "u32" || f == "bcd24" || f == "bcd32" || f == "u24") return std::pair(DataType::u32, 2);
    if (f == "s32" || f == "s24") return std::pair(DataType::s32, 2);
    if (f == "float") return std::pair(DataType::f32, 2);
    warn(where, fmt::format("format '{}' takes more than two registers or is text: the spec language states 1- and "
                            "2-word values; left out", f));
    return std::nullopt;
  }

  Reg& at(Table t, uint32_t a) {
    if (Reg* r = find(t, a)) return *r;
    index_[{int(t), a}] = regs_.size();
    regs_.push_back({});
    regs_.back().table = t;
    regs_.back().address = a;
    return regs_.back();
  }
  Reg* find(Table t, uint32_t a) {
    auto it = index_.find({int(t), a});
    return it == index_.end() ? nullptr : &regs_[it->second];
  }

  std::string key_for(const std::string& id, const std::string& name) {
    std::string base;
    for (char c : id.empty() ? name : id) base += std::isalnum(static_cast<unsigned char>(c)) ? char(std::tolower(static_cast<unsigned char>(c))) : '_';
    while (base.find("__") != std::string::npos) base.replace(base.find("__"), 2, "_");
    if (base.empty() || !std::isalnum(static_cast<unsigned char>(base[0]))) base = "r" + base;
    if (base.size() > 60) base.resize(60);  // an id is at most 80 characters, and a bitfield's is the key + "-bits"
    std::string k = base;
    // The next free suffix per base: 100,000 channels of one name stay linear.
    if (keys_.count(k)) {
      int& n = next_suffix_[base];
      if (n < 2) n = 2;
      do k = fmt::format("{}_{}", base, n++);
      while (keys_.count(k));
    }
    keys_.insert(k);
    return k;
  }

  void channel(const json& c, const std::string& where, bool parameter) {
    std::string name = english(*device_, c.value("name", c.value("title", c.value("id", where))));
    std::string at_ = where + " '" + name + "'";
    auto table = table_of(c, at_);
    if (!table || !c.contains("address")) {
      if (table) error(at_, "no address");
      return;
    }
    auto addr = address_of(c["address"], at_);
    if (!addr) return;
    bool bits_table = *table == Table::coil || *table == Table::discrete_input;
    // Input registers and discrete inputs are read-only whatever the template says (MBAP v1.1b3 §4.3).
    bool writable = !c.value("readonly", false) && (*table == Table::holding || *table == Table::coil);
    if (addr->bit) {  // a bit channel: a field of the register
      if (bits_table) return error(at_, "a bit address in a table of bits");
      Reg& r = at(*table, addr->address);
      for (const auto& f : r.fields)
        if (!(addr->bit.value() + addr->width.value() - 1 < f.lo || addr->bit.value() > f.hi))
          return warn(at_, fmt::format("bits {}..{} overlap '{}': left out", *addr->bit, *addr->bit + *addr->width - 1, f.name));
      r.fields.push_back({*addr->bit, *addr->bit + *addr->width - 1, name});
      r.writable |= writable;
      take_role(r, name);
      if (r.origin.empty()) r.origin = where;
      return;
    }
    auto fmt_ = format_of(c.value("format", bits_table ? "bit" : "u16"), at_, bits_table);
    if (!fmt_) return;
    if (Reg* other = find(*table, addr->address); other && other->whole) {
      warn(at_, fmt::format("a second channel on {} 0x{:04X} ('{}' is the first): left out", csv_table_name(*table), addr->address,
                            other->name));
      return;
    }
    if (addr->address + uint32_t(fmt_->second) - 1 > 0xFFFF) return error(at_, "the value runs past address 0xFFFF");
    Reg& r = at(*table, addr->address);
    r.whole = true;
    r.name = name;
    r.key = key_for(c.value("id", ""), name);
    r.origin = where;
    r.type = fmt_->first;
    r.words = fmt_->second;
    r.low_first = c.value("word_order", "big_endian") == "little_endian";
    r.writable |= writable;
    take_role(r, name);
    r.unit = c.value("units", "");
    if (c.contains("scale") && c["scale"].is_number() && c["scale"].get<double>() > 0) r.scale = c["scale"].get<double>();
    // min/max are of the value wb-mqtt-serial publishes (raw x scale): the spec's range is raw.
    auto raw = [&](const char* k) -> std::optional<double> {
      if (!c.contains(k) || !c[k].is_number()) return std::nullopt;
      return std::round(c[k].get<double>() / r.scale);
    };
    r.min = raw("min");
    r.max = raw("max");
    if (r.max && !r.min) r.min = r.type == DataType::s16 || r.type == DataType::s32 ? std::optional<double>() : std::optional<double>(0);
    if (c.contains("enum") && c["enum"].is_array()) {
      const json titles = c.value("enum_titles", json::array());
      for (size_t i = 0; i < c["enum"].size(); ++i)
        if (c["enum"][i].is_number_integer())
          r.enum_values.emplace_back(c["enum"][i].get<int64_t>(),
                                     i < titles.size() && titles[i].is_string() ? english(*device_, titles[i].get<std::string>())
                                                                                 : fmt::format("value {}", c["enum"][i].get<int64_t>()));
    }
    if (parameter) r.note = "a parameter of the template (a setting written from its configuration)";
  }

  void setup(const json& s, const std::string& where) {
    std::string title = english(*device_, s.value("title", where));
    std::string at_ = where + " '" + title + "'";
    auto table = table_of(s, at_);
    if (!table || !s.contains("address") || !s.contains("value") || !s["value"].is_number_integer()) {
      if (table) error(at_, "a setup item needs an address and an integer value");
      return;
    }
    if (*table != Table::holding && *table != Table::coil) return error(at_, "a setup write to a table no function writes");
    auto addr = address_of(s["address"], at_);
    if (!addr) return;
    Reg* r = find(*table, addr->address);
    if (!r || !r->whole) {
      // Written but read by no channel: a register of its own.
      Reg& n = at(*table, addr->address);
      n.whole = true;
      n.name = title;
      n.key = key_for("", title);
      n.origin = where;
      auto f = format_of(s.value("format", "u16"), at_, *table == Table::coil);
      if (f) {
        n.type = f->first;
        n.words = f->second;
      }
      r = &n;
    }
    r->writable = true;
    take_role(*r, title);
    setups_.push_back({r->key, s["value"].get<int64_t>(), where, title});
  }

  std::string emit(const json& d) {
    std::sort(regs_.begin(), regs_.end(), [](const Reg& a, const Reg& b) { return std::pair(int(a.table), a.address) < std::pair(int(b.table), b.address); });
    for (auto& r : regs_) {
      if (r.key.empty()) r.key = key_for("", fmt::format("bits_{}", r.address));
      if (r.name.empty()) r.name = fmt::format("bits of 0x{:04X}", r.address);
    }
    std::set<Table> tables;
    bool write_holding = false, write_coil = false;
    for (const auto& r : regs_) {
      tables.insert(r.table);
      if (r.writable) (r.table == Table::coil ? write_coil : write_holding) = true;
    }
    const std::string cite = name_;
    std::string y;
    y += fmt::format("# {}: imported from the wb-mqtt-serial template {} by `mbconform spec import --wb-template`.\n", id_, name_);
    y += "# Every register cites the template entry it came from. A template states no serial\n"
         "# line, function codes or exception policy: those below are placeholders.\n";
    y += "mbconform_spec: 1\n\ndevice:\n";
    y += fmt::format("  id: {}\n  vendor: {}\n  title: {}\n  models: [{}]\n", id_, yaml_str("from the wb-mqtt-serial template " + name_),
                     yaml_str(title_), yaml_str(d.value("name", id_)));
    // source: wb-mqtt-serial: the facts are the template's, not a manual's: each is inferred (spec/README.md).
    y += fmt::format("  manual: {{file: {}, source: wb-mqtt-serial, address_notation: decimal, addressing_note: {}}}\n", yaml_str(name_),
                     yaml_str("wb-mqtt-serial addresses are wire (PDU) addresses, decimal unless written 0x...; A:B:W is bit B, W bits wide, of register A"));
    y += fmt::format("  section: {}\n\n", yaml_str(cite));
    y += "serial:\n  note: \"placeholder: the template leaves the line to the port's configuration; the standard's values\"\n"
         "  slave_id: {min: 1, max: 247, section: \"MB-SL 2.2\"}\n"
         "  broadcast: {writes: unspecified, reply: unspecified}\n"
         "  baud_rates: {values: [9600, 19200], default: 9600, section: \"MB-SL 3.2\"}\n"
         "  frame_formats: {values: [8N1, 8N2, 8E1], default: 8N2, section: \"MB-SL 2.5.1\"}\n";
    // The registers that set the line: never written by a run (conformance/policy/).
    std::string settings;
    for (const auto& r : regs_)
      if (spec::is_line_setting(r.role) && r.table == Table::holding)
        settings += fmt::format("    - {{register: {}, setting: {}, section: {}, note: {}}}\n", r.address,
                                r.role == spec::Role::slave_address ? "slave_id"
                                : r.role == spec::Role::baud        ? "baud_rate"
                                                                    : "frame_format",
                                yaml_str(cite + " " + r.origin),
                                yaml_str(fmt::format("role {} (the name's word '{}')", spec::to_string(r.role), r.role_word)));
    if (!settings.empty()) y += "  settings:\n" + settings;
    y += "\n";
    int max_read = d.value("max_read_registers", 0);
    y += "profile:\n  note: \"the function codes of the tables the template reads and writes (MBAP 6); the exception policy is not in a template\"\n";
    y += "  function_codes:\n";
    auto fc = [&](int code, const char* clause, bool limited) {
      y += fmt::format("    - {{code: {}, section: \"MBAP {}\"", code, clause);
      if (limited && max_read > 0) y += fmt::format(", max_quantity: {}, note: \"max_read_registers of {}\"", max_read, name_);
      y += "}\n";
    };
    if (tables.count(Table::coil)) fc(1, "6.1", false);
    if (tables.count(Table::discrete_input)) fc(2, "6.2", false);
    if (tables.count(Table::holding)) fc(3, "6.3", true);
    if (tables.count(Table::input)) fc(4, "6.4", true);
    if (write_coil) fc(5, "6.5", false);
    if (write_holding) fc(6, "6.6", false);
    if (write_coil) fc(15, "6.11", false);
    if (write_holding) fc(16, "6.12", false);
    y += "  exception_policy:\n";
    for (auto v : spec::kAllViolations) y += fmt::format("    {}: unspecified\n", spec::to_string(v));

    std::string bitfields;
    for (const auto& r : regs_) {
      if (r.fields.empty()) continue;
      bitfields += fmt::format("  - id: {}-bits\n    section: {}\n    fields:\n", r.key, yaml_str(cite + " " + r.origin));
      auto fields = r.fields;
      std::sort(fields.begin(), fields.end(), [](const Field& a, const Field& b) { return a.lo < b.lo; });
      for (const auto& f : fields)
        bitfields += f.lo == f.hi ? fmt::format("      - {{bit: {}, name: {{en: {}}}}}\n", f.lo, yaml_str(f.name))
                                  : fmt::format("      - {{bits: [{}, {}], name: {{en: {}}}}}\n", f.lo, f.hi, yaml_str(f.name));
    }
    if (!bitfields.empty()) y += "\nbitfields:\n" + bitfields;

    y += "\nregisters:\n";
    for (const auto& r : regs_) {
      bool bits = r.table == Table::coil || r.table == Table::discrete_input;
      Access access = access_of(r);
      std::string m = fmt::format("address: {}", r.address);
      if (r.table != Table::holding) m += fmt::format(", table: {}", spec::to_string(r.table));
      m += fmt::format(", key: {}, name: {{en: {}}}, access: {}", r.key, yaml_str(r.name), spec::to_string(access));
      if (!r.fields.empty() && r.words == 1 && !bits) {
        m += fmt::format(", type: bitfield, bitfield: {}-bits", r.key);
      } else if (!r.enum_values.empty() && r.words == 1 && !bits) {
        m += ", type: enum, enum: [";
        for (size_t i = 0; i < r.enum_values.size(); ++i)
          m += fmt::format("{}{{value: {}, name: {{en: {}}}}}", i ? ", " : "", r.enum_values[i].first, yaml_str(r.enum_values[i].second));
        m += "]";
      } else {
        m += fmt::format(", type: {}", spec::to_string(r.type));
      }
      if (r.words == 2) m += fmt::format(", words: 2, word_order: {}", r.low_first ? "low_first" : "high_first");
      if (r.min && r.max && r.enum_values.empty() && r.fields.empty())
        m += fmt::format(", range: {{min: {}, max: {}}}, basis: {{range: {{inferred: {}, searched: {}}}}}", num(*r.min), num(*r.max),
                         yaml_str("the template's min/max are of the published value (raw x scale " + num(r.scale) + "); raw = value / scale"),
                         yaml_str(name_));
      if (!r.unit.empty()) m += fmt::format(", unit: {}", yaml_str(r.unit));
      if (r.scale != 1) m += fmt::format(", scale: {}", num(r.scale));
      if (access == Access::command && r.role == spec::Role::motion)
        m += fmt::format(", command: {{effect: {}, motion: true}}",
                         yaml_str(fmt::format("a channel of the template starts, stops or reverses the drive (the name's word '{}'): "
                                              "written only with --allow-motion", r.role_word)));
      else if (access == Access::command)
        m += fmt::format(", command: {{effect: {}, eeprom: true}}",
                         yaml_str(fmt::format("the template names it a {} (the word '{}'): written only with the EEPROM opt-in",
                                              r.role == spec::Role::save ? "save" : "factory reset", r.role_word)));
      if (!r.note.empty()) m += fmt::format(", note: {}", yaml_str(r.note));
      m += fmt::format(", section: {}", yaml_str(cite + " " + r.origin));
      y += "  - {" + m + "}\n";
    }
    if (!setups_.empty()) {
      y += fmt::format("\noperations:\n  section: {}\n  setup:\n", yaml_str(cite + " setup"));
      for (const auto& s : setups_)
        y += fmt::format("    - {{register: {}, value: {}, section: {}}}  # {}\n", s.key, s.value, yaml_str(cite + " " + s.where), s.title);
    }
    std::string timing;
    for (const char* k : {"response_timeout_ms", "frame_timeout_ms", "guard_interval_us"})
      if (d.contains(k) && d[k].is_number()) timing += fmt::format("  {}: {}\n", k, num(d[k].get<double>()));
    if (!timing.empty()) y += "\ntiming:\n" + timing + fmt::format("  section: {}\n", yaml_str(cite));
    y += "\nexamples: []\nerrata: []\n";
    return y;
  }

  struct Setup {
    std::string key;
    int64_t value;
    std::string where, title;
  };
  std::string file_, id_, name_, title_;
  const json* device_ = nullptr;
  std::vector<Reg> regs_;
  std::vector<Setup> setups_;
  std::set<std::string> keys_;
  std::map<std::string, int> next_suffix_;
  std::vector<std::string> errors_, warnings_;
  size_t error_count_ = 0, warning_count_ = 0;
  std::map<std::pair<int, uint32_t>, size_t> index_;  // (table, address) -> regs_ index, until emit sorts regs_
};

}  // namespace

ImportResult import_wb_template(const std::string& text, const std::string& file, const std::string& id) {
  return WbImporter(file, id).run(text);
}

std::string wb_template_id(const std::string& text) {
  try {
    if (text.size() > kMaxImportBytes) return "";
    json t = parse_template(text);
    std::string id = t.at("device").value("id", t.value("device_type", ""));
    std::string out;
    for (char c : id) out += std::isalnum(static_cast<unsigned char>(c)) ? char(std::tolower(static_cast<unsigned char>(c))) : '-';
    while (!out.empty() && out.front() == '-') out.erase(out.begin());
    return out;
  } catch (...) {
    return "";
  }
}

}  // namespace mbc::exchange
