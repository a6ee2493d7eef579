#include "engine/device.h"

#include <algorithm>
#include <bit>
#include <cmath>
#include <cstring>
#include <stdexcept>

#include "modbus/bytes.h"
#include "modbus/crc16.h"
#include "modbus/limits.h"
#include "modbus/rtu.h"
#include "modbus/words.h"
#include "loader.h"

namespace mbc::ref {

using spec::Access;
using spec::DataType;
using spec::PolicyEntry;
using spec::Register;
using spec::Table;
using spec::Violation;

namespace {

// The Modbus standard as the project states it (spec/devices/modbus-standard.yaml):
// its quantity limits and its answer to each violation are what a device
// falls back to where its manual is silent. Nothing of it is repeated here.
const spec::Spec& standard_spec() {
  static const spec::Spec s = spec::load_spec_by_id("modbus-standard");
  return s;
}

}  // namespace

// The protocol engine: one PDU in, one PDU (or silence) out. Kept as a
// friend struct so Device's public surface stays data-like.
struct Engine {
  Device& d;

  std::optional<Bytes> exception(uint8_t fc, uint8_t code) {
    ++d.counters_.exceptions;
    return Bytes{uint8_t(fc | 0x80), code};
  }

  // The answer resolve_spec() found for `v` (the device's policy, else the standard's).
  std::optional<Bytes> violate(Violation v, uint8_t fc) {
    int16_t code = d.answers_[size_t(v)];
    if (code < 0) {
      ++d.counters_.no_responses;
      return std::nullopt;
    }
    return exception(fc, uint8_t(code));
  }

  int max_quantity(uint8_t fc) const { return d.functions_[fc & 0x7F].max_quantity; }

  // Address check of [start, start+qty) in `table`, run by run of registers
  // with the same access; the violation of the first address that fails.
  std::optional<Violation> check_addresses(Table table, uint32_t start, uint32_t qty, bool reading) {
    const auto& last = d.last_address_[int(table)];
    const auto& runs = d.runs_[int(table)];
    for (uint32_t a = start; a < start + qty;) {
      if (a > 0xFFFF || !last || a > *last) return Violation::address_past_map;
      auto it = std::upper_bound(runs.begin(), runs.end(), a, [](uint32_t x, const Device::MappedRun& r) { return x < r.first; });
      if (it == runs.begin() || (--it)->last < a) return Violation::unmapped_address;
      if (reading && !it->readable) return Violation::read_write_only;
      if (!reading && !it->writable) return Violation::write_read_only;
      a = uint32_t(it->last) + 1;
    }
    return std::nullopt;
  }

  // Would the holding registers touched by writing `values` at `start` stay
  // in range? Checks each affected register's whole value (a 2-word value
  // written one word at a time is checked with its other word as stored).
  bool values_in_range(uint16_t start, std::span<const uint16_t> values) {
    std::vector<uint16_t> saved(values.size());
    for (size_t i = 0; i < values.size(); ++i) {
      saved[i] = d.holding_[uint16_t(start + i)];
      d.holding_[uint16_t(start + i)] = values[i];
    }
    bool ok = true;
    for (size_t i = 0; i < values.size() && ok; ++i) {
      const Register* r = d.spec_.register_covering(uint16_t(start + i));
      if (r) ok = in_range(*r);
    }
    for (size_t i = 0; i < values.size(); ++i) d.holding_[uint16_t(start + i)] = saved[i];
    return ok;
  }

  bool in_range(const Register& r) {
    if (r.type == DataType::f32) {
      if (!r.range) return true;
      double f = d.float_value(r);
      return !std::isnan(f) && f >= r.range->min && f <= r.range->max;
    }
    double v = double(d.value(r));
    if (r.range) return v >= r.range->min && v <= r.range->max;
    if (r.type == DataType::enumeration && !r.enum_id.empty()) {
      const spec::Enumeration* e = d.spec_.find_enum(r.enum_id);
      return !e || std::any_of(e->values.begin(), e->values.end(), [&](const spec::EnumValue& x) { return double(x.value) == v; });
    }
    return true;
  }

  // Stores words, keeps the EEPROM image for registers persisted on write,
  // and runs the behaviour's on_write hook once for the whole write.
  void store(uint16_t start, std::span<const uint16_t> values) {
    d.touched_[int(Table::holding)].mark(start, uint32_t(values.size()));
    for (size_t i = 0; i < values.size(); ++i) d.holding_[uint16_t(start + i)] = values[i];
    for (size_t i = 0; i < values.size(); ++i) {
      uint16_t a = uint16_t(start + i);
      const Register* r = d.spec_.register_covering(a);
      if (!r || r->persistence.store == spec::Store::none || r->persistence.by != spec::PersistBy::on_write) continue;
      if (r->persistence.unless_register && d.holding_[*r->persistence.unless_register] == uint16_t(r->persistence.unless_value))
        continue;  // e.g. 57HS-R 0x0016 = 1: "不更新" EEPROM
      d.stored_[a] = values[i];
      ++d.eeprom_writes_;
    }
    d.behaviour_->on_write(d, start, uint16_t(values.size()));
    // A command register reads back a fixed value after it fired, unless the
    // behaviour put something else there (HSC60 70: reads 6).
    for (size_t i = 0; i < values.size(); ++i) {
      const Register* r = d.spec_.register_covering(uint16_t(start + i));
      if (r && r->command && r->command->reads_back && r->address == uint16_t(start + i) &&
          d.holding_[r->address] == values[i])
        d.set_value(*r, *r->command->reads_back);
    }
  }

  std::optional<Bytes> write_holding(uint8_t fc, uint16_t start, std::span<const uint16_t> values) {
    if (auto v = check_addresses(Table::holding, start, uint32_t(values.size()), false)) return violate(*v, fc);
    if (!values_in_range(start, values)) return violate(Violation::value_out_of_range, fc);
    if (auto code = d.behaviour_->check_write(d, start, values)) return exception(fc, *code);
    store(start, values);
    return Bytes{};  // caller builds the echo
  }

  std::optional<Bytes> read_words(uint8_t fc, std::span<const uint8_t> pdu, Table table) {
    if (pdu.size() != 5) return violate(Violation::wrong_byte_count, fc);
    uint16_t start = be16(pdu, 1), qty = be16(pdu, 3);
    if (qty == 0) return violate(Violation::quantity_zero, fc);
    if (qty > max_quantity(fc)) return violate(Violation::quantity_over_limit, fc);
    if (auto v = check_addresses(table, start, qty, true)) return violate(*v, fc);
    return read_block(fc, start, qty, table);
  }

  Bytes read_block(uint8_t fc, uint16_t start, uint16_t qty, Table table) {
    d.behaviour_->before_read(d, start, qty);
    Bytes out(2 + 2 * size_t(qty));
    out[0] = fc;
    out[1] = uint8_t(qty * 2);
    const auto& words = table == Table::input ? d.input_ : d.holding_;
    uint8_t* o = out.data() + 2;
    for (uint32_t a = start; a < uint32_t(start) + qty; ++a, o += 2) {
      uint16_t w = words[uint16_t(a)];
      o[0] = uint8_t(w >> 8);
      o[1] = uint8_t(w);
    }
    return out;
  }

  std::optional<Bytes> read_bits(uint8_t fc, std::span<const uint8_t> pdu, Table table) {
    if (pdu.size() != 5) return violate(Violation::wrong_byte_count, fc);
    uint16_t start = be16(pdu, 1), qty = be16(pdu, 3);
    if (qty == 0) return violate(Violation::quantity_zero, fc);
    if (qty > max_quantity(fc)) return violate(Violation::quantity_over_limit, fc);
    if (auto v = check_addresses(table, start, qty, true)) return violate(*v, fc);
    const auto& bits = table == Table::coil ? d.coils_ : d.discrete_;
    Bytes out{fc, uint8_t((qty + 7) / 8)};
    out.resize(2 + out[1], 0);
    for (uint16_t i = 0; i < qty; ++i)
      if (bits[uint16_t(start + i)]) out[2 + i / 8] |= uint8_t(1 << (i % 8));
    return out;
  }

  std::optional<Bytes> write_single_coil(std::span<const uint8_t> pdu) {
    const uint8_t fc = 5;
    if (pdu.size() != 5) return violate(Violation::wrong_byte_count, fc);
    uint16_t addr = be16(pdu, 1), value = be16(pdu, 3);
    // MBAP v1.1b3 §6.5: any value but 0x0000 / 0xFF00 is an ILLEGAL DATA VALUE.
    if (value != 0x0000 && value != 0xFF00) return exception(fc, 3);
    if (auto v = check_addresses(Table::coil, addr, 1, false)) return violate(*v, fc);
    d.touched_[int(Table::coil)].mark(addr);
    d.coils_[addr] = value == 0xFF00;
    return Bytes(pdu.begin(), pdu.end());
  }

  std::optional<Bytes> write_multiple_coils(std::span<const uint8_t> pdu) {
    const uint8_t fc = 15;
    if (pdu.size() < 6) return violate(Violation::wrong_byte_count, fc);
    uint16_t start = be16(pdu, 1), qty = be16(pdu, 3);
    uint8_t bc = pdu[5];
    if (qty == 0) return violate(Violation::quantity_zero, fc);
    if (qty > max_quantity(fc)) return violate(Violation::quantity_over_limit, fc);
    if (bc != (qty + 7) / 8 || pdu.size() != size_t(6 + bc)) return violate(Violation::wrong_byte_count, fc);
    if (auto v = check_addresses(Table::coil, start, qty, false)) return violate(*v, fc);
    d.touched_[int(Table::coil)].mark(start, qty);
    for (uint16_t i = 0; i < qty; ++i) d.coils_[uint16_t(start + i)] = (pdu[6 + i / 8] >> (i % 8)) & 1;
    Bytes out{fc};
    put_be16(out, start);
    put_be16(out, qty);
    return out;
  }

  std::optional<Bytes> write_single(std::span<const uint8_t> pdu) {
    const uint8_t fc = 6;
    if (pdu.size() != 5) return violate(Violation::wrong_byte_count, fc);
    uint16_t addr = be16(pdu, 1), value = be16(pdu, 3);
    auto r = write_holding(fc, addr, std::span<const uint16_t>(&value, 1));
    if (!r || !r->empty()) return r;
    return Bytes(pdu.begin(), pdu.end());
  }

  std::optional<Bytes> write_multiple(std::span<const uint8_t> pdu) {
    const uint8_t fc = 16;
    if (pdu.size() < 6) return violate(Violation::wrong_byte_count, fc);
    uint16_t start = be16(pdu, 1), qty = be16(pdu, 3);
    uint8_t bc = pdu[5];
    if (qty == 0) return violate(Violation::quantity_zero, fc);
    if (qty > max_quantity(fc)) return violate(Violation::quantity_over_limit, fc);
    if (bc != qty * 2 || pdu.size() != size_t(6 + bc)) return violate(Violation::wrong_byte_count, fc);
    std::vector<uint16_t> values(qty);
    for (uint16_t i = 0; i < qty; ++i) values[i] = be16(pdu, 6 + 2 * i);
    auto r = write_holding(fc, start, values);
    if (!r || !r->empty()) return r;
    Bytes out{fc};
    put_be16(out, start);
    put_be16(out, qty);
    return out;
  }

  std::optional<Bytes> mask_write(std::span<const uint8_t> pdu) {
    const uint8_t fc = 22;
    if (pdu.size() != 7) return violate(Violation::wrong_byte_count, fc);
    uint16_t addr = be16(pdu, 1), and_mask = be16(pdu, 3), or_mask = be16(pdu, 5);
    if (auto v = check_addresses(Table::holding, addr, 1, false)) return violate(*v, fc);
    // MBAP v1.1b3 §6.16: Result = (Current AND And_Mask) OR (Or_Mask AND (NOT And_Mask))
    uint16_t value = uint16_t((d.holding_[addr] & and_mask) | (or_mask & ~and_mask));
    auto r = write_holding(fc, addr, std::span<const uint16_t>(&value, 1));
    if (!r || !r->empty()) return r;
    return Bytes(pdu.begin(), pdu.end());
  }

  std::optional<Bytes> read_write_multiple(std::span<const uint8_t> pdu) {
    const uint8_t fc = 23;
    if (pdu.size() < 10) return violate(Violation::wrong_byte_count, fc);
    uint16_t rstart = be16(pdu, 1), rqty = be16(pdu, 3), wstart = be16(pdu, 5), wqty = be16(pdu, 7);
    uint8_t bc = pdu[9];
    int rmax = d.functions_[fc].max_read, wmax = d.functions_[fc].max_write;
    if (rqty == 0 || wqty == 0) return violate(Violation::quantity_zero, fc);
    if (rqty > rmax || wqty > wmax) return violate(Violation::quantity_over_limit, fc);
    if (bc != wqty * 2 || pdu.size() != size_t(10 + bc)) return violate(Violation::wrong_byte_count, fc);
    if (auto v = check_addresses(Table::holding, rstart, rqty, true)) return violate(*v, fc);
    std::vector<uint16_t> values(wqty);
    for (uint16_t i = 0; i < wqty; ++i) values[i] = be16(pdu, 10 + 2 * i);
    auto r = write_holding(fc, wstart, values);  // MBAP §6.17: the write is performed before the read
    if (!r || !r->empty()) return r;
    return read_block(fc, rstart, rqty, Table::holding);
  }

  std::optional<Bytes> read_exception_status() {
    uint8_t status = 0;
    for (int i = 0; i < 8; ++i)
      if (d.coils_[uint16_t(i)]) status |= uint8_t(1 << i);
    return Bytes{7, status};
  }

  std::optional<Bytes> diagnostics(std::span<const uint8_t> pdu) {
    const uint8_t fc = 8;
    if (pdu.size() < 3) return violate(Violation::wrong_byte_count, fc);
    uint16_t sub = be16(pdu, 1);
    const spec::FunctionCode* f = d.spec_.profile.function(fc);
    if (f && !f->subfunctions.empty() && std::find(f->subfunctions.begin(), f->subfunctions.end(), sub) == f->subfunctions.end())
      return exception(fc, 1);
    Bytes echo(pdu.begin(), pdu.end());
    auto counter = [&](uint16_t v) {
      Bytes out{fc};
      put_be16(out, sub);
      put_be16(out, v);
      return out;
    };
    if (sub != 0 && pdu.size() != 5) return violate(Violation::wrong_byte_count, fc);
    uint16_t data = pdu.size() >= 5 ? be16(pdu, 3) : 0;
    auto& c = d.counters_;
    switch (sub) {
      case 0: return echo;  // Return Query Data
      case 1: {             // Restart Communications Option (MB-SL v1.02 §6.1.2)
        if (data != 0x0000 && data != 0xFF00) return exception(fc, 3);
        bool was_listen_only = d.listen_only_;
        d.listen_only_ = false;
        c = DiagnosticCounters{};
        if (was_listen_only) return std::nullopt;
        return echo;
      }
      case 2: return counter(0);  // diagnostic register
      case 3: return echo;        // Change ASCII Input Delimiter (RTU: no effect)
      case 4: d.listen_only_ = true; return std::nullopt;
      case 10: c = DiagnosticCounters{}; return echo;
      case 11: return counter(c.bus_messages);
      case 12: return counter(c.bus_comm_errors);
      case 13: return counter(c.exceptions);
      case 14: return counter(c.server_messages);
      case 15: return counter(c.no_responses);
      case 16: return counter(c.nak);
      case 17: return counter(c.busy);
      case 18: return counter(c.overruns);
      case 20: c.overruns = 0; return echo;
      default: return exception(fc, 1);
    }
  }

  std::vector<std::pair<uint8_t, std::string>> identification() const {
    const auto& idn = d.spec_.device.identification;
    return {{0, idn.vendor_name}, {1, idn.product_code}, {2, idn.revision}};
  }

  std::optional<Bytes> report_server_id() {
    const auto& idn = d.spec_.device.identification;
    const std::string& name = idn.additional_data;
    Bytes out{17, 0, uint8_t(idn.server_id.value_or(d.slave_id_)), uint8_t(idn.run_indicator)};
    out.insert(out.end(), name.begin(), name.end());
    out[1] = uint8_t(out.size() - 2);
    return out;
  }

  // MBAP v1.1b3 §6.21: Read Device Identification, basic objects only,
  // stream (01) and individual (04) access; conformity level 0x81.
  std::optional<Bytes> encapsulated(std::span<const uint8_t> pdu) {
    const uint8_t fc = 43;
    if (pdu.size() < 2) return violate(Violation::wrong_byte_count, fc);
    if (pdu[1] != 0x0E) return exception(fc, 1);
    if (pdu.size() != 4) return violate(Violation::wrong_byte_count, fc);
    uint8_t code = pdu[2], object = pdu[3];
    auto objects = identification();
    if (code < 1 || code > 4) return exception(fc, 3);
    Bytes out{fc, 0x0E, code, 0x81, 0x00, 0x00};
    if (code == 4) {
      if (object >= objects.size()) return exception(fc, 2);
      out.push_back(1);
      out.push_back(object);
      out.push_back(uint8_t(objects[object].second.size()));
      out.insert(out.end(), objects[object].second.begin(), objects[object].second.end());
      return out;
    }
    if (object >= objects.size()) object = 0;  // §6.21: an unknown start object restarts at 0
    out.push_back(uint8_t(objects.size() - object));
    for (size_t i = object; i < objects.size(); ++i) {
      out.push_back(objects[i].first);
      out.push_back(uint8_t(objects[i].second.size()));
      out.insert(out.end(), objects[i].second.begin(), objects[i].second.end());
    }
    return out;
  }

  std::optional<Bytes> dispatch(std::span<const uint8_t> pdu) {
    uint8_t fc = pdu[0];
    if (fc & 0x80 || !d.functions_[fc].supported) return violate(Violation::unsupported_function, fc & 0x7F);
    switch (fc) {
      case 1: return read_bits(fc, pdu, Table::coil);
      case 2: return read_bits(fc, pdu, Table::discrete_input);
      case 3: return read_words(fc, pdu, Table::holding);
      case 4: return read_words(fc, pdu, Table::input);
      case 5: return write_single_coil(pdu);
      case 6: return write_single(pdu);
      case 7: return read_exception_status();
      case 8: return diagnostics(pdu);
      case 15: return write_multiple_coils(pdu);
      case 16: return write_multiple(pdu);
      case 17: return report_server_id();
      case 22: return mask_write(pdu);
      case 23: return read_write_multiple(pdu);
      case 43: return encapsulated(pdu);
      default: return violate(Violation::unsupported_function, fc);  // in the spec but not implemented here
    }
  }
};

// ---- Device ----

Device::Device(spec::Spec s, uint8_t slave_id) : Device(s, slave_id, make_behaviour(s.device.id)) {}

Device::Device(spec::Spec s, uint8_t slave_id, std::unique_ptr<Behaviour> behaviour)
    : spec_(std::move(s)),
      holding_(65536),
      input_(65536),
      coils_(65536),
      discrete_(65536),
      slave_id_(slave_id),
      behaviour_(behaviour ? std::move(behaviour) : std::make_unique<Behaviour>()) {
  resolve_spec();
  power_cycle();
}

void Device::resolve_spec() {
  // The Modbus standard as the project states it (spec/devices/modbus-standard.yaml):
  // its quantity limits and its answer to each violation are what a device
  // falls back to where its manual is silent. Nothing of it is repeated here.
  const spec::Spec& standard = spec_.device.id == "modbus-standard" ? spec_ : standard_spec();
  for (Table t : {Table::holding, Table::input, Table::coil, Table::discrete_input}) {
    last_address_[int(t)] = spec_.last_address(t);
    auto& runs = runs_[int(t)];
    runs.clear();
    // registers are sorted by (table, address) and do not overlap (spec checks).
    for (const auto& r : spec_.registers) {
      if (r.table != t) continue;
      MappedRun run{r.address, uint16_t(std::min<uint32_t>(r.last_address(), 0xFFFF)), r.access != Access::wo,
                    r.access != Access::ro};
      if (!runs.empty() && uint32_t(runs.back().last) + 1 == run.first && runs.back().readable == run.readable &&
          runs.back().writable == run.writable)
        runs.back().last = run.last;
      else
        runs.push_back(run);
    }
  }
  // A quantity limit of the device's profile, capped by the standard's
  // (which the PDU size fixes: MBAP v1.1b3 §6).
  auto limit = [&](int fc, std::optional<int> spec::FunctionCode::*which) {
    const spec::FunctionCode* s = standard.profile.function(fc);
    int cap = s && s->*which ? *(s->*which) : int(kMaxPdu);
    const spec::FunctionCode* f = spec_.profile.function(fc);
    return f && f->*which ? std::min(*(f->*which), cap) : cap;
  };
  for (int fc = 0; fc < int(functions_.size()); ++fc)
    functions_[size_t(fc)] = {spec_.profile.function(fc) != nullptr, limit(fc, &spec::FunctionCode::max_quantity),
                              limit(fc, &spec::FunctionCode::max_read_quantity),
                              limit(fc, &spec::FunctionCode::max_write_quantity)};
  // quantity_zero is optional in the language: the over-limit policy covers it.
  auto policy = [](const spec::Spec& s, Violation v) {
    if (v == Violation::quantity_zero && !s.profile.exception_policy.count(v))
      return s.profile.policy(Violation::quantity_over_limit);
    return s.profile.policy(v);
  };
  static_assert(std::size(spec::kAllViolations) <= std::tuple_size_v<decltype(answers_)>);
  for (Violation v : spec::kAllViolations) {
    PolicyEntry p = policy(spec_, v);
    if (p.kind == PolicyEntry::Kind::unspecified) p = policy(standard, v);  // the manual is silent: the standard's answer
    answers_[size_t(v)] = p.kind == PolicyEntry::Kind::exception ? int16_t(uint8_t(p.code)) : int16_t(-1);
  }
}

Device::~Device() = default;
Device::Device(Device&&) noexcept = default;
Device& Device::operator=(Device&&) noexcept = default;

std::optional<Bytes> Device::handle_rtu(std::span<const uint8_t> adu) {
  if (adu.size() < 4 || adu.size() > kMaxRtuAdu) return std::nullopt;  // not a frame: nobody answers
  uint8_t address = adu[0];
  bool broadcast = spec_.serial.broadcast_address && address == *spec_.serial.broadcast_address;
  if (!crc_ok(adu)) {
    ++counters_.bus_comm_errors;
    if (address != slave_id_) return std::nullopt;
    Engine e{*this};
    auto pdu = e.violate(Violation::crc_error, adu[1] & 0x7F);
    if (!pdu) return std::nullopt;
    return rtu_frame(address, *pdu);
  }
  if (!broadcast && address != slave_id_) return std::nullopt;
  ++counters_.bus_messages;
  auto pdu = handle_pdu(adu.subspan(1, adu.size() - 3), broadcast);
  if (!pdu || broadcast) return std::nullopt;
  return rtu_frame(address, *pdu);
}

std::optional<Bytes> Device::handle_pdu(std::span<const uint8_t> pdu, bool broadcast) {
  if (pdu.empty() || pdu.size() > kMaxPdu) return std::nullopt;
  ++counters_.server_messages;
  // MB-SL v1.02 §6.1.2: in Listen Only Mode only Restart Communications is acted on.
  if (listen_only_ && !(pdu.size() >= 3 && pdu[0] == 8 && be16(pdu, 1) == 1)) {
    ++counters_.no_responses;
    return std::nullopt;
  }
  if (broadcast && spec_.serial.broadcast_writes == "ignored") return std::nullopt;
  // MB-SL v1.02 §2.1: broadcast requests are writes; reads make no sense and are not executed.
  if (broadcast && pdu[0] <= 4) return std::nullopt;
  Engine e{*this};
  auto reply = e.dispatch(pdu);
  if (broadcast) {
    ++counters_.no_responses;
    return std::nullopt;
  }
  return reply;
}

uint16_t Device::word(uint16_t a) const { return holding_[a]; }
void Device::set_word(uint16_t a, uint16_t v) {
  touched_[int(Table::holding)].mark(a);
  holding_[a] = v;
}
uint16_t Device::input_word(uint16_t a) const { return input_[a]; }
void Device::set_input_word(uint16_t a, uint16_t v) {
  touched_[int(Table::input)].mark(a);
  input_[a] = v;
}
bool Device::coil(uint16_t a) const { return coils_[a]; }
void Device::set_coil(uint16_t a, bool on) {
  touched_[int(Table::coil)].mark(a);
  coils_[a] = on;
}
bool Device::discrete_input(uint16_t a) const { return discrete_[a]; }
void Device::set_discrete_input(uint16_t a, bool on) {
  touched_[int(Table::discrete_input)].mark(a);
  discrete_[a] = on;
}

namespace {
std::vector<uint16_t>& words_of(const Register& r, std::vector<uint16_t>& holding, std::vector<uint16_t>& input) {
  return r.table == Table::input ? input : holding;
}
}  // namespace

int64_t Device::value(const Register& r) const {
  if (r.table == Table::coil) return coils_[r.address];
  if (r.table == Table::discrete_input) return discrete_[r.address];
  const auto& w = r.table == Table::input ? input_ : holding_;
  if (r.words == 1) {
    uint16_t v = w[r.address];
    return r.type == DataType::s16 ? int64_t(int16_t(v)) : int64_t(v);
  }
  uint32_t v = join_u32(w[r.address], w[uint16_t(r.address + 1)], r.low_word_first());
  return r.type == DataType::s32 ? int64_t(int32_t(v)) : int64_t(v);
}

void Device::set_value(const Register& r, int64_t v) {
  auto& touched = touched_[int(r.table)];
  touched.mark(r.address);
  if (r.words == 2) touched.mark(uint16_t(r.address + 1));
  if (r.table == Table::coil) {
    coils_[r.address] = v != 0;
    return;
  }
  if (r.table == Table::discrete_input) {
    discrete_[r.address] = v != 0;
    return;
  }
  auto& w = words_of(r, holding_, input_);
  if (r.words == 1) {
    w[r.address] = uint16_t(v);
    return;
  }
  auto split = split_u32(uint32_t(v), r.low_word_first());
  w[r.address] = split[0];
  w[uint16_t(r.address + 1)] = split[1];
}

double Device::float_value(const Register& r) const {
  if (r.type != DataType::f32) return double(value(r));
  return double(std::bit_cast<float>(uint32_t(value(r))));
}

const Register* Device::reg(uint16_t address, Table table) const { return spec_.register_covering(address, table); }

int64_t Device::value_at(uint16_t address) const {
  const Register* r = reg(address);
  if (!r) throw std::out_of_range("register " + std::to_string(address) + " is not in spec " + spec_.device.id);
  return value(*r);
}

void Device::set_value_at(uint16_t address, int64_t v) {
  const Register* r = reg(address);
  if (!r) throw std::out_of_range("register " + std::to_string(address) + " is not in spec " + spec_.device.id);
  set_value(*r, v);
}

const Register* Device::find_by_key(const std::string& key) const { return spec_.find_by_key(key); }

const Register& Device::reg_by_key(const std::string& key) const {
  const Register* r = spec_.find_by_key(key);
  if (!r) throw std::out_of_range("spec " + spec_.device.id + " has no register with key '" + key + "'");
  return *r;
}

std::map<uint16_t, uint16_t> Device::holding_image() const {
  std::map<uint16_t, uint16_t> m;
  for (const auto& r : spec_.registers)
    if (r.table == Table::holding)
      for (int i = 0; i < r.words; ++i) m[uint16_t(r.address + i)] = holding_[uint16_t(r.address + i)];
  return m;
}

void Device::advance(uint64_t dt_us) {
  now_us_ += dt_us;
  behaviour_->advance(*this, dt_us);
}

namespace {
int64_t default_raw(const Register& r) {
  // No printed default: power up at 0, unless the register's range excludes 0;
  // then at the range's minimum (a device never holds a value it would refuse
  // as a write, so a master can always write back what it read).
  std::optional<double> v = r.default_value;
  if (!v && r.range && (r.range->min > 0 || r.range->max < 0)) v = r.range->min;
  if (!v) return 0;
  if (r.type == DataType::f32) return int64_t(std::bit_cast<uint32_t>(float(*v)));
  return int64_t(*v);
}
}  // namespace

void Device::power_cycle() {
  auto clear = [&](auto& table, Table t) {
    Touched& w = touched_[int(t)];
    if (w.lo < w.hi) std::fill(table.begin() + w.lo, table.begin() + w.hi, 0);
    w = Touched{};
  };
  clear(holding_, Table::holding);
  clear(input_, Table::input);
  clear(coils_, Table::coil);
  clear(discrete_, Table::discrete_input);
  for (const auto& r : spec_.registers) set_value(r, default_raw(r));
  // Persistent registers come back from the stored image.
  for (const auto& r : spec_.registers) {
    if (r.persistence.store == spec::Store::none || r.table != Table::holding) continue;
    for (int i = 0; i < r.words; ++i) {
      auto it = stored_.find(uint16_t(r.address + i));
      if (it != stored_.end()) set_word(uint16_t(r.address + i), it->second);
    }
  }
  listen_only_ = false;
  counters_ = DiagnosticCounters{};
  AxisInputs inputs = axis_.inputs;  // the switches stay where the machine has them
  axis_ = Axis{};
  axis_.inputs = inputs;
  behaviour_->power_on(*this);
}

void Device::factory_reset() {
  for (const auto& r : spec_.registers) set_value(r, default_raw(r));
  stored_.clear();
  for (const auto& r : spec_.registers)
    if (r.persistence.store != spec::Store::none && r.table == Table::holding)
      for (int i = 0; i < r.words; ++i) {
        stored_[uint16_t(r.address + i)] = holding_[uint16_t(r.address + i)];
        ++eeprom_writes_;
      }
}

void Device::save_persistent() {
  for (const auto& r : spec_.registers)
    if (r.persistence.store != spec::Store::none && r.table == Table::holding)
      for (int i = 0; i < r.words; ++i) {
        stored_[uint16_t(r.address + i)] = holding_[uint16_t(r.address + i)];
        ++eeprom_writes_;
      }
}

void Device::load_stored_image(std::map<uint16_t, uint16_t> image) { stored_ = std::move(image); }

// ---- Bus ----

Device* Bus::find(uint8_t id) {
  for (auto& d : devices_)
    if (d->slave_id() == id) return d.get();
  return nullptr;
}

std::optional<Bytes> Bus::handle_rtu(std::span<const uint8_t> adu) {
  if (adu.size() < 4 || adu.size() > kMaxRtuAdu) return std::nullopt;
  // A broadcast (each device's spec names its address, MB-SL v1.02 §2.1):
  // every device it addresses acts, none answers.
  bool broadcast = false;
  for (auto& d : devices_)
    if (d->spec().serial.broadcast_address == adu[0]) {
      d->handle_rtu(adu);
      broadcast = true;
    }
  if (broadcast) return std::nullopt;
  Device* d = find(adu[0]);
  return d ? d->handle_rtu(adu) : std::nullopt;
}

Device* Bus::direct(uint8_t unit) {
  return (unit == 0 || unit == 0xFF) && devices_.size() == 1 ? devices_.front().get() : nullptr;
}

std::optional<Bytes> Bus::handle_pdu(uint8_t unit, std::span<const uint8_t> pdu) {
  if (Device* d = direct(unit)) return d->handle_pdu(pdu, false);
  bool broadcast = false;
  for (auto& d : devices_)
    if (d->spec().serial.broadcast_address == unit) {
      d->handle_pdu(pdu, true);
      broadcast = true;
    }
  if (broadcast) return std::nullopt;
  Device* d = find(unit);
  return d ? d->handle_pdu(pdu, false) : std::nullopt;
}

void Bus::advance(uint64_t dt_us) {
  for (auto& d : devices_) d->advance(dt_us);
}

}  // namespace mbc::ref
