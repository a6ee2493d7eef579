// Family "registers": what the register table states, register by register.
//   read        every readable register answers a read of its words;
//   write-min / write-max / write-mid
//               in-range writes are accepted (MBAP v1.1b3 §6.6/§6.12 echo)
//               and read back as written, multi-word values whole;
//   below-min / above-max
//               out-of-range writes get the policy's value_out_of_range
//               answer and leave the value unchanged;
//   word-order  a 2-word value with distinct halves reads back with its words
//               where the spec's word_order puts them;
//   read-only / write-only
//               writes to ro and reads of wo registers get the policy's answer.
// Registers with no stated range are written at the type's bounds as OBSERVED.
#include <fmt/core.h>

#include <algorithm>
#include <bit>
#include <cmath>

#include "cases/common.h"
#include "cases/facts.h"

namespace mbc::conf {
namespace {

using cases::clause;
using cases::hex16;
using spec::Access;
using spec::DataType;
using spec::Register;
using spec::Table;

std::string table_prefix(Table t) {
  switch (t) {
    case Table::holding: return "";
    case Table::input: return "input-";
    case Table::coil: return "coil-";
    case Table::discrete_input: return "di-";
  }
  return "";
}

// Raw words for an engineering value (f32 registers carry float bits).
std::vector<uint16_t> words_for(const Register& r, double v) {
  if (r.type == DataType::f32) return cases::encode(r, int64_t(std::bit_cast<uint32_t>(float(v))));
  return cases::encode(r, int64_t(v));
}

std::string show(const Register& r, double v) {
  if (r.type == DataType::f32) return fmt::format("{}", v);
  return fmt::format("{}", int64_t(v));
}

struct Gen {
  const GenContext& g;
  std::vector<Case>& out;

  Case base(const Register& r, const std::string& what) {
    Case c;
    c.family = "registers";
    c.id = fmt::format("{}/registers/{}{}/{}", g.spec.device.id, table_prefix(r.table), hex16(r.address), what);
    c.clause = clause(g.spec, r.section);
    if (r.table == Table::holding) c.register_address = r.address;
    c.errata = r.errata;
    // The reading of the manual's address notation every register case rests
    // on (rieding-dhe: the "+1" note read as PLC numbering).
    if (!g.spec.device.manual.erratum.empty()) c.errata.push_back(g.spec.device.manual.erratum);
    return c;
  }

  Expect want_words(const Register& r, std::vector<uint16_t> w, std::string text) {
    Expect e;
    e.kind = Expect::Kind::registers;
    if (r.table == Table::coil || r.table == Table::discrete_input)
      for (auto& x : w) x = x ? 1 : 0;
    e.words = std::move(w);
    e.text = std::move(text);
    return e;
  }

  void read(const Register& r) {
    Case c = base(r, "read");
    c.title = fmt::format("read {} ({})", hex16(r.address), r.name.en);
    c.requirement = fmt::format("{} {} is readable ({}, {} word{}).", spec::to_string(r.table), hex16(r.address),
                                spec::to_string(r.access), r.words, r.words == 1 ? "" : "s");
    facts::readable(c.relies, r);
    Expect e = cases::normal(fmt::format("a normal reply with {} item{}", r.words, r.words == 1 ? "" : "s"));
    auto st = cases::read_step(g, r, e);
    if (!st) return;
    c.steps.push_back(std::move(*st));
    out.push_back(std::move(c));
  }

  bool writable(const Register& r, Case& c) {
    if (auto why = cases::write_forbidden(g, r); !why.empty()) {
      c.skip_reason = why;
      return false;
    }
    return true;
  }

  // Write `v`, expect the echo, read it back.
  void write_in_range(const Register& r, const std::string& what, double v, Level level, const std::string& why,
                      const facts::Relies& relies) {
    Case c = base(r, what);
    c.level = level;
    c.relies = relies;
    facts::writable(c.relies, r);
    facts::readable(c.relies, r);  // the read-back
    facts::word_order(c.relies, r);
    c.title = fmt::format("write {} = {} ({}) and read it back", hex16(r.address), show(r, v), why);
    c.requirement = level == Level::observed ? fmt::format("{} states no range; a write of {} (the type's {}) is recorded.",
                                                           hex16(r.address), show(r, v), why)
                    : r.range ? fmt::format("{} accepts {} ({} of {}..{}) and reads it back.", hex16(r.address), show(r, v), why,
                                            show(r, r.range->min), show(r, r.range->max))
                              : fmt::format("{} accepts {} and reads it back (MBAP v1.1b3 §6.5).", hex16(r.address), show(r, v));
    c.touches.push_back({r.address, r.words});
    auto w = words_for(r, v);
    auto st = cases::write_step(g, r, w);
    if (!st) {
      c.skip_reason = "the profile has no function code to write it whole";
    } else {
      writable(r, c);  // a forbidden write is skipped, its frames still shown by --plan
      c.steps.push_back(std::move(*st));
      Expect back = want_words(r, w, fmt::format("{} (as written)", show(r, v)));
      if (r.word_order_readings.size() > 1 && w.size() == 2) {
        // Word order printed two ways: either order reads back right.
        back.reading = fmt::format("{} (word order {})", show(r, v), spec::to_string(r.word_order));
        Expect swapped = want_words(r, {w[1], w[0]}, "");
        swapped.reading = swapped.text = fmt::format("{} (the other word order)", show(r, v));
        back.either.push_back(std::move(swapped));
        back.text += " or its words swapped (word order printed two ways)";
      }
      if (auto rd = cases::read_step(g, r, back)) c.steps.push_back(std::move(*rd));
    }
    out.push_back(std::move(c));
  }

  // A rejected write: read (memo), write, the policy's answer, read unchanged.
  void rejected_write(const Register& r, const std::string& what, std::vector<uint16_t> w, spec::Violation v,
                      const std::string& title, const facts::Relies& relies = {}) {
    Case c = base(r, what);
    c.relies = relies;
    facts::word_order(c.relies, r);  // the words of the rejected value
    auto pe = cases::policy_expect(g, v);
    c.level = pe.level;
    c.clause = pe.level == Level::observed ? clause(g.spec, r.section) + "; " + pe.clause : pe.clause;
    if (!pe.erratum.empty()) c.errata.push_back(pe.erratum);
    c.title = title;
    c.requirement = fmt::format("{}: {}; the value stays unchanged.", title, pe.expect.text);
    c.touches.push_back({r.address, r.words});
    bool readable = facts::readable(c.relies, r);  // the before/after reads
    int memo = -1;
    if (readable) {
      if (auto rd = cases::read_step(g, r, Expect{})) {
        rd->setup = true;
        rd->note = "before: " + rd->note;
        memo = 0;
        c.steps.push_back(std::move(*rd));
      }
    }
    auto st = cases::write_step(g, r, w, pe.expect);
    if (!st) {
      c.skip_reason = "the profile has no function code to write it whole";
    } else {
      writable(r, c);
      c.steps.push_back(std::move(*st));
      if (memo >= 0) {
        Expect same;
        same.kind = Expect::Kind::same;
        same.memo = memo;
        same.text = "the value read before (unchanged)";
        if (auto rd = cases::read_step(g, r, same)) c.steps.push_back(std::move(*rd));
      }
    }
    out.push_back(std::move(c));
  }

  void writes(const Register& r) {
    facts::Relies rel;
    const auto& range = facts::range(rel, r);
    facts::type(rel, r);
    bool has_range = range.has_value();
    double lo = has_range ? range->min : double(cases::type_min(r));
    double hi = has_range ? range->max : double(cases::type_max(r));
    // An enumeration without a range takes its value set as one (spec/README.md):
    // the printed values are what a write may carry, so its writes are stated.
    bool enum_values = false;
    if (const auto* en = !has_range && r.type == DataType::enumeration ? g.spec.find_enum(r.enum_id) : nullptr;
        en && !en->values.empty()) {
      auto [a, b] = std::minmax_element(en->values.begin(), en->values.end(),
                                        [](const auto& x, const auto& y) { return x.value < y.value; });
      lo = double(a->value);
      hi = double(b->value);
      enum_values = true;
    }
    // Range printed two ways: accepted writes stay inside both readings,
    // rejected ones outside both, so a case passes on either.
    double out_lo = lo, out_hi = hi;
    for (const auto& x : r.range_readings) {
      lo = std::max(lo, x.min);
      hi = std::min(hi, x.max);
      out_lo = std::min(out_lo, x.min);
      out_hi = std::max(out_hi, x.max);
    }
    if (lo > hi) return;  // the readings share no value
    if (r.type == DataType::f32 && !has_range) return;  // no float bounds to test
    if (r.type == DataType::bitfield && !has_range) return;  // reserved bits make type bounds meaningless
    // A coil's values are the type itself (MBAP v1.1b3 §6.5: OFF or ON); other
    // registers without a stated range are written at the type's bounds, OBSERVED.
    Level lv = has_range || enum_values || r.type == DataType::bit ? Level::must : Level::observed;
    write_in_range(r, "write-min", lo, lv, "minimum", rel);
    if (hi != lo) write_in_range(r, "write-max", hi, lv, "maximum", rel);
    double mid = r.type == DataType::f32 ? (lo + hi) / 2 : std::floor((lo + hi) / 2);
    if (r.type == DataType::enumeration) {
      // The middle of an enumeration is its middle value, not a hole between values.
      if (const auto* en = g.spec.find_enum(r.enum_id); en && !en->values.empty())
        mid = double(en->values[en->values.size() / 2].value);
    }
    if (mid != lo && mid != hi) write_in_range(r, "write-mid", mid, lv, "middle", rel);

    if (has_range && r.type != DataType::f32 && r.type != DataType::bit) {
      if (out_lo - 1 >= double(cases::type_min(r)))
        rejected_write(r, "below-min", words_for(r, out_lo - 1), spec::Violation::value_out_of_range,
                       fmt::format("write {} = {} (minimum - 1)", hex16(r.address), show(r, out_lo - 1)), rel);
      if (out_hi + 1 <= double(cases::type_max(r)))
        rejected_write(r, "above-max", words_for(r, out_hi + 1), spec::Violation::value_out_of_range,
                       fmt::format("write {} = {} (maximum + 1)", hex16(r.address), show(r, out_hi + 1)), rel);
    }
    if (r.words == 2 && r.type != DataType::f32) {
      // Both halves non-zero and different, so swapped words cannot read back right.
      int64_t v = 0x00010002;
      if (v < lo || v > hi) v = -0x00010002;
      // The case checks where the words go, not the range: 0x00010002 has
      // halves any 16-bit reading of the words accepts, so it relies on the
      // type and word order only (a 32-bit range read from per-word rows,
      // 57HS-R 0x0024, is inferred, but not what this case is about).
      facts::Relies words_only;
      facts::type(words_only, r);
      if (v >= lo && v <= hi) write_in_range(r, "word-order", double(v), lv, "distinct words", words_only);
    }
  }

  // Power-on state (spec/README.md: `default` is the power-on value of a
  // volatile register; a persistent one keeps what was stored).
  void power_cycle(const Register& r) {
    facts::Relies rel;
    const auto& range = facts::range(rel, r);
    const auto& persistence = facts::persistence(rel, r);
    if (r.table != Table::holding || r.words != 1 || !range || r.type == DataType::f32) return;
    if (persistence.by == spec::PersistBy::save_command) return;  // needs the save command; the examples cover it
    bool persistent = persistence.store != spec::Store::none;
    std::optional<double> dv = persistent ? r.default_value : facts::default_value(rel, r);
    if (!persistent && !dv) return;
    // A range printed two ways: the value written lies inside every reading.
    double lo = range->min, hi = range->max;
    for (const auto& x : r.range_readings) lo = std::max(lo, x.min), hi = std::min(hi, x.max);
    double dflt = dv.value_or(lo);
    if (lo > hi || dflt < range->min || dflt > range->max) return;  // a default the range excludes is an erratum of its own
    double v = hi != dflt ? hi : lo;
    if (v == dflt) return;
    for (double x : r.default_readings)
      if (x == v) return;  // every reading's default must differ from the value written
    Case c = base(r, persistent ? "persists" : "volatile");
    c.relies = rel;
    facts::writable(c.relies, r);
    facts::readable(c.relies, r);
    c.clause = clause(g.spec, !r.persistence.section.empty() ? r.persistence.section : r.section);
    c.title = persistent ? fmt::format("{} keeps {} across a power cycle", hex16(r.address), show(r, v))
                         : fmt::format("{} returns to its default {} after a power cycle", hex16(r.address), show(r, dflt));
    c.requirement = persistent ? fmt::format("{} is stored ({}): a written value survives a power cycle.", hex16(r.address),
                                             r.persistence.store == spec::Store::eeprom ? "EEPROM" : "flash")
                               : fmt::format("{} is volatile: after a power cycle it reads its default {}.", hex16(r.address), show(r, dflt));
    c.touches.push_back({r.address, 1});
    if (!g.target.power_cycle) {
      c.skip_reason = "the target cannot be power-cycled";
      out.push_back(std::move(c));
      return;
    }
    writable(r, c);
    if (persistent && r.persistence.unless_register) {
      // The "do not persist" switch must be off for the write to be stored.
      const Register* sw = g.spec.find_register(*r.persistence.unless_register);
      if (!sw) return;
      int64_t off = r.persistence.unless_value == 0 ? 1 : 0;
      if (auto st = cases::write_step(g, *sw, cases::encode(*sw, off))) {
        st->setup = true;
        st->note = "persistence on: " + st->note;
        c.steps.push_back(std::move(*st));
        c.touches.push_back({sw->address, 1});
      }
    }
    auto w = words_for(r, v);
    auto st = cases::write_step(g, r, w);
    if (!st) return;
    c.steps.push_back(std::move(*st));
    Step pc;
    pc.kind = Step::Kind::power_cycle;
    pc.note = "power cycle";
    c.steps.push_back(std::move(pc));
    auto want = persistent ? w : words_for(r, dflt);
    Expect after = want_words(r, want, persistent ? show(r, v) + " (stored)" : show(r, dflt) + " (the default)");
    if (!persistent && r.default_readings.size() > 1) {
      // The default is printed two ways: either reads back right.
      after.reading = after.text;
      for (double x : r.default_readings) {
        if (x == dflt) continue;
        Expect alt = want_words(r, words_for(r, x), show(r, x) + " (the other printed default)");
        alt.reading = alt.text;
        after.either.push_back(std::move(alt));
      }
    }
    if (auto rd = cases::read_step(g, r, after)) c.steps.push_back(std::move(*rd));
    out.push_back(std::move(c));
  }

  void run() {
    for (const auto& r : g.spec.registers) {
      if (r.access == Access::rw) power_cycle(r);
      if (r.access != Access::wo && r.access != Access::command) read(r);
      if (r.access == Access::rw && (r.table == Table::holding || r.table == Table::coil)) writes(r);
      if (r.access == Access::ro && r.table == Table::holding) {
        double v = r.default_value.value_or(0);
        facts::Relies rel;
        facts::writable(rel, r);  // that it is not writable
        facts::default_value(rel, r);  // the value written
        rejected_write(r, "read-only", r.type == DataType::f32 ? words_for(r, v) : cases::encode(r, int64_t(v)),
                       spec::Violation::write_read_only, fmt::format("write read-only {}", hex16(r.address)), rel);
      }
      if (r.access == Access::wo) {
        Case c = base(r, "write-only");
        auto pe = cases::policy_expect(g, spec::Violation::read_write_only);
        c.level = pe.level;
        c.clause = pe.clause;
        if (!pe.erratum.empty()) c.errata.push_back(pe.erratum);
        facts::readable(c.relies, r);  // that it is not readable
        c.title = fmt::format("read write-only {}", hex16(r.address));
        c.requirement = fmt::format("A read of write-only {}: {}.", hex16(r.address), pe.expect.text);
        if (auto st = cases::read_step(g, r, pe.expect)) {
          c.steps.push_back(std::move(*st));
          out.push_back(std::move(c));
        }
      }
    }
  }
};

}  // namespace

std::vector<Case> register_cases(const GenContext& g) {
  std::vector<Case> out;
  Gen{g, out}.run();
  return out;
}

}  // namespace mbc::conf
