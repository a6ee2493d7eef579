// A fleet: every drive a scan identified on one or more lines, each
// qualified by its own `run` into a report directory of its own
// (tools/mbconform/cmd_run.cpp, `run --scan` / `--scan-file`). This is the
// one summary over them: summary.json, the terminal's table and a junit.xml
// with one testsuite per drive (the units not identified are listed, never run).
#pragma once

#include <string>
#include <vector>

#include <nlohmann/json.hpp>

#include "report/report.h"

namespace mbc::conf {

struct FleetDrive {
  std::string line;        // the serial port, or HOST:PORT of a gateway
  int unit = 0;
  std::string target;      // the run target (rtu://...&unit=N)
  std::string device_id;   // the spec the scan matched; empty: not identified
  std::string confidence;  // the scan's: high | medium | low | none
  std::string dir;         // its report directory, under the fleet's
  // What its run came to: PASS | PARTIAL | FAIL | INCOMPLETE (Verdict::word),
  // or NOT RUN (not identified); `exit_code` as `run` on it alone would exit.
  std::string verdict;
  int exit_code = 0;
  std::string why;         // INCOMPLETE or NOT RUN: the one line why
  DeviceRun run;           // its cases (empty when not run)
};

// The exit code of the whole fleet: the worst of the drives' (2 could not be
// done > 1 fail > 3 partial under --require-complete > 0); 0 when none ran.
int fleet_exit_code(const std::vector<FleetDrive>& drives);

// summary.json: per drive its line, unit, target, spec, confidence, report
// directory, verdict, exit code and counts; then the fleet's exit code.
nlohmann::json fleet_summary(const std::vector<FleetDrive>& drives, const std::string& started_at, const std::string& version);
// The terminal's table, one row per drive, and the verdict line of the fleet.
std::string fleet_table(const std::vector<FleetDrive>& drives);
// junit.xml of the fleet: one testsuite per drive ("ttyUSB0-unit3 hsc60"),
// a drive not run as one skipped testcase saying why.
std::string fleet_junit(const std::vector<FleetDrive>& drives, const std::string& started_at, const std::string& version,
                        bool fail_on_should);

}  // namespace mbc::conf
