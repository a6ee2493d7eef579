// The qualification summary that opens report.html: what an integrator files.
// One banner with the verdict; per device its identity (the FC 43 objects the
// run read, else the spec's), firmware, target and line settings; the counts
// by level with the share that is only OBSERVED and why; the MUST failures
// grouped by cause with register names and a command that replays them; the
// manual's errata the run touched; the skipped families with the flag that
// enables each. A print stylesheet (html.cpp) keeps it to two A4 pages.
#include <fmt/core.h>
#include <fmt/format.h>

#include <algorithm>
#include <map>
#include <set>

#include "modbus/framing.h"
#include "report/html_util.h"
#include "report/report.h"

namespace mbc::conf::html {
namespace {

// How many of each list the summary shows before "and N more below".
constexpr size_t kShown = 6;

// The PDU inside a framed request or reply: MBAP has a 7-byte header, RTU a
// slave byte before and a CRC after.
std::optional<Bytes> pdu_of(const Bytes& frame, bool mbap) {
  // modbus/'s framing: what an ADU carries, even when its CRC or length is wrong.
  Unframed u = (mbap ? kTcp : kRtu).unframe(frame);
  if (u.pdu.empty()) return std::nullopt;
  return u.pdu;
}

bool is_mbap(const DeviceRun& d) { return d.target_uri.rfind("tcp://", 0) == 0; }

// The identification objects a FC 43 / MEI 0E reply of the run carried
// (MBAP v1.1b3 §6.21): object id -> value.
std::vector<std::pair<std::string, std::string>> identity_read(const DeviceRun& d) {
  static const char* kNames[] = {"VendorName", "ProductCode", "MajorMinorRevision", "VendorUrl", "ProductName", "ModelName",
                                 "UserApplicationName"};
  std::map<int, std::string> objects;
  for (const auto& r : d.cases)
    for (const auto& f : r.frames) {
      if (!f.actual) continue;
      auto rq = pdu_of(f.request, is_mbap(d));
      auto rp = pdu_of(*f.actual, is_mbap(d));
      if (!rq || !rp || rq->size() < 2 || (*rq)[0] != 0x2B || (*rq)[1] != 0x0E) continue;
      const Bytes& p = *rp;
      if (p.size() < 7 || p[0] != 0x2B || p[1] != 0x0E) continue;
      size_t at = 7, n = p[6];
      for (size_t i = 0; i < n && at + 2 <= p.size(); ++i) {
        int id = p[at];
        size_t len = p[at + 1];
        if (at + 2 + len > p.size()) break;
        objects.emplace(id, std::string(p.begin() + long(at) + 2, p.begin() + long(at + 2 + len)));
        at += 2 + len;
      }
    }
  std::vector<std::pair<std::string, std::string>> out;
  for (const auto& [id, v] : objects)
    out.emplace_back(id < 7 ? kNames[id] : fmt::format("object 0x{:02X}", id), v);
  return out;
}

// The value a FC 03 read of `address` got in the run, if one did.
std::optional<uint16_t> value_read(const DeviceRun& d, uint16_t address) {
  for (const auto& r : d.cases)
    for (const auto& f : r.frames) {
      if (!f.actual) continue;
      auto rq = pdu_of(f.request, is_mbap(d));
      auto rp = pdu_of(*f.actual, is_mbap(d));
      if (!rq || !rp || rq->size() < 5 || (*rq)[0] != 3 || uint16_t((*rq)[1] << 8 | (*rq)[2]) != address) continue;
      if (rp->size() >= 4 && (*rp)[0] == 3 && (*rp)[1] >= 2) return uint16_t((*rp)[2] << 8 | (*rp)[3]);
    }
  return std::nullopt;
}

// Why a case is only OBSERVED: the facts it relies on that the manual does
// not state (cases/facts.cpp appends " [relies on ...]"), else the level the
// generator gave it (a reading the manual leaves open, a deviation from
// modbus-standard).
std::string observed_why(const CaseResult& r) {
  auto at = r.requirement.find(" [relies on ");
  if (at != std::string::npos) {
    std::string s = r.requirement.substr(at + 12);
    if (!s.empty() && s.back() == ']') s.pop_back();
    // One reason per fact: "range: inferred (why...)" -> "range: inferred"
    std::string fact = s.substr(0, s.find(" ("));
    if (auto semi = fact.find(';'); semi != std::string::npos) fact.resize(semi);
    return "relies on a fact the manual does not state (" + fact + ")";
  }
  if (r.family == "deviations") return "a deviation from modbus-standard, recorded";
  return "the manual leaves the behaviour open (" + r.family + ")";
}

template <class Map>
std::vector<std::pair<std::string, size_t>> by_count(const Map& m) {
  std::vector<std::pair<std::string, size_t>> v;
  for (const auto& [k, n] : m) v.emplace_back(k, n.size());
  std::stable_sort(v.begin(), v.end(), [](const auto& a, const auto& b) { return a.second > b.second; });
  return v;
}

std::string device_summary(const RunReport& rep, const DeviceRun& d) {
  std::string h = fmt::format("<section class=device-summary data-device=\"{0}\"><h2>{1} <small>{0}</small></h2>", esc(d.device_id),
                              esc(d.facts.title.empty() ? d.device_id : d.facts.title));
  // Identity.
  h += "<table class=facts>";
  auto read = identity_read(d);
  if (!read.empty()) {
    std::string s;
    for (const auto& [k, v] : read) s += fmt::format("{}{}: <b>{}</b>", s.empty() ? "" : " · ", esc(k), esc(v));
    h += "<tr><th>Identity (FC 43, read)</th><td class=identity>" + s + "</td></tr>";
  } else if (!d.facts.identity.empty()) {
    std::string s;
    for (const auto& [k, v] : d.facts.identity) s += fmt::format("{}{}: {}", s.empty() ? "" : " · ", esc(k), esc(v));
    h += "<tr><th>Identity (the spec's)</th><td class=identity>" + s + " <i>(no FC 43 reply in this run)</i></td></tr>";
  } else {
    h += "<tr><th>Identity</th><td class=identity><i>no FC 43 reply in this run; the spec states no objects</i></td></tr>";
  }
  std::string fw;
  for (uint16_t a : d.facts.firmware_registers) {
    auto name = d.facts.register_names.count(a) ? d.facts.register_names.at(a) : "";
    auto v = value_read(d, a);
    fw += fmt::format("{}0x{:04X} {}: {}", fw.empty() ? "" : " · ", a, esc(name),
                      v ? fmt::format("<b>{}</b> (0x{:04X})", *v, *v) : std::string("<i>not read in this run</i>"));
  }
  h += "<tr><th>Firmware</th><td class=firmware>" + (fw.empty() ? std::string("<i>the spec names no firmware register</i>") : fw) + "</td></tr>";
  h += fmt::format("<tr><th>Target</th><td><code>{}</code>{}</td></tr>", esc(d.target_uri),
                   d.baud ? fmt::format(" · {} baud on the line", *d.baud) : "");
  if (!d.facts.line.empty()) h += "<tr><th>Line settings</th><td>" + esc(d.facts.line) + "</td></tr>";
  h += "<tr><th>Spec</th><td><code>" + esc(d.spec_path) + "</code></td></tr>";
  for (const auto& n : d.notes)
    if (n.rfind("PARTIAL", 0) == 0 || n.rfind("DEVIATION", 0) == 0) h += "<tr><th>Note</th><td class=fail>" + esc(n) + "</td></tr>";
  if (!d.error.empty()) h += "<tr><th>Run stopped</th><td class=fail>" + esc(d.error) + "</td></tr>";
  h += "</table>";

  // Counts by level.
  struct Row { size_t cases = 0, pass = 0, fail = 0, observed = 0, skip = 0, error = 0, quirk = 0; };
  std::map<Level, Row> rows;
  size_t total = 0, observed_level = 0;
  std::map<std::string, std::vector<const CaseResult*>> why;
  for (const auto& r : d.cases) {
    Row& row = rows[r.level];
    ++row.cases;
    ++total;
    switch (r.outcome) {
      case Outcome::pass: ++row.pass; break;
      case Outcome::fail: (r.quirk.empty() ? row.fail : row.quirk)++; break;
      case Outcome::observed: ++row.observed; break;
      case Outcome::skip: ++row.skip; break;
      case Outcome::error: ++row.error; break;
    }
    if (r.level == Level::observed) {
      ++observed_level;
      why[observed_why(r)].push_back(&r);
    }
  }
  h += "<table class=counts><tr><th>level</th><th>cases</th><th>pass</th><th>fail</th><th>recorded</th><th>skipped</th><th>not run</th></tr>";
  for (Level l : {Level::must, Level::should, Level::observed}) {
    const Row& r = rows[l];
    bool failing = l == Level::must || (l == Level::should && rep.fail_on_should);
    h += fmt::format("<tr data-level={0}><th>{0}</th><td>{1}</td><td>{2}</td><td class={3}>{4}{5}</td><td>{6}</td><td>{7}</td><td>{8}</td></tr>",
                     to_string(l), r.cases, r.pass, r.fail ? (failing ? "fail" : "observed") : "", r.fail,
                     r.quirk ? fmt::format(" (+{} declared quirks)", r.quirk) : "", r.observed, r.skip, r.error);
  }
  h += "</table>";
  if (total) {
    double share = 100.0 * double(observed_level) / double(total);
    h += fmt::format("<p class=observed-share><b>{:.0f}% of the cases ({} of {}) are only OBSERVED</b>: recorded, never failed, "
                     "because they rest on what the manual does not state.",
                     share, observed_level, total);
    if (!why.empty()) {
      h += " Why:</p><ul class=why>";
      auto v = by_count(why);
      for (size_t i = 0; i < v.size() && i < kShown - 2; ++i) h += fmt::format("<li>{} cases: {}</li>", v[i].second, esc(v[i].first));
      if (v.size() > kShown - 2) h += fmt::format("<li>{} more reasons below</li>", v.size() - (kShown - 2));
      h += "</ul>";
    } else {
      h += "</p>";
    }
  }

  // MUST failures grouped by cause: what the device did against what was due.
  auto causes = failure_causes(rep, d);
  if (!causes.empty()) {
    size_t n = 0;
    for (const auto& g : causes) n += g.cases.size();
    h += fmt::format("<h3>{} failing case{}, {} cause{}</h3><table class=causes><tr><th>cases</th><th>cause</th><th>function codes</th>"
                     "<th>registers</th><th>replay (all of them)</th></tr>",
                     n, n == 1 ? "" : "s", causes.size(), causes.size() == 1 ? "" : "s");
    for (size_t i = 0; i < causes.size() && i < kShown; ++i) {
      const CauseGroup& g = causes[i];
      std::string rs;
      size_t shown = 0;
      for (uint16_t a : g.registers) {
        if (shown++ == 4) {
          rs += fmt::format(" and {} more", g.registers.size() - 4);
          break;
        }
        auto it = d.facts.register_names.find(a);
        rs += fmt::format("{}0x{:04X}{}", rs.empty() ? "" : ", ", a, it == d.facts.register_names.end() ? "" : " " + esc(it->second));
      }
      std::string fs;
      for (int fc : g.function_codes) fs += fmt::format("{}{:02}", fs.empty() ? "FC " : ", ", fc);
      const CaseResult& first = *g.cases.front();
      h += fmt::format("<tr class=fail><td>{}</td><td class=cause>{}<br><small>e.g. {}: {}</small></td><td class=fcs>{}</td><td>{}</td>"
                       "<td><code class=replay>{}</code></td></tr>",
                       g.cases.size(), esc(g.text), esc(first.id), esc(first.message), fs.empty() ? "—" : fs, rs.empty() ? "—" : rs,
                       esc(g.replay));
    }
    if (causes.size() > kShown) h += fmt::format("<tr><td colspan=5>{} more causes: see report.json</td></tr>", causes.size() - kShown);
    h += "</table>";
  }

  // Errata the run touched: those the cases that ran rely on.
  std::map<std::string, std::vector<const CaseResult*>> errata;
  for (const auto& r : d.cases)
    if (r.outcome != Outcome::skip && r.outcome != Outcome::error)
      for (const auto& e : r.errata) errata[e].push_back(&r);
  if (!errata.empty()) {
    h += "<h3>The manual's errata this run touched</h3><ul class=errata>";
    size_t i = 0;
    for (const auto& [id, cases] : errata) {
      if (i++ == kShown) {
        h += fmt::format("<li>{} more (report.json)</li>", errata.size() - kShown);
        break;
      }
      auto it = d.facts.errata.find(id);
      h += fmt::format("<li><b>{}</b> ({} case{}): {}</li>", esc(id), cases.size(), cases.size() == 1 ? "" : "s",
                       it == d.facts.errata.end() ? "" : esc(it->second));
    }
    h += "</ul>";
  }

  // Skipped families, with the flag that enables each.
  std::map<std::string, std::vector<const CaseResult*>> skipped;
  for (const auto& r : d.cases) {
    if (r.outcome != Outcome::skip) continue;
    std::string how = !r.opt_in.empty() ? "enable with " + r.opt_in : "not applicable: " + r.message;
    skipped[r.family + " — " + how].push_back(&r);
  }
  if (!skipped.empty()) {
    h += "<h3>Skipped</h3><ul class=skipped>";
    auto v = by_count(skipped);
    // What a flag would enable first: that is what the integrator can act on.
    std::stable_sort(v.begin(), v.end(), [](const auto& a, const auto& b) {
      return (a.first.find("enable with") != std::string::npos) > (b.first.find("enable with") != std::string::npos);
    });
    for (size_t i = 0; i < v.size() && i < kShown; ++i) h += fmt::format("<li>{} cases: {}</li>", v[i].second, esc(v[i].first));
    if (v.size() > kShown) h += fmt::format("<li>{} more reasons below</li>", v.size() - kShown);
    h += "</ul>";
  }
  return h + "</section>";
}

}  // namespace

std::string byte_diff(const Bytes& expected, const std::optional<Bytes>& actual) {
  if (!actual) return "<span class=diff>silence</span>";
  std::string e, a;
  size_t n = std::max(expected.size(), actual->size());
  for (size_t i = 0; i < n; ++i) {
    bool same = i < expected.size() && i < actual->size() && expected[i] == (*actual)[i];
    auto byte = [&](std::string& out, uint8_t b) {
      out += (out.empty() ? "" : " ") + (same ? fmt::format("{:02X}", b) : fmt::format("<mark>{:02X}</mark>", b));
    };
    if (i < expected.size()) byte(e, expected[i]);
    if (i < actual->size()) byte(a, (*actual)[i]);
  }
  return "<code class=diff>expected " + e + "<br>actual&nbsp;&nbsp; " + a + "</code>";
}

std::string summary(const RunReport& rep) {
  // One verdict for every report (report/result.h): its word, its line.
  Verdict v = verdict(rep);
  std::string word = v.word();
  std::string cls = word == "PASS" ? "pass" : word == "FAIL" ? "fail" : word == "PARTIAL" ? "partial" : "incomplete";
  std::string devices;
  for (const auto& d : rep.devices) devices += (devices.empty() ? "" : ", ") + d.device_id;
  std::string line = v.line();
  if (auto colon = line.find(": "); colon != std::string::npos && line.compare(0, colon, word) == 0) line = line.substr(colon + 2);
  std::string h = fmt::format("<section class=summary><div class=\"verdict {0}\" id=verdict><b>{1}</b> {2}<br><small>{3} · {4} {5} · {6}</small></div>",
                              cls, word, esc(line), esc(devices), esc(rep.command), esc(rep.version), esc(rep.started_at));
  if (!v.missing.empty()) {
    h += "<ul class=opt-ins id=opt-ins>";
    for (const auto& [flag, n] : v.missing)
      h += fmt::format("<li><code>{}</code> would enable {} MUST case{} this run skipped</li>", esc(flag), n, n == 1 ? "" : "s");
    h += "</ul>";
  }
  for (const auto& d : rep.devices) h += device_summary(rep, d);
  return h + "</section>";
}

}  // namespace mbc::conf::html
