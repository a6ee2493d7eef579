// mbconform run: the conformance cases generated from a spec, against any
// target, with reports for people (HTML, terminal) and CI (JUnit, JSON).
//
//   mbconform run                                   # every reference device in-process
//   mbconform run --target tcp://10.0.0.5:502?unit=3 --device hsc60 --allow-motion
//   mbconform run --target ref:hsc60 --filter '*/registers/*' --plan
//   mbconform run --scan-file scan.json             # a fleet: every drive a scan identified (run_fleet)
//
// Exit codes: 0 every MUST case passed (PASS), or every MUST case that ran
// passed but some were skipped for want of an opt-in (PARTIAL); 1 a MUST case
// failed (or a declared quirk is gone: its cases ran and passed); 2 the run
// could not be done (bad target, bad spec, bad arguments, interrupted); 3 a
// PARTIAL run under --require-complete. A fleet exits with the worst of its
// drives' codes (2 > 1 > 3 > 0); a unit not identified is not run and counts for none.
#include <fmt/core.h>
#include <re2/re2.h>
#include <unistd.h>

#include <algorithm>
#include <atomic>
#include <cctype>
#include <chrono>
#include <csignal>
#include <ctime>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <mutex>
#include <set>
#include <thread>
#include <tuple>

#include "capture/pcap_tap.h"
#include "cases/case.h"
#include "cases/common.h"
#include "commands.h"
#include "conventions.h"
#include "loader.h"
#include "map/map.h"
#include "options.h"
#include "report/quirks.h"
#include "report/fleet.h"
#include "report/report.h"
#include "runner/runner.h"
#include "scan/scan.h"
#include "check/text.h"
#include "safety/safety.h"
#include "security/security.h"
#include "timing/timing.h"
#include "session/session.h"
#include "session/progress.h"
#include "session/signals.h"
#include "spec_path.h"
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
  // A fleet (run_fleet): the lines' scan files, or --scan of each --target first.
  std::vector<std::string> scan_files;
  bool scan = false;
  std::string scan_units = "1-247", scan_budget = "10m";
};

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
// What a target will be, for --list and --plan: a live one is not opened
// (nothing is connected, nothing is sent); an in-process one says itself.
conf::TargetInfo planned_info(const std::string& uri, const spec::Spec& s) {
  conf::Uri u = conf::parse_uri(uri);
  conf::TargetInfo i;
  i.uri = uri;
  i.kind = conf::kind_of_uri(u, uri);
  i.framing = conf::framing_of(i.kind);  // what open_target's target would say
  i.live = conf::is_live(i.kind);
  // An in-process target (ref:, plugin:) describes itself once opened, as the
  // run opens it (nothing reaches a wire): a plugin takes raw RTU ADUs
  // (`raw`: the cases of malformed frames) only when it exports handle_rtu,
  // and power cycles or a clock only when it exports them; a ref: device
  // has both. The scheme does not say.
  if (!i.live) return conf::open_target(uri)->info();
  // A transport carries ADU bytes as they are (tcp: raw MBAP; rtu, rtu-tcp, mbtls).
  i.raw = true;
  i.unit = uint8_t(std::stoi(u.param("unit").value_or(std::to_string(s.serial.slave_default.value_or(1)))));
  if (auto b = u.param("baud")) i.baud = std::stoi(*b);
  return i;
}

// What every target of one `run` shares, set up once before anything is opened.
struct RunSetup {
  std::optional<spec::Spec> standard;
  std::optional<spec::Spec> named;
  conf::quirks::Quirks quirks;
  std::optional<conf::map::Map> given_map;
  std::function<bool(const std::string&)> keep;
  std::optional<std::chrono::steady_clock::time_point> deadline;
  bool dry = false;  // --list or --plan: nothing is opened but ref: targets
  bool tty = false;
  bool no_progress = false;  // several lines at once: no progress lines over each other
  // A stop signal, or the deadline passed.
  bool should_stop() const {
    return conf::stop_requested() || (deadline && std::chrono::steady_clock::now() >= *deadline);
  }
};

// Reads what every target shares; empty, or the one line to print (exit 2).
std::string set_up(const RunArgs& a, RunSetup& c) {
  try {
    c.standard = spec::load_spec_by_id("modbus-standard");
  } catch (const std::exception& e) {
    fmt::print(stderr, "mbconform run: warning: no modbus-standard spec ({}); deviations are not checked\n", e.what());
  }
  try {
    c.named = named_spec(a.t);
  } catch (const std::exception& e) {
    return fmt::format("mbconform run: error: {}", e.what());
  }
  // A map without a spec: the standard's cases where the map allows.
  if (!a.map.empty() && !c.named && c.standard) c.named = *c.standard;
  if (!a.quirks_file.empty()) {
    try {
      std::string file = conf::quirks::find(a.quirks_file);  // a path, or a declared library's name
      check_readable(file, kMaxQuirksBytes, "--quirks");
      c.quirks = conf::quirks::load(file);
    } catch (const std::exception& e) {
      return e.what();
    }
  }
  if (!a.map.empty() && a.map != "auto") {
    try {
      c.given_map = conf::map::parse_option(a.map);
    } catch (const std::exception& e) {
      return fmt::format("mbconform run: error: {}", e.what());
    }
  }
  try {
    c.keep = [](const std::string&) { return true; };
    if (!a.filter.empty()) {
      // The same selection as select_cases, for ids no generator makes (the TLS checks).
      auto pattern = pattern_for(a.filter);
      c.keep = [filter = a.filter, pattern](const std::string& id) {
        conf::Case k;
        k.id = id;
        return !conf::select_cases({k}, filter, pattern).empty();
      };
      (void)c.keep("");  // a pattern RE2 does not take fails here, before anything is opened
    }
  } catch (const std::exception& e) {
    return fmt::format("mbconform run: error: {}", e.what());
  }
  conf::install_stop_signals();
  if (!a.deadline.empty()) {
    auto d = parse_duration(a.deadline);
    if (!d) return fmt::format("mbconform run: error: {}", duration_error("--deadline", a.deadline));
    c.deadline = std::chrono::steady_clock::now() + *d;
  }
  c.dry = a.list || a.plan;
  c.tty = isatty(STDOUT_FILENO) && !a.quiet;
  return "";
}

conf::RunReport new_report(const RunArgs& a) {
  conf::RunReport report;
  report.command = "run";
  report.started_at = conf::utc_now();
  report.version = kVersionLine;
  report.fail_on_should = a.fail_on_should;
  return report;
}

// What became of one target.
struct TargetEnd {
  enum class Kind { next, stop, cannot } kind = Kind::next;  // go on; stop the run (a signal, the deadline); not done
  std::string why;                                           // cannot: the line to print after "mbconform run: error: "
};

// The one path of a target: opens `uri` through a session (unless dry),
// lists or plans its cases, or runs them with the spec `s` and puts their
// results into `report` (journal in `out`). `first`: the first target of the
// run (the plan's header); `many`: --list names the target on each line.
TargetEnd run_target(const RunArgs& a, const RunSetup& c, const std::string& uri, spec::Spec s, const std::string& out,
                     bool first, bool many, conf::RunReport& report, conf::quirks::Quirks& quirks,
                     std::vector<std::string>& quirks_gone) {
  using Kind = TargetEnd::Kind;
  const auto& keep = c.keep;
  // Every frame goes through the session: its gate, its journal (in the
  // report directory), its restore (conformance/session/session.h).
  std::unique_ptr<conf::Session> session;
  conf::Link* target = nullptr;  // the session, as the one Link every frame goes through
  conf::TargetInfo info;
  try {
    if (!c.dry || (uri.rfind("ref:", 0) == 0 && !c.named)) {
      auto so = session_options(a.t, "run", out);
      so.stop_mid_exchange = false;  // the runner stops between cases
      session = std::make_unique<conf::Session>(uri, &s, std::move(so));
      if (!session->journal_path().empty())
        fmt::print(stderr, "journal: {} (if this command is killed: mbconform restore {})\n", session->journal_path(),
                   session->journal_path());
      target = session.get();
      info = target->info();
      for (const auto& n : info.notes) fmt::print(stderr, "note: {}\n", n);  // how it was opened (a USB latency timer, ...)
    } else {
      info = planned_info(conf::line_settings(uri, &s).uri, s);
    }
  } catch (const std::exception& e) {
    return {Kind::cannot, fmt::format("cannot open target {}: {}", uri, e.what())};
  }

  // Modbus/TCP Security: what the server does around the TLS handshake
  // (conformance/security/), each check on connections of its own, before
  // the cases. A server that does not carry the MBAP ADU inside TLS cannot
  // run a case: its failure is the run's verdict (exit 1), not "could not
  // be done".
  std::vector<conf::CaseResult> security_results;
  bool no_mbap = false;
  if (info.kind == conf::TargetKind::tls && target && !c.dry && !conf::stop_requested()) {
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
    return {};
  }

  std::vector<std::string> notes;
  std::optional<conf::map::Map> map = c.given_map;
  if (a.map == "auto" && target) {
    if (std::string why = session->reachable(); !why.empty()) return {Kind::cannot, why};
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

  conf::GenContext g{s, info, a.t.policy, c.standard ? &*c.standard : nullptr, std::nullopt};
  if (map) g.map = conf::map::terms(*map);
  std::vector<conf::Case> cases;
  cases = conf::select_cases(conf::all_cases(g), a.filter, pattern_for(a.filter));
  bool security_kept = false;  // an mbtls:// target also runs conformance/security/'s checks
  if (info.kind == conf::TargetKind::tls)
    for (const auto& n : conf::security::check_names()) security_kept = security_kept || keep(s.device.id + "/security/" + n);
  bool timing_kept = false;  // an rtu:// target also runs conformance/timing/'s checks
  if (info.kind == conf::TargetKind::rtu)
    for (const auto& k : conf::timing::check_listing()) timing_kept = timing_kept || keep(s.device.id + "/timing/" + k.id);
  if (cases.empty() && !a.filter.empty() && !security_kept && !timing_kept)
    return {Kind::cannot, fmt::format("--filter '{}' matches none of the {} cases for {}", a.filter, conf::all_cases(g).size(), uri)};
  if (a.list) {
    std::string column = many ? uri + "  " : "";
    for (const auto& k : cases)
      fmt::print("{}{}  {}  {}  {}{}\n", column, k.id, conf::to_string(k.level), k.clause, k.title,
                 k.skip_reason.empty() ? "" : "  [skip: " + k.skip_reason + "]");
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
    return {};
  }
  if (a.plan) {
    // A frame script (conformance/check/README.md): `mbconform replay` runs it.
    if (first) fmt::print("{}\n", conf::check::kHeader);
    fmt::print("#\n# {}: {} cases, unit {}, {}\ndevice {}\n", info.uri, cases.size(), info.unit,
               info.framing == &mbc::kRtu ? "RTU frames" : "MBAP frames (transaction id * : the target numbers its own)",
               s.device.id);
    for (const auto& k : cases) {
      fmt::print("#\n");
      for (const auto& l : conf::check::case_lines(k, info.framing)) fmt::print("{}\n", l);
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
    return {};
  }
  fmt::print("{}: {} cases against {}\n", s.device.id, cases.size(), info.uri);
  std::fflush(stdout);
  conf::RunOptions opt;
  std::atomic<bool> stop_run{c.should_stop()};  // set between cases: a stop signal, or the deadline passed
  opt.stop = &stop_run;
  conf::Progress progress(fmt::format("run {}", s.device.id), a.t.progress && !c.no_progress, a.quiet || c.no_progress);
  opt.on_case = [&](const conf::CaseResult& r, size_t done, size_t total) {
    if (c.should_stop()) stop_run = true;
    // On a terminal a failure stays on screen as it happens; elsewhere (a
    // log, CI) the summary at the end lists it, once. -v: every case.
    if (a.verbose || (r.outcome == conf::Outcome::fail && c.tty)) {
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
  if (std::string why = prepare_live(*session, live_opts, snap_notes); !why.empty()) return {Kind::cannot, why};
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
    for (auto& q : conf::quirks::apply(quirks, dr)) quirks_gone.push_back(std::move(q));
  report.devices.push_back(std::move(dr));
  if (stop_run.load()) {
    report.interrupted = true;
    report.devices.back().interrupted = true;
    return {Kind::stop, ""};
  }
  return {};
}

// Writes `report` into `out` (and --summary's directory); empty, or the line to print.
std::string write_run(const RunArgs& a, const conf::RunReport& report, const std::string& out) {
  try {
    conf::write_reports(report, out, a.junit_only);
    if (!a.summary_dir.empty()) {
      std::filesystem::create_directories(a.summary_dir);
      auto sj = conf::stable_summary(report);
      std::ofstream(a.summary_dir + "/summary.json") << sj.dump(1) << "\n";
      std::ofstream(a.summary_dir + "/summary.md") << conf::summary_markdown(sj);
    }
  } catch (const std::exception& e) {
    return fmt::format("mbconform run: error: {}", e.what());
  }
  return "";
}

// The exit code of a run that was done (the top of this file).
int exit_code_of(const RunArgs& a, const conf::RunReport& report, const std::vector<std::string>& quirks_gone) {
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

int run_fleet(RunArgs& a);

int run(RunArgs& a) {
  if (a.scan || !a.scan_files.empty()) return run_fleet(a);
  RunSetup c;
  if (std::string why = set_up(a, c); !why.empty()) {
    fmt::print(stderr, "{}\n", why);
    return kExitUsage;
  }
  // No target: every reference device, or, when a spec is named, its own
  // reference device once (not every reference device under one spec).
  std::vector<std::string> targets = a.t.targets;
  if (targets.empty() && c.named) targets.push_back("ref:" + c.named->device.id);
  if (targets.empty()) targets = targets_or_default(a.t);

  conf::RunReport report = new_report(a);
  std::vector<std::string> quirks_gone;  // declared quirks whose cases ran and passed (in the notes too)
  const std::string out = !a.t.out.empty() ? a.t.out : c.dry ? std::string() : default_out_dir("run");
  if (!c.dry && !conf::out_dir_ok(out, "mbconform run")) return kExitUsage;
  if (!c.dry && !a.summary_dir.empty()) {
    if (std::string why = conf::out_dir_problem(a.summary_dir); !why.empty()) {
      fmt::print(stderr, "mbconform run: error: --summary: {}\n", why);
      return kExitUsage;
    }
  }
  for (const auto& uri : targets) {
    spec::Spec s;
    try {
      s = spec_for(c.named, uri);
    } catch (const std::exception& e) {
      fmt::print(stderr, "mbconform run: error: target {}: {}\n", uri, e.what());
      return kExitUsage;
    }
    TargetEnd end = run_target(a, c, uri, std::move(s), out, &uri == &targets.front(), targets.size() > 1, report, c.quirks,
                                quirks_gone);
    if (end.kind == TargetEnd::Kind::cannot) {
      fmt::print(stderr, "mbconform run: error: {}\n", end.why);
      return kExitUsage;
    }
    if (end.kind == TargetEnd::Kind::stop) break;
  }
  if (c.dry) return kExitOk;
  if (std::string why = write_run(a, report, out); !why.empty()) {
    fmt::print(stderr, "{}\n", why);
    return kExitUsage;
  }
  fmt::print("reports: {}\n", out);
  // The table, then the verdict in words as the last line (report/result.h).
  fmt::print("{}", conf::summary_table(report));
  return exit_code_of(a, report, quirks_gone);
}

// ---- a fleet: every drive a scan identified (run --scan, run --scan-file) ----
//
// Each drive is one run_target() of its own, on the target and spec the
// scan found (its unit; its matched spec), into its own report directory
// OUT/<port-or-host>-unit<N>/; the drives of one line one after another (a
// line carries one exchange at a time), the lines at once. Every frame still
// goes through that drive's session and the one frame policy: a session
// writes to its own unit only, and a broadcast (which every drive of the
// line would take) is refused up front. A unit the scan did not identify is
// listed and never run.

// One line of a fleet, and the scan of it (read from a file, or made here).
struct FleetLine {
  std::string key;       // scan::line_of: the port, or HOST:PORT
  std::string scan_uri;  // --scan: the line to scan
  std::optional<conf::scan::Result> scanned;
  std::string prefix;    // its drives' report directories: PREFIX-unitN
};

// "/dev/ttyUSB0" -> "ttyUSB0", "10.0.0.5:502" -> "10.0.0.5": a directory name.
std::string dir_prefix(const std::string& key) {
  std::string base = key.substr(key.find_last_of('/') + 1);
  if (auto colon = base.find(':'); colon != std::string::npos) base.resize(colon);
  for (char& ch : base)
    if (!std::isalnum(static_cast<unsigned char>(ch)) && ch != '.' && ch != '-' && ch != '_') ch = '-';
  return base.empty() || base == "." || base == ".." ? "line" : base;
}

// Why these options cannot make a fleet, or empty.
std::string fleet_refusal(const RunArgs& a) {
  if (a.scan && !a.scan_files.empty()) return "--scan and --scan-file: one or the other (a scan file is a scan already made)";
  if (a.scan && a.t.targets.empty()) return "--scan: name each line to scan with --target (rtu:///dev/ttyUSB0, tcp://HOST:PORT; repeatable)";
  if (!a.scan_files.empty() && !a.t.targets.empty())
    return "--scan-file names its lines and units: --target goes with --scan (or without a scan, for one drive)";
  if (a.scan && (a.plan || a.list))
    return "--plan and --list open nothing, and --scan sends reads: scan first (mbconform scan URI --out scan.json), then "
           "run --scan-file scan.json --plan";
  if (!a.t.device.empty() || !a.t.spec_file.empty())
    return "--device/--spec: each drive of a fleet runs on the spec its scan matched (a unit not identified is not run)";
  if (!a.map.empty()) return "--map: each drive of a fleet runs on the spec its scan matched";
  if (a.t.policy.allow_broadcast)
    return "--allow-broadcast: every drive of a fleet's line would take a broadcast, and a fleet writes to no drive but the one "
           "it qualifies (run one drive with --target to broadcast)";
  if (!a.t.pcap.empty()) return "--pcap: a fleet's drives run at once on several lines; capture one drive with --target";
  if (!a.summary_dir.empty()) return "--summary: a fleet writes its summary.json beside the drives' reports (--out)";
  return "";
}

// Qualifies every drive of `line`, one after another, appending each to `drives`.
void qualify_line(const RunArgs& a, const RunSetup& c, FleetLine& line, const std::vector<const spec::Spec*>& specs,
                  const std::string& out, std::vector<conf::FleetDrive>& drives, std::mutex& mu) {
  auto add = [&](conf::FleetDrive d) {
    std::lock_guard lock(mu);
    drives.push_back(std::move(d));
  };
  auto line_incomplete = [&](const std::string& why) {
    conf::FleetDrive d;
    d.line = line.key;
    d.target = line.scanned ? line.scanned->uri : line.scan_uri;
    d.verdict = "INCOMPLETE";
    d.exit_code = kExitUsage;
    d.why = why;
    add(std::move(d));
  };
  if (!line.scanned) {
    conf::scan::Options o;
    o.uri = line.scan_uri;
    std::tie(o.first_unit, o.last_unit) = conf::scan::parse_units(a.scan_units);
    o.budget = *parse_duration(a.scan_budget);
    fmt::print("scanning {} (units {}, budget {}; read-only)\n", line.scan_uri, a.scan_units, a.scan_budget);
    try {
      line.scanned = conf::scan::scan(o, specs);
    } catch (const std::exception& e) {
      fmt::print(stderr, "mbconform run: error: scan of {}: {}\n", line.scan_uri, e.what());
      line_incomplete(fmt::format("the scan of the line failed: {}", e.what()));
      return;
    }
    fmt::print("{}", conf::scan::table(*line.scanned));
  }
  const conf::scan::Result& r = *line.scanned;
  if (r.partial) line_incomplete(fmt::format("the scan of this line was PARTIAL ({}): drives may be missing", r.partial_why));
  for (const conf::scan::Found& f : r.units) {
    conf::FleetDrive d;
    d.line = line.key;
    d.unit = f.unit;
    d.target = f.target;
    d.confidence = f.confidence;
    if (!f.best || f.confidence == "none") {
      d.verdict = "NOT RUN";
      d.why = fmt::format("not identified by the scan (no known spec matched): not run; to see it: {}", f.command);
      add(std::move(d));
      continue;
    }
    d.device_id = f.best->spec_id;
    d.dir = fmt::format("{}-unit{}", line.prefix, f.unit);
    const std::string drive_out = out + "/" + d.dir;
    conf::RunReport report = new_report(a);
    conf::quirks::Quirks quirks = c.quirks;  // each drive's own: apply() marks what it matched
    std::vector<std::string> quirks_gone;
    TargetEnd end;
    if (c.should_stop()) {
      end = {TargetEnd::Kind::cannot, conf::stop_requested() ? "not run: the fleet was stopped before it"
                                                             : fmt::format("not run: --deadline {} ran out before it", a.deadline)};
    } else {
      try {
        spec::Spec s = spec::load_spec_by_id(d.device_id);
        if (std::string why = conf::out_dir_problem(drive_out); !why.empty())
          end = {TargetEnd::Kind::cannot, "--out: " + why};
        else
          end = run_target(a, c, f.target, std::move(s), drive_out, true, false, report, quirks, quirks_gone);
      } catch (const std::exception& e) {
        end = {TargetEnd::Kind::cannot, fmt::format("spec {}: {}", d.device_id, e.what())};
      }
    }
    if (end.kind == TargetEnd::Kind::cannot || report.devices.empty()) {
      if (end.why.empty()) end.why = "the run made no report";
      fmt::print(stderr, "mbconform run: error: {} unit {}: {}\n", line.key, f.unit, end.why);
      conf::DeviceRun dr;
      dr.device_id = d.device_id;
      dr.target_uri = f.target;
      dr.error = end.why;
      report.devices.push_back(std::move(dr));
      d.why = end.why;
    }
    if (std::string why = write_run(a, report, drive_out); !why.empty()) {
      fmt::print(stderr, "{}\n", why);
      d.why = why;
      report.devices.back().error = why;
    }
    d.exit_code = exit_code_of(a, report, quirks_gone);
    d.verdict = conf::verdict(report).word();
    d.run = report.devices.back();
    fmt::print("{} unit {} ({}): {}, exit {}; reports: {}\n", line.key, f.unit, d.device_id, d.verdict, d.exit_code, drive_out);
    std::fflush(stdout);
    add(std::move(d));
  }
}

// --plan / --list of a fleet from its scan files: nothing is opened.
int plan_fleet(const RunArgs& a, const RunSetup& c, std::vector<FleetLine>& lines) {
  bool first = true;
  for (auto& line : lines)
    for (const conf::scan::Found& f : line.scanned->units) {
      if (!f.best || f.confidence == "none") {
        fmt::print(a.plan ? stdout : stderr, "# {} unit {}: not identified by the scan: not run\n", line.key, f.unit);
        continue;
      }
      conf::RunReport unused;
      std::vector<std::string> gone;
      spec::Spec s;
      try {
        s = spec::load_spec_by_id(f.best->spec_id);
      } catch (const std::exception& e) {
        fmt::print(stderr, "mbconform run: error: {} unit {}: spec {}: {}\n", line.key, f.unit, f.best->spec_id, e.what());
        return kExitUsage;
      }
      conf::quirks::Quirks quirks = c.quirks;
      TargetEnd end = run_target(a, c, f.target, std::move(s), "", first, true, unused, quirks, gone);
      first = false;
      if (end.kind == TargetEnd::Kind::cannot) {
        fmt::print(stderr, "mbconform run: error: {}\n", end.why);
        return kExitUsage;
      }
    }
  return kExitOk;
}

int run_fleet(RunArgs& a) {
  if (std::string why = fleet_refusal(a); !why.empty()) {
    fmt::print(stderr, "mbconform run: error: {}\n", why);
    return kExitUsage;
  }
  if (a.scan) {
    try {
      (void)conf::scan::parse_units(a.scan_units);
    } catch (const std::exception& e) {
      fmt::print(stderr, "mbconform run: error: --scan-units {}\n", e.what());
      return kExitUsage;
    }
    if (!parse_duration(a.scan_budget)) {
      fmt::print(stderr, "mbconform run: error: {}\n", duration_error("--scan-budget", a.scan_budget));
      return kExitUsage;
    }
  }
  std::vector<FleetLine> lines;
  auto add_line = [&](FleetLine l, const std::string& from) {
    for (const auto& other : lines)
      if (other.key == l.key) throw std::invalid_argument(fmt::format("{}: the line {} is named twice", from, l.key));
    lines.push_back(std::move(l));
  };
  try {
    for (const auto& file : a.scan_files) {
      check_readable(file, kMaxTextFileBytes, "--scan-file");
      std::ifstream in(file, std::ios::binary);
      std::string text((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
      FleetLine l;
      l.scanned = conf::scan::from_json(text, file);
      l.key = conf::scan::line_of(l.scanned->uri);
      add_line(std::move(l), file);
    }
    for (const auto& uri : a.t.targets) {
      FleetLine l;
      l.scan_uri = uri;
      l.key = conf::scan::line_of(uri);
      add_line(std::move(l), uri);
    }
  } catch (const std::exception& e) {
    fmt::print(stderr, "mbconform run: error: {}\n", e.what());
    return kExitUsage;
  }
  // Each line's directory names, told apart when two lines share a base name.
  std::set<std::string> prefixes;
  for (auto& l : lines) {
    std::string p = dir_prefix(l.key);
    for (int k = 2; !prefixes.insert(p).second; ++k) p = fmt::format("{}-{}", dir_prefix(l.key), k);
    l.prefix = p;
  }
  RunSetup c;
  if (std::string why = set_up(a, c); !why.empty()) {
    fmt::print(stderr, "{}\n", why);
    return kExitUsage;
  }
  if (c.dry) return plan_fleet(a, c, lines);

  // The known specs a --scan identifies drives against.
  std::vector<spec::Spec> loaded;
  std::vector<const spec::Spec*> specs;
  if (a.scan) {
    for (const auto& id : spec::spec_ids()) loaded.push_back(spec::load_spec_by_id(id));
    for (const auto& s : loaded) specs.push_back(&s);
  }
  const std::string started = conf::utc_now();
  const std::string out = !a.t.out.empty() ? a.t.out : default_out_dir("run");
  if (!conf::out_dir_ok(out, "mbconform run")) return kExitUsage;
  c.no_progress = lines.size() > 1;
  std::vector<conf::FleetDrive> drives;
  std::mutex mu;
  auto one = [&](FleetLine& line) {
    try {
      qualify_line(a, c, line, specs, out, drives, mu);
    } catch (const std::exception& e) {
      fmt::print(stderr, "mbconform run: error: {}: {}\n", line.key, e.what());
      std::lock_guard lock(mu);
      conf::FleetDrive d;
      d.line = line.key;
      d.verdict = "INCOMPLETE";
      d.exit_code = kExitUsage;
      d.why = e.what();
      drives.push_back(std::move(d));
    }
  };
  if (lines.size() == 1) {
    one(lines.front());
  } else {
    // One thread per line: a line carries one exchange at a time, the lines at once.
    std::vector<std::thread> threads;
    for (auto& l : lines) threads.emplace_back(one, std::ref(l));
    for (auto& t : threads) t.join();
  }
  std::sort(drives.begin(), drives.end(), [](const conf::FleetDrive& x, const conf::FleetDrive& y) {
    return std::tie(x.line, x.unit) < std::tie(y.line, y.unit);
  });
  try {
    std::ofstream(out + "/summary.json") << conf::fleet_summary(drives, started, kVersionLine).dump(1) << "\n";
    std::ofstream junit(out + "/junit.xml");
    junit << conf::fleet_junit(drives, started, kVersionLine, a.fail_on_should);
    if (!junit) throw std::runtime_error("cannot write " + out + "/junit.xml");
  } catch (const std::exception& e) {
    fmt::print(stderr, "mbconform run: error: {}\n", e.what());
    return kExitUsage;
  }
  fmt::print("{}", conf::fleet_table(drives));
  fmt::print("reports: {} (summary.json, junit.xml; one directory per drive)\n", out);
  return conf::fleet_exit_code(drives);
}

}  // namespace

void add_require_complete_flag(CLI::App& cmd, bool& require_complete) {
  cmd.add_flag("--require-complete", require_complete,
               "a PARTIAL run (MUST cases skipped for want of an opt-in such as --allow-writes) exits 3 instead of 0: "
               "for a CI gate that must see every MUST case run");
}

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
  add_require_complete_flag(*cmd, a->require_complete);
  cmd->add_flag("--scan", a->scan,
                "a fleet: scan each --target line first (read-only, as `mbconform scan`), then qualify every drive it "
                "identified on the spec it matched, one drive at a time per line, the lines at once; a report per drive "
                "in OUT/<port-or-host>-unit<N>/, summary.json and junit.xml over all (conformance/scan/README.md)");
  cmd->add_option("--scan-file", a->scan_files,
                  "FILE: a fleet from a scan already made (`mbconform scan URI --out FILE`; repeatable, one per line): "
                  "qualify every drive it identified, as --scan does; --plan opens nothing")
      ->excludes(cmd->get_option("--scan"));
  cmd->add_option("--scan-units", a->scan_units, "FIRST-LAST: the units --scan tries")->capture_default_str();
  cmd->add_option("--scan-budget", a->scan_budget, "DURATION: the longest --scan of one line runs")->capture_default_str();
  cmd->add_flag("--junit-only", a->junit_only, "write only junit.xml");
  cmd->add_flag("-q,--quiet", a->quiet, "no progress on stderr, no failure lines as they happen");
  cmd->add_flag("-v,--verbose", a->verbose, "a line for every case as it ends, not only for failures");
  cmd->callback([a, &exit_code] { exit_code = run(*a); });
}

}  // namespace mbc::cli
