// `spec export --format wb-template`: a spec's register map as a
// wb-mqtt-serial device template, the form import_wb.cpp reads back.
#include <fmt/core.h>
#include <nlohmann/json.hpp>

#include <map>

#include "exchange.h"

namespace mbc::exchange {

std::string export_wb_template(const spec::Spec& s) {
  using nlohmann::ordered_json;
  using spec::Access;
  using spec::DataType;
  using spec::Table;
  auto reg_type = [](Table t) {
    switch (t) {
      case Table::holding: return "holding";
      case Table::input: return "input";
      case Table::coil: return "coil";
      case Table::discrete_input: return "discrete";
    }
    return "holding";
  };
  auto format = [](const spec::Register& r) -> const char* {
    switch (r.type) {
      case DataType::s16: return "s16";
      case DataType::u32: return "u32";
      case DataType::s32: return "s32";
      case DataType::f32: return "float";
      case DataType::enumeration:
      case DataType::bitfield: return r.words == 2 ? "u32" : "u16";
      default: return "u16";
    }
  };
  ordered_json channels = ordered_json::array();
  for (const auto& r : s.registers) {
    bool bits = r.table == Table::coil || r.table == Table::discrete_input;
    ordered_json c;
    c["name"] = r.name.en;
    c["id"] = r.key;
    c["reg_type"] = reg_type(r.table);
    c["address"] = r.address;
    c["type"] = bits ? "switch" : "value";
    if (!bits) c["format"] = format(r);
    if (r.words == 2) c["word_order"] = r.low_word_first() ? "little_endian" : "big_endian";
    if (r.scale != 1) c["scale"] = r.scale;
    if (!r.unit.empty()) c["units"] = r.unit;
    if (r.access == Access::ro) c["readonly"] = true;
    if (r.range && !bits) {
      c["min"] = r.range->min * r.scale;  // the template's min/max are of the published value (raw x scale)
      c["max"] = r.range->max * r.scale;
    }
    if (r.type == DataType::enumeration)
      if (const spec::Enumeration* e = s.find_enum(r.enum_id)) {
        ordered_json values = ordered_json::array(), titles = ordered_json::array();
        for (const auto& v : e->values) {
          values.push_back(v.value);
          titles.push_back(v.name.en);
        }
        c["enum"] = values;
        c["enum_titles"] = titles;
      }
    channels.push_back(c);
    if (r.type == DataType::bitfield && r.words == 1)
      if (const spec::Bitfield* b = s.find_bitfield(r.bitfield_id))
        for (const auto& f : b->fields) {
          if (f.reserved) continue;
          ordered_json bc;
          bc["name"] = f.name.en;
          bc["reg_type"] = reg_type(r.table);
          bc["address"] = fmt::format("{}:{}:{}", r.address, f.lo, f.hi - f.lo + 1);
          bc["type"] = f.lo == f.hi ? "switch" : "value";
          bc["format"] = "u16";
          if (r.access == Access::ro) bc["readonly"] = true;
          channels.push_back(bc);
        }
  }
  ordered_json setup = ordered_json::array();
  for (const auto& w : s.operations.setup) {
    const spec::Register* r = s.find_by_key(w.key);
    if (!r) continue;
    setup.push_back({{"title", r->name.en}, {"address", r->address}, {"reg_type", reg_type(r->table)}, {"format", format(*r)},
                     {"value", w.value}});
  }
  ordered_json device;
  device["name"] = s.device.title;
  device["id"] = s.device.id;
  if (s.timing.response_timeout_ms) device["response_timeout_ms"] = *s.timing.response_timeout_ms;
  if (s.timing.frame_timeout_ms) device["frame_timeout_ms"] = *s.timing.frame_timeout_ms;
  if (s.timing.guard_interval_us) device["guard_interval_us"] = *s.timing.guard_interval_us;
  if (const spec::FunctionCode* f = s.profile.function(3); f && f->max_quantity) device["max_read_registers"] = *f->max_quantity;
  if (!setup.empty()) device["setup"] = setup;
  device["channels"] = channels;
  ordered_json t;
  t["title"] = s.device.title;
  t["device_type"] = s.device.id;
  t["device"] = device;
  return t.dump(4) + "\n";
}

}  // namespace mbc::exchange
