// junit.xml: one <testsuite> per device, one <testcase> per case. A case
// that fails the run (a MUST, or a SHOULD under --fail-on should) carries
// <failure>, so the CI's verdict agrees with the exit code; a failed SHOULD
// otherwise passes in JUnit terms and says so in <system-out>, as OBSERVED
// cases do. A skipped case carries <skipped>. Classnames are dotted
// identifiers (mbconform.<device>.<family>): CI tools split them on dots
// into packages and classes.
#include <fmt/core.h>

#include <algorithm>
#include <cctype>

#include "report/report.h"

namespace mbc::conf {
namespace {

std::string xml_escape(const std::string& s) {
  std::string out;
  out.reserve(s.size());
  for (unsigned char c : s) {
    switch (c) {
      case '&': out += "&amp;"; break;
      case '<': out += "&lt;"; break;
      case '>': out += "&gt;"; break;
      case '"': out += "&quot;"; break;
      case '\'': out += "&apos;"; break;
      default:
        // XML 1.0 forbids most control characters even as references.
        if (c < 0x20 && c != '\t' && c != '\n' && c != '\r') out += '?';
        else out += char(c);
    }
  }
  return out;
}

// "sihong-57hs-r" -> "sihong_57hs_r": a Java-style identifier, as JUnit
// consumers expect of each dotted part of a classname.
std::string identifier(const std::string& s) {
  std::string out;
  for (unsigned char c : s) out += std::isalnum(c) ? char(c) : '_';
  if (out.empty() || std::isdigit(static_cast<unsigned char>(out[0]))) out = "_" + out;
  return out;
}

}  // namespace

std::string junit_classname(const std::string& device, const std::string& family) {
  return "mbconform." + identifier(device) + "." + identifier(family);
}

std::string junit_xml(const RunReport& rep) {
  std::string x = "<?xml version=\"1.0\" encoding=\"UTF-8\"?>\n";
  // The verdict first (report/result.h): INCOMPLETE, FAIL, PARTIAL (naming
  // the opt-ins) or PASS; a CI reading only JUnit sees a partial run.
  Verdict v = verdict(rep);
  auto comment = [&](std::string line) {
    for (size_t at; (at = line.find("--")) != std::string::npos;) line.replace(at, 2, "- ");  // not inside a comment
    x += "<!-- " + xml_escape(line) + " -->\n";
  };
  if (std::string inc = incomplete_line(rep); !inc.empty()) comment(inc);
  if (v.kind != Verdict::Kind::incomplete) comment(v.line());
  size_t tests = 0, failures = 0, skipped = 0, errors = 0;
  // Failures in JUnit's sense: the cases that fail the run.
  auto failing = [&](const DeviceRun& d) {
    return size_t(std::count_if(d.cases.begin(), d.cases.end(), [&](const CaseResult& r) { return fails_run(r, rep); }));
  };
  for (const auto& d : rep.devices) {
    Counts c = count(d);
    tests += c.total();
    failures += failing(d);
    skipped += c.skip;
    errors += c.error;
  }
  x += fmt::format("<testsuites name=\"mbconform {}\" tests=\"{}\" failures=\"{}\" errors=\"{}\" skipped=\"{}\">\n",
                   xml_escape(rep.command), tests, failures, errors, skipped);
  std::string opt_ins;  // each opt-in MUST cases were skipped for want of, with how many
  for (const auto& [flag, n] : v.missing)
    opt_ins += fmt::format("<property name=\"opt-in\" value=\"{}: would enable {} MUST cases\"/>", xml_escape(flag), n);
  for (const auto& d : rep.devices) {
    Counts c = count(d);
    x += fmt::format("  <testsuite name=\"{}\" tests=\"{}\" failures=\"{}\" errors=\"{}\" skipped=\"{}\" time=\"{:.3f}\"{}>\n",
                     xml_escape(d.device_id), c.total(), failing(d), c.error, c.skip, d.wall_seconds,
                     rep.started_at.empty() ? "" : fmt::format(" timestamp=\"{}\"", xml_escape(rep.started_at)));
    x += fmt::format("    <properties><property name=\"target\" value=\"{}\"/><property name=\"spec\" value=\"{}\"/>"
                     "<property name=\"interrupted\" value=\"{}\"/><property name=\"verdict\" value=\"{}\"/>{}</properties>\n",
                     xml_escape(d.target_uri), xml_escape(d.spec_path), d.interrupted ? "true" : "false", v.word(), opt_ins);
    for (const auto& r : d.cases) {
      x += fmt::format("    <testcase name=\"{}\" classname=\"{}\" time=\"{:.6f}\">\n", xml_escape(r.id),
                       xml_escape(junit_classname(d.device_id, r.family)), r.duration_ms / 1000.0);
      std::string head = fmt::format("[{}] {} — {}", to_string(r.level), r.clause, r.requirement);
      if (r.outcome == Outcome::fail && !r.quirk.empty()) {
        x += fmt::format("      <system-out>{}</system-out>\n",
                         xml_escape("DECLARED QUIRK: " + r.quirk + "\n" + head + "\n" + r.message));
      } else if (r.outcome == Outcome::fail && !fails_run(r, rep)) {
        x += fmt::format("      <system-out>{}</system-out>\n",
                         xml_escape("FAILED " + std::string(to_string(r.level)) +
                                    " (does not fail the run; --fail-on should makes it a failure): " + head + "\n" + r.message));
      } else if (r.outcome == Outcome::fail) {
        std::string body = head + "\n";
        for (const auto& f : r.frames)
          body += fmt::format("{}\n  request  {}\n  expected {}{}\n  actual   {}\n", f.step, to_hex(f.request), f.expected_text,
                              f.expected ? " = " + to_hex(*f.expected) : "", f.actual ? to_hex(*f.actual) : "silence");
        x += fmt::format("      <failure message=\"{}\" type=\"{}\">{}</failure>\n", xml_escape(r.message), to_string(r.level),
                         xml_escape(body));
      } else if (r.outcome == Outcome::error) {
        x += fmt::format("      <error message=\"{}\" type=\"not run\"/>\n", xml_escape(r.message));
      } else if (r.outcome == Outcome::skip) {
        x += fmt::format("      <skipped message=\"{}\"/>\n", xml_escape(r.message));
      } else if (r.outcome == Outcome::observed) {
        x += fmt::format("      <system-out>{}</system-out>\n", xml_escape("OBSERVED: " + head + "\n" + r.message));
      }
      x += "    </testcase>\n";
    }
    x += "  </testsuite>\n";
  }
  x += "</testsuites>\n";
  return x;
}

}  // namespace mbc::conf
