// `mbconform spec export ID --format csv|home-assistant|edgex`.
#include <fmt/core.h>
#include <fmt/format.h>
#include <fnmatch.h>

#include <cctype>
#include <cstdlib>
#include <optional>
#include <nlohmann/json.hpp>

#include "csv.h"
#include "exchange.h"

namespace mbc::exchange {
namespace {

using spec::Access;
using spec::DataType;
using spec::Register;
using spec::Table;
using spec::WordOrder;

std::string num(double d) { return fmt::format("{}", d); }
std::string yaml_str(const std::string& s) { return nlohmann::json(s).dump(); }

// The integer type that carries an enum or bitfield register on the wire.
DataType wire_type(const Register& r) {
  if (r.type == DataType::enumeration || r.type == DataType::bitfield) return r.words == 2 ? DataType::u32 : DataType::u16;
  return r.type;
}

// A name unique in the map: the register's key, else its address.
std::string ident(const spec::Spec& s, const Register& r) {
  std::string base = r.key.empty() ? fmt::format("{}_{:04x}", spec::to_string(r.table), r.address) : r.key;
  std::string id;
  for (char c : base) id += (std::isalnum(static_cast<unsigned char>(c)) ? c : '_');
  return s.device.id + "_" + id;
}

// Decimal places that show one step of `scale` (0.1 -> 1, 0.01 -> 2).
int precision(double scale) {
  int p = 0;
  for (double v = scale; p < 6 && std::abs(v - std::round(v)) > 1e-9; v *= 10) ++p;
  return p;
}

}  // namespace

const char* csv_table_name(Table t) {
  switch (t) {
    case Table::coil: return "coil";
    case Table::discrete_input: return "discrete input";
    case Table::input: return "input register";
    case Table::holding: return "holding register";
  }
  return "?";
}

// The role the spec gives a register (spec/roles/roles.h), for the `role`
// column: a line setting it lists, a command that moves or writes the
// EEPROM (the factory reset when operations names it so), else none. An
// import reads it back as it is, whatever the register's name says.
static spec::Role spec_role(const spec::Spec& s, const Register& r) {
  if (r.table == Table::holding)
    for (const auto& st : s.serial.settings)
      if (st.register_address == r.address)
        return st.setting == "slave_id" ? spec::Role::slave_address : st.setting == "baud_rate" ? spec::Role::baud : spec::Role::frame_format;
  if (r.command && r.command->motion) return spec::Role::motion;
  if (s.operations.factory_reset && !r.key.empty() && s.operations.factory_reset->key == r.key) return spec::Role::factory_reset;
  if ((r.command && r.command->eeprom) || (s.operations.save && !r.key.empty() && s.operations.save->key == r.key)) return spec::Role::save;
  return spec::Role::none;
}

std::string export_csv(const spec::Spec& s) {
  std::string out;
  for (size_t i = 0; i < kCsvColumns.size(); ++i) out += (i ? "," : "") + kCsvColumns[i];
  out += "\n";
  for (const auto& r : s.registers) {
    std::vector<std::string> f = {
        csv_table_name(r.table),
        fmt::format("0x{:04X}", r.address),
        r.name.en,
        spec::to_string(r.access),
        spec::to_string(spec_role(s, r)),
        spec::to_string(wire_type(r)),
        std::to_string(r.words),
        r.word_order == WordOrder::none ? "" : spec::to_string(r.word_order),
        r.range ? num(r.range->min) : "",
        r.range ? num(r.range->max) : "",
        r.default_value ? num(*r.default_value) : "",
        r.unit,
        r.scale == 1 ? "" : num(r.scale),
        r.note,
    };
    for (size_t i = 0; i < f.size(); ++i) out += (i ? "," : "") + csv_field(f[i]);
    out += "\n";
  }
  return out;
}

// Home Assistant's modbus integration, YAML configuration. The keys and
// values are those of its schema (homeassistant/components/modbus/__init__.py)
// in the 2024 releases: `device_address` (since 2023.10, core PR #100399; the
// older `slave` is being retired), platforms binary_sensor, climate, cover,
// fan, light, sensor and switch (there is no `number` platform), data types
// int16/uint16/int32/uint32/float32, `swap: word` for the low word first.
// spec/exchange/tests/export_test.py checks every key against that schema.
bool register_matches(const spec::Register& r, const std::vector<std::string>& patterns) {
  auto number = [](const std::string& t) -> std::optional<uint32_t> {
    if (t.empty()) return std::nullopt;
    char* end = nullptr;
    unsigned long v = std::strtoul(t.c_str(), &end, t.size() > 2 && t[0] == '0' && (t[1] == 'x' || t[1] == 'X') ? 16 : 10);
    if (*end != '\0' || v > 0xFFFF) return std::nullopt;
    return uint32_t(v);
  };
  auto lower = [](std::string t) {
    for (auto& c : t) c = char(std::tolower(static_cast<unsigned char>(c)));
    return t;
  };
  for (const auto& p : patterns) {
    if (auto a = number(p)) {
      if (r.address <= *a && *a <= r.last_address()) return true;
      continue;
    }
    if (auto dash = p.find('-'); dash != std::string::npos && dash > 0) {
      auto lo = number(p.substr(0, dash)), hi = number(p.substr(dash + 1));
      if (lo && hi) {
        if (r.last_address() >= *lo && r.address <= *hi) return true;
        continue;
      }
    }
    std::string lp = lower(p);
    if (fnmatch(lp.c_str(), lower(r.key).c_str(), 0) == 0 || fnmatch(lp.c_str(), lower(r.name.en).c_str(), 0) == 0) return true;
  }
  return patterns.empty();
}

std::string export_home_assistant(const spec::Spec& s, const HomeAssistantOptions& o) {
  int unit = s.serial.slave_default.value_or(1);
  std::string frame = s.serial.frame_default.value_or(s.serial.frame_formats.empty() ? "8E1" : s.serial.frame_formats[0]);
  int baud = s.serial.baud_default.value_or(s.serial.baud_rates.empty() ? 19200 : s.serial.baud_rates[0]);
  std::vector<std::string> sensors, binary, switches, writes;
  size_t left_out = 0;
  for (const auto& r : s.registers) {
    if (!register_matches(r, o.only)) {
      ++left_out;
      continue;
    }
    // What the drive changes by itself is polled often; a setting changes
    // only when written.
    bool changes_by_itself = r.access == Access::ro;
    std::string head = fmt::format("      - name: {}\n        unique_id: {}\n        address: {}\n        device_address: {}\n"
                                   "        scan_interval: {}\n",
                                   yaml_str(fmt::format("{} {} (0x{:04X})", s.device.id, r.name.en, r.address)),
                                   ident(s, r), r.address, unit, changes_by_itself ? o.fast_scan : o.slow_scan);
    bool bits = r.table == Table::coil || r.table == Table::discrete_input;
    if (bits) {
      if (r.table == Table::coil && r.access != Access::ro) {
        switches.push_back(head + "        write_type: coil\n" +
                           (r.access == Access::rw ? "        verify:\n          input_type: coil\n" : ""));
      } else {
        binary.push_back(head + fmt::format("        input_type: {}\n", r.table == Table::coil ? "coil" : "discrete_input"));
      }
      continue;
    }
    if (r.table == Table::holding && r.access != Access::ro)
      writes.push_back(fmt::format("#   0x{:04X} {} ({}, {} word{})", r.address, r.name.en, spec::to_string(r.access),
                                   r.words, r.words == 2 ? fmt::format("s, {}", spec::to_string(r.word_order)) : ""));
    if (r.access == Access::wo || r.access == Access::command) continue;  // nothing to read
    static const std::map<DataType, const char*> types = {{DataType::u16, "uint16"}, {DataType::s16, "int16"},
                                                          {DataType::u32, "uint32"}, {DataType::s32, "int32"},
                                                          {DataType::f32, "float32"}};
    std::string e = head + fmt::format("        input_type: {}\n        data_type: {}\n",
                                       r.table == Table::input ? "input" : "holding", types.at(wire_type(r)));
    if (r.word_order == WordOrder::low_first) e += "        swap: word\n";
    if (r.scale != 1) e += fmt::format("        scale: {}\n        precision: {}\n", num(r.scale), precision(r.scale));
    if (!r.unit.empty()) e += fmt::format("        unit_of_measurement: {}\n", yaml_str(r.unit));
    bool coded = r.type == DataType::enumeration || r.type == DataType::bitfield;
    if (changes_by_itself && !coded) {
      std::string n = r.name.en;
      for (auto& c : n) c = char(std::tolower(static_cast<unsigned char>(c)));
      bool counts_up = false;
      for (const char* w : {"total", "count", "hours", "energy"}) counts_up |= n.find(w) != std::string::npos;
      e += fmt::format("        state_class: {}\n", counts_up ? "total_increasing" : "measurement");
    }
    sensors.push_back(e);
  }
  std::string y;
  y += fmt::format("# Home Assistant modbus configuration for {} ({}), from spec/devices/{}.yaml\n", s.device.id,
                   s.device.title, s.device.id);
  y += "# by `mbconform spec export --format home-assistant`. Keys: the modbus integration's\n"
       "# schema of the Home Assistant 2024 releases. Set `port` to your adapter.\n#\n";
  y += fmt::format("# scan_interval: {} s for read-only registers (status, measurements), {} s for\n"
                   "# settings; state_class on numeric read-only sensors (long-term statistics).\n",
                   o.fast_scan, o.slow_scan);
  if (!o.only.empty())
    y += fmt::format("# --only {}: {} of the spec's {} registers left out.\n", fmt::format("{}", fmt::join(o.only, ",")), left_out,
                     s.registers.size());
  y += "# Writes to holding registers go through the modbus.write_register action (one\n"
       "# value: FC 06; a list: FC 16, one value per register in address order, so a\n"
       "# low_first register takes its low word first), e.g.\n";
  if (!writes.empty()) {
    const Register* w = nullptr;
    for (const auto& r : s.registers)
      if (r.table == Table::holding && r.access == Access::rw && !w) w = &r;
    if (!w)
      for (const auto& r : s.registers)
        if (r.table == Table::holding && r.access != Access::ro && !w) w = &r;
    y += fmt::format("#   action: modbus.write_register\n#   data: {{hub: {}, device_address: {}, address: {}, value: {}}}\n",
                     s.device.id, unit, w->address, w->words == 2 ? "[0, 0]" : "0");
    y += "# Writable holding registers:\n";
    for (const auto& line : writes) y += line + "\n";
  } else {
    y += "#   (this device has no writable holding register)\n";
  }
  y += fmt::format("modbus:\n  - name: {}\n    type: serial\n    method: rtu\n    port: /dev/ttyUSB0\n", s.device.id);
  y += fmt::format("    baudrate: {}\n    bytesize: {}\n    parity: {}\n    stopbits: {}\n", baud, frame.substr(0, 1),
                   frame.substr(1, 1), frame.substr(2, 1));
  auto block = [&](const char* key, const std::vector<std::string>& items) {
    if (items.empty()) return;
    y += fmt::format("    {}:\n", key);
    for (const auto& i : items) y += i;
  };
  block("sensors", sensors);
  block("binary_sensors", binary);
  block("switches", switches);
  return y;
}

// EdgeX Foundry v3 device profile for device-modbus: primaryTable
// (COILS | DISCRETES_INPUT | INPUT_REGISTERS | HOLDING_REGISTERS),
// startingAddress (wire address), rawType (what the registers hold),
// isWordSwap (low word first), properties valueType / readWrite / units /
// scale / minimum / maximum / defaultValue.
std::string export_edgex(const spec::Spec& s) {
  static const std::map<DataType, std::pair<const char*, const char*>> types = {
      {DataType::u16, {"UINT16", "Uint16"}}, {DataType::s16, {"INT16", "Int16"}}, {DataType::u32, {"UINT32", "Uint32"}},
      {DataType::s32, {"INT32", "Int32"}},   {DataType::f32, {"FLOAT32", "Float32"}}};
  std::string y;
  y += fmt::format("# EdgeX v3 device-modbus profile for {}, from spec/devices/{}.yaml\n", s.device.id, s.device.id);
  y += "# by `mbconform spec export --format edgex`.\n";
  y += fmt::format("apiVersion: v3\nname: {}\nmanufacturer: {}\nmodel: {}\nlabels: [modbus, mbconform]\ndescription: {}\n",
                   yaml_str(s.device.id), yaml_str(s.device.vendor),
                   yaml_str(s.device.models.empty() ? s.device.id : s.device.models[0]), yaml_str(s.device.title));
  y += "deviceResources:\n";
  for (const auto& r : s.registers) {
    const char* table = r.table == Table::coil             ? "COILS"
                        : r.table == Table::discrete_input ? "DISCRETES_INPUT"
                        : r.table == Table::input          ? "INPUT_REGISTERS"
                                                           : "HOLDING_REGISTERS";
    const char* rw = r.access == Access::ro ? "R" : r.access == Access::rw ? "RW" : "W";
    y += fmt::format("  - name: {}\n    isHidden: false\n    description: {}\n", yaml_str(ident(s, r)), yaml_str(r.name.en));
    y += fmt::format("    attributes: {{primaryTable: {}, startingAddress: {}", table, r.address);
    std::string value_type = "Bool";
    if (r.type != DataType::bit) {
      auto [raw, value] = types.at(wire_type(r));
      value_type = r.scale != 1 ? "Float32" : value;
      y += fmt::format(", rawType: {}", raw);
      if (r.words == 2) y += fmt::format(", isWordSwap: {}", r.word_order == WordOrder::low_first ? "true" : "false");
    }
    y += "}\n";
    y += fmt::format("    properties: {{valueType: {}, readWrite: {}", value_type, rw);
    if (!r.unit.empty()) y += fmt::format(", units: {}", yaml_str(r.unit));
    if (r.scale != 1) y += fmt::format(", scale: {}", num(r.scale));
    if (r.range) y += fmt::format(", minimum: {}, maximum: {}", num(r.range->min * r.scale), num(r.range->max * r.scale));
    if (r.default_value) y += fmt::format(", defaultValue: {}", yaml_str(num(*r.default_value * r.scale)));
    y += "}\n";
  }
  y += "deviceCommands: []\n";
  return y;
}

}  // namespace mbc::exchange
