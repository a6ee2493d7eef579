#include "spec_registers.h"

#include <cmath>

namespace mbc::serve_test {

using spec::Access;
using spec::DataType;
using spec::Register;
using spec::Table;

bool plain_rw(const spec::Spec& s, const Register& r, bool allow_enum) {
  bool word_type = r.type == DataType::u16 || r.type == DataType::s16 || (allow_enum && r.type == DataType::enumeration);
  if (r.table != Table::holding || r.access != Access::rw || r.words != 1 || !word_type || !r.range || r.command ||
      r.takes_effect != spec::TakesEffect::immediate)
    return false;
  for (const auto& setting : s.serial.settings)
    if (setting.register_address == r.address) return false;
  return true;
}

static uint16_t raw(const Register& r, double engineering) {
  auto v = int64_t(std::llround(engineering));
  return uint16_t(v & 0xFFFF);  // s16 as its two's complement word
}

uint16_t middle_word(const Register& r) { return raw(r, std::floor((r.range->min + r.range->max) / 2)); }

const Register* pick_rw(const spec::Spec& s) {
  for (const auto& r : s.registers)
    if (plain_rw(s, r)) return &r;
  return nullptr;
}

const Register* pick_rw_word(const spec::Spec& s) {
  for (const auto& r : s.registers) {
    if (r.range) continue;
    Register ranged = r;
    ranged.range = spec::Range{0, 0};
    if (plain_rw(s, ranged)) return &r;
  }
  return nullptr;
}

const Register* pick_default_word(const spec::Spec& s) {
  auto one_word = [](const Register& r) {
    return (r.table == Table::holding || r.table == Table::input) && r.words == 1 && r.default_value &&
           r.type != DataType::f32 && r.type != DataType::bit && !r.command;
  };
  for (const auto& r : s.registers)
    if (one_word(r) && r.access == Access::ro) return &r;
  for (const auto& r : s.registers)
    if (one_word(r) && r.access == Access::rw) return &r;
  return nullptr;
}

uint16_t word_other_than_default(const Register& r) {
  double def = r.default_value.value_or(0);
  double mid = std::floor((r.range->min + r.range->max) / 2);
  if (mid != def) return raw(r, mid);
  return raw(r, r.range->max != def ? r.range->max : r.range->min);
}

const Register* pick_persistent_on_write(const spec::Spec& s) {
  for (const auto& r : s.registers)
    if (plain_rw(s, r, true) && r.persistence.store != spec::Store::none && r.persistence.by == spec::PersistBy::on_write &&
        r.range->min != r.range->max)
      return &r;
  return nullptr;
}

const Register* pick_lost_at_power_off(const spec::Spec& s) {
  for (const auto& r : s.registers)
    if (plain_rw(s, r) && r.persistence.by != spec::PersistBy::on_write && r.default_value && r.range->min != r.range->max)
      return &r;
  return nullptr;
}

}  // namespace mbc::serve_test
