#include "report/fleet.h"

#include <fmt/core.h>

namespace mbc::conf {
namespace {

// The worse exit code: 2 (could not be done) > 1 (fail) > 3 (partial, a gate asked for complete) > 0.
int severity(int code) { return code == 2 ? 3 : code == 1 ? 2 : code == 3 ? 1 : 0; }

}  // namespace

int fleet_exit_code(const std::vector<FleetDrive>& drives) {
  int worst = 0;
  for (const auto& d : drives)
    if (d.verdict != "NOT RUN" && severity(d.exit_code) > severity(worst)) worst = d.exit_code;
  return worst;
}

nlohmann::json fleet_summary(const std::vector<FleetDrive>& drives, const std::string& started_at, const std::string& version) {
  nlohmann::json j;
  j["command"] = "mbconform run (fleet)";
  j["started_at"] = started_at;
  j["version"] = version;
  j["drives"] = nlohmann::json::array();
  size_t run = 0;
  for (const auto& d : drives) {
    nlohmann::json dj{{"line", d.line},         {"unit", d.unit},       {"target", d.target},
                      {"confidence", d.confidence}, {"verdict", d.verdict}, {"exit_code", d.exit_code}};
    dj["spec"] = d.device_id.empty() ? nlohmann::json() : nlohmann::json(d.device_id);
    dj["report"] = d.dir.empty() ? nlohmann::json() : nlohmann::json(d.dir);
    if (!d.why.empty()) dj["why"] = d.why;
    if (d.verdict != "NOT RUN") {
      ++run;
      Counts c = count(d.run);
      dj["counts"] = {{"total", c.total()}, {"pass", c.pass}, {"fail", c.fail}, {"must_failed", c.must_failed},
                      {"observed", c.observed}, {"skip", c.skip}, {"error", c.error}};
    }
    j["drives"].push_back(std::move(dj));
  }
  j["run"] = run;
  j["not_run"] = drives.size() - run;
  j["exit_code"] = fleet_exit_code(drives);
  return j;
}

std::string fleet_table(const std::vector<FleetDrive>& drives) {
  std::string s = fmt::format("\n{:<24} {:<5} {:<24} {:<10} {:<11} {:>6} {:>5} {:>6} {:>5}  {}\n", "line", "unit", "spec",
                              "confidence", "verdict", "cases", "fail", "MUST!", "skip", "report");
  size_t not_run = 0;
  for (const auto& d : drives) {
    Counts c = count(d.run);
    const bool ran = d.verdict != "NOT RUN";
    not_run += !ran;
    s += fmt::format("{:<24} {:<5} {:<24} {:<10} {:<11} {:>6} {:>5} {:>6} {:>5}  {}\n", d.line, d.unit,
                     d.device_id.empty() ? "(not identified)" : d.device_id, d.confidence, d.verdict, ran ? c.total() : 0,
                     ran ? c.fail : 0, ran ? c.must_failed : 0, ran ? c.skip : 0, ran ? d.dir : "-");
  }
  for (const auto& d : drives)
    if (!d.why.empty()) s += fmt::format("{} unit {}: {}\n", d.line, d.unit, d.why);
  const int code = fleet_exit_code(drives);
  s += fmt::format("FLEET: {} drive(s) qualified, {} not identified (not run); the worst verdict exits {} "
                   "(0 pass, 1 fail, 2 incomplete, 3 partial under --require-complete)\n",
                   drives.size() - not_run, not_run, code);
  return s;
}

std::string fleet_junit(const std::vector<FleetDrive>& drives, const std::string& started_at, const std::string& version,
                        bool fail_on_should) {
  // One RunReport over every drive, each named by its line and unit as well
  // as its spec (two drives of one spec are two testsuites), through the one
  // JUnit writer.
  RunReport all;
  all.command = "run (fleet)";
  all.started_at = started_at;
  all.version = version;
  all.fail_on_should = fail_on_should;
  for (const auto& d : drives) {
    DeviceRun r = d.run;
    r.target_uri = d.target;
    if (d.verdict == "NOT RUN") {
      r.device_id = fmt::format("{} not-identified", d.dir.empty() ? fmt::format("unit{}", d.unit) : d.dir);
      CaseResult c;
      c.id = fmt::format("{}/unit{}/not-identified", d.line, d.unit);
      c.family = "fleet";
      c.level = Level::observed;
      c.outcome = Outcome::skip;
      c.message = d.why;
      r.cases = {std::move(c)};
    } else {
      r.device_id = fmt::format("{} {}", d.dir, d.device_id);
    }
    all.devices.push_back(std::move(r));
  }
  return junit_xml(all);
}

}  // namespace mbc::conf
