#include "spec.h"

#include <algorithm>

namespace mbc::spec {

const char* to_string(Violation v) {
  switch (v) {
    case Violation::unsupported_function: return "unsupported_function";
    case Violation::unmapped_address: return "unmapped_address";
    case Violation::address_past_map: return "address_past_map";
    case Violation::quantity_zero: return "quantity_zero";
    case Violation::quantity_over_limit: return "quantity_over_limit";
    case Violation::value_out_of_range: return "value_out_of_range";
    case Violation::write_read_only: return "write_read_only";
    case Violation::read_write_only: return "read_write_only";
    case Violation::crc_error: return "crc_error";
    case Violation::wrong_byte_count: return "wrong_byte_count";
  }
  return "?";
}

Table table_for_function(int fc) {
  switch (fc) {
    case 1:
    case 5:
    case 7:
    case 15: return Table::coil;
    case 2: return Table::discrete_input;
    case 4: return Table::input;
    default: return Table::holding;
  }
}

const char* to_string(Table t) {
  switch (t) {
    case Table::holding: return "holding";
    case Table::input: return "input";
    case Table::coil: return "coil";
    case Table::discrete_input: return "discrete_input";
  }
  return "?";
}

const char* to_string(Access a) {
  switch (a) {
    case Access::ro: return "ro";
    case Access::rw: return "rw";
    case Access::wo: return "wo";
    case Access::command: return "command";
  }
  return "?";
}

const char* to_string(DataType t) {
  switch (t) {
    case DataType::u16: return "u16";
    case DataType::s16: return "s16";
    case DataType::u32: return "u32";
    case DataType::s32: return "s32";
    case DataType::f32: return "f32";
    case DataType::bitfield: return "bitfield";
    case DataType::enumeration: return "enum";
    case DataType::bit: return "bit";
  }
  return "?";
}

const char* to_string(WordOrder w) {
  switch (w) {
    case WordOrder::none: return "none";
    case WordOrder::high_first: return "high_first";
    case WordOrder::low_first: return "low_first";
  }
  return "?";
}

const Register* Spec::find_register(uint16_t address, Table table) const {
  for (const auto& r : registers)
    if (r.table == table && r.address == address) return &r;
  return nullptr;
}

const Register* Spec::register_covering(uint16_t address, Table table) const {
  // registers are sorted by (table, address): binary search the last start <= address.
  auto it = std::upper_bound(registers.begin(), registers.end(), std::pair(int(table), address),
                             [](const std::pair<int, uint16_t>& key, const Register& r) {
                               return key < std::pair(int(r.table), r.address);
                             });
  while (it != registers.begin()) {
    --it;
    if (it->table != table) return nullptr;
    if (it->address <= address && it->last_address() >= address) return &*it;
    if (it->address + 2 <= address) return nullptr;  // no register is wider than 2 words
  }
  return nullptr;
}

const Register* Spec::find_by_key(const std::string& key) const {
  for (const auto& r : registers)
    if (!r.key.empty() && r.key == key) return &r;
  return nullptr;
}

const Enumeration* Spec::find_enum(const std::string& id) const {
  for (const auto& e : enums)
    if (e.id == id) return &e;
  return nullptr;
}

const Bitfield* Spec::find_bitfield(const std::string& id) const {
  for (const auto& b : bitfields)
    if (b.id == id) return &b;
  return nullptr;
}

const Erratum* Spec::find_erratum(const std::string& id) const {
  for (const auto& e : errata)
    if (e.id == id) return &e;
  return nullptr;
}

std::optional<uint16_t> Spec::last_address(Table table) const {
  std::optional<uint16_t> last;
  for (const auto& r : registers)
    if (r.table == table && (!last || r.last_address() > *last)) last = uint16_t(std::min<uint32_t>(r.last_address(), 0xFFFF));
  return last;
}

}  // namespace mbc::spec

namespace mbc::spec {

const char* to_string(Basis b) {
  switch (b) {
    case Basis::stated: return "stated";
    case Basis::inferred: return "inferred";
    case Basis::observed: return "observed";
    case Basis::either: return "either";
  }
  return "?";
}

const char* to_string(Fact f) {
  switch (f) {
    case Fact::read: return "read";
    case Fact::write: return "write";
    case Fact::range: return "range";
    case Fact::default_value: return "default";
    case Fact::word_order: return "word_order";
    case Fact::type: return "type";
    case Fact::takes_effect: return "takes_effect";
    case Fact::persistence: return "persistence";
    case Fact::persistence_unless: return "persistence_unless";
  }
  return "?";
}

FactBasis Register::basis_of(Fact f) const {
  auto it = basis.find(f);
  if (it != basis.end()) return it->second;
  FactBasis b;
  b.section = section;
  b.loc = loc;
  return b;
}

FactBasis FunctionCode::basis_of(const std::string& fact) const {
  auto it = basis.find(fact);
  if (it != basis.end()) return it->second;
  FactBasis b;
  b.section = section;
  b.loc = loc;
  return b;
}

}  // namespace mbc::spec

namespace mbc::spec {
bool Erratum::contests_fact(const std::string& what) const {
  if (!contests_given) return true;
  for (const auto& c : contests)
    if (c == what) return true;
  return false;
}
const char* to_string(Trigger t) {
  switch (t) {
    case Trigger::level: return "level";
    case Trigger::edge: return "edge";
    case Trigger::write: return "write";
  }
  return "?";
}

const ControlState* Control::state(const std::string& id) const {
  for (const auto& s : states)
    if (s.id == id) return &s;
  return nullptr;
}

const ControlCommand* Control::command(const std::string& id) const {
  for (const auto& c : commands)
    if (c.id == id) return &c;
  return nullptr;
}

const ControlMode* Control::mode(const std::string& id) const {
  for (const auto& m : modes)
    if (m.id == id) return &m;
  return nullptr;
}

std::vector<const ControlTransition*> Control::transitions_on(const std::string& from, const std::string& cmd) const {
  std::vector<const ControlTransition*> out;
  for (const auto& t : transitions)
    if (t.command == cmd && (t.from == from || t.from == "*")) out.push_back(&t);
  return out;
}

}  // namespace mbc::spec
