#include "control.h"

#include <algorithm>
#include <cstdio>
#include <filesystem>
#include <map>
#include <set>
#include <tuple>

#include "spec_path.h"

namespace mbc::spec {
namespace {

using nlohmann::json;

std::string hex16(unsigned v) {
  char buf[8];
  std::snprintf(buf, sizeof buf, "0x%04X", v & 0xFFFF);
  return buf;
}

std::string str(const json& j, const char* key, std::string def = "") {
  auto it = j.find(key);
  return it != j.end() && it->is_string() ? it->get<std::string>() : def;
}

Name name_of(const json& j) {
  Name n;
  if (j.is_object()) {
    n.zh = str(j, "zh");
    n.en = str(j, "en");
  }
  return n;
}

// Where an entry was declared: in the device's file, or in its profile's.
struct Origin {
  const JsonDocument* doc = nullptr;
  std::string file;
  std::string pointer;
  bool profile = false;

  SourceLoc loc(const std::string& sub = "") const { return doc ? doc->where(pointer + sub) : SourceLoc{}; }
  std::string from() const { return profile ? " (from profile " + std::filesystem::path(file).stem().string() + ")" : ""; }
};

template <class T>
struct Entry {
  T value;
  Origin origin;
};

// Reads the entries of one document: the device's `control:` or a profile.
struct Reader {
  const JsonDocument& doc;
  std::string file;
  bool profile;
  std::string section;  // what an entry without `section:` inherits

  Origin origin(const std::string& p) const { return {&doc, file, p, profile}; }

  FactBasis basis(const json& j, const std::string& p, const std::string& sec) const {
    FactBasis b;
    std::string k = str(j, "basis", "stated");
    b.basis = k == "inferred" ? Basis::inferred : k == "either" ? Basis::either : Basis::stated;
    b.quote = str(j, "quote");
    b.why = str(j, "why");
    b.erratum = str(j, "erratum");
    if (j.contains("readings"))
      for (const auto& r : j["readings"]) b.readings.push_back(r.dump());
    b.section = sec;
    b.loc = doc.where(p);
    return b;
  }

  std::string section_of(const json& j) const { return str(j, "section", section); }

  static StatusMatch match(const json& j) {
    StatusMatch m;
    m.register_key = str(j, "register");
    m.mask = j.value("mask", uint16_t(0xFFFF));
    m.value = j["value"].get<uint16_t>();
    return m;
  }

  Entry<ControlState> state(const json& j, const std::string& p) const {
    ControlState x;
    x.id = str(j, "id");
    x.name = name_of(j.value("name", json()));
    for (const auto& m : j["status"]) x.status.push_back(match(m));
    x.motion = j.value("motion", false);
    x.fault = j.value("fault", false);
    x.section = section_of(j);
    x.basis = basis(j, p, x.section);
    x.loc = doc.where(p);
    return {x, origin(p)};
  }

  Entry<ControlCommand> command(const json& j, const std::string& p) const {
    ControlCommand x;
    x.id = str(j, "id");
    x.name = name_of(j.value("name", json()));
    x.register_key = str(j, "register");
    x.mask = j.value("mask", uint16_t(0xFFFF));
    x.value = j["value"].get<uint16_t>();
    if (j.contains("write")) x.write = j["write"].get<uint16_t>();
    std::string t = str(j, "trigger", "level");
    x.trigger = t == "edge" ? Trigger::edge : t == "write" ? Trigger::write : Trigger::level;
    x.edge_mask = j.value("edge_mask", uint16_t(0));
    x.motion = j.value("motion", false);
    if (j.contains("setpoints")) x.setpoint_keys = j["setpoints"].get<std::vector<std::string>>();
    x.stops = j.value("stops", false);
    if (j.contains("stop_within_ms")) x.stop_within_ms = j["stop_within_ms"].get<double>();
    x.section = section_of(j);
    x.basis = basis(j, p, x.section);
    x.loc = doc.where(p);
    return {x, origin(p)};
  }

  Entry<ControlTransition> transition(const json& j, const std::string& p) const {
    ControlTransition x;
    x.id = str(j, "id");
    x.from = str(j, "from");
    x.command = str(j, "command");
    x.event = str(j, "event");
    x.to = str(j, "to");
    if (j.contains("within_ms")) x.within_ms = j["within_ms"].get<double>();
    if (j.contains("when"))
      for (const auto& w : j["when"]) x.when.push_back({str(w, "register"), w["values"].get<std::vector<int64_t>>()});
    x.motion = j.value("motion", false);
    x.section = section_of(j);
    x.basis = basis(j, p, x.section);
    x.loc = doc.where(p);
    return {x, origin(p)};
  }

  Entry<ControlMode> mode(const json& j, const std::string& p) const {
    ControlMode x;
    x.id = str(j, "id");
    x.section = section_of(j);
    if (j.contains("select")) {
      const json& s = j["select"];
      RegisterWrite w;
      w.key = str(s, "register");
      w.value = s["value"].get<int64_t>();
      w.settle_us = uint64_t(s.value("settle_ms", 0.0) * 1000);
      w.section = x.section;
      w.loc = doc.where(p + "/select");
      x.select = w;
    }
    x.display_key = str(j, "display");
    if (j.contains("setpoints")) x.setpoint_keys = j["setpoints"].get<std::vector<std::string>>();
    x.actual_key = str(j, "actual");
    x.start_command = str(j, "start");
    if (j.contains("done")) x.done = match(j["done"]);
    if (j.contains("select_in")) x.select_in = j["select_in"].get<std::vector<std::string>>();
    x.basis = basis(j, p, x.section);
    x.loc = doc.where(p);
    return {x, origin(p)};
  }

  UndefinedCommand undefined(const json& j, const std::string& p) const {
    UndefinedCommand u;
    u.kind = str(j, "kind") == "exception" ? UndefinedCommand::Kind::exception : UndefinedCommand::Kind::ignored;
    u.code = j.value("code", 0);
    u.section = section_of(j);
    u.basis = basis(j, p, u.section);
    return u;
  }
};

// The register keys an entry names (roles, in a profile's).
std::vector<std::string*> keys_of(ControlState& x) {
  std::vector<std::string*> k;
  for (auto& m : x.status) k.push_back(&m.register_key);
  return k;
}
std::vector<std::string*> keys_of(ControlCommand& x) { return {&x.register_key}; }
std::vector<std::string*> keys_of(ControlTransition& x) {
  std::vector<std::string*> k;
  for (auto& w : x.when) k.push_back(&w.register_key);
  return k;
}
std::vector<std::string*> keys_of(ControlMode& x) {
  std::vector<std::string*> k;
  if (x.select) k.push_back(&x.select->key);
  if (!x.display_key.empty()) k.push_back(&x.display_key);
  for (auto& s : x.setpoint_keys) k.push_back(&s);
  if (!x.actual_key.empty()) k.push_back(&x.actual_key);
  if (x.done) k.push_back(&x.done->register_key);
  return k;
}

const char* kind_of(const ControlState&) { return "state"; }
const char* kind_of(const ControlCommand&) { return "command"; }
const char* kind_of(const ControlTransition&) { return "transition"; }
const char* kind_of(const ControlMode&) { return "mode"; }

// Word constraints per register (mask, value) of a list of readings; nullopt
// when two of them contradict each other.
using Constraints = std::map<std::string, std::pair<uint16_t, uint16_t>>;
std::optional<Constraints> merge(Constraints c, const std::vector<StatusMatch>& ms) {
  for (const auto& m : ms) {
    auto& [mask, value] = c[m.register_key];
    if ((value ^ m.value) & mask & m.mask) return std::nullopt;
    value = uint16_t((value & mask) | (m.value & m.mask));
    mask = uint16_t(mask | m.mask);
  }
  return c;
}

struct Builder {
  Builder(Spec& spec, const JsonDocument& d, const std::string& f, Diagnostics& o) : s(spec), doc(d), file(f), out(o) {}
  Spec& s;
  const JsonDocument& doc;
  std::string file;
  Diagnostics& out;

  std::vector<Entry<ControlState>> states;
  std::vector<Entry<ControlCommand>> commands;
  std::vector<Entry<ControlTransition>> transitions;
  std::vector<Entry<ControlMode>> modes;
  Origin initial_o, safe_o, undefined_o;
  Control c;

  // The profile, when named.
  std::optional<JsonDocument> profile_doc;
  std::string profile_file;
  std::set<std::string> roles;
  std::map<std::string, std::string> mapping;  // role -> device register key

  // Every diagnostic is a line of the device's file: one about a profile's
  // entry stands at the device's `control:` mapping (what the user wrote, and
  // can change) and names where the entry is in the profile.
  void error(const Origin& o, const std::string& sub, const std::string& rule, const std::string& msg) {
    SourceLoc l = o.loc(sub);
    if (!o.profile) {
      out.push_back({o.file, l.line, l.col, rule, msg});
      return;
    }
    SourceLoc at = doc.where(mapping_pointer());
    std::string where = std::filesystem::path(o.file).filename().string();
    if (l.line > 0) where += ":" + std::to_string(l.line) + ":" + std::to_string(l.col);
    out.push_back({file, at.line, at.col, rule, msg + " [profile entry at " + where + "]"});
  }
  Origin device(const std::string& p) const { return {&doc, file, p, false}; }

  template <class T>
  static void put(std::vector<Entry<T>>& list, Entry<T> e) {
    for (auto& x : list)
      if (x.value.id == e.value.id && x.origin.profile && !e.origin.profile) {
        x = std::move(e);  // the device overrides the profile's entry
        return;
      }
    list.push_back(std::move(e));
  }

  void read(const Reader& rd, const json& j, const std::string& p) {
    if (j.contains("states"))
      for (size_t i = 0; i < j["states"].size(); ++i) put(states, rd.state(j["states"][i], p + "/states/" + std::to_string(i)));
    if (j.contains("commands"))
      for (size_t i = 0; i < j["commands"].size(); ++i)
        put(commands, rd.command(j["commands"][i], p + "/commands/" + std::to_string(i)));
    if (j.contains("transitions"))
      for (size_t i = 0; i < j["transitions"].size(); ++i)
        put(transitions, rd.transition(j["transitions"][i], p + "/transitions/" + std::to_string(i)));
    if (j.contains("modes"))
      for (size_t i = 0; i < j["modes"].size(); ++i) put(modes, rd.mode(j["modes"][i], p + "/modes/" + std::to_string(i)));
    if (j.contains("initial")) c.initial = str(j, "initial"), initial_o = rd.origin(p + "/initial");
    if (j.contains("safe")) c.safe = str(j, "safe"), safe_o = rd.origin(p + "/safe");
    if (j.contains("undefined")) c.undefined = rd.undefined(j["undefined"], p + "/undefined"), undefined_o = rd.origin(p + "/undefined");
    if (j.contains("top_speed")) c.top_speed = j["top_speed"].get<double>();
  }

  bool load_profile(const json& ctl) {
    c.profile = str(ctl, "profile");
    profile_file = profile_path(c.profile, file);
    if (profile_file.empty()) {
      error(device("/control/profile"), "", "control-profile",
            "no library profile '" + c.profile + "' (spec/profiles/" + c.profile + ".yaml, or profiles/ of a spec directory)");
      return false;
    }
    profile_doc = load_profile_document(profile_file, out);
    if (!profile_doc) return false;
    const json& r = profile_doc->root;
    if (str(r["profile"], "id") != c.profile) {
      Origin o{&*profile_doc, profile_file, "/profile/id", true};
      error(o, "", "id-matches-file", "profile id '" + str(r["profile"], "id") + "' is not the file's name '" + c.profile + "'");
      return false;
    }
    for (const auto& [k, v] : r["roles"].items()) roles.insert(k);
    return true;
  }

  // A profile entry's roles -> the device's register keys. False when one
  // is not mapped (the entry cannot stand on this device).
  template <class T>
  bool resolve(Entry<T>& e, std::vector<std::string>& unmapped) {
    bool ok = true;
    for (std::string* k : keys_of(e.value)) {
      if (!roles.count(*k)) {
        error(e.origin, "", "control-unknown-role",
              std::string(kind_of(e.value)) + " " + e.value.id + " names '" + *k + "', which is not a role of the profile (roles:)");
        ok = false;
        continue;
      }
      auto it = mapping.find(*k);
      if (it == mapping.end()) {
        unmapped.push_back(*k);
        ok = false;
        continue;
      }
      *k = it->second;
    }
    return ok;
  }

  template <class T>
  void resolve_all(std::vector<Entry<T>>& list, bool drop_unmapped) {
    std::vector<Entry<T>> kept;
    for (auto& e : list) {
      if (!e.origin.profile) {
        kept.push_back(std::move(e));
        continue;
      }
      std::vector<std::string> unmapped;
      if (resolve(e, unmapped)) {
        kept.push_back(std::move(e));
        continue;
      }
      dropped.insert({kind_of(e.value), e.value.id});  // what names it is not told again
      if (unmapped.empty() || drop_unmapped) continue;  // a mode the device lacks: left out
      for (const auto& u : unmapped) {
        auto& users = unmapped_users[u];
        std::string who = std::string(kind_of(e.value)) + " " + e.value.id;
        if (std::find(users.begin(), users.end(), who) == users.end()) users.push_back(who);
      }
    }
    list = std::move(kept);
  }

  // One line per role the profile's entries need and control.registers does
  // not map, naming the entries that need it.
  std::map<std::string, std::vector<std::string>> unmapped_users;
  void tell_unmapped() {
    for (const auto& [role, users] : unmapped_users) {
      std::string names;
      for (size_t i = 0; i < users.size() && i < 4; ++i) names += (i ? ", " : "") + users[i];
      if (users.size() > 4) names += " and " + std::to_string(users.size() - 4) + " more";
      error(device(mapping_pointer()), "", "control-unmapped-role",
            "role '" + role + "' of profile " + c.profile + ", which control.registers does not map, is read or written by " + names +
                ": map it, or override those entries by id");
    }
  }

  std::string roles_list() const {
    std::string all;
    for (const auto& r : roles) all += (all.empty() ? "" : ", ") + r;
    return all;
  }

  // Profile entries left out because a role they use is not mapped (already
  // reported, or a mode the device lacks): (kind, id).
  std::set<std::pair<std::string, std::string>> dropped;
  bool was_dropped(const char* kind, const std::string& id) const { return dropped.count({kind, id}) > 0; }

  std::string mapping_pointer() const { return doc.root["control"].contains("registers") ? "/control/registers" : "/control/profile"; }

  void build() {
    const json& ctl = doc.root["control"];
    c.loc = doc.where("/control");
    std::string device_section = str(ctl, "section");
    if (ctl.contains("profile") && load_profile(ctl)) {
      const json& pr = profile_doc->root;
      Reader rd{*profile_doc, profile_file, true, str(pr, "section")};
      c.section = str(pr, "section");
      read(rd, pr, "");
    }
    if (!device_section.empty()) c.section = device_section;
    if (ctl.contains("registers")) {
      if (!ctl.contains("profile"))
        error(device("/control/registers"), "", "control-profile", "control.registers maps a profile's roles: name the profile (profile: <id>)");
      for (const auto& [role, key] : ctl["registers"].items()) {
        mapping[role] = key.get<std::string>();
        if (profile_doc && !roles.count(role))
          error(device("/control/registers/" + role), "", "control-unknown-role",
                "'" + role + "' is not a role of profile " + c.profile + " (its roles: " + roles_list() + ")");
        else if (profile_doc && !s.find_by_key(mapping[role]))
          error(device("/control/registers/" + role), "", "unknown-register-key",
                "role '" + role + "' is mapped to '" + mapping[role] + "', which is no register's key");
      }
    }
    Reader rd{doc, file, false, c.section};
    read(rd, ctl, "/control");
    if (profile_doc) {
      resolve_all(states, false);
      resolve_all(commands, false);
      resolve_all(transitions, false);
      resolve_all(modes, true);
      tell_unmapped();
      // A profile's condition on a role the device has not mapped: error above.
    }
    if (ctl.contains("motion")) c.motion = motion(ctl["motion"], "/control/motion");
    if (ctl.contains("no_motion")) {
      c.no_motion = Control::Unstated{str(ctl["no_motion"], "section"), str(ctl["no_motion"], "why")};
      if (c.motion)
        error(rd.origin("/control/no_motion"), "", "control-motion-unstated",
              "control has both motion: and no_motion: (why the manual gives no position move): keep the one that is true");
    }
    check();
    for (auto& e : states) c.states.push_back(e.value);
    for (auto& e : commands) c.commands.push_back(e.value);
    for (auto& e : transitions) c.transitions.push_back(e.value);
    for (auto& e : modes) c.modes.push_back(e.value);
    s.control = std::move(c);
  }

  RegisterWrite register_write(const json& j, const std::string& p) {
    RegisterWrite w;
    w.key = str(j, "register");
    w.value = j["value"].get<int64_t>();
    w.settle_us = uint64_t(j.value("settle_ms", 0.0) * 1000);
    w.section = str(j, "section");
    w.loc = doc.where(p);
    return w;
  }
  std::optional<RegisterWrite> optional_write(const json& j, const char* key, const std::string& p) {
    if (!j.contains(key)) return std::nullopt;
    return register_write(j[key], p + "/" + key);
  }

  MotionOperations motion(const json& m, const std::string& mp) {
    MotionOperations mo;
    mo.loc = doc.where(mp);
    mo.section = str(m, "section");
    for (const char* list : {"assumes", "setup"}) {
      if (!m.contains(list)) continue;
      auto& into = std::string(list) == "assumes" ? mo.assumes : mo.setup;
      for (size_t i = 0; i < m[list].size(); ++i) into.push_back(register_write(m[list][i], mp + "/" + list + "/" + std::to_string(i)));
    }
    const json& dist = m["distance"];
    mo.distance_key = str(dist, "register");
    mo.reverse_distance_key = str(dist, "reverse_register");
    mo.signed_distance = dist.value("signed", false);
    mo.max_distance = dist.value("max", int64_t(4000));
    mo.start_forward = optional_write(m, "start_forward", mp);
    mo.start_reverse = optional_write(m, "start_reverse", mp);
    mo.stop = optional_write(m, "stop", mp);
    mo.emergency_stop = optional_write(m, "emergency_stop", mp);
    mo.position_key = str(m["position"], "register");
    mo.position_high_key = str(m["position"], "high_register");
    mo.max_speed_pulses_per_s = m["max_speed_pulses_per_s"].get<double>();
    mo.decel_seconds = m["decel_seconds"].get<double>();
    if (m.contains("decel")) {
      Reader rd{doc, file, false, mo.section};
      mo.decel_basis = rd.basis(m["decel"], mp + "/decel", rd.section_of(m["decel"]));
      basis(rd.origin(mp + "/decel"), mo.decel_basis, "control.motion.decel");
    }
    const json& st = m["status"];
    mo.status_key = str(st, "register");
    mo.running_mask = st["running_mask"].get<uint16_t>();
    mo.running_when_set = st.value("running_when_set", true);
    mo.in_position_mask = st.value("in_position_mask", uint16_t(0));
    if (m.contains("positioning_needs_homing")) {
      mo.positioning_needs_homing = true;
      mo.position_command_key = str(m["positioning_needs_homing"], "position_command");
    }
    return mo;
  }

  // ---- the rules (spec/README.md, "Control": the rules spec check applies) ----

  const Register* key(const Origin& o, const std::string& sub, const std::string& k, const std::string& what) {
    const Register* r = s.find_by_key(k);
    if (!r && !o.profile)  // a profile's key is a mapped role's: told at the mapping
      error(o, sub, "unknown-register-key",
            "no register has key '" + k + "' (" + what + o.from() + ")");
    return r;
  }

  bool has_state(const std::string& id) const {
    return std::any_of(states.begin(), states.end(), [&](const auto& e) { return e.value.id == id; });
  }
  const ControlCommand* find_command(const std::string& id) const {
    for (const auto& e : commands)
      if (e.value.id == id) return &e.value;
    return nullptr;
  }

  void basis(const Origin& o, const FactBasis& b, const std::string& what) {
    if (b.basis == Basis::inferred && b.why.empty())
      error(o, "", "control-basis", what + ": an inferred entry says why (why: ...)" + o.from());
    if (b.basis == Basis::either && b.erratum.empty())
      error(o, "", "control-basis", what + ": an entry the source prints two ways cites the erratum that records it (erratum: <id>)" + o.from());
    if (!b.erratum.empty() && !o.profile && !s.find_erratum(b.erratum))
      error(o, "", "unknown-reference", what + " cites erratum '" + b.erratum + "', which errata: does not define");
  }

  template <class T>
  void unique(const std::vector<Entry<T>>& list) {
    std::set<std::string> seen;
    for (const auto& e : list)
      if (!seen.insert(e.value.id).second)
        error(e.origin, "/id", "control-duplicate-id", std::string(kind_of(e.value)) + " id '" + e.value.id + "' is declared twice");
  }

  void check() {
    unique(states);
    unique(commands);
    unique(transitions);
    unique(modes);

    // States: each reading is a pattern, and no word matches two states.
    std::vector<std::optional<Constraints>> cons;
    for (const auto& e : states) {
      const auto& x = e.value;
      bool known = true;
      for (size_t i = 0; i < x.status.size(); ++i) {
        const auto& m = x.status[i];
        std::string sub = "/status/" + std::to_string(i);
        known = key(e.origin, sub + "/register", m.register_key, "state " + x.id) && known;
        if (m.value & ~m.mask)
          error(e.origin, sub, "control-status", "state " + x.id + ": value " + hex16(m.value) + " has bits outside mask " +
                                                    hex16(m.mask) + ", so no word matches it" + e.origin.from());
      }
      auto c1 = merge({}, x.status);
      if (!c1) error(e.origin, "/status", "control-status", "state " + x.id + ": its readings contradict each other, so no word matches it");
      cons.push_back(known ? c1 : std::nullopt);
      basis(e.origin, x.basis, "state " + x.id);
    }
    for (size_t a = 0; a < states.size(); ++a)
      for (size_t b = a + 1; b < states.size(); ++b) {
        if (!cons[a] || !cons[b] || states[a].value.id == states[b].value.id) continue;
        auto both = merge(*cons[a], states[b].value.status);
        if (!both) continue;
        std::string word;
        for (const auto& [reg, mv] : *both) word += (word.empty() ? "" : ", ") + reg + " = " + hex16(mv.second);
        error(states[b].origin, "/status", "control-states-indistinguishable",
              "states " + states[a].value.id + " and " + states[b].value.id + " both match " + word +
                  ": no status reading tells them apart" + states[b].origin.from());
      }

    // Commands: one word pattern each, written to a writable register.
    for (size_t i = 0; i < commands.size(); ++i) {
      const auto& e = commands[i];
      const auto& x = e.value;
      const Register* r = key(e.origin, "/register", x.register_key, "command " + x.id);
      if (r && r->access == Access::ro)
        error(e.origin, "/register", "control-writes-read-only", "command " + x.id + " writes register '" + x.register_key + "', which is read-only");
      if (x.value & ~x.mask)
        error(e.origin, "/value", "control-command-pattern", "command " + x.id + ": value " + hex16(x.value) +
                                                                 " has bits outside mask " + hex16(x.mask) + ", so no word gives it" + e.origin.from());
      else if (x.write && !x.selected_by(*x.write))
        error(e.origin, "/write", "control-command-pattern", "command " + x.id + ": the word it writes, " + hex16(*x.write) +
                                                                 ", does not match its own pattern " + hex16(x.mask) + "/" + hex16(x.value));
      if (x.trigger == Trigger::edge && !x.edge_mask)
        error(e.origin, "", "control-command-pattern", "command " + x.id + ": an edge command names the bits whose rising edge acts (edge_mask:)");
      if (x.setpoint_keys)
        for (size_t k = 0; k < x.setpoint_keys->size(); ++k)
          key(e.origin, "/setpoints/" + std::to_string(k), (*x.setpoint_keys)[k], "command " + x.id);
      for (size_t j = 0; j < i; ++j) {
        const auto& y = commands[j].value;
        if (y.id != x.id && y.register_key == x.register_key && y.mask == x.mask && y.value == x.value && y.trigger == x.trigger)
          error(e.origin, "", "control-command-pattern", "commands " + y.id + " and " + x.id + " are one word pattern (" + hex16(x.mask) + "/" +
                                                             hex16(x.value) + "): a command id is one word pattern, and the transitions say what it does in each state");
      }
      basis(e.origin, x.basis, "command " + x.id);
    }

    // Transitions: known states and commands; automatic steps name their event.
    for (const auto& e : transitions) {
      const auto& x = e.value;
      std::string what = "transition " + x.id;
      if (x.from != "*" && !has_state(x.from) && !was_dropped("state", x.from))
        error(e.origin, "/from", "control-unknown-state", what + " starts from '" + x.from + "', which states: does not define" + e.origin.from());
      if (!has_state(x.to) && !was_dropped("state", x.to))
        error(e.origin, "/to", "control-unknown-state", what + " goes to '" + x.to + "', which states: does not define" + e.origin.from());
      const ControlCommand* cmd = nullptr;
      if (!x.command.empty() && !(cmd = find_command(x.command)) && !was_dropped("command", x.command))
        error(e.origin, "/command", "control-unknown-command", what + " is given by '" + x.command + "', which commands: does not define" + e.origin.from());
      if (x.automatic() && x.event.empty())
        error(e.origin, "", "control-automatic-needs-event", what + " has no command: an automatic step names what ends it (event: power_on, motion_done, fault, reaction_done or time)" + e.origin.from());
      if (x.motion && cmd && !cmd->motion)
        error(e.origin, "/motion", "control-moving-command", what + " moves the axis, but its command " + cmd->id +
                                                                  " is not marked motion: true (the frame policy would let it out without --allow-motion)" + e.origin.from());
      for (size_t i = 0; i < x.when.size(); ++i) key(e.origin, "/when/" + std::to_string(i) + "/register", x.when[i].register_key, what);
      basis(e.origin, x.basis, what);
    }

    // Modes: their registers, start command and states exist.
    for (const auto& e : modes) {
      const auto& x = e.value;
      std::string what = "mode " + x.id;
      if (x.select) {
        const Register* r = key(e.origin, "/select/register", x.select->key, what);
        if (r && r->access == Access::ro)
          error(e.origin, "/select/register", "control-writes-read-only", what + " is selected by a write to '" + x.select->key + "', which is read-only");
      }
      if (!x.display_key.empty()) key(e.origin, "/display", x.display_key, what);
      for (size_t i = 0; i < x.setpoint_keys.size(); ++i) key(e.origin, "/setpoints/" + std::to_string(i), x.setpoint_keys[i], what);
      if (!x.actual_key.empty()) key(e.origin, "/actual", x.actual_key, what);
      if (x.done) key(e.origin, "/done/register", x.done->register_key, what);
      if (!x.start_command.empty() && !find_command(x.start_command) && !was_dropped("command", x.start_command))
        error(e.origin, "/start", "control-unknown-command", what + " is started by '" + x.start_command + "', which commands: does not define" + e.origin.from());
      for (size_t i = 0; i < x.select_in.size(); ++i)
        if (!has_state(x.select_in[i]) && !was_dropped("state", x.select_in[i]))
          error(e.origin, "/select_in/" + std::to_string(i), "control-unknown-state", what + " is selectable in '" + x.select_in[i] + "', which states: does not define");
      basis(e.origin, x.basis, what);
    }

    // initial and safe: every state machine has both, and they are states.
    if (!states.empty()) {
      Origin here = device("/control");
      for (auto [name, id, o] : {std::tuple{"initial", &c.initial, &initial_o}, std::tuple{"safe", &c.safe, &safe_o}}) {
        if (id->empty())
          error(here, "", "control-initial-safe", std::string("control: names no ") + name + " state (" + name + ": <state id>)");
        else if (!has_state(*id) && !was_dropped("state", *id))
          error(*o, "", "control-unknown-state", std::string(name) + " state '" + *id + "' is not one of states:" + o->from());
      }
    } else if (!transitions.empty() || !commands.empty()) {
      error(device("/control"), "", "control-initial-safe", "control: has commands or transitions but no states: a state machine names its states");
    }
    // A state in which the axis may move has a command that stops it.
    bool moving = std::any_of(states.begin(), states.end(), [](const auto& e) { return e.value.motion; });
    bool stop = std::any_of(commands.begin(), commands.end(), [](const auto& e) { return e.value.stops; });
    bool command_dropped = std::any_of(dropped.begin(), dropped.end(), [](const auto& d) { return d.first == "command"; });
    if (moving && !stop && !command_dropped)  // a stop left out for an unmapped role is told already
      error(device("/control"), "", "control-stop-command",
            "a state moves the axis (motion: true) but no command stops it: mark the command that stops the axis from every moving state (stops: true)");
    if (c.undefined.kind == UndefinedCommand::Kind::exception && c.undefined.code == 0)
      error(undefined_o, "", "control-undefined", "undefined: {kind: exception} names the exception code (code: N)");
    if (undefined_o.doc) basis(undefined_o, c.undefined.basis, "undefined");
  }
};

}  // namespace

void build_control(Spec& s, const JsonDocument& doc, const std::string& file, Diagnostics& out) {
  if (!doc.root.contains("control")) return;
  Builder b(s, doc, file, out);
  b.build();
}

}  // namespace mbc::spec
