// The report writers: one RunReport (result.h) in, one format out.
//   report.json  everything, for tools (json.cpp)
//   junit.xml    one testsuite per device, one testcase per case (junit.cpp)
//   report.html  one self-contained page for people (html.cpp)
//   terminal     progress line and summary table (terminal.cpp)
//   summary      the stable digest committed as reports/reference/ (summary.cpp):
//                no timestamps, no wall times, so a test can check it is fresh.
#pragma once

#include <optional>
#include <set>
#include <string>
#include <vector>

#include <nlohmann/json.hpp>

#include "report/result.h"
#include "spec.h"

namespace mbc::conf {

// Fills `d.facts` from the spec the run used (device_facts.cpp).
void describe_device(DeviceRun& d, const spec::Spec& s);

nlohmann::json report_json(const RunReport&);
std::string junit_xml(const RunReport&);
// "mbconform.<device>.<family>", each part an identifier ([A-Za-z0-9_], not
// starting with a digit): what JUnit consumers split into packages.
std::string junit_classname(const std::string& device, const std::string& family);
std::string html_report(const RunReport&);

// "  12/812 sihong-57hs-r/registers/0x0020/write-min  pass"
std::string progress_line(const CaseResult&, size_t done, size_t total);
// Per device: pass / fail / skip / observed counts, MUST failures, wall time
// against the wire-time bound; then the failing MUST cases.
std::string summary_table(const RunReport&);

nlohmann::json stable_summary(const RunReport&);
std::string summary_markdown(const nlohmann::json& summary);

// Counts over a device run.
struct Counts {
  size_t pass = 0, fail = 0, skip = 0, observed = 0, error = 0, quirks = 0, must_failed = 0;
  size_t total() const { return pass + fail + skip + observed + error + quirks; }
};
Counts count(const DeviceRun&);

// The failures of one device that fail the run, grouped by cause (what the
// device did against what was due, result.h's Cause), most cases first
// (causes.cpp). A failure with no judged step groups by its clause and message.
struct CauseGroup {
  std::string text;                     // "exception 02 where exception 01 is due"
  std::optional<MismatchKind> kind;     // unset for a failure with no judged step
  std::vector<const CaseResult*> cases;
  std::set<int> function_codes;         // the requests' function codes
  std::set<uint16_t> registers;         // the cases' registers
  std::string replay;                   // one `mbconform run` that re-runs every case of the group
};
std::vector<CauseGroup> failure_causes(const RunReport&, const DeviceRun&);
// `mbconform run` on the device's target selecting exactly `cases`.
std::string replay_command(const DeviceRun&, const std::vector<const CaseResult*>& cases);
// `s` as one shell word.
std::string shell_quote(const std::string& s);

// Creates `dir` and checks a file can be written into it, before a run sends
// its first frame; what is wrong, or empty. out_dir_ok prints it as
// "COMMAND: error: --out: ..." and returns false (the caller exits 2).
std::string out_dir_problem(const std::string& dir);
bool out_dir_ok(const std::string& dir, const char* command);
// A new directory PARENT/STEM (PARENT created), or PARENT/STEM-2, -3, ...
// when that one exists: mkdir(2) claims it atomically, so two commands
// started in the same second (the default report directories are named by
// the second) never share one. When no directory can be made (PARENT not
// writable), PARENT/STEM, for out_dir_problem to name the reason.
std::string claim_new_dir(const std::string& parent, const std::string& stem);
// "INCOMPLETE: ..." when a target was lost or the run was interrupted, else
// empty: the first line of every report (terminal, HTML, JUnit comment, JSON
// "incomplete").
std::string incomplete_line(const RunReport&);

// Writes junit.xml, report.json and (unless junit_only) report.html into
// `dir` (created), each whole or not at all. Throws std::runtime_error when
// a file cannot be written (a full disk), having removed the ones it wrote.
void write_reports(const RunReport&, const std::string& dir, bool junit_only = false);

}  // namespace mbc::conf
