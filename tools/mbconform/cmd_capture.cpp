// mbconform check-capture: a recorded capture (pcap, pcapng, or a serial log
// in timestamped hex) judged against a device's spec without sending a
// frame (conformance/capture/README.md).
//
//   mbconform check-capture gateway.pcapng --device hsc60 --port 1502
//   mbconform check-capture line.log --device sihong-57hs-r --baud 115200
//   mbconform check-capture plant.pcap --map 'holding=0-199' --out reports/plant
//
// Exit codes: 0 every MUST case the capture exercised passed; 1 one failed;
// 2 the capture could not be read to its end, or bad arguments.
#include <fmt/core.h>

#include <filesystem>

#include "capture/check.h"
#include "commands.h"
#include "conventions.h"
#include "loader.h"
#include "map/map.h"
#include "options.h"
#include "report/report.h"
#include "report/utc_now.h"

namespace mbc::cli {
namespace {

struct CaptureArgs {
  std::string file, device, spec_file, map, map_file, out;
  std::vector<uint16_t> ports;
  std::optional<int> unit, baud;
  bool junit_only = false, quiet = false;
};

int check_capture(const CaptureArgs& a) {
  const char* me = "mbconform check-capture";
  std::optional<spec::Spec> s;
  try {
    TargetOptions t;
    t.device = a.device;
    t.spec_file = a.spec_file;
    s = named_spec(t);
    bool mapped = !a.map.empty() || !a.map_file.empty();
    if (!s && mapped) s = spec::load_spec_by_id("modbus-standard");
    if (!s) {
      fmt::print(stderr, "{}: error: give --device ID, --spec FILE, --map or --map-file\n", me);
      return kExitUsage;
    }
    if (!a.map.empty()) *s = conf::map::apply(*s, conf::map::parse_option(a.map));
    if (!a.map_file.empty()) *s = conf::map::apply(*s, conf::map::load_file(a.map_file));
  } catch (const std::exception& e) {
    fmt::print(stderr, "{}: error: {}\n", me, e.what());
    return kExitUsage;
  }
  try {
    // A capture may be large, but it must be a file: a FIFO or a device hangs the reader.
    check_readable(a.file, UINTMAX_MAX, "capture");
  } catch (const std::exception& e) {
    fmt::print(stderr, "{}: error: {}\n", me, e.what());
    return kExitUsage;
  }
  const std::string out = a.out.empty() ? default_out_dir("check-capture") : a.out;
  if (!conf::out_dir_ok(out, me)) return kExitUsage;

  conf::capture::Options o;
  for (auto p : a.ports)
    if (std::find(o.read.ports.begin(), o.read.ports.end(), p) == o.read.ports.end()) o.read.ports.push_back(p);
  o.judge.unit = a.unit;
  o.judge.baud = a.baud.value_or(s->serial.baud_default.value_or(19200));
  conf::capture::Result r = conf::capture::check_capture(a.file, *s, o);

  conf::RunReport report;
  report.command = "check-capture";
  report.started_at = conf::utc_now();
  report.version = kVersionLine;
  report.devices.push_back(r.run);
  try {
    conf::write_reports(report, out, a.junit_only);
    if (!a.junit_only) conf::capture::write_coverage(r, out);
  } catch (const std::exception& e) {
    fmt::print(stderr, "{}: error: {}\n", me, e.what());
    return kExitUsage;
  }
  if (!a.quiet) fmt::print("{}", conf::summary_table(report));
  fmt::print("reports: {}\n", out);
  if (!r.stats.error.empty()) {
    fmt::print(stderr, "{}: error: {}: {}\n", me, a.file, r.stats.error);
    return kExitUsage;
  }
  return conf::count(r.run).must_failed > 0 ? kExitFailed : kExitOk;
}

}  // namespace

void add_capture_command(CLI::App& app, int& exit_code) {
  auto a = std::make_shared<CaptureArgs>();
  auto* cmd = app.add_subcommand("check-capture", "Judge a recorded capture (pcap, pcapng, serial log) against a spec, sending nothing");
  cmd->add_option("file", a->file, "the capture: pcap, pcapng, or a serial log (TIME [LINK] rx|tx HEX per line)")->required();
  auto* dev = cmd->add_option("--device", a->device, "the spec the device is judged against, by id");
  cmd->add_option("--spec", a->spec_file, "the spec, by file")->excludes(dev);
  cmd->add_option("--map", a->map, "the device's data map instead of the spec's: inline or a map file (conformance/README.md, Maps)");
  cmd->add_option("--map-file", a->map_file, "a map file (mbconform_map: 1)");
  cmd->add_option("--port", a->ports, "another server port carrying Modbus TCP or RTU over TCP (502 always); repeatable");
  cmd->add_option("--unit", a->unit, "judge only this unit id (slave address); every unit is counted in coverage")->check(CLI::Range(0, 255));
  cmd->add_option("--baud", a->baud, "serial logs: the line rate for t1.5 and t3.5 (default: the spec's)")->check(CLI::Range(300, 4000000));
  cmd->add_option("--out", a->out, "report directory (default reports/check-capture/<UTC date-time>/)");
  cmd->add_flag("--junit-only", a->junit_only, "write only junit.xml");
  cmd->add_flag("-q,--quiet", a->quiet, "no summary table: only the reports' directory and errors");
  cmd->callback([a, &exit_code] { exit_code = check_capture(*a); });
}

}  // namespace mbc::cli
