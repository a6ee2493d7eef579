#include "errata.h"

#include "erratum_extra.h"

#include <algorithm>
#include <map>
#include <set>
#include <sstream>

#include "modbus/crc16.h"
#include "modbus/hex.h"
#include "modbus/rtu.h"

namespace mbc::spec {
namespace {

using nlohmann::json;

json frame_entry(const Example& e, const std::string& role, const std::string& hex) {
  json f{{"example", e.id}, {"section", e.section}, {"role", role}, {"hex", hex}};
  auto bytes = parse_hex(hex);
  if (!bytes || bytes->size() < 3) {
    f["crc_ok"] = false;
    f["crc_correct"] = nullptr;
    f["problem"] = "too short to carry a CRC";
    return f;
  }
  std::span<const uint8_t> body(bytes->data(), bytes->size() - 2);
  uint16_t c = crc16(body);
  uint8_t lo = uint8_t(c & 0xFF), hi = uint8_t(c >> 8);
  bool ok = (*bytes)[bytes->size() - 2] == lo && (*bytes)[bytes->size() - 1] == hi;
  f["crc_ok"] = ok;
  f["crc_printed"] = to_hex(std::span<const uint8_t>(bytes->data() + bytes->size() - 2, 2));
  uint8_t correct[2] = {lo, hi};
  f["crc_correct"] = to_hex(correct);
  if (!ok) {
    Bytes fixed(body.begin(), body.end());
    fixed.push_back(lo);
    fixed.push_back(hi);
    f["corrected_frame"] = to_hex(fixed);
    // Printed with the two CRC bytes swapped?
    if ((*bytes)[bytes->size() - 2] == hi && (*bytes)[bytes->size() - 1] == lo) f["problem"] = "CRC bytes printed high byte first";
  }
  // MB-SL v1.02 §2.5.1.1 with MBAP v1.1b3 §6; 0 when it depends on more than the frame says.
  size_t want = rtu_adu_length(*bytes, role == "request" ? Direction::request : Direction::reply).value_or(0);
  f["length_ok"] = want == 0 || want == bytes->size();
  if (want && want != bytes->size())
    f["problem"] = std::to_string(bytes->size()) + " bytes where a function " + std::to_string((*bytes)[1] & 0x7F) + " " +
                   role + " has " + std::to_string(want) + ": the CRC check is meaningless until the missing or extra bytes are known";
  f["errata"] = e.errata;
  return f;
}

std::string policy_text(const PolicyEntry& e) {
  switch (e.kind) {
    case PolicyEntry::Kind::exception: return "exception " + std::to_string(e.code);
    case PolicyEntry::Kind::silent: return "no reply";
    case PolicyEntry::Kind::unspecified: return "not stated";
  }
  return "?";
}

bool requires_two_stop_bits_violation(const std::string& f) { return f.size() == 3 && f[1] == 'N' && f[2] == '1'; }

json deviations(const Spec& d, const Spec& std_) {
  json out = json::array();
  auto add = [&](std::string topic, std::string device, std::string standard, std::string clause, std::string section) {
    out.push_back({{"topic", std::move(topic)}, {"device", std::move(device)}, {"standard", std::move(standard)},
                   {"clause", std::move(clause)}, {"section", std::move(section)}});
  };
  if (d.device.id == std_.device.id) return out;

  // Serial framing: MB over Serial Line v1.02 §2.5.1: 11 bits per character;
  // no parity requires two stop bits; even parity is the default.
  for (const auto& f : d.serial.frame_formats)
    if (requires_two_stop_bits_violation(f))
      add("serial.frame_format", f + " (no parity, 1 stop bit: 10-bit characters)",
          "no parity requires 2 stop bits (8N2); even parity (8E1) is the default", "MB-SL v1.02 §2.5.1", d.serial.frame_section);
  if (std::find(d.serial.frame_formats.begin(), d.serial.frame_formats.end(), "8E1") == d.serial.frame_formats.end())
    add("serial.frame_format", "even parity (8E1) not offered", "even parity is required", "MB-SL v1.02 §2.5.1", d.serial.frame_section);
  for (int baud : {9600, 19200})
    if (std::find(d.serial.baud_rates.begin(), d.serial.baud_rates.end(), baud) == d.serial.baud_rates.end())
      add("serial.baud_rate", std::to_string(baud) + " bit/s not offered", std::to_string(baud) + " bit/s is required",
          "MB-SL v1.02 §2.5.1", d.serial.baud_section);
  if (d.serial.baud_default && std_.serial.baud_default && *d.serial.baud_default != *std_.serial.baud_default)
    add("serial.baud_rate.default", std::to_string(*d.serial.baud_default), std::to_string(*std_.serial.baud_default),
        "MB-SL v1.02 §2.5.1", d.serial.baud_section);
  if (d.serial.slave_min != std_.serial.slave_min || d.serial.slave_max != std_.serial.slave_max)
    add("serial.slave_id", std::to_string(d.serial.slave_min) + ".." + std::to_string(d.serial.slave_max),
        std::to_string(std_.serial.slave_min) + ".." + std::to_string(std_.serial.slave_max), "MB-SL v1.02 §2.2",
        d.serial.slave_section);
  if (d.serial.slave_default && *d.serial.slave_default == 0)
    add("serial.slave_id.default", "0 (the broadcast address)", "a unicast address 1..247", "MB-SL v1.02 §2.2", d.serial.slave_section);
  if (d.serial.broadcast_writes != std_.serial.broadcast_writes || d.serial.broadcast_reply != std_.serial.broadcast_reply)
    add("serial.broadcast", "writes " + d.serial.broadcast_writes + ", reply " + d.serial.broadcast_reply,
        "writes " + std_.serial.broadcast_writes + ", reply " + std_.serial.broadcast_reply, "MB-SL v1.02 §2.1",
        d.serial.broadcast_section);

  // Function codes and their limits.
  for (const auto& f : d.profile.function_codes) {
    const FunctionCode* s = std_.profile.function(f.code);
    if (!s) {
      add("function_code." + std::to_string(f.code), "supported", "not a public function code of MBAP v1.1b3", "MBAP v1.1b3 §5.1", f.section);
      continue;
    }
    if (s->max_quantity && f.max_quantity && *f.max_quantity != *s->max_quantity)
      add("function_code." + std::to_string(f.code) + ".max_quantity", std::to_string(*f.max_quantity),
          std::to_string(*s->max_quantity), s->section, f.section);
    if (s->max_quantity && !f.max_quantity)
      add("function_code." + std::to_string(f.code) + ".max_quantity", "not stated", std::to_string(*s->max_quantity), s->section, f.section);
  }

  // Exception policy, kind by kind.
  for (Violation v : kAllViolations) {
    PolicyEntry a = d.profile.policy(v), b = std_.profile.policy(v);
    bool same = a.kind == b.kind && (a.kind != PolicyEntry::Kind::exception || a.code == b.code);
    if (!same)
      add(std::string("exception_policy.") + to_string(v), policy_text(a), policy_text(b), b.section, a.section);
  }
  // Exception codes given a meaning of the device's own.
  for (const auto& c : d.profile.exception_codes) {
    static const char* standard_names[] = {"", "ILLEGAL FUNCTION", "ILLEGAL DATA ADDRESS", "ILLEGAL DATA VALUE", "SERVER DEVICE FAILURE",
                                           "ACKNOWLEDGE", "SERVER DEVICE BUSY", "", "MEMORY PARITY ERROR"};
    std::string std_name = c.code >= 1 && c.code <= 8 ? standard_names[c.code] : "";
    add("exception_code." + std::to_string(c.code), c.name.en + (c.name.zh.empty() ? "" : " (" + c.name.zh + ")"),
        std_name.empty() ? "not defined" : std_name, "MBAP v1.1b3 §7", c.section);
  }
  return out;
}

// Every fact the spec states, infers, observed or prints two ways
// (spec/README.md, "Where each fact comes from"), with the inferred and
// either ones listed.
json fact_bases(const Spec& d) {
  std::map<std::string, int> count{{"stated", 0}, {"inferred", 0}, {"observed", 0}, {"either", 0}};
  json inferred = json::array(), either = json::array();
  auto add = [&](const std::string& fact, const FactBasis& b) {
    count[to_string(b.basis)]++;
    json e{{"fact", fact}, {"basis", to_string(b.basis)}, {"section", b.section}};
    if (b.basis == Basis::either) {
      e["readings"] = b.readings;
      e["erratum"] = b.erratum;
      if (words_only(b)) e["outcomes"] = true;  // no expectation holds both: its cases are OBSERVED
      either.push_back(e);
    } else if (b.is_inferred()) {
      e["why"] = b.why;
      if (!b.searched.empty()) e["searched"] = b.searched;
      inferred.push_back(e);
    }
  };
  for (const auto& r : d.registers) {
    if (r.block_index > 0) continue;  // a block's facts are stated once
    std::string reg = std::string(r.table == Table::holding ? "" : std::string(to_string(r.table)) + " ") + "register " +
                      std::to_string(r.address) + (r.block_index == 0 ? " (block)" : "");
    for (Fact f : kRegisterFacts) {
      bool present = r.basis.count(f) > 0 || f == Fact::read || f == Fact::write || f == Fact::type ||
                     (f == Fact::range && r.range) || (f == Fact::default_value && r.default_value) ||
                     (f == Fact::word_order && r.words == 2) ||
                     (f == Fact::takes_effect && r.takes_effect != TakesEffect::immediate) ||
                     (f == Fact::persistence && r.persistence.store != Store::none);
      if (present) add(reg + " " + to_string(f), r.basis_of(f));
    }
  }
  for (const auto& f : d.profile.function_codes) add("FC " + std::to_string(f.code) + " supported", f.basis_of("supported"));
  for (const auto& f : d.profile.function_codes)
    for (const char* k : {"max_quantity", "max_read_quantity", "max_write_quantity"}) {
      bool set = std::string(k) == "max_quantity" ? bool(f.max_quantity)
                 : std::string(k) == "max_read_quantity" ? bool(f.max_read_quantity) : bool(f.max_write_quantity);
      if (set) add("FC " + std::to_string(f.code) + " " + k, f.basis_of(k));
    }
  for (Violation v : kAllViolations) {
    PolicyEntry p = d.profile.policy(v);
    if (p.kind != PolicyEntry::Kind::unspecified || p.basis.basis == Basis::either)
      add(std::string("exception_policy.") + to_string(v), p.basis);
  }
  for (const auto& e : d.examples) add("example " + e.id, e.basis);
  return {{"stated", count["stated"]}, {"inferred", count["inferred"]}, {"observed", count["observed"]},
          {"either", count["either"]}, {"inferred_facts", inferred}, {"either_facts", either}};
}

}  // namespace

nlohmann::json errata_report(const Spec& d, const Spec& standard, const nlohmann::json& demoted) {
  json r;
  r["device"] = {{"id", d.device.id}, {"vendor", d.device.vendor}, {"title", d.device.title}, {"models", d.device.models}};
  r["manual"] = {{"file", d.device.manual.file}, {"address_notation", d.device.manual.address_notation},
                 {"addressing_note", d.device.manual.addressing_note}};
  json frames = json::array();
  for (const auto& e : d.examples) {
    frames.push_back(frame_entry(e, "request", e.request));
    if (e.response) frames.push_back(frame_entry(e, "response", *e.response));
  }
  r["frames"] = frames;
  json contradictions = json::array();
  for (const auto& e : d.errata) {
    json refs = json::array();
    for (const auto& reg : d.registers)
      if (reg.block_index <= 0 && std::find(reg.errata.begin(), reg.errata.end(), e.id) != reg.errata.end())
        refs.push_back("register " + std::to_string(reg.address));
    for (const auto& ex : d.examples)
      if (std::find(ex.errata.begin(), ex.errata.end(), e.id) != ex.errata.end()) refs.push_back("example " + ex.id);
    if (d.device.manual.erratum == e.id) refs.push_back("every register address (device.manual.addressing_note)");
    for (const auto& [v, p] : d.profile.exception_policy)
      if (p.erratum == e.id || p.basis.erratum == e.id) refs.push_back(std::string("exception_policy.") + to_string(v));
    for (const auto& f : d.profile.function_codes)
      if (f.erratum == e.id) refs.push_back("FC " + std::to_string(f.code));
    ErratumExtra x = erratum_extra(d, e.id);
    json c{{"id", e.id}, {"section", e.section}, {"kind", e.kind}, {"class", x.cls}, {"printed", e.printed},
           {"resolved", e.resolved}, {"why", e.why}, {"affects", refs}};
    if (e.contests_given) c["contests"] = e.contests;
    if (!x.about.empty()) c["about"] = x.about;
    if (!x.decided_by.empty()) c["decided_by"] = x.decided_by;
    if (!e.settled_by.empty()) c["settled_by"] = e.settled_by;
    contradictions.push_back(std::move(c));
  }
  r["errata"] = contradictions;
  r["deviations"] = deviations(d, standard);
  r["facts"] = fact_bases(d);
  r["observed_cases"] = demoted;
  auto of_class = [&](const char* k) {
    return std::count_if(d.errata.begin(), d.errata.end(), [&](const Erratum& e) { return erratum_extra(d, e.id).cls == k; });
  };
  size_t bad = std::count_if(frames.begin(), frames.end(), [](const json& f) { return !f["crc_ok"].get<bool>(); });
  size_t bad_len = std::count_if(frames.begin(), frames.end(), [](const json& f) { return !f.value("length_ok", true); });
  r["summary"] = {{"frames", frames.size()}, {"frames_bad_crc", bad}, {"frames_bad_length", bad_len}, {"errata", d.errata.size()},
                  {"contradictions", of_class("contradiction")}, {"typos", of_class("typo")}, {"nits", of_class("nit")},
                  {"deviations", r["deviations"].size()}, {"registers", d.registers.size()}, {"examples", d.examples.size()},
                  {"facts_stated", r["facts"]["stated"]}, {"facts_inferred", r["facts"]["inferred"].get<int>() + r["facts"]["observed"].get<int>()},
                  {"facts_either", r["facts"]["either"]}, {"cases_observed_by_inference", demoted.size()}};
  return r;
}

std::string errata_markdown(const nlohmann::json& r) {
  std::ostringstream o;
  auto cell = [](std::string s) {
    for (size_t i = 0; (i = s.find('|', i)) != std::string::npos; i += 2) s.replace(i, 1, "\\|");
    std::replace(s.begin(), s.end(), '\n', ' ');
    return s;
  };
  const json& d = r["device"];
  o << "# Manual errata: " << d["title"].get<std::string>() << " (`" << d["id"].get<std::string>() << "`)\n\n";
  o << "Generated by `mbconform spec errata` from `spec/devices/" << d["id"].get<std::string>()
    << ".yaml`; do not edit by hand.\n\n";
  o << "- Vendor: " << d["vendor"].get<std::string>() << "\n- Manual: `" << r["manual"]["file"].get<std::string>()
    << "` (register numbers printed in " << r["manual"]["address_notation"].get<std::string>() << ")\n";
  if (!r["manual"]["addressing_note"].get<std::string>().empty())
    o << "- Addressing: " << r["manual"]["addressing_note"].get<std::string>() << "\n";
  const json& s = r["summary"];
  o << "- " << s["frames"] << " printed frames, " << s["frames_bad_crc"] << " with a wrong CRC, " << s["frames_bad_length"]
    << " with a wrong length; " << s["errata"] << " errata (" << s.value("contradictions", 0) << " contradictions, "
    << s.value("typos", 0) << " typo" << (s.value("typos", 0) == 1 ? "" : "s") << ", " << s.value("nits", 0) << " nit"
    << (s.value("nits", 0) == 1 ? "" : "s") << "); " << s["deviations"]
    << " deviations from modbus-standard\n\n";

  o << "## Printed frames, CRC checked\n\n| example | section | role | frame as printed | CRC | correct CRC |\n|---|---|---|---|---|---|\n";
  for (const auto& f : r["frames"]) {
    bool ok = f["crc_ok"].get<bool>();
    o << "| " << cell(f["example"]) << " | " << cell(f["section"]) << " | " << f["role"].get<std::string>() << " | `"
      << f["hex"].get<std::string>() << "` | " << (ok ? "ok" : "**wrong**") << " | "
      << (f["crc_correct"].is_null() ? std::string("-") : (ok ? "" : "`" + f["crc_correct"].get<std::string>() + "`"));
    if (f.contains("problem")) o << " " << f["problem"].get<std::string>();
    o << " |\n";
  }
  // Contradictions first, then typos and nits in a class of their own, so
  // the contradiction count means what it says.
  auto erratum = [&](const json& e) {
    o << "### " << e["id"].get<std::string>() << " (§" << e["section"].get<std::string>() << ", " << e["kind"].get<std::string>()
      << ")\n\n";
    o << "- **Printed:** " << e["printed"].get<std::string>() << "\n";
    if (e.value("class", std::string("contradiction")) != "contradiction") o << "- **Class:** " << e["class"].get<std::string>() << "\n";
    o << "- **Resolved:** " << e["resolved"].get<std::string>() << "\n";
    o << "- **Why:** " << e["why"].get<std::string>() << "\n";
    if (e.contains("settled_by")) {
      o << "- **Settled by the printed frame" << (e["settled_by"].size() > 1 ? "s" : "") << ":** ";
      bool first = true;
      for (const auto& a : e["settled_by"]) o << (first ? "" : ", ") << "`" << a.get<std::string>() << "`", first = false;
      o << " (a fact it names may support a MUST case)";
      if (e.contains("decided_by")) o << "; the standard decides: " << e["decided_by"].get<std::string>();
      o << "\n";
    } else if (e.contains("contests") && e["contests"].empty()) {
      o << "- **Contests:** nothing a case relies on (recorded only)";
      if (e.contains("about")) {
        o << "; about the citers' ";
        bool first = true;
        for (const auto& a : e["about"]) o << (first ? "" : ", ") << a.get<std::string>(), first = false;
      }
      o << "\n";
    } else if (e.contains("contests")) {
      o << "- **Contests:** ";
      bool first = true;
      for (const auto& a : e["contests"]) o << (first ? "" : ", ") << a.get<std::string>(), first = false;
      o << " of what cites it (either or inferred there; never a MUST)\n";
    }
    if (!e["affects"].empty()) {
      o << "- **Affects:** ";
      bool first = true;
      for (const auto& a : e["affects"]) {
        o << (first ? "" : ", ") << a.get<std::string>();
        first = false;
      }
      o << "\n";
    }
    o << "\n";
  };
  auto section = [&](const char* title, auto keep) {
    o << "\n## " << title << "\n\n";
    size_t n = 0;
    for (const auto& e : r["errata"])
      if (keep(e.value("class", std::string("contradiction")))) erratum(e), ++n;
    if (!n) o << "None recorded.\n";
  };
  section("Contradictions and their resolution", [](const std::string& c) { return c == "contradiction"; });
  section("Typos and nits (not contradictions)", [](const std::string& c) { return c != "contradiction"; });
  const json& fb = r["facts"];
  o << "## Where the facts come from\n\n" << fb["stated"] << " stated, " << fb["inferred"] << " inferred, " << fb["observed"]
    << " observed, " << fb["either"] << " printed two ways (spec/README.md, \"Where each fact comes from\"). A case relying on an "
    << "inferred or observed fact is OBSERVED; one relying on a fact printed two ways passes on either reading.\n\n";
  if (!fb["inferred_facts"].empty()) {
    o << "| inferred fact | section | why | searched |\n|---|---|---|---|\n";
    for (const auto& f : fb["inferred_facts"])
      o << "| " << cell(f["fact"]) << (f["basis"] == "observed" ? " (observed)" : "") << " | " << cell(f["section"]) << " | "
        << cell(f["why"]) << " | " << cell(f.value("searched", std::string())) << " |\n";
    o << "\n";
  }
  if (!fb["either_facts"].empty()) {
    o << "| fact printed two ways | section | readings | erratum |\n|---|---|---|---|\n";
    for (const auto& f : fb["either_facts"]) {
      std::string rs;
      for (const auto& x : f["readings"]) rs += (rs.empty() ? "" : " / ") + x.get<std::string>();
      o << "| " << cell(f["fact"]) << (f.value("outcomes", false) ? " (OBSERVED: no one expectation holds both)" : "") << " | "
        << cell(f["section"]) << " | " << cell(rs) << " | " << cell(f["erratum"]) << " |\n";
    }
    o << "\n";
  }
  if (r.contains("observed_cases") && !r["observed_cases"].empty()) {
    o << "## Cases OBSERVED because a fact is inferred\n\n" << r["observed_cases"].size()
      << " cases would be MUST or SHOULD if every fact they rely on were stated; each is run and recorded, never failed. "
      << "The inferred facts, why, and the sections searched for a statement:\n\n";
    o << "| case | would be | inferred fact | why | sections searched |\n|---|---|---|---|---|\n";
    for (const auto& c : r["observed_cases"]) {
      bool first = true;
      for (const auto& f : c["facts"]) {
        o << "| " << (first ? "`" + c["case"].get<std::string>() + "`" : std::string("")) << " | "
          << (first ? c["level_if_stated"].get<std::string>() : std::string("")) << " | " << cell(f["fact"])
          << (f["basis"] == "observed" ? " (observed)" : "") << " | " << cell(f.value("why", std::string())) << " | "
          << cell(f.value("searched", std::string())) << " |\n";
        first = false;
      }
    }
    o << "\n";
  }
  o << "## Deviations from modbus-standard\n\n";
  if (r["deviations"].empty()) o << "None.\n";
  else {
    o << "| topic | this device | the standard | clause | manual section |\n|---|---|---|---|---|\n";
    for (const auto& v : r["deviations"])
      o << "| " << cell(v["topic"]) << " | " << cell(v["device"]) << " | " << cell(v["standard"]) << " | " << cell(v["clause"])
        << " | " << cell(v["section"]) << " |\n";
  }
  return o.str();
}

}  // namespace mbc::spec
