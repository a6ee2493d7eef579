// mbconform props: the RapidCheck properties of the profile invariants
// (conformance/properties/) against any target, with the runner's reports.
//
//   mbconform props                                        # every reference device, in-process
//   mbconform props --target ref:hsc60?fault=lost-write --cases 500 --seed 7
//   mbconform props --target tcp://10.0.0.5:502?unit=3 --device hsc60 --only read-after-write
//   mbconform props --replay conformance/properties/regressions/hsc60-lost-write.txt
//
// A falsified property prints its shrunk counterexample as hex frames with
// the seed, and writes it to DIR/regressions/ in the format of
// conformance/properties/regressions/ (add it there to replay it in ctest).
//
// Exit codes: 0 every property held, or PARTIAL (every property that ran
// held; some were skipped for want of an opt-in, named); 1 a property was
// falsified (or a replay disagreed); 2 the run could not be done or finish
// (bad target, bad spec, bad arguments, a stop signal, a target lost on the
// way: INCOMPLETE); 3 PARTIAL under --require-complete.
#include <fmt/core.h>

#include <chrono>
#include <ctime>
#include <filesystem>
#include <fstream>

#include <fcntl.h>
#include <rapidcheck/detail/Configuration.h>
#include <unistd.h>

#include "capture/pcap_tap.h"
#include "commands.h"
#include "conventions.h"
#include "loader.h"
#include "options.h"
#include "properties/properties.h"
#include "properties/stateful.h"
#include "report/report.h"
#include "safety/safety.h"
#include "session/session.h"
#include "session/progress.h"
#include "session/signals.h"
#include "report/utc_now.h"

namespace mbc::cli {
namespace {

struct PropsArgs {
  TargetOptions t;
  std::vector<std::string> only, replay;
  int cases = 100, max_size = 60;
  uint64_t seed = 0;
  bool list = false, quiet = false;
  bool require_complete = false;  // --require-complete: a PARTIAL run exits 3
};

// Replays regression files through the model; with --out, writes each back
// to DIR/regressions/ with the expectations the model gives its steps now.
int replay_files(const PropsArgs& a) {
  int rc = kExitOk;
  for (const auto& path : a.replay) {
    conf::props::Regression r;
    try {
      check_readable(path, kMaxTextFileBytes, "--replay");
      r = conf::props::parse_regression(path);
    } catch (const std::exception& e) {
      fmt::print(stderr, "mbconform props: error: {}\n", e.what());
      return kExitUsage;
    }
    std::string uri = a.t.targets.empty() ? "ref:" + r.device_id : a.t.targets.front();
    try {
      auto named = named_spec(a.t);
      if (!named) named = spec::load_spec_by_id(r.device_id);
      std::string out = a.t.out.empty() ? default_out_dir("props") : a.t.out;
      auto opened = open_session(named, uri, session_options(a.t, "props", out));
      const spec::Spec& s = *opened.spec;
      std::vector<std::string> notes;
      if (std::string why = prepare_live(*opened.session, a.t, notes); !why.empty()) throw std::runtime_error(why);
      conf::props::SpecView view(s, opened.session->info(), a.t.policy);
      conf::props::Session session(*opened.session, view, conf::props::facts_for(s));
      std::string why = conf::props::replay(session, r.steps);
      restore_and_say(*opened.session, "props");
      if (auto stop = opened.session->stopped()) {
        fmt::print("{} on {}: INCOMPLETE: {}\n", path, uri, *stop);
        return kExitUsage;
      }
      fmt::print("{} on {}: {}\n", path, uri, why.empty() ? "agrees with the model" : why);
      if (!why.empty()) rc = kExitFailed;
      if (!a.t.out.empty() && session.steps().size() >= r.steps.size()) {
        std::vector<conf::props::Step> steps(session.steps().begin(), session.steps().begin() + long(r.steps.size()));
        auto dir = std::filesystem::path(a.t.out) / "regressions";
        std::filesystem::create_directories(dir);
        std::ofstream(dir / std::filesystem::path(path).filename()) << conf::props::format_regression(r.device_id, r.fault, r.note, steps);
      }
    } catch (const std::exception& e) {
      fmt::print(stderr, "mbconform props: error: {}: {}\n", uri, e.what());
      return kExitUsage;
    }
  }
  return rc;
}

// RapidCheck prints "Using configuration: seed=..." (its own, unused here:
// each property gets --seed) the first time it reads RC_PARAMS; read it quietly.
void load_rapidcheck_quietly() {
  std::fflush(stderr);
  int saved = dup(STDERR_FILENO);
  int null = open("/dev/null", O_WRONLY);
  if (saved < 0 || null < 0) return;
  dup2(null, STDERR_FILENO);
  (void)rc::detail::configuration();
  std::fflush(stderr);
  dup2(saved, STDERR_FILENO);
  close(null);
  close(saved);
}

int run(PropsArgs& a) {
  load_rapidcheck_quietly();
  if (!a.replay.empty()) return replay_files(a);
  if (a.list) {
    for (const auto& inv : conf::props::invariants())
      fmt::print("{:<28} {}\n{:<28} {}\n", inv.name, inv.requirement, "", inv.clause);
    return kExitOk;
  }
  for (const auto& o : a.only)
    if (!conf::props::find_invariant(o)) {
      fmt::print(stderr, "mbconform props: error: --only {}: no such invariant (see --list)\n", o);
      return kExitUsage;
    }
  std::optional<spec::Spec> named;
  try {
    named = named_spec(a.t);
  } catch (const std::exception& e) {
    fmt::print(stderr, "mbconform props: error: {}\n", e.what());
    return kExitUsage;
  }
  const std::vector<std::string> targets = targets_or_default(a.t);

  conf::props::Options opt;
  opt.cases = a.cases;
  opt.seed = a.seed ? a.seed : uint64_t(std::chrono::system_clock::now().time_since_epoch().count());
  opt.max_size = a.max_size;
  opt.policy = a.t.policy;
  opt.only = a.only;

  conf::RunReport report;
  report.command = "props";
  report.started_at = conf::utc_now();
  report.version = kVersionLine;
  std::string out = a.t.out.empty() ? default_out_dir("props") : a.t.out;
  if (!conf::out_dir_ok(out, "mbconform props")) return kExitUsage;
  conf::install_stop_signals();
  bool failed = false, lost = false;
  std::vector<std::pair<std::string, std::string>> regressions;  // file name, text

  for (const auto& uri : targets) {
    if (conf::stop_requested()) break;
    // Every frame goes through the session: its gate, its journal (in the
    // report directory), its restore (conformance/session/session.h).
    Opened opened;
    conf::props::TargetSource src;
    // Inside a property too: the frames sent so far.
    std::unique_ptr<conf::Progress> progress;
    uint64_t frames_before = 0;
    try {
      auto so = session_options(a.t, "props", out);
      so.on_frame = [&](uint64_t n) {
        if (progress) progress->update(n - frames_before, 0, "frames");
      };
      opened = open_session(named, uri, std::move(so));
    } catch (const std::exception& e) {
      fmt::print(stderr, "mbconform props: error: target {}: {}\n", uri, e.what());
      return kExitUsage;
    }
    conf::Session& session = *opened.session;
    const conf::TargetInfo info = session.info();
    for (const auto& n : info.notes) fmt::print(stderr, "note: {}\n", n);  // how it was opened (a USB latency timer, ...)
    src.uri = info.uri;
    src.spec = opened.spec.get();
    // In-process targets start each generated case at power-on; a live one is the same drive throughout.
    src.link = &session;
    if (!info.live) src.afresh = [&session] { session.restart(); };
    conf::DeviceRun dr;
    if (std::string why = prepare_live(session, a.t, dr.safety_notes); !why.empty()) {
      fmt::print(stderr, "mbconform props: error: {}\n", why);
      return kExitUsage;
    }
    dr.device_id = src.spec->device.id;
    dr.target_uri = info.uri;
    dr.spec_path = src.spec->path;
    dr.baud = info.baud;
    fmt::print("{}: properties against {} (seed {}, {} cases each)\n", dr.device_id, info.uri, opt.seed, opt.cases);
    auto t0 = std::chrono::steady_clock::now();
    for (const auto& inv : conf::props::invariants()) {
      if (!a.only.empty() && std::find(a.only.begin(), a.only.end(), inv.name) == a.only.end()) continue;
      if (session.stopped()) break;
      progress = std::make_unique<conf::Progress>(fmt::format("props {} {}", dr.device_id, inv.name), a.t.progress, a.quiet);
      frames_before = session.frames();
      conf::CaseResult c = conf::props::run_invariant(inv, src, opt);
      progress.reset();
      if (auto stop = session.stopped()) {
        // Cut off inside the property: no verdict, the report says so.
        fmt::print("  {:<34} INCOMPLETE: {}\n", c.id, *stop);
        c.outcome = conf::Outcome::error;
        c.message = "not finished: " + *stop;
        c.extra.erase("regression");
        dr.interrupted = report.interrupted = true;
        dr.cases.push_back(std::move(c));
        break;
      }
      if (c.extra.contains("target_lost")) {
        // The target is gone: no verdict from this property nor the ones after it.
        fmt::print("  {:<34} INCOMPLETE: the target was lost: {}\n", c.id, c.extra["target_lost"].get<std::string>());
        c.extra.erase("regression");
        dr.interrupted = report.interrupted = lost = true;
        dr.cases.push_back(std::move(c));
        break;
      }
      for (const auto& b : c.extra.value("broadcast_writes", nlohmann::json::array())) dr.broadcast_writes.push_back(c.id + ": " + b.get<std::string>());
      fmt::print("  {:<34} {:<5} {:>5} cases {:>8.1f} ms{}\n", c.id, conf::to_string(c.outcome), c.extra.value("cases", 0),
                 c.duration_ms, c.outcome == conf::Outcome::skip ? "  (" + c.message + ")" : "");
      if (c.outcome == conf::Outcome::fail) {
        failed = true;
        if (!a.quiet) fmt::print("{}\n", c.message);
        if (c.extra.contains("regression"))
          regressions.emplace_back(fmt::format("{}-{}.txt", dr.device_id, c.title), c.extra["regression"].get<std::string>());
      }
      dr.cases.push_back(std::move(c));
    }
    dr.wall_seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
    dr.frames_sent = session.frames();  // every frame the properties sent, through the session
    if (info.live) dr.restore_failures = restore_and_say(session, "props");
    report.devices.push_back(std::move(dr));
    if (conf::stop_requested()) report.interrupted = true;
  }
  try {
    conf::write_reports(report, out);
    if (!regressions.empty()) {
      std::filesystem::create_directories(out + "/regressions");
      for (const auto& [name, text] : regressions) std::ofstream(out + "/regressions/" + name) << text;
    }
  } catch (const std::exception& e) {
    fmt::print(stderr, "mbconform props: error: writing reports: {}; no report written\n", e.what());
    return kExitUsage;
  }
  fmt::print("{}", conf::summary_table(report));
  fmt::print("reports: {}\n", out);
  if (!regressions.empty()) fmt::print("counterexamples: {}/regressions/ (copy to conformance/properties/regressions/ to replay in ctest)\n", out);
  if (lost) fmt::print("INCOMPLETE: the target was lost; the properties not run are not verdicts\n");
  if (report.interrupted) return kExitUsage;
  if (failed) return kExitFailed;
  // PARTIAL (MUST properties skipped for want of an opt-in, named by the
  // summary's last line): 0, unless the CI gate asks for a complete run.
  if (a.require_complete && conf::verdict(report).kind == conf::Verdict::Kind::partial) return kExitPartial;
  return kExitOk;
}

}  // namespace

void add_props_command(CLI::App& app, int& exit_code) {
  static PropsArgs a;
  auto* cmd = app.add_subcommand("props", "Property tests (RapidCheck) of the profile invariants against any target");
  add_target_options(*cmd, a.t, true, "DIR: reports (junit.xml, report.json, report.html) and counterexamples");
  cmd->add_option("--cases", a.cases, "generated cases per invariant (default 100)")->check(CLI::Range(1, 1000000));
  cmd->add_option("--seed", a.seed, "RapidCheck seed (default: from the clock; printed)");
  cmd->add_option("--max-size", a.max_size, "RapidCheck size bound: longest stateful sequence (default 60)")->check(CLI::Range(1, 10000));
  cmd->add_option("--only", a.only, "NAME: run only this invariant; repeatable (see --list)");
  cmd->add_option("--replay", a.replay,
                  "FILE: replay a regression file through the model (on ref:ID, or --target); with --out, write it back "
                  "to DIR/regressions/ with the model's expectations");
  cmd->add_flag("--list", a.list, "print the invariants and exit");
  add_require_complete_flag(*cmd, a.require_complete);
  cmd->add_flag("-q,--quiet", a.quiet, "do not print counterexamples (they are in the reports) nor progress");
  cmd->callback([&exit_code] { exit_code = run(a); });
}

}  // namespace mbc::cli
