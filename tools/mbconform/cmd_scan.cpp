// mbconform scan: every drive on a line, read-only (conformance/scan/scan.h).
//
//   mbconform scan rtu:///dev/ttyUSB0 [--units 1-247] [--budget 10m] [--timeout 100ms] [--out scan.json]
//   mbconform scan tcp://10.0.0.5:502          (a gateway: units only)
//   mbconform run --scan-file scan.json        (then qualify every drive it identified: cmd_run.cpp)
//
// Exit codes: 0 the scan finished (whether or not it found a drive: the
// table says); 1 it found nothing; 2 it could not run, or a stop signal or
// the budget ended it before it was done (PARTIAL: the table shows what it found).
#include <fmt/core.h>

#include <fstream>
#include <iostream>
#include <tuple>

#include "commands.h"
#include "conventions.h"
#include "loader.h"
#include "scan/scan.h"
#include "session/progress.h"
#include "session/signals.h"
#include "spec_path.h"

namespace mbc::cli {
namespace {

struct ScanArgs {
  std::string uri, units = "1-247", budget = "10m", timeout = "100ms", out;
  std::vector<std::string> devices;
  bool all_settings = false, progress = false, quiet = false;
};

int run_scan(const ScanArgs& a) {
  conf::scan::Options o;
  o.uri = a.uri;
  o.all_settings = a.all_settings;
  auto budget = parse_duration(a.budget);
  auto timeout = parse_duration(a.timeout, std::chrono::milliseconds(1), std::chrono::milliseconds(60000));
  if (!budget) throw CLI::ValidationError("--budget", duration_error("--budget", a.budget));
  if (!timeout)
    throw CLI::ValidationError("--timeout", duration_error("--timeout", a.timeout, std::chrono::milliseconds(1),
                                                           std::chrono::milliseconds(60000)));
  o.budget = *budget;
  o.timeout = *timeout;
  try {
    std::tie(o.first_unit, o.last_unit) = conf::scan::parse_units(a.units);
  } catch (const std::invalid_argument& e) {
    throw CLI::ValidationError("--units", e.what());
  }

  std::vector<spec::Spec> loaded;
  std::vector<std::string> ids = a.devices.empty() ? spec::spec_ids() : a.devices;
  for (const auto& id : ids) loaded.push_back(spec::load_spec_by_id(id));
  std::vector<const spec::Spec*> specs;
  for (const auto& s : loaded) specs.push_back(&s);

  conf::install_stop_signals();
  conf::Progress progress("scan", a.progress, a.quiet);
  o.on_probe = [&](uint64_t requests, const std::string& at) {
    progress.update_timed(requests, fmt::format("requests, at {}", at).c_str(), o.budget);
  };
  conf::scan::Result r = conf::scan::scan(o, specs);
  progress.clear();
  std::cout << conf::scan::table(r);
  if (!a.out.empty()) {
    std::ofstream f(a.out);
    f << conf::scan::to_json(r);
    if (!f) throw std::runtime_error("cannot write " + a.out);
  }
  std::cout << fmt::format("{}: {} unit(s) found, {} requests in {:.1f} s{}\n", r.partial ? "PARTIAL" : "DONE",
                           r.units.size(), r.requests, r.seconds, r.partial ? " (" + r.partial_why + ")" : "");
  if (r.partial) return kExitUsage;
  return r.units.empty() ? kExitFailed : kExitOk;
}

}  // namespace

void add_scan_command(CLI::App& app, int& exit_code) {
  static ScanArgs a;
  auto* cmd = app.add_subcommand("scan", "Find every drive on a line, read-only: its unit, line settings and identity, "
                                         "and the run command for each");
  cmd->add_option("target", a.uri, "rtu:///dev/ttyUSB0 (settings found; baud=/parity= narrow them), tcp://HOST:PORT or "
                                   "rtu-tcp://HOST:PORT (a gateway: units only)")
      ->required();
  cmd->add_option("--units", a.units, "FIRST-LAST: the units to try")->capture_default_str();
  cmd->add_option("--budget", a.budget, "DURATION: the longest the scan runs (then PARTIAL)")->capture_default_str();
  cmd->add_option("--timeout", a.timeout, "DURATION: the wait for each probe's reply")->capture_default_str();
  cmd->add_option("--device", a.devices, "ID: a spec to identify against (repeatable; default: every known spec)");
  cmd->add_option("--out", a.out, "FILE: the scan as JSON (units, settings, identities, commands): the scan file "
                                  "`run --scan-file FILE` qualifies, every drive identified");
  cmd->add_flag("--all-settings", a.all_settings, "keep trying line settings after one answered (drives at several settings)");
  cmd->add_flag("--progress", a.progress, "progress on stderr even when it is not a terminal");
  cmd->add_flag("-q,--quiet", a.quiet, "no progress");
  cmd->callback([&exit_code] {
    try {
      exit_code = run_scan(a);
    } catch (const CLI::ValidationError&) {
      throw;
    } catch (const std::exception& e) {
      fmt::print(stderr, "mbconform scan: error: {}\n", e.what());
      exit_code = kExitUsage;
    }
  });
}

}  // namespace mbc::cli
