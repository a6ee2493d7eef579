// Family "deviations": every way the device's spec departs from the
// modbus-standard baseline (the list `spec errata` reports), each recorded as
// OBSERVED, never failed. Where a request provokes the deviation (an
// exception policy, a quantity limit) the case sends it and records the
// device's answer beside the standard's; the rest (line settings, exception
// code meanings) are recorded as documented.
#include <fmt/core.h>

#include <algorithm>
#include <map>

#include "cases/common.h"
#include "cases/facts.h"
#include "policy/policy.h"
#include "modbus/function_codes.h"
#include "errata.h"
#include "modbus/crc16.h"
#include "modbus/pdu.h"
#include "modbus/rtu.h"

namespace mbc::conf {
namespace {

using cases::hex16;
using spec::Access;
using spec::Table;
using spec::Violation;

const spec::Register* first_where(const spec::Spec& s, auto pred) {
  for (const auto& r : s.registers)
    if (pred(r)) return &r;
  return nullptr;
}

// The request that provokes a violation kind on this device, if its map has one.
std::optional<Step> provoke(const GenContext& g, Violation v) {
  const auto& s = g.spec;
  Step st;
  st.unit = g.target.unit;
  auto readable = [](const spec::Register& r) {
    return r.table == Table::holding && r.access != Access::wo && r.access != Access::command;
  };
  const spec::Register* first = first_where(s, readable);
  switch (v) {
    case Violation::unsupported_function:
      for (int fc : {1, 2, 4, 5, 15, 65, 100})
        if (!cases::has_fc(s, fc)) {
          st.pdu = {uint8_t(fc), 0, 0, 0, 1};
          return st;
        }
      return std::nullopt;
    case Violation::address_past_map: {
      auto last = s.last_address(Table::holding);
      if (!last || *last == 0xFFFF) return std::nullopt;
      st.pdu = read_request(3, uint16_t(*last + 1), 1);
      return st;
    }
    case Violation::unmapped_address: {
      auto last = s.last_address(Table::holding);
      if (!last) return std::nullopt;
      bool seen = false;
      for (uint32_t a = 0; a < *last; ++a) {
        if (s.register_covering(uint16_t(a))) seen = true;
        else if (seen) {
          st.pdu = read_request(3, uint16_t(a), 1);
          return st;
        }
      }
      return std::nullopt;
    }
    case Violation::quantity_zero:
      if (!first) return std::nullopt;
      st.pdu = read_request(3, first->address, 0);
      return st;
    case Violation::quantity_over_limit:
      if (!first) return std::nullopt;
      st.pdu = read_request(3, first->address, 126);  // MBAP v1.1b3 §6.3: 1 to 125
      return st;
    case Violation::value_out_of_range: {
      const spec::Register* r = cases::plain_register(g);
      if (!r || !r->range || r->range->max >= cases::type_max(*r)) return std::nullopt;
      st.pdu = write_single_register(r->address, cases::encode(*r, int64_t(r->range->max) + 1)[0]);
      return st;
    }
    case Violation::write_read_only: {
      const spec::Register* r = first_where(s, [](const spec::Register& r) {
        return r.table == Table::holding && r.access == Access::ro && r.words == 1;
      });
      if (!r) return std::nullopt;
      st.pdu = write_single_register(r->address, uint16_t(int64_t(r->default_value.value_or(0))));
      return st;
    }
    case Violation::read_write_only: {
      const spec::Register* r = first_where(s, [](const spec::Register& r) { return r.table == Table::holding && r.access == Access::wo; });
      if (!r) return std::nullopt;
      st.pdu = read_request(3, r->address, uint16_t(r->words));
      return st;
    }
    case Violation::crc_error: {
      if (!first || !g.target.raw || g.target.framing != &mbc::kRtu) return std::nullopt;
      st.kind = Step::Kind::raw;
      st.bytes = rtu_frame(g.target.unit, read_request(3, first->address, 1));
      st.bytes.back() ^= 0xFF;
      return st;
    }
    case Violation::wrong_byte_count: {
      const spec::Register* r = cases::plain_register(g);
      if (!r || !cases::has_fc(s, 16)) return std::nullopt;
      st.pdu = {16, uint8_t(r->address >> 8), uint8_t(r->address & 0xFF), 0, 2, 2, 0, 0};
      return st;
    }
  }
  return std::nullopt;
}

}  // namespace

std::vector<Case> deviation_cases(const GenContext& g) {
  std::vector<Case> out;
  if (!g.standard || g.spec.device.id == g.standard->device.id) return out;
  nlohmann::json report = spec::errata_report(g.spec, *g.standard);
  for (const auto& d : report.value("deviations", nlohmann::json::array())) {
    std::string topic = d.value("topic", "");
    Case c;
    c.family = "deviations";
    c.id = fmt::format("{}/deviations/{}/1", g.spec.device.id, topic);
    c.level = Level::observed;
    std::string section = d.value("section", "");
    c.clause = d.value("clause", "") + (section.empty() ? "" : "; " + cases::clause(g.spec, section));
    c.title = fmt::format("{}: device {} / standard {}", topic, d.value("device", ""), d.value("standard", ""));
    c.requirement = fmt::format("The manual departs from the standard ({}): the device {}, the standard {}.",
                                d.value("clause", ""), d.value("device", ""), d.value("standard", ""));
    if (topic.rfind("exception_policy.", 0) == 0) {
      std::string kind = topic.substr(std::string("exception_policy.").size());
      for (Violation v : spec::kAllViolations) {
        if (kind != spec::to_string(v)) continue;
        spec::PolicyEntry sp = g.standard->profile.policy(v);
        auto st = provoke(g, v);
        if (!st) break;
        if (sp.kind == spec::PolicyEntry::Kind::exception)
          st->expect = cases::exception(uint8_t(sp.code), fmt::format("the standard's exception {:02X}", sp.code));
        else
          st->expect = cases::silence("the standard's silence");
        st->note = fmt::format("provoke {}", kind);
        spec::PolicyEntry dp = g.spec.profile.policy(v);
        st->may_go_unanswered = dp.kind == spec::PolicyEntry::Kind::silent ||
                                std::any_of(dp.readings.begin(), dp.readings.end(), [](const auto& r) { return r.kind == spec::PolicyEntry::Kind::silent; });
        if (const auto* r = cases::plain_register(g); r && (v == Violation::value_out_of_range || v == Violation::wrong_byte_count)) {
          c.touches.push_back({r->address, v == Violation::wrong_byte_count ? 2 : 1});
          if (auto why = cases::write_forbidden(g, *r); !why.empty()) c.skip_reason = why;
        }
        c.steps.push_back(std::move(*st));
      }
    } else if (topic.rfind("function_code.", 0) == 0 && topic.find(".max_quantity") != std::string::npos) {
      int fc = std::atoi(topic.c_str() + std::string("function_code.").size());
      const auto* sf = g.standard->profile.function(fc);
      if (fc >= 1 && fc <= 4 && sf && sf->max_quantity) {
        // The standard's limit of items in one read: recorded.
        Table t = spec::table_for_function(fc);
        for (const auto& r : g.spec.registers)
          if (r.table == t && r.access != Access::wo && r.access != Access::command) {
            Step st;
            st.unit = g.target.unit;
            st.pdu = read_request(uint8_t(fc), r.address, uint16_t(*sf->max_quantity));
            st.note = fmt::format("read {} x{} (the standard's limit)", hex16(r.address), *sf->max_quantity);
            st.expect.text = "recorded (the standard allows this many; the map may not have them)";
            c.steps.push_back(std::move(st));
            break;
          }
      }
    }
    out.push_back(std::move(c));
  }
  return out;
}

namespace {

// A case on a map (GenContext::map): which public function codes the server
// implements is its own choice (MBAP v1.1b3 §5.1), so an exception 01 to a
// code the case did not mean to refuse makes it not apply (function-codes
// sets this itself for the codes the map's spec leaves out).
void on_map(Case& c, const OnMap&) {
  if (c.family != "function-codes") c.functions_optional = true;
}

// Why one of the case's frames may not go out to this target (the frame
// policy, policy/policy.h), or nullopt: a case that cannot go out whole is
// a skip naming the opt-in, and `run --plan` prints only what will be sent.
std::optional<std::string> refused_step(const PolicyFacts& p, const Case& c) {
  for (const auto& st : c.steps) {
    Decision d = st.kind == Step::Kind::frame ? allowed(p, st.unit, st.pdu)
                 : st.kind == Step::Kind::raw ? allowed_raw(p, st.bytes, st.gap)
                                              : Decision{};
    if (!d) return d.refused->reason;
  }
  return std::nullopt;
}

}  // namespace

std::vector<Case> all_cases(const GenContext& g) {
  std::vector<Case> out;
  for (auto gen : {examples_cases, register_cases, function_code_cases, framing_cases, standard_cases, deviation_cases}) {
    auto v = gen(g);
    for (auto& c : v) out.push_back(std::move(c));
  }
  // Ids are stable and unique: a repeated one gets "-2", "-3", ...
  std::map<std::string, int> seen;
  for (auto& c : out) {
    if (int n = ++seen[c.id]; n > 1) c.id += fmt::format("-{}", n);
    // Every function code a case sends is one the profile supports (fact
    // `supported`); a printed example relies on its frame instead, and a
    // deviation compares with the standard.
    if (c.family != "examples" && c.family != "deviations")
      for (const auto& st : c.steps)
        if (const auto* f = st.pdu.empty() ? nullptr : g.spec.profile.function(st.pdu[0])) facts::supported(c.relies, *f);
    facts::settle_level(c);
    if (g.map) on_map(c, *g.map);
    if (c.skip_reason.empty())
      if (auto why = refused_step(PolicyFacts{&g.spec, g.target, g.policy}, c)) c.skip_reason = *why;
  }
  return out;
}

}  // namespace mbc::conf
