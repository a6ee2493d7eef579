// mbconform run: the conformance cases generated from a spec, against any
// target, with reports for people (HTML, terminal) and CI (JUnit, JSON).
//
//   mbconform run                                   # every reference device in-process
//   mbconform run --target tcp://10.0.0.5:502?unit=3 --device hsc60 --allow-motion
//   mbconform run --target ref:hsc60 --filter '*/registers/*' --plan
//
// Exit codes: 0 every MUST case passed (PASS), or every MUST case that ran
// passed but some were skipped for want of an opt-in (PARTIAL); 1 a MUST case
// failed (or a declared quirk is gone: its cases ran and passed); 2 the run
// could not be done (bad target, bad spec, bad arguments, interrupted); 3 a
// PARTIAL run under --require-complete.
#include <fmt/core.h>
#include <re2/re2.h>
#include <unistd.h>

#include <atomic>
#include <chrono>
#include <csignal>
#include <ctime>
#include <filesystem>
#include <fstream>

#include "capture/pcap_tap.h"
#include "cases/case.h"
#include "cases/common.h"
#include "commands.h"
#include "conventions.h"
#include "loader.h"
#include "map/map.h"
#include "options.h"
#include "report/quirks.h"
#include "report/report.h"
#include "runner/runner.h"
#include "check/text.h"
#include "safety/safety.h"
#include "security/security.h"
#include "timing/timing.h"
#include "session/session.h"
#include "session/progress.h"
#include "session/signals.h"
#include "targets/target.h"
#include "report/utc_now.h"

namespace mbc::cli {
namespace {

struct RunArgs {
  TargetOptions t;
  std::string filter, summary_dir;
  bool list = false, plan = false, junit_only = false, quiet = false;
  std::string map;  // --map auto | FILE | inline
  int map_budget = conf::map::kDefaultBudget;
  std::optional<std::chrono::milliseconds> map_time;  // --map-time
  bool fail_on_should = false;                        // --fail-on should
  bool verbose = false;                               // -v: every case's line, not only failures
  std::string quirks_file;
  std::string deadline;  // --deadline: the whole run's time
  bool require_complete = false;  // --require-complete: a PARTIAL run exits 3
};

// A PARTIAL run under --require-complete (MUST cases skipped for want of an opt-in).
constexpr int kExitPartial = 3;

// What --filter selects (conf::select_cases: literal unless it holds '*'
// or '?', a glob over the whole id, '*' crossing '/'; or "re:REGEX", searched
// in the id), matched with RE2 in time linear in the id whatever the
// pattern. Throws std::invalid_argument with one line.
conf::Matcher re2_matcher(const std::string& text, bool glob) {
  std::string pattern;
  if (glob) {
    pattern = "^";
    for (char c : text) pattern += c == '*' ? ".*" : c == '?' ? "." : RE2::QuoteMeta(std::string(1, c));
    pattern += "$";
  } else {
    pattern = text;
  }
  RE2::Options o;
  o.set_log_errors(false);
  o.set_max_mem(8 << 20);
  auto re = std::make_shared<RE2>(pattern, o);
  if (!re->ok()) throw std::invalid_argument(fmt::format("--filter '{}': not a pattern RE2 takes: {}",
                                                         text.size() > 60 ? text.substr(0, 60) + "..." : text, re->error()));
  return [re](const std::string& id) { return RE2::PartialMatch(id, *re); };
}
std::function<conf::Matcher(const std::string&)> pattern_for(const std::string& filter) {
  bool regex = filter.rfind("re:", 0) == 0;
  return [regex](const std::string& text) { return re2_matcher(text, !regex); };
}
// What a target will be, without opening it (for --list and --plan on live
// targets: nothing is connected, nothing is sent).
conf::TargetInfo planned_info(const std::string& uri, const spec::Spec& s) {
  conf::Uri u = conf::parse_uri(uri);
  conf::TargetInfo i;
  i.uri = uri;
  i.kind = conf::kind_of_uri(u, uri);
  i.framing = conf::framing_of(i.kind);  // what open_target's target would say
  i.live = conf::is_live(i.kind);
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
      std::string file = conf::quirks::find(a.quirks_file);  // a path, or a declared library's name
      check_readable(file, kMaxQuirksBytes, "--quirks");
      quirks = conf::quirks::load(file);
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

  std::function<bool(const std::string&)> keep;
  try {
    keep = [](const std::string&) { return true; };
    if (!a.filter.empty()) {
      // The same selection as select_cases, for ids no generator makes (the TLS checks).
      auto pattern = pattern_for(a.filter);
      keep = [filter = a.filter, pattern](const std::string& id) {
        conf::Case c;
        c.id = id;
        return !conf::select_cases({c}, filter, pattern).empty();
      };
      (void)keep("");  // a pattern RE2 does not take fails here, before anything is opened
    }
  } catch (const std::exception& e) {
    fmt::print(stderr, "mbconform run: error: {}\n", e.what());
    return kExitUsage;
  }
  conf::RunReport report;
  std::vector<std::string> quirks_gone;  // declared quirks whose cases ran and passed (in the notes too)
  report.command = "run";
  report.started_at = conf::utc_now();
  report.version = kVersionLine;
  report.fail_on_should = a.fail_on_should;

  conf::install_stop_signals();
  std::optional<std::chrono::steady_clock::time_point> deadline;
  if (!a.deadline.empty()) {
    auto d = parse_duration(a.deadline);
    if (!d) {
      fmt::print(stderr, "mbconform run: error: {}\n", duration_error("--deadline", a.deadline));
      return kExitUsage;
    }
    deadline = std::chrono::steady_clock::now() + *d;
  }
  // Set between cases: a stop signal, or the deadline passed.
  std::atomic<bool> stop_run{false};
  auto should_stop = [&] {
    return conf::stop_requested() || (deadline && std::chrono::steady_clock::now() >= *deadline);
  };
  bool dry = a.list || a.plan;
  bool tty = isatty(STDOUT_FILENO) && !a.quiet;
  const std::string out = !a.t.out.empty() ? a.t.out : dry ? std::string() : default_out_dir("run");
  if (!dry && !conf::out_dir_ok(out, "mbconform run")) return kExitUsage;
  if (!dry && !a.summary_dir.empty()) {
    if (std::string why = conf::out_dir_problem(a.summary_dir); !why.empty()) {
      fmt::print(stderr, "mbconform run: error: --summary: {}\n", why);
      return kExitUsage;
    }
  }
  for (const auto& uri : targets) {
    spec::Spec s;
    try {
      s = spec_for(named, uri);
    } catch (const std::exception& e) {
      fmt::print(stderr, "mbconform run: error: target {}: {}\n", uri, e.what());
      return kExitUsage;
    }
    // Every frame goes through the session: its gate, its journal (in the
    // report directory), its restore (conformance/session/session.h).
    std::unique_ptr<conf::Session> session;
    conf::Target* target = nullptr;
    conf::TargetInfo info;
    try {
      if (!dry || (uri.rfind("ref:", 0) == 0 && !named)) {
        auto so = session_options(a.t, "run", out);
        so.stop_mid_exchange = false;  // the runner stops between cases
        session = std::make_unique<conf::Session>(uri, &s, std::move(so));
        if (!session->journal_path().empty())
          fmt::print(stderr, "journal: {} (if this command is killed: mbconform restore {})\n", session->journal_path(),
                     session->journal_path());
        target = &session->target();
        info = target->info();
        for (const auto& n : info.notes) fmt::print(stderr, "note: {}\n", n);  // how it was opened (a USB latency timer, ...)
      } else {
        info = planned_info(conf::line_settings(uri, &s).uri, s);
      }
    } catch (const std::exception& e) {
      fmt::print(stderr, "mbconform run: error: cannot open target {}: {}\n", uri, e.what());
      return kExitUsage;
    }

    // Modbus/TCP Security: what the server does around the TLS handshake
    // (conformance/security/), each check on connections of its own, before
    // the cases. A server that does not carry the MBAP ADU inside TLS cannot
    // run a case: its failure is the run's verdict (exit 1), not "could not
    // be done".
    std::vector<conf::CaseResult> security_results;
    bool no_mbap = false;
    if (info.kind == conf::TargetKind::tls && target && !dry && !conf::stop_requested()) {
      for (auto& r : conf::security::check_server(conf::security::from_uri(uri), s.device.id)) {
        bool mbap_failed = r.id == s.device.id + "/security/mbap-inside-tls" && r.outcome == conf::Outcome::fail;
        no_mbap = no_mbap || mbap_failed;
        if (keep(r.id) || mbap_failed) security_results.push_back(std::move(r));
      }
    }
    if (no_mbap) {
      conf::DeviceRun dr;
      dr.device_id = s.device.id;
      dr.target_uri = info.uri;
      dr.spec_path = s.path;
      dr.cases = std::move(security_results);
      dr.notes.push_back("the standard cases were not run: the server does not carry the MBAP ADU inside TLS "
                         "(security/mbap-inside-tls), so no Modbus request of theirs could be framed for it");
      conf::describe_device(dr, s);
      report.devices.push_back(std::move(dr));
      continue;
    }

    std::vector<std::string> notes;
    std::optional<conf::map::Map> map = given_map;
    if (a.map == "auto" && target) {
      if (std::string why = session->reachable(); !why.empty()) {
        fmt::print(stderr, "mbconform run: error: {}\n", why);
        return kExitUsage;
      }
      map = conf::map::probe(*target, conf::map::ProbeLimits{a.map_budget, a.map_time, nullptr});
      notes = conf::map::probe_notes(*map);
      if (!a.quiet) fmt::print("{}: {}\n", uri, notes.front());
    } else if (a.map == "auto" && a.plan) {
      fmt::print("# --map auto: the probe sends at most {} reads (FC 01/02/03/04, --map-budget) before the cases; "
                 "the cases below are the spec's own map's\n", conf::map::planned_requests(a.map_budget));
      // The cases will run on a probed map, whose facts the frame policy
      // takes as observed: the plan's writes are skipped as the run's will be.
      if (info.live) s.device.manual.source = "probe";
    } else if (map) {
      notes.push_back(fmt::format("map from {}: {}", map->source, map->describe()));
    }
    if (map && (a.map != "auto" || target)) s = conf::map::apply(s, *map);

    conf::GenContext g{s, info, a.t.policy, standard ? &*standard : nullptr, std::nullopt};
    if (map) g.map = conf::map::terms(*map);
    std::vector<conf::Case> cases;
    cases = conf::select_cases(conf::all_cases(g), a.filter, pattern_for(a.filter));
    bool security_kept = false;  // an mbtls:// target also runs conformance/security/'s checks
    if (info.kind == conf::TargetKind::tls)
      for (const auto& n : conf::security::check_names()) security_kept = security_kept || keep(s.device.id + "/security/" + n);
    bool timing_kept = false;  // an rtu:// target also runs conformance/timing/'s checks
    if (info.kind == conf::TargetKind::rtu)
      for (const auto& k : conf::timing::check_listing()) timing_kept = timing_kept || keep(s.device.id + "/timing/" + k.id);
    if (cases.empty() && !a.filter.empty() && !security_kept && !timing_kept) {
      fmt::print(stderr, "mbconform run: error: --filter '{}' matches none of the {} cases for {}\n", a.filter,
                 conf::all_cases(g).size(), uri);
      return kExitUsage;
    }
    if (a.list) {
      std::string column = targets.size() > 1 ? uri + "  " : "";
      for (const auto& c : cases)
        fmt::print("{}{}  {}  {}  {}{}\n", column, c.id, conf::to_string(c.level), c.clause, c.title,
                   c.skip_reason.empty() ? "" : "  [skip: " + c.skip_reason + "]");
      if (info.kind == conf::TargetKind::tls)
        for (const auto& k : conf::security::check_listing())
          if (keep(s.device.id + "/security/" + k.id))
            fmt::print("{}{}/security/{}  {}  {}  {}  [a TLS check, made on connections of its own]\n", column, s.device.id, k.id,
                       conf::to_string(k.level), k.clause, k.title);
      if (info.kind == conf::TargetKind::rtu)
        for (const auto& k : conf::timing::check_listing())
          if (keep(s.device.id + "/timing/" + k.id))
            fmt::print("{}{}/timing/{}  {}  {}  {}  [a timing check, made after the cases; OBSERVED where the line cannot measure it]\n",
                       column, s.device.id, k.id, conf::to_string(k.level), k.clause, k.title);
      continue;
    }
    if (a.plan) {
      // A frame script (conformance/check/README.md): `mbconform replay` runs it.
      if (&uri == &targets.front()) fmt::print("{}\n", conf::check::kHeader);
      fmt::print("#\n# {}: {} cases, unit {}, {}\ndevice {}\n", info.uri, cases.size(), info.unit,
                 info.framing == &mbc::kRtu ? "RTU frames" : "MBAP frames (transaction id * : the target numbers its own)",
                 s.device.id);
      for (const auto& c : cases) {
        fmt::print("#\n");
        for (const auto& l : conf::check::case_lines(c, info.framing)) fmt::print("{}\n", l);
      }
      for (const auto& b : conf::cases::planned_broadcast_writes(cases)) fmt::print("# every drive on the line receives: {}\n", b);
      if (info.kind == conf::TargetKind::tls) {
        // Connections of their own, not frames of this plan: `run` makes them after the cases; replay does not.
        bool any = false;
        for (const auto& k : conf::security::check_listing())
          if (keep(s.device.id + "/security/" + k.id)) {
            if (!any) fmt::print("#\n# TLS checks `run` makes after the cases, each on connections of its own (replay does not make them):\n");
            any = true;
            fmt::print("#   {}/security/{}  {}  {}  {}\n", s.device.id, k.id, conf::to_string(k.level), k.clause, k.title);
          }
      }
      continue;
    }
    fmt::print("{}: {} cases against {}\n", s.device.id, cases.size(), info.uri);
    std::fflush(stdout);
    conf::RunOptions opt;
    stop_run = should_stop();
    opt.stop = &stop_run;
    conf::Progress progress(fmt::format("run {}", s.device.id), a.t.progress, a.quiet);
    opt.on_case = [&](const conf::CaseResult& r, size_t done, size_t total) {
      if (should_stop()) stop_run = true;
      // On a terminal a failure stays on screen as it happens; elsewhere (a
      // log, CI) the summary at the end lists it, once. -v: every case.
      if (a.verbose || (r.outcome == conf::Outcome::fail && tty)) {
        progress.clear();
        fmt::print("{}\n", conf::progress_line(r, done, total));
        std::fflush(stdout);
      }
      progress.update(done, total, "cases");
    };
    // Live drives: keep every register the run may write, put them back
    // afterwards (also after SIGINT or a target error) and report what could not be.
    std::vector<std::string> snap_notes;
    // A map in use: the target is judged by its own map, not identified as the spec's device.
    TargetOptions live_opts = a.t;
    if (!a.map.empty()) live_opts.no_preflight = true;
    if (std::string why = prepare_live(*session, live_opts, snap_notes); !why.empty()) {
      fmt::print(stderr, "mbconform run: error: {}\n", why);
      return kExitUsage;
    }
    conf::DeviceRun dr = conf::run_cases(*session, s, cases, opt);
    // The Modbus/TCP Security checks made before the cases, beside them in the report.
    for (auto& r : security_results) dr.cases.push_back(std::move(r));
    // A serial line: the RTU timing checks with figures (conformance/timing/), after the cases.
    if (info.kind == conf::TargetKind::rtu && !stop_run && !conf::stop_requested() && timing_kept) {
      try {
        for (auto& r : conf::timing::check_line(*target, s))
          if (keep(r.id)) dr.cases.push_back(std::move(r));
      } catch (const std::exception& e) {
        dr.notes.push_back(fmt::format("the timing checks stopped: {}", e.what()));
      }
    }
    conf::describe_device(dr, s);
    progress.clear();
    if (info.live) {
      for (auto& f : restore_and_say(*session, "run")) dr.restore_failures.push_back(std::move(f));
      for (auto& n : snap_notes) dr.safety_notes.push_back(std::move(n));
    }
    if (stop_run && !conf::stop_requested()) {
      // The deadline: every case not run is named, and the report is INCOMPLETE.
      for (size_t k = dr.cases.size(); k < cases.size(); ++k) {
        conf::CaseResult nr = conf::check::result_header(cases[k]);
        nr.outcome = conf::Outcome::error;
        nr.message = fmt::format("not run: --deadline {} ran out", a.deadline);
        dr.cases.push_back(std::move(nr));
      }
      dr.interrupted = true;
      report.interrupted = true;
      dr.notes.push_back(fmt::format("--deadline {} ran out: the cases not run are listed as errors", a.deadline));
    }
    dr.notes.insert(dr.notes.begin(), notes.begin(), notes.end());
    if (!quirks.empty())
      for (auto& g : conf::quirks::apply(quirks, dr)) quirks_gone.push_back(std::move(g));
    report.devices.push_back(std::move(dr));
    if (stop_run.load()) {
      report.interrupted = true;
      report.devices.back().interrupted = true;
      break;
    }
  }
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
  fmt::print("reports: {}\n", out);
  // The table, then the verdict in words as the last line (report/result.h).
  fmt::print("{}", conf::summary_table(report));
  // Interrupted, or a target lost (DeviceRun::error): the run was not done
  // (2, INCOMPLETE), whatever it found so far; the case it was lost in is a
  // FAIL in the report (a device that dies on a request is a finding).
  if (report.interrupted) return kExitUsage;
  for (const auto& d : report.devices)
    if (!d.error.empty()) return kExitUsage;
  if (run_failed(report) || !quirks_gone.empty()) return kExitFailed;
  // PARTIAL (MUST cases skipped for want of an opt-in): 0, unless the CI
  // gate asks for a complete run.
  if (a.require_complete && conf::verdict(report).kind == conf::Verdict::Kind::partial) return kExitPartial;
  return kExitOk;
}

}  // namespace

void add_run_command(CLI::App& app, int& exit_code) {
  auto a = std::make_shared<RunArgs>();
  auto* cmd = app.add_subcommand("run", "Run the conformance cases generated from a spec against targets; write reports");
  add_target_options(*cmd, a->t, true, "DIR: report directory (default reports/run/<UTC date-time>/)");
  cmd->add_flag("--list", a->list, "print the cases (id, level, clause, title) and exit");
  cmd->add_option("--filter", a->filter, "select cases by id: a part of the id, taken literally ('fc15/quantity-limit+1'); "
                  "a glob ('*/registers/*'); or a regex after 're:' ('re:fc1[56]/')");
  cmd->add_flag("--plan", a->plan, "print every frame the cases would send, without sending anything");
  cmd->add_option("--summary", a->summary_dir, "also write the stable summary.md and summary.json into this directory");
  cmd->add_option("--map", a->map,
                  "the target's data map instead of the spec's: 'auto' (probe it with reads), a map file, or "
                  "'holding=0-199,coils=0-199,input=0-199,discrete=0-199' (conformance/README.md, Maps)");
  cmd->add_option("--map-budget", a->map_budget, "the most requests --map auto sends (default 2000)")->check(CLI::Range(1, 1000000));
  add_map_time_option(cmd, a->map_time);
  add_fail_on_option(cmd, a->fail_on_should);
  cmd->add_option("--quirks", a->quirks_file, "FILE|NAME: a quirks file, or a declared library's name (jsmodbus): known deviations (case ids or globs, with "
                  "reasons) reported apart, not failed (conformance/README.md, Quirks files)");
  cmd->add_option("--deadline", a->deadline, "the whole run's time (e.g. 10m): then the run stops between cases, restores, "
                  "and names the cases not run (report INCOMPLETE, exit 2)");
  cmd->add_flag("--require-complete", a->require_complete,
                "a PARTIAL run (MUST cases skipped for want of an opt-in such as --allow-writes) exits 3 instead of 0: "
                "for a CI gate that must see every MUST case run");
  cmd->add_flag("--junit-only", a->junit_only, "write only junit.xml");
  cmd->add_flag("-q,--quiet", a->quiet, "no progress on stderr, no failure lines as they happen");
  cmd->add_flag("-v,--verbose", a->verbose, "a line for every case as it ends, not only for failures");
  cmd->callback([a, &exit_code] { exit_code = run(*a); });
}

}  // namespace mbc::cli
