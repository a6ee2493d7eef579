// mbconform run: the conformance cases generated from a spec, against any
// target, with reports for people (HTML, terminal) and CI (JUnit, JSON).
//
//   mbconform run                                   # every reference device in-process
//   mbconform run --target tcp://10.0.0.5:502?unit=3 --device hsc60 --allow-motion
//   mbconform run --target ref:hsc60 --filter '*/registers/*' --plan
//
// Exit codes: 0 every MUST case passed; 1 a MUST case failed; 2 the run could
// not be done (bad target, bad spec, bad arguments, interrupted).
#include <fmt/core.h>
#include <fnmatch.h>
#include <unistd.h>

#include <atomic>
#include <chrono>
#include <csignal>
#include <ctime>
#include <filesystem>
#include <fstream>
#include <regex>

#include "cases/case.h"
#include "cases/common.h"
#include "commands.h"
#include "loader.h"
#include "map/map.h"
#include "options.h"
#include "quirks/quirks.h"
#include "report/report.h"
#include "runner/runner.h"
#include "check/text.h"
#include "safety/safety.h"
#include "targets/target.h"

namespace mbc::cli {
namespace {

std::atomic<bool> g_stop{false};
extern "C" void on_signal(int) { g_stop.store(true); }

struct RunArgs {
  TargetOptions t;
  std::string filter, summary_dir;
  bool list = false, plan = false, junit_only = false, quiet = false;
  std::string map;  // --map auto | FILE | inline
  int map_budget = conf::map::kDefaultBudget;
  bool allow_writes = false;
  std::string quirks_file;
};

// The pattern a --filter asks for (conf::select_cases: a filter is literal
// unless it holds '*' or '?', or starts with "re:"): GLOB (fnmatch, '*'
// crosses '/') or, when it has regex syntax, an ECMAScript regex searched in
// the id; a plain word matches as a substring.
std::function<bool(const std::string&)> make_filter(const std::string& f) {
  if (f.empty()) return [](const std::string&) { return true; };
  if (f.find_first_of("^$()|+[]\\{}") != std::string::npos) {
    std::regex re(f, std::regex::ECMAScript);
    return [re](const std::string& id) { return std::regex_search(id, re); };
  }
  if (f.find_first_of("*?") != std::string::npos)
    return [f](const std::string& id) { return fnmatch(f.c_str(), id.c_str(), 0) == 0; };
  return [f](const std::string& id) { return id.find(f) != std::string::npos; };
}

// What a target will be, without opening it (for --list and --plan on live
// targets: nothing is connected, nothing is sent).
conf::TargetInfo planned_info(const std::string& uri, const spec::Spec& s) {
  conf::Uri u = conf::parse_uri(uri);
  conf::TargetInfo i;
  i.uri = uri;
  i.kind = u.scheme;
  i.framing = u.scheme == "tcp" ? conf::Framing::mbap : conf::Framing::rtu;
  i.live = u.scheme != "ref" && u.scheme != "plugin";
  i.raw = true;  // every kind sends raw frames in its own framing (tcp: raw MBAP), as the opened target says
  i.unit = uint8_t(std::stoi(u.param("unit").value_or(std::to_string(s.serial.slave_default.value_or(1)))));
  if (auto b = u.param("baud")) i.baud = std::stoi(*b);
  else if (u.scheme == "ref") i.baud = s.serial.baud_default;
  return i;
}

int run(RunArgs& a) {

  std::optional<spec::Spec> standard;
  try {
    standard = spec::load_spec_by_id("modbus-standard");
  } catch (const std::exception& e) {
    fmt::print(stderr, "mbconform run: warning: no modbus-standard spec ({}); deviations are not checked\n", e.what());
  }
  std::optional<spec::Spec> named;
  try {
    named = named_spec(a.t);
  } catch (const std::exception& e) {
    fmt::print(stderr, "mbconform run: error: {}\n", e.what());
    return kExitUsage;
  }

  // A map without a spec: the standard's cases where the map allows.
  if (!a.map.empty() && !named && standard) named = *standard;
  conf::quirks::Quirks quirks;
  if (!a.quirks_file.empty()) {
    try {
      quirks = conf::quirks::load(a.quirks_file);
    } catch (const std::exception& e) {
      fmt::print(stderr, "{}\n", e.what());
      return kExitUsage;
    }
  }
  std::optional<conf::map::Map> given_map;
  if (!a.map.empty() && a.map != "auto") {
    try {
      given_map = conf::map::parse_option(a.map);
    } catch (const std::exception& e) {
      fmt::print(stderr, "mbconform run: error: {}\n", e.what());
      return kExitUsage;
    }
  }
  // No target: every reference device, or, when a spec is named, its own
  // reference device once (not every reference device under one spec).
  std::vector<std::string> targets = a.t.targets;
  if (targets.empty() && named) targets.push_back("ref:" + named->device.id);
  if (targets.empty()) targets = targets_or_default(a.t);

  conf::RunReport report;
  report.command = "run";
  report.started_at = utc_now("%Y-%m-%dT%H:%M:%SZ");
  report.version = "mbconform 0.1";

  std::signal(SIGINT, on_signal);
  std::signal(SIGTERM, on_signal);
  bool dry = a.list || a.plan;
  bool tty = isatty(STDOUT_FILENO) && !a.quiet;
  const std::string out = a.t.out.empty() ? "reports/runs/" + utc_now("%Y%m%dT%H%M%SZ") : a.t.out;
  if (!dry && !conf::out_dir_ok(out, "mbconform run")) return kExitUsage;
  for (const auto& uri : targets) {
    spec::Spec s;
    try {
      s = spec_for(named, uri);
    } catch (const std::exception& e) {
      fmt::print(stderr, "mbconform run: error: target {}: {}\n", uri, e.what());
      return kExitUsage;
    }
    std::unique_ptr<conf::Target> target;
    conf::TargetInfo info;
    try {
      if (!dry || (uri.rfind("ref:", 0) == 0 && !named)) {
        target = conf::open_target(uri);
        info = target->info();
      } else {
        info = planned_info(uri, s);
      }
    } catch (const std::exception& e) {
      fmt::print(stderr, "mbconform run: error: cannot open target {}: {}\n", uri, e.what());
      return kExitUsage;
    }

    std::vector<std::string> notes;
    std::optional<conf::map::Map> map = given_map;
    if (a.map == "auto" && target) {
      if (std::string why = conf::unreachable(*target, s); !why.empty()) {
        fmt::print(stderr, "mbconform run: error: target {}: {}\n", uri, why);
        return kExitUsage;
      }
      auto t0 = std::chrono::steady_clock::now();
      map = conf::map::probe(*target, a.map_budget);
      double secs = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
      notes.push_back(fmt::format("map probed in {} requests, {:.2f} s: {}", map->requests, secs, map->describe()));
      for (const auto& u : map->unmapped)
        notes.push_back(fmt::format("unmapped {} addresses answered: {} ({} probes)", conf::map::table_name(u.table), u.answer, u.seen));
      if (map->partial)
        notes.push_back(fmt::format("PARTIAL MAP: the probe budget of {} requests ran out at {}; nothing past it was probed",
                                    a.map_budget, map->partial_at));
      if (!a.quiet) fmt::print("{}: {}\n", uri, notes.front());
    } else if (a.map == "auto" && a.plan) {
      fmt::print("# --map auto: the probe sends at most {} reads (FC 01/02/03/04, --map-budget) before the cases; "
                 "the cases below are the spec's own map's\n", conf::map::planned_requests(a.map_budget));
    } else if (map) {
      notes.push_back(fmt::format("map from {}: {}", map->source, map->describe()));
    }
    if (map && (a.map != "auto" || target)) s = conf::map::apply(s, *map);

    conf::GenContext g{s, info, a.t.policy, standard ? &*standard : nullptr, std::nullopt};
    if (map) g.map = conf::map::terms(*map, a.allow_writes);
    std::vector<conf::Case> cases;
    try {
      cases = conf::select_cases(conf::all_cases(g), a.filter, make_filter);
    } catch (const std::exception& e) {
      fmt::print(stderr, "mbconform run: error: --filter '{}': {}\n", a.filter, e.what());
      return kExitUsage;
    }
    if (cases.empty() && !a.filter.empty()) {
      fmt::print(stderr, "mbconform run: error: --filter '{}' matches none of the {} cases for {}\n", a.filter,
                 conf::all_cases(g).size(), uri);
      return kExitUsage;
    }
    if (a.list) {
      std::string column = targets.size() > 1 ? uri + "  " : "";
      for (const auto& c : cases)
        fmt::print("{}{}  {}  {}  {}{}\n", column, c.id, conf::to_string(c.level), c.clause, c.title,
                   c.skip_reason.empty() ? "" : "  [skip: " + c.skip_reason + "]");
      continue;
    }
    if (a.plan) {
      // A frame script (conformance/check/README.md): `mbconform replay` runs it.
      if (&uri == &targets.front()) fmt::print("{}\n", conf::check::kHeader);
      fmt::print("#\n# {}: {} cases, unit {}, {}\ndevice {}\n", info.uri, cases.size(), info.unit,
                 info.framing == conf::Framing::rtu ? "RTU frames" : "MBAP frames (transaction id * : the target numbers its own)",
                 s.device.id);
      for (const auto& c : cases) {
        fmt::print("#\n");
        for (const auto& l : conf::check::case_lines(c, info.framing)) fmt::print("{}\n", l);
      }
      for (const auto& b : conf::cases::planned_broadcast_writes(cases)) fmt::print("# every drive on the line receives: {}\n", b);
      continue;
    }
    fmt::print("{}: {} cases against {}\n", s.device.id, cases.size(), info.uri);
    std::fflush(stdout);
    conf::RunOptions opt;
    opt.stop = &g_stop;
    opt.on_case = [&](const conf::CaseResult& r, size_t done, size_t total) {
      if (r.outcome == conf::Outcome::fail) {
        fmt::print("{}{}\n", tty ? "\r\033[K" : "", conf::progress_line(r, done, total));
      } else if (tty) {
        fmt::print("\r\033[K{}", conf::progress_line(r, done, total));
      }
      std::fflush(stdout);
    };
    // Live drives: keep every register the run may write, put them back
    // afterwards (also after SIGINT or a target error) and report what could not be.
    std::optional<conf::Snapshot> snap;
    std::vector<std::string> snap_notes;
    if (info.live) {
      if (std::string why = conf::unreachable(*target, s); !why.empty()) {
        fmt::print(stderr, "mbconform run: error: target {}: {}\n", uri, why);
        return kExitUsage;
      }
      try {
        snap = conf::Snapshot::take(*target, s, a.t.policy);
        for (const auto& f : snap->failures()) snap_notes.push_back(f);
      } catch (const std::exception& e) {
        fmt::print(stderr, "mbconform run: error: target {}: cannot read the registers to keep: {}\n", uri, e.what());
        return kExitUsage;
      }
    }
    conf::DeviceRun dr = conf::run_cases(*target, s, cases, opt);
    if (tty) fmt::print("\r\033[K");
    if (snap) {
      try {
        for (auto& f : snap->restore(*target)) dr.restore_failures.push_back(std::move(f));
      } catch (const std::exception& e) {
        dr.restore_failures.push_back(fmt::format("restore stopped: {}", e.what()));
      }
      for (auto& n : snap_notes) dr.safety_notes.push_back(std::move(n));
      for (const auto& f : dr.restore_failures) fmt::print(stderr, "mbconform run: {}: {}\n", s.device.id, f);
    }
    dr.notes.insert(dr.notes.begin(), notes.begin(), notes.end());
    if (!quirks.empty()) conf::quirks::apply(quirks, dr);
    report.devices.push_back(std::move(dr));
    if (g_stop.load()) {
      report.interrupted = true;
      report.devices.back().interrupted = true;
      break;
    }
  }
  std::signal(SIGINT, SIG_DFL);
  std::signal(SIGTERM, SIG_DFL);
  if (dry) return kExitOk;

  try {
    conf::write_reports(report, out, a.junit_only);
    if (!a.summary_dir.empty()) {
      std::filesystem::create_directories(a.summary_dir);
      auto sj = conf::stable_summary(report);
      std::ofstream(a.summary_dir + "/summary.json") << sj.dump(1) << "\n";
      std::ofstream(a.summary_dir + "/summary.md") << conf::summary_markdown(sj);
    }
  } catch (const std::exception& e) {
    fmt::print(stderr, "mbconform run: error: {}\n", e.what());
    return kExitUsage;
  }
  fmt::print("{}", conf::summary_table(report));
  fmt::print("reports: {}\n", out);
  // Interrupted: the run was not done (2), whatever it found so far. A lost
  // target is recorded as the FAIL of the case it was lost in (1).
  if (report.interrupted) return kExitUsage;
  bool must_failed = false;
  for (const auto& d : report.devices) must_failed |= conf::count(d).must_failed > 0;
  if (must_failed) return kExitFailed;
  for (const auto& d : report.devices)
    if (!d.error.empty()) return kExitUsage;
  return kExitOk;
}

}  // namespace

void add_run_command(CLI::App& app, int& exit_code) {
  auto a = std::make_shared<RunArgs>();
  auto* cmd = app.add_subcommand("run", "Run the conformance cases generated from a spec against targets; write reports");
  add_target_options(*cmd, a->t, true, "DIR: report directory (default reports/runs/<UTC date-time>/)");
  cmd->add_flag("--list", a->list, "print the cases (id, level, clause, title) and exit");
  cmd->add_option("--filter", a->filter, "select cases by id: a part of the id, taken literally ('fc15/quantity-limit+1'); "
                  "a glob ('*/registers/*'); or a regex after 're:' ('re:fc1[56]/')");
  cmd->add_flag("--plan", a->plan, "print every frame the cases would send, without sending anything");
  cmd->add_option("--summary", a->summary_dir, "also write the stable summary.md and summary.json into this directory");
  cmd->add_option("--map", a->map,
                  "the target's data map instead of the spec's: 'auto' (probe it with reads), a map file, or "
                  "'holding=0-199,coils=0-199,input=0-199,discrete=0-199' (conformance/README.md, Maps)");
  cmd->add_option("--map-budget", a->map_budget, "the most requests --map auto sends (default 2000)")->check(CLI::Range(1, 1000000));
  cmd->add_flag("--allow-writes", a->allow_writes, "with --map auto or a map without access: run the cases that write");
  cmd->add_option("--quirks", a->quirks_file, "a quirks file: known deviations (case ids or globs, with reasons) "
                  "reported apart, not failed (conformance/README.md, Quirks files)");
  cmd->add_flag("--junit-only", a->junit_only, "write only junit.xml");
  cmd->add_flag("--quiet", a->quiet, "no progress line");
  cmd->callback([a, &exit_code] { exit_code = run(*a); });
}

}  // namespace mbc::cli
