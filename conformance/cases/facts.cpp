#include "cases/facts.h"

#include "erratum_extra.h"

#include <fmt/core.h>

#include <algorithm>

namespace mbc::conf::facts {

using spec::Basis;
using spec::Fact;
using spec::FactBasis;

namespace {

void note(Relies& into, std::string fact, FactBasis b) {
  for (const auto& r : into)
    if (r.fact == fact) return;
  into.push_back({std::move(fact), std::move(b)});
}

void note(Relies& into, const spec::Register& r, Fact f) {
  note(into, fmt::format("register 0x{:04X} {}", r.address, spec::to_string(f)), r.basis_of(f));
}

}  // namespace

bool readable(Relies& into, const spec::Register& r) {
  note(into, r, Fact::read);
  return r.access != spec::Access::wo && r.access != spec::Access::command;
}

bool writable(Relies& into, const spec::Register& r) {
  note(into, r, Fact::write);
  return r.access == spec::Access::rw || r.access == spec::Access::wo || r.access == spec::Access::command;
}

const std::optional<spec::Range>& range(Relies& into, const spec::Register& r) {
  note(into, r, Fact::range);
  return r.range;
}

std::optional<double> default_value(Relies& into, const spec::Register& r) {
  note(into, r, Fact::default_value);
  return r.default_value;
}

spec::WordOrder word_order(Relies& into, const spec::Register& r) {
  if (r.words == 2) note(into, r, Fact::word_order);
  return r.word_order;
}

spec::DataType type(Relies& into, const spec::Register& r) {
  note(into, r, Fact::type);
  return r.type;
}

spec::TakesEffect takes_effect(Relies& into, const spec::Register& r) {
  note(into, r, Fact::takes_effect);
  return r.takes_effect;
}

const spec::Persistence& persistence(Relies& into, const spec::Register& r) {
  note(into, r, Fact::persistence);
  return r.persistence;
}

void supported(Relies& into, const spec::FunctionCode& f) {
  note(into, fmt::format("FC {} supported", f.code), f.basis_of("supported"));
}

std::optional<int> limit(Relies& into, const spec::FunctionCode& f, const char* which) {
  std::string w = which;
  std::optional<int> v = w == "max_read_quantity" ? f.max_read_quantity : w == "max_write_quantity" ? f.max_write_quantity : f.max_quantity;
  if (v) note(into, fmt::format("FC {} {}", f.code, w), f.basis_of(w));
  return v;
}

spec::PolicyEntry policy(Relies& into, const spec::Spec& s, spec::Violation v) {
  spec::PolicyEntry p = s.profile.policy(v);
  if (p.kind != spec::PolicyEntry::Kind::unspecified || p.basis.basis == Basis::either) {
    FactBasis b = p.basis;
    if (b.section.empty()) b.section = p.section;
    note(into, fmt::format("{} exception_policy.{}", s.device.id, spec::to_string(v)), b);
  }
  return p;
}

const spec::Example& example(Relies& into, const spec::Example& e) {
  note(into, "example " + e.id, e.basis);
  return e;
}

void settle_level(Case& c) {
  if (c.requirement.find(" [relies on ") != std::string::npos) return;
  std::vector<std::string> inferred;
  for (const auto& r : all_relies(c))
    if (spec::demotes(r.basis)) inferred.push_back(describe(r));  // inferred, or printed two ways in words
  if (inferred.empty()) return;
  if (c.level == Level::must || c.level == Level::should) {
    c.level_if_stated = c.level;
    c.level = Level::observed;
  }
  std::string s;
  for (const auto& x : inferred) s += (s.empty() ? "" : "; ") + x;
  c.requirement += " [relies on " + s + "]";
}

}  // namespace mbc::conf::facts
