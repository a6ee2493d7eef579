#include "dump.h"

#include <cmath>

namespace mbc::spec {

namespace {

nlohmann::json write_json(const std::optional<RegisterWrite>& w) {
  if (!w) return nullptr;
  return {{"register", w->key}, {"value", w->value}, {"settle_ms", double(w->settle_us) / 1000}, {"section", w->section}};
}

nlohmann::json operations_json(const Operations& o) {
  nlohmann::json j = {{"section", o.section}, {"save", write_json(o.save)}, {"factory_reset", write_json(o.factory_reset)}};
  nlohmann::json setup = nlohmann::json::array();
  for (const auto& w : o.setup) setup.push_back(write_json(w));
  j["setup"] = setup;
  return j;
}

nlohmann::json motion_json(const std::optional<MotionOperations>& mo) {
  if (!mo) return nullptr;
  const MotionOperations& m = *mo;
  nlohmann::json j;
  auto list = [](const std::vector<RegisterWrite>& v) {
    nlohmann::json a = nlohmann::json::array();
    for (const auto& w : v) a.push_back(write_json(w));
    return a;
  };
  j = {{"section", m.section},
                 {"assumes", list(m.assumes)},
                 {"setup", list(m.setup)},
                 {"distance", {{"register", m.distance_key}, {"reverse_register", m.reverse_distance_key},
                               {"signed", m.signed_distance}, {"max", m.max_distance}}},
                 {"start_forward", write_json(m.start_forward)},
                 {"start_reverse", write_json(m.start_reverse)},
                 {"position", {{"register", m.position_key}, {"high_register", m.position_high_key}}},
                 {"max_speed_pulses_per_s", m.max_speed_pulses_per_s},
                 {"decel_seconds", m.decel_seconds},
                 {"decel_basis", to_string(m.decel_basis.basis)},
                 {"stop", write_json(m.stop)},
                 {"emergency_stop", write_json(m.emergency_stop)},
                 {"status", {{"register", m.status_key}, {"running_mask", m.running_mask},
                             {"running_when_set", m.running_when_set}, {"in_position_mask", m.in_position_mask}}},
                 {"positioning_needs_homing", m.positioning_needs_homing},
                 {"position_command", m.position_command_key}};
  return j;
}

}  // namespace

namespace {

using nlohmann::json;

json number(double d) {
  if (d == std::floor(d) && std::fabs(d) < 9.0e15) return int64_t(d);
  return d;
}

json name(const Name& n) { return {{"zh", n.zh}, {"en", n.en}}; }

// Where a fact comes from (spec/README.md, "Where each fact comes from").
json basis(const FactBasis& b) {
  json j{{"basis", to_string(b.basis)}};
  if (!b.section.empty()) j["section"] = b.section;
  if (!b.quote.empty()) j["quote"] = b.quote;
  if (!b.why.empty()) j[b.basis == Basis::observed ? "observed" : "why"] = b.why;
  if (!b.searched.empty()) j["searched"] = b.searched;
  if (b.basis == Basis::either) {
    json r = json::array();
    for (const auto& t : b.readings) r.push_back(json::parse(t, nullptr, false));
    j["readings"] = r;
    j["erratum"] = b.erratum;
  }
  return j;
}

json policy(const PolicyEntry& e) {
  json j;
  switch (e.kind) {
    case PolicyEntry::Kind::exception:
      j["response"] = "exception";
      j["code"] = e.code;
      break;
    case PolicyEntry::Kind::silent: j["response"] = "silent"; break;
    case PolicyEntry::Kind::unspecified: j["response"] = "unspecified"; break;
  }
  j["section"] = e.section;
  if (!e.erratum.empty()) j["erratum"] = e.erratum;
  if (e.kind != PolicyEntry::Kind::unspecified || e.basis.basis == Basis::either) j["basis"] = basis(e.basis);
  return j;
}

json reg(const Register& r) {
  json j;
  j["address"] = r.address;
  if (!r.key.empty()) j["key"] = r.key;
  j["words"] = r.words;
  j["table"] = to_string(r.table);
  j["name"] = r.name.en;
  j["name_zh"] = r.name.zh;
  j["access"] = to_string(r.access);
  j["type"] = to_string(r.type);
  j["word_order"] = r.words == 2 ? json(to_string(r.word_order)) : json(nullptr);
  j["range"] = r.range ? json{{"min", number(r.range->min)}, {"max", number(r.range->max)}} : json(nullptr);
  j["default"] = r.default_value ? number(*r.default_value) : json(nullptr);
  j["unit"] = r.unit;
  j["scale"] = number(r.scale);
  if (r.persistence.store == Store::none) {
    j["persistence"] = "volatile";
  } else {
    json p{{"store", r.persistence.store == Store::flash ? "flash" : "eeprom"},
           {"by", r.persistence.by == PersistBy::save_command ? "save_command" : "on_write"}};
    if (r.persistence.command) p["command"] = *r.persistence.command;
    if (r.persistence.unless_register)
      p["unless"] = {{"register", *r.persistence.unless_register}, {"value", r.persistence.unless_value}};
    j["persistence"] = p;
  }
  j["takes_effect"] = r.takes_effect == TakesEffect::power_cycle ? "power_cycle" : "immediate";
  if (!r.enum_id.empty()) j["enum"] = r.enum_id;
  if (!r.bitfield_id.empty()) j["bitfield"] = r.bitfield_id;
  if (r.command) {
    json c{{"effect", r.command->effect}, {"motion", r.command->motion}, {"eeprom", r.command->eeprom}};
    if (r.command->reads_back) c["reads_back"] = *r.command->reads_back;
    if (!r.command->values.empty()) c["values"] = r.command->values;
    j["command"] = c;
  }
  if (!r.printed.empty()) j["printed"] = r.printed;
  j["errata"] = r.errata;
  if (!r.note.empty()) j["note"] = r.note;
  j["section"] = r.section;
  // Every fact not stated by the register's table row (absent = stated by `section`).
  json b = json::object();
  for (const auto& [fact, fb] : r.basis) b[to_string(fact)] = basis(fb);
  if (!b.empty()) j["basis"] = b;
  j["line"] = r.loc.line;
  return j;
}

json match(const StatusMatch& m) { return {{"register", m.register_key}, {"mask", m.mask}, {"value", m.value}}; }

// The resolved control: a profile's entries carry the device's register keys.
json control(const std::optional<Control>& co) {
  if (!co) return nullptr;
  const Control& c = *co;
  json j{{"profile", c.profile}, {"section", c.section}, {"initial", c.initial}, {"safe", c.safe}};
  j["top_speed"] = c.top_speed ? json(*c.top_speed) : json(nullptr);
  j["undefined"] = {{"kind", c.undefined.kind == UndefinedCommand::Kind::exception ? "exception" : "ignored"},
                    {"code", c.undefined.code}, {"basis", basis(c.undefined.basis)}};
  json states = json::array();
  for (const auto& x : c.states) {
    json st = json::array();
    for (const auto& m : x.status) st.push_back(match(m));
    states.push_back({{"id", x.id}, {"name", name(x.name)}, {"status", st}, {"motion", x.motion}, {"fault", x.fault},
                      {"basis", basis(x.basis)}});
  }
  j["states"] = states;
  json commands = json::array();
  for (const auto& x : c.commands)
    commands.push_back({{"id", x.id}, {"name", name(x.name)}, {"register", x.register_key}, {"mask", x.mask}, {"value", x.value},
                        {"write", x.word()}, {"trigger", to_string(x.trigger)}, {"edge_mask", x.edge_mask}, {"motion", x.motion},
                        {"setpoints", x.setpoint_keys ? json(*x.setpoint_keys) : json(nullptr)}, {"stops", x.stops}, {"stop_within_ms", x.stop_within_ms ? json(*x.stop_within_ms) : json(nullptr)},
                        {"basis", basis(x.basis)}});
  j["commands"] = commands;
  json transitions = json::array();
  for (const auto& x : c.transitions) {
    json when = json::array();
    for (const auto& w : x.when) when.push_back({{"register", w.register_key}, {"values", w.values}});
    transitions.push_back({{"id", x.id}, {"from", x.from}, {"command", x.command}, {"event", x.event}, {"to", x.to},
                           {"within_ms", x.within_ms ? json(*x.within_ms) : json(nullptr)}, {"when", when},
                           {"motion", x.motion}, {"basis", basis(x.basis)}});
  }
  j["transitions"] = transitions;
  json modes = json::array();
  for (const auto& x : c.modes)
    modes.push_back({{"id", x.id}, {"select", write_json(x.select)}, {"display", x.display_key}, {"setpoints", x.setpoint_keys},
                     {"actual", x.actual_key}, {"start", x.start_command}, {"done", x.done ? match(*x.done) : json(nullptr)},
                     {"select_in", x.select_in}, {"basis", basis(x.basis)}});
  j["modes"] = modes;
  j["motion"] = motion_json(c.motion);
  j["no_motion"] = c.no_motion ? json{{"section", c.no_motion->section}, {"why", c.no_motion->why}} : json(nullptr);
  return j;
}

json values(const std::vector<RegisterValue>& v) {
  json a = json::array();
  for (const auto& x : v) a.push_back({{"address", x.address}, {"value", number(x.value)}, {"table", to_string(x.table)}});
  return a;
}

}  // namespace

nlohmann::json to_json(const Spec& s) {
  json j;
  j["mbconform_spec"] = 1;
  j["device"] = {{"id", s.device.id},
                 {"vendor", s.device.vendor},
                 {"title", s.device.title},
                 {"models", s.device.models},
                 {"manual",
                  {{"file", s.device.manual.file},
                   {"address_notation", s.device.manual.address_notation},
                   {"source", s.device.manual.source},
                   {"addressing_note", s.device.manual.addressing_note}}},
                 {"section", s.device.section}};
  const Serial& se = s.serial;
  j["serial"] = {
      {"slave_id", {{"min", se.slave_min}, {"max", se.slave_max}, {"default", se.slave_default ? json(*se.slave_default) : json(nullptr)}, {"set_by", se.slave_set_by}, {"section", se.slave_section}}},
      {"broadcast", {{"address", se.broadcast_address ? json(*se.broadcast_address) : json(nullptr)}, {"writes", se.broadcast_writes}, {"reply", se.broadcast_reply}, {"section", se.broadcast_section}}},
      {"baud_rates", {{"values", se.baud_rates}, {"default", se.baud_default ? json(*se.baud_default) : json(nullptr)}, {"section", se.baud_section}}},
      {"frame_formats", {{"values", se.frame_formats}, {"default", se.frame_default ? json(*se.frame_default) : json(nullptr)}, {"section", se.frame_section}}},
      {"section", se.section}};
  json settings = json::array();
  for (const auto& st : se.settings) {
    json enc = json::array();
    for (const auto& [v, m] : st.encoding) enc.push_back({{"value", v}, {"means", m}});
    settings.push_back({{"register", st.register_address}, {"setting", st.setting}, {"encoding", enc}, {"section", st.section}});
  }
  j["serial"]["settings"] = settings;

  json fcs = json::array();
  for (const auto& f : s.profile.function_codes) {
    json x{{"code", f.code}, {"section", f.section}};
    x["max_quantity"] = f.max_quantity ? json(*f.max_quantity) : json(nullptr);
    if (f.max_read_quantity) x["max_read_quantity"] = *f.max_read_quantity;
    if (f.max_write_quantity) x["max_write_quantity"] = *f.max_write_quantity;
    if (!f.subfunctions.empty()) x["subfunctions"] = f.subfunctions;
    if (!f.mei_types.empty()) x["mei_types"] = f.mei_types;
    if (!f.note.empty()) x["note"] = f.note;
    for (const auto& [fact, fb] : f.basis) x["basis"][fact] = basis(fb);
    fcs.push_back(x);
  }
  json pol = json::object();
  for (Violation v : kAllViolations) pol[to_string(v)] = policy(s.profile.policy(v));
  json codes = json::array();
  for (const auto& c : s.profile.exception_codes)
    codes.push_back({{"code", c.code}, {"name", name(c.name)}, {"meaning", c.meaning}, {"section", c.section}});
  j["profile"] = {{"function_codes", fcs}, {"exception_policy", pol}, {"exception_codes", codes}, {"section", s.profile.section}};

  json enums = json::array();
  for (const auto& e : s.enums) {
    json vals = json::array();
    for (const auto& v : e.values) vals.push_back({{"value", v.value}, {"name", name(v.name)}});
    enums.push_back({{"id", e.id}, {"section", e.section}, {"values", vals}});
  }
  j["enums"] = enums;
  json bfs = json::array();
  for (const auto& b : s.bitfields) {
    json fields = json::array();
    for (const auto& f : b.fields) {
      json x{{"lo", f.lo}, {"hi", f.hi}, {"name", name(f.name)}, {"reserved", f.reserved}};
      if (f.default_value) x["default"] = *f.default_value;
      if (!f.enum_id.empty()) x["enum"] = f.enum_id;
      if (!f.key.empty()) x["key"] = f.key;
      fields.push_back(x);
    }
    bfs.push_back({{"id", b.id}, {"section", b.section}, {"fields", fields}});
  }
  j["bitfields"] = bfs;

  json regs = json::array();
  for (const auto& r : s.registers) regs.push_back(reg(r));
  j["registers"] = regs;

  json ex = json::array();
  for (const auto& e : s.examples) {
    json x{{"id", e.id}, {"section", e.section}, {"does", e.does}, {"request", e.request},
           {"response", e.response ? json(*e.response) : json(nullptr)}, {"given", values(e.given)},
           {"after", values(e.after)}, {"errata", e.errata}, {"no_reply", e.no_reply}};
    if (!e.sequence.empty()) x["sequence"] = {{"id", e.sequence}, {"step", e.step}};
    if (e.has_resolution()) {
      json r = json::object();
      if (e.resolved_request) r["request"] = *e.resolved_request;
      if (e.resolved_response) r["response"] = *e.resolved_response;
      if (e.resolved_silent) r["silent"] = true;
      x["resolved"] = r;
    }
    x["basis"] = basis(e.basis);
    ex.push_back(x);
  }
  j["examples"] = ex;
  json er = json::array();
  for (const auto& e : s.errata)
    er.push_back({{"id", e.id}, {"section", e.section}, {"kind", e.kind}, {"printed", e.printed}, {"resolved", e.resolved}, {"why", e.why}});
  j["errata"] = er;
  j["operations"] = operations_json(s.operations);
  j["control"] = control(s.control);
  auto opt = [](const std::optional<double>& v) { return v ? nlohmann::json(*v) : nlohmann::json(nullptr); };
  j["timing"] = {{"response_timeout_ms", opt(s.timing.response_timeout_ms)},
                 {"frame_timeout_ms", opt(s.timing.frame_timeout_ms)},
                 {"guard_interval_us", opt(s.timing.guard_interval_us)},
                 {"response_time_ms", opt(s.timing.response_time_ms)},
                 {"section", s.timing.section}};
  return j;
}

}  // namespace mbc::spec
