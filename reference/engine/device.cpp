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

bool is_bit_table(Table t) { return t == Table::coil || t == Table::discrete_input; }

// How many cells of its table r takes: a bit is one, a value 1 or 2 words.
int cells(const Register& r) { return is_bit_table(r.table) ? 1 : r.words; }

// The cells `v` is stored as in r's table: a bit 0 or 1; a 2-word value in
// r's word order.
std::array<uint16_t, 2> raw_cells(const Register& r, int64_t v) {
  if (is_bit_table(r.table)) return {uint16_t(v != 0), 0};
  if (r.words == 1) return {uint16_t(v), 0};
  return split_u32(uint32_t(v), r.low_word_first());
}

}  // namespace

// The protocol engine: one PDU in, the reply PDU written into the caller's
// storage `out` (Device::max_reply_pdu() bytes). Every handler returns the
// reply's length, kSilence (0) when the device stays silent: a reply PDU is
// never empty. Kept as a friend struct so Device's public surface stays data-like.
struct Engine {
  Device& d;
  uint8_t* out;

  static constexpr size_t kSilence = 0;
  // A request's byte count field is one byte: it carries at most 127 words
  // (FC 16, FC 23), so a stack array of this size holds any write.
  static constexpr size_t kMaxWriteWords = 0xFF / 2;

  size_t exception(uint8_t fc, uint8_t code) {
    ++d.counters_.exceptions;
    out[0] = uint8_t(fc | 0x80);
    out[1] = code;
    return 2;
  }

  // The answer resolve_spec() found for `v` (the device's policy, else the standard's).
  size_t violate(Violation v, uint8_t fc) {
    int16_t code = d.answers_[size_t(v)];
    if (code < 0) {
      ++d.counters_.no_responses;
      return kSilence;
    }
    return exception(fc, uint8_t(code));
  }

  size_t echo(std::span<const uint8_t> pdu) {
    std::memcpy(out, pdu.data(), pdu.size());
    return pdu.size();
  }

  // fc, a big-endian start and quantity: the reply of FC 15 and FC 16.
  size_t start_and_quantity(uint8_t fc, uint16_t start, uint16_t qty) {
    out[0] = fc;
    set_be16(std::span(out, 5), 1, start);
    set_be16(std::span(out, 5), 3, qty);
    return 5;
  }

  int max_quantity(uint8_t fc) const { return d.functions_[fc & 0x7F].max_quantity; }

  // Address check of [start, start+qty) in `table`, run by run of registers
  // with the same access; false with the violation of the first address that
  // fails. The page index (resolve_spec) starts the walk at the first run
  // that can hold `start`, so no request searches the whole map. (Not an
  // optional<Violation>: GCC returns that through the stack, a store-forwarding
  // stall that cost a third of an FC 03 request.)
  bool addresses_ok(Table table, uint32_t start, uint32_t qty, bool reading, Violation& failed) {
    const int32_t last = d.last_address_[int(table)];
    const Device::MappedRun* run = d.runs_[int(table)].data() + d.page_runs_[int(table)][start >> 8];
    auto fail = [&](Violation v) {
      failed = v;
      return false;
    };
    for (uint32_t a = start; a < start + qty; ++run) {
      // last <= 0xFFFF, so this also stops addresses past the 16-bit space.
      if (int64_t(a) > last) return fail(Violation::address_past_map);
      // Some run ends at `last` >= a: the walk stays inside the runs.
      while (run->last < a) ++run;
      if (run->first > a) return fail(Violation::unmapped_address);
      if (reading && !run->readable) return fail(Violation::read_write_only);
      if (!reading && !run->writable) return fail(Violation::write_read_only);
      a = uint32_t(run->last) + 1;
    }
    return true;
  }

  // Would the holding registers touched by writing `values` at `start` stay
  // in range? Checks each affected register's whole value (a 2-word value
  // written one word at a time is checked with its other word as stored).
  bool values_in_range(uint16_t start, std::span<const uint16_t> values) {
    std::array<uint16_t, kMaxWriteWords> saved;
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

  // Checks and stores a write of holding registers: nullopt when stored (the
  // caller builds its reply), else the refusal's reply (an exception or silence).
  std::optional<size_t> write_holding(uint8_t fc, uint16_t start, std::span<const uint16_t> values) {
    if (Violation v; !addresses_ok(Table::holding, start, uint32_t(values.size()), false, v)) return violate(v, fc);
    if (!values_in_range(start, values)) return violate(Violation::value_out_of_range, fc);
    if (auto code = d.behaviour_->check_write(d, start, values)) return exception(fc, *code);
    store(start, values);
    return std::nullopt;
  }

  size_t read_words(uint8_t fc, std::span<const uint8_t> pdu, Table table) {
    if (pdu.size() != 5) return violate(Violation::wrong_byte_count, fc);
    uint16_t start = be16(pdu, 1), qty = be16(pdu, 3);
    if (qty == 0) return violate(Violation::quantity_zero, fc);
    if (qty > max_quantity(fc)) return violate(Violation::quantity_over_limit, fc);
    if (Violation v; !addresses_ok(table, start, qty, true, v)) return violate(v, fc);
    return read_block(fc, start, qty, table);
  }

  size_t read_block(uint8_t fc, uint16_t start, uint16_t qty, Table table) {
    d.behaviour_->before_read(d, start, qty);
    out[0] = fc;
    out[1] = uint8_t(qty * 2);
    const uint16_t* words = (table == Table::input ? d.input_ : d.holding_).data();
    uint8_t* o = out + 2;
    for (uint32_t a = start; a < uint32_t(start) + qty; ++a, o += 2) {
      uint16_t w = words[uint16_t(a)];
      o[0] = uint8_t(w >> 8);
      o[1] = uint8_t(w);
    }
    return 2 + 2 * size_t(qty);
  }

  size_t read_bits(uint8_t fc, std::span<const uint8_t> pdu, Table table) {
    if (pdu.size() != 5) return violate(Violation::wrong_byte_count, fc);
    uint16_t start = be16(pdu, 1), qty = be16(pdu, 3);
    if (qty == 0) return violate(Violation::quantity_zero, fc);
    if (qty > max_quantity(fc)) return violate(Violation::quantity_over_limit, fc);
    if (Violation v; !addresses_ok(table, start, qty, true, v)) return violate(v, fc);
    const auto& bits = table == Table::coil ? d.coils_ : d.discrete_;
    size_t bytes = (qty + 7) / 8;
    out[0] = fc;
    out[1] = uint8_t(bytes);
    std::memset(out + 2, 0, bytes);
    for (uint16_t i = 0; i < qty; ++i)
      if (bits[uint16_t(start + i)]) out[2 + i / 8] |= uint8_t(1 << (i % 8));
    return 2 + bytes;
  }

  size_t write_single_coil(std::span<const uint8_t> pdu) {
    const uint8_t fc = 5;
    if (pdu.size() != 5) return violate(Violation::wrong_byte_count, fc);
    uint16_t addr = be16(pdu, 1), value = be16(pdu, 3);
    // MBAP v1.1b3 §6.5: any value but 0x0000 / 0xFF00 is an ILLEGAL DATA VALUE.
    if (value != 0x0000 && value != 0xFF00) return exception(fc, 3);
    if (Violation v; !addresses_ok(Table::coil, addr, 1, false, v)) return violate(v, fc);
    d.touched_[int(Table::coil)].mark(addr);
    d.coils_[addr] = value == 0xFF00;
    return echo(pdu);
  }

  size_t write_multiple_coils(std::span<const uint8_t> pdu) {
    const uint8_t fc = 15;
    if (pdu.size() < 6) return violate(Violation::wrong_byte_count, fc);
    uint16_t start = be16(pdu, 1), qty = be16(pdu, 3);
    uint8_t bc = pdu[5];
    if (qty == 0) return violate(Violation::quantity_zero, fc);
    if (qty > max_quantity(fc)) return violate(Violation::quantity_over_limit, fc);
    if (bc != (qty + 7) / 8 || pdu.size() != size_t(6 + bc)) return violate(Violation::wrong_byte_count, fc);
    if (Violation v; !addresses_ok(Table::coil, start, qty, false, v)) return violate(v, fc);
    d.touched_[int(Table::coil)].mark(start, qty);
    for (uint16_t i = 0; i < qty; ++i) d.coils_[uint16_t(start + i)] = (pdu[6 + i / 8] >> (i % 8)) & 1;
    return start_and_quantity(fc, start, qty);
  }

  size_t write_single(std::span<const uint8_t> pdu) {
    const uint8_t fc = 6;
    if (pdu.size() != 5) return violate(Violation::wrong_byte_count, fc);
    uint16_t addr = be16(pdu, 1), value = be16(pdu, 3);
    if (auto refused = write_holding(fc, addr, std::span<const uint16_t>(&value, 1))) return *refused;
    return echo(pdu);
  }

  size_t write_multiple(std::span<const uint8_t> pdu) {
    const uint8_t fc = 16;
    if (pdu.size() < 6) return violate(Violation::wrong_byte_count, fc);
    uint16_t start = be16(pdu, 1), qty = be16(pdu, 3);
    uint8_t bc = pdu[5];
    if (qty == 0) return violate(Violation::quantity_zero, fc);
    if (qty > max_quantity(fc)) return violate(Violation::quantity_over_limit, fc);
    if (bc != qty * 2 || pdu.size() != size_t(6 + bc)) return violate(Violation::wrong_byte_count, fc);
    std::array<uint16_t, kMaxWriteWords> values;  // qty == bc / 2
    for (uint16_t i = 0; i < qty; ++i) values[i] = be16(pdu, 6 + 2 * i);
    if (auto refused = write_holding(fc, start, std::span(values.data(), qty))) return *refused;
    return start_and_quantity(fc, start, qty);
  }

  size_t mask_write(std::span<const uint8_t> pdu) {
    const uint8_t fc = 22;
    if (pdu.size() != 7) return violate(Violation::wrong_byte_count, fc);
    uint16_t addr = be16(pdu, 1), and_mask = be16(pdu, 3), or_mask = be16(pdu, 5);
    if (Violation v; !addresses_ok(Table::holding, addr, 1, false, v)) return violate(v, fc);
    // MBAP v1.1b3 §6.16: Result = (Current AND And_Mask) OR (Or_Mask AND (NOT And_Mask))
    uint16_t value = uint16_t((d.holding_[addr] & and_mask) | (or_mask & ~and_mask));
    if (auto refused = write_holding(fc, addr, std::span<const uint16_t>(&value, 1))) return *refused;
    return echo(pdu);
  }

  size_t read_write_multiple(std::span<const uint8_t> pdu) {
    const uint8_t fc = 23;
    if (pdu.size() < 10) return violate(Violation::wrong_byte_count, fc);
    uint16_t rstart = be16(pdu, 1), rqty = be16(pdu, 3), wstart = be16(pdu, 5), wqty = be16(pdu, 7);
    uint8_t bc = pdu[9];
    int rmax = d.functions_[fc].max_read, wmax = d.functions_[fc].max_write;
    if (rqty == 0 || wqty == 0) return violate(Violation::quantity_zero, fc);
    if (rqty > rmax || wqty > wmax) return violate(Violation::quantity_over_limit, fc);
    if (bc != wqty * 2 || pdu.size() != size_t(10 + bc)) return violate(Violation::wrong_byte_count, fc);
    if (Violation v; !addresses_ok(Table::holding, rstart, rqty, true, v)) return violate(v, fc);
    std::array<uint16_t, kMaxWriteWords> values;  // wqty == bc / 2
    for (uint16_t i = 0; i < wqty; ++i) values[i] = be16(pdu, 10 + 2 * i);
    // MBAP §6.17: the write is performed before the read
    if (auto refused = write_holding(fc, wstart, std::span(values.data(), wqty))) return *refused;
    return read_block(fc, rstart, rqty, Table::holding);
  }

  size_t read_exception_status() {
    uint8_t status = 0;
    for (int i = 0; i < 8; ++i)
      if (d.coils_[uint16_t(i)]) status |= uint8_t(1 << i);
    out[0] = 7;
    out[1] = status;
    return 2;
  }

  size_t diagnostics(std::span<const uint8_t> pdu) {
    const uint8_t fc = 8;
    if (pdu.size() < 3) return violate(Violation::wrong_byte_count, fc);
    uint16_t sub = be16(pdu, 1);
    const spec::FunctionCode* f = d.spec_.profile.function(fc);
    if (f && !f->subfunctions.empty() && std::find(f->subfunctions.begin(), f->subfunctions.end(), sub) == f->subfunctions.end())
      return exception(fc, 1);
    auto counter = [&](uint16_t v) {
      out[0] = fc;
      set_be16(std::span(out, 5), 1, sub);
      set_be16(std::span(out, 5), 3, v);
      return size_t(5);
    };
    if (sub != 0 && pdu.size() != 5) return violate(Violation::wrong_byte_count, fc);
    uint16_t data = pdu.size() >= 5 ? be16(pdu, 3) : 0;
    auto& c = d.counters_;
    switch (sub) {
      case 0: return echo(pdu);  // Return Query Data
      case 1: {                  // Restart Communications Option (MB-SL v1.02 §6.1.2)
        if (data != 0x0000 && data != 0xFF00) return exception(fc, 3);
        bool was_listen_only = d.listen_only_;
        d.listen_only_ = false;
        c = DiagnosticCounters{};
        if (was_listen_only) return kSilence;
        return echo(pdu);
      }
      case 2: return counter(0);  // diagnostic register
      case 3: return echo(pdu);   // Change ASCII Input Delimiter (RTU: no effect)
      case 4: d.listen_only_ = true; return kSilence;
      case 10: c = DiagnosticCounters{}; return echo(pdu);
      case 11: return counter(c.bus_messages);
      case 12: return counter(c.bus_comm_errors);
      case 13: return counter(c.exceptions);
      case 14: return counter(c.server_messages);
      case 15: return counter(c.no_responses);
      case 16: return counter(c.nak);
      case 17: return counter(c.busy);
      case 18: return counter(c.overruns);
      case 20: c.overruns = 0; return echo(pdu);
      default: return exception(fc, 1);
    }
  }

  // The basic identification objects (MBAP v1.1b3 §6.21, object ids 0..2).
  std::array<const std::string*, 3> identification() const {
    const auto& idn = d.spec_.device.identification;
    return {&idn.vendor_name, &idn.product_code, &idn.revision};
  }

  size_t report_server_id() {
    const auto& idn = d.spec_.device.identification;
    const std::string& name = idn.additional_data;
    out[0] = 17;
    out[1] = uint8_t(2 + name.size());
    out[2] = uint8_t(idn.server_id.value_or(d.slave_id_));
    out[3] = uint8_t(idn.run_indicator);
    std::memcpy(out + 4, name.data(), name.size());
    return 4 + name.size();
  }

  // MBAP v1.1b3 §6.21: Read Device Identification, basic objects only,
  // stream (01) and individual (04) access; conformity level 0x81.
  size_t encapsulated(std::span<const uint8_t> pdu) {
    const uint8_t fc = 43;
    if (pdu.size() < 2) return violate(Violation::wrong_byte_count, fc);
    if (pdu[1] != 0x0E) return exception(fc, 1);
    if (pdu.size() != 4) return violate(Violation::wrong_byte_count, fc);
    uint8_t code = pdu[2], object = pdu[3];
    auto objects = identification();
    if (code < 1 || code > 4) return exception(fc, 3);
    const uint8_t head[] = {fc, 0x0E, code, 0x81, 0x00, 0x00};
    std::memcpy(out, head, sizeof head);
    size_t n = sizeof head;
    auto put_object = [&](uint8_t id) {
      const std::string& value = *objects[id];
      out[n++] = id;
      out[n++] = uint8_t(value.size());
      std::memcpy(out + n, value.data(), value.size());
      n += value.size();
    };
    if (code == 4) {
      if (object >= objects.size()) return exception(fc, 2);
      out[n++] = 1;
      put_object(object);
      return n;
    }
    if (object >= objects.size()) object = 0;  // §6.21: an unknown start object restarts at 0
    out[n++] = uint8_t(objects.size() - object);
    for (size_t i = object; i < objects.size(); ++i) put_object(uint8_t(i));
    return n;
  }

  size_t dispatch(std::span<const uint8_t> pdu) {
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

Device::Device(spec::Spec s, uint8_t slave_id) : Device(s, slave_id, make_behaviour(s)) {}

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
    auto last = spec_.last_address(t);
    last_address_[int(t)] = last ? int32_t(*last) : -1;
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
    // What a power cycle writes: every register's default, as stored.
    auto& image = power_on_[int(t)];
    auto& span = power_on_span_[int(t)];
    image.clear();
    span = Touched{};
    for (const auto& r : spec_.registers) {
      if (r.table != t) continue;
      span.mark(r.address);
      if (r.words == 2) span.mark(uint16_t(r.address + 1));
      auto raw = raw_cells(r, default_raw(r));
      for (int i = 0; i < cells(r); ++i) image.push_back({uint16_t(r.address + i), raw[size_t(i)]});
    }
    auto& pages = page_runs_[int(t)];
    for (uint32_t page = 0, i = 0; page < pages.size(); ++page) {
      while (i < runs.size() && runs[i].last < page << 8) ++i;
      pages[page] = i;
    }
  }
  persistent_words_.clear();
  for (const auto& r : spec_.registers)
    if (r.persistence.store != spec::Store::none && r.table == Table::holding)
      for (int i = 0; i < r.words; ++i) persistent_words_.push_back(uint16_t(r.address + i));
  // Behaviours name registers by key on every hook (reg_by_key, value_of):
  // a hash lookup, not a scan of the register list. The first register with
  // a key wins, as in Spec::find_by_key.
  by_key_.clear();
  for (const auto& r : spec_.registers)
    if (!r.key.empty()) by_key_.emplace(r.key, &r);
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
  // The longest reply: kMaxPdu bounds every request and so every echo; the
  // reads are bounded by the limits above; FC 17 and FC 43 carry the spec's
  // identification strings, whatever their length.
  max_reply_pdu_ = kMaxPdu;
  auto reply_at_most = [&](size_t n) { max_reply_pdu_ = std::max(max_reply_pdu_, n); };
  for (int fc : {1, 2}) reply_at_most(2 + (size_t(functions_[size_t(fc)].max_quantity) + 7) / 8);
  for (int fc : {3, 4}) reply_at_most(2 + 2 * size_t(functions_[size_t(fc)].max_quantity));
  reply_at_most(2 + 2 * size_t(functions_[23].max_read));
  const auto& idn = spec_.device.identification;
  reply_at_most(4 + idn.additional_data.size());
  reply_at_most(7 + 3 * 2 + idn.vendor_name.size() + idn.product_code.size() + idn.revision.size());
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

size_t Device::handle_rtu_into(std::span<const uint8_t> adu, std::span<uint8_t> reply) {
  if (reply.size() < kRtuAddress + max_reply_pdu_ + kRtuCrc)
    throw std::length_error("Device::handle_rtu_into: the reply buffer is shorter than max_reply_pdu() + 3");
  if (adu.size() < 4 || adu.size() > kMaxRtuAdu) return 0;  // not a frame: nobody answers
  uint8_t address = adu[0];
  bool broadcast = spec_.serial.broadcast_address && address == *spec_.serial.broadcast_address;
  uint8_t* pdu_out = reply.data() + kRtuAddress;
  size_t n = 0;
  if (!crc_ok(adu)) {
    ++counters_.bus_comm_errors;
    if (address != slave_id_) return 0;
    n = Engine{*this, pdu_out}.violate(Violation::crc_error, adu[1] & 0x7F);
  } else {
    if (!broadcast && address != slave_id_) return 0;
    n = reply_pdu(kRtu.pdu_bytes(adu), pdu_out, broadcast);
    if (broadcast) return 0;
  }
  if (n == 0) return 0;
  // MB-SL v1.02 §2.5.1.2: slave, PDU, CRC low byte first.
  reply[0] = address;
  uint16_t crc = crc16(reply.first(kRtuAddress + n));
  reply[kRtuAddress + n] = uint8_t(crc & 0xFF);
  reply[kRtuAddress + n + 1] = uint8_t(crc >> 8);
  return kRtuAddress + n + kRtuCrc;
}

size_t Device::handle_pdu_into(std::span<const uint8_t> pdu, std::span<uint8_t> reply, bool broadcast) {
  if (reply.size() < max_reply_pdu_)
    throw std::length_error("Device::handle_pdu_into: the reply buffer is shorter than max_reply_pdu()");
  return reply_pdu(pdu, reply.data(), broadcast);
}

size_t Device::reply_pdu(std::span<const uint8_t> pdu, uint8_t* out, bool broadcast) {
  if (pdu.empty() || pdu.size() > kMaxPdu) return 0;
  // MB-SL v1.02 §6.1.2: every message addressed to this device counts, on
  // every transport (RTU frames, MBAP PDUs, TLS): the bus message count and
  // the server message count alike.
  ++counters_.bus_messages;
  ++counters_.server_messages;
  // MB-SL v1.02 §6.1.2: in Listen Only Mode only Restart Communications is acted on.
  if (listen_only_ && !(pdu.size() >= 3 && pdu[0] == 8 && be16(pdu, 1) == 1)) {
    ++counters_.no_responses;
    return 0;
  }
  if (broadcast && spec_.serial.broadcast_writes == "ignored") return 0;
  // MB-SL v1.02 §2.1: broadcast requests are writes; reads make no sense and are not executed.
  if (broadcast && pdu[0] <= 4) return 0;
  size_t n = Engine{*this, out}.dispatch(pdu);
  if (broadcast) {
    ++counters_.no_responses;
    return 0;
  }
  return n;
}

// The Bytes API over the one above: the reply is built on the stack (or, for
// a spec whose identification outgrows a PDU, on the heap) and copied out once.
namespace {
template <size_t Extra, class Handle>
std::optional<Bytes> reply_bytes(size_t max_reply_pdu, Handle&& handle) {
  std::array<uint8_t, kMaxPdu + Extra> stack;
  Bytes heap;
  std::span<uint8_t> buf(stack);
  if (max_reply_pdu > kMaxPdu) {
    heap.resize(max_reply_pdu + Extra);
    buf = heap;
  }
  size_t n = handle(buf);
  if (n == 0) return std::nullopt;
  return Bytes(buf.begin(), buf.begin() + ptrdiff_t(n));
}
}  // namespace

std::optional<Bytes> Device::handle_rtu(std::span<const uint8_t> adu) {
  return reply_bytes<kRtuAddress + kRtuCrc>(max_reply_pdu_, [&](std::span<uint8_t> buf) { return handle_rtu_into(adu, buf); });
}

std::optional<Bytes> Device::handle_pdu(std::span<const uint8_t> pdu, bool broadcast) {
  return reply_bytes<0>(max_reply_pdu_, [&](std::span<uint8_t> buf) { return reply_pdu(pdu, buf.data(), broadcast); });
}

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

void Device::put_cell(Table t, uint16_t a, uint16_t v) {
  switch (t) {
    case Table::holding: holding_[a] = v; break;
    case Table::input: input_[a] = v; break;
    case Table::coil: coils_[a] = uint8_t(v); break;
    case Table::discrete_input: discrete_[a] = uint8_t(v); break;
  }
}

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
  auto raw = raw_cells(r, v);
  for (int i = 0; i < cells(r); ++i) put_cell(r.table, uint16_t(r.address + i), raw[size_t(i)]);
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

const Register* Device::find_by_key(std::string_view key) const {
  auto it = by_key_.find(key);
  return it == by_key_.end() ? nullptr : it->second;
}

const Register& Device::reg_by_key(std::string_view key) const {
  const Register* r = find_by_key(key);
  if (!r) throw std::out_of_range("spec " + spec_.device.id + " has no register with key '" + std::string(key) + "'");
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

void Device::write_power_on_image() {
  for (size_t t = 0; t < power_on_.size(); ++t) {
    const Touched& span = power_on_span_[t];
    if (span.lo < span.hi) touched_[t].mark(span.lo, span.hi - span.lo);
    for (const auto& [address, value] : power_on_[t]) put_cell(Table(t), address, value);
  }
}

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
  write_power_on_image();
  // Persistent registers come back from the stored image (both sorted by address).
  auto stored = stored_.begin();
  for (uint16_t a : persistent_words_) {
    while (stored != stored_.end() && stored->first < a) ++stored;
    if (stored != stored_.end() && stored->first == a) set_word(a, stored->second);
  }
  listen_only_ = false;
  counters_ = DiagnosticCounters{};
  AxisInputs inputs = axis_.inputs;  // the switches stay where the machine has them
  axis_ = Axis{};
  axis_.inputs = inputs;
  behaviour_->power_on(*this);
}

bool Device::trip_fault() { return behaviour_->trip_fault(*this); }

void Device::factory_reset() {
  write_power_on_image();
  stored_.clear();
  save_persistent();
}

void Device::save_persistent() {
  for (uint16_t a : persistent_words_) {
    stored_[a] = holding_[a];
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

size_t Bus::max_reply_pdu() const {
  size_t n = kMaxPdu;
  for (const auto& d : devices_) n = std::max(n, d->max_reply_pdu());
  return n;
}

size_t Bus::handle_rtu_into(std::span<const uint8_t> adu, std::span<uint8_t> reply) {
  if (reply.size() < kRtuAddress + max_reply_pdu() + kRtuCrc)
    throw std::length_error("Bus::handle_rtu_into: the reply buffer is shorter than max_reply_pdu() + 3");
  if (adu.size() < 4 || adu.size() > kMaxRtuAdu) return 0;
  // A broadcast (each device's spec names its address, MB-SL v1.02 §2.1):
  // every device it addresses acts, none answers.
  bool broadcast = false;
  for (auto& d : devices_)
    if (d->spec().serial.broadcast_address == adu[0]) {
      d->handle_rtu_into(adu, reply);
      broadcast = true;
    }
  if (broadcast) return 0;
  Device* d = find(adu[0]);
  return d ? d->handle_rtu_into(adu, reply) : 0;
}

Device* Bus::direct(uint8_t unit) {
  return (unit == 0 || unit == 0xFF) && devices_.size() == 1 ? devices_.front().get() : nullptr;
}

size_t Bus::handle_pdu_into(uint8_t unit, std::span<const uint8_t> pdu, std::span<uint8_t> reply) {
  if (reply.size() < max_reply_pdu())
    throw std::length_error("Bus::handle_pdu_into: the reply buffer is shorter than max_reply_pdu()");
  if (Device* d = direct(unit)) return d->handle_pdu_into(pdu, reply, false);
  bool broadcast = false;
  for (auto& d : devices_)
    if (d->spec().serial.broadcast_address == unit) {
      d->handle_pdu_into(pdu, reply, true);
      broadcast = true;
    }
  if (broadcast) return 0;
  Device* d = find(unit);
  return d ? d->handle_pdu_into(pdu, reply, false) : 0;
}

std::optional<Bytes> Bus::handle_rtu(std::span<const uint8_t> adu) {
  return reply_bytes<kRtuAddress + kRtuCrc>(max_reply_pdu(), [&](std::span<uint8_t> buf) { return handle_rtu_into(adu, buf); });
}

std::optional<Bytes> Bus::handle_pdu(uint8_t unit, std::span<const uint8_t> pdu) {
  return reply_bytes<0>(max_reply_pdu(), [&](std::span<uint8_t> buf) { return handle_pdu_into(unit, pdu, buf); });
}

void Bus::advance(uint64_t dt_us) {
  for (auto& d : devices_) d->advance(dt_us);
}

}  // namespace mbc::ref
