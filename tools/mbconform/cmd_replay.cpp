// mbconform replay: any frame script (a case plan, a property counterexample
// or regression, a fuzz reproducer; conformance/check/README.md) against
// any target.
//
//   mbconform replay FILE [--target URI] [--device ID | --spec FILE]
//
// Steps without a case stop at the first miss (its line is named); cases (a
// plan from `run --plan`) run the way `run` runs them: every case judged,
// OBSERVED and SHOULD outcomes recorded as such, one line of counts.
// Exit 0: every expectation met (cases: no MUST case failed); 1: one was not;
// 2: the script cannot run there (raw bytes of another framing, a clock or a
// power cycle on a live target, an unreadable file, a target that cannot be
// opened), or it did not run to the end (a stop, a target lost: INCOMPLETE).
#include <fmt/core.h>

#include "commands.h"
#include "conventions.h"
#include "loader.h"
#include "options.h"
#include "check/text.h"
#include "loader.h"
#include "report/report.h"
#include "runner/runner.h"
#include "session/progress.h"
#include "session/session.h"
#include "session/signals.h"
#include "targets/target.h"

namespace mbc::cli {

int replay_file(const std::string& file, const std::string& uri_in, const TargetOptions& o, const char* command) {
  conf::check::Script sc;
  try {
    check_readable(file, kMaxTextFileBytes, "frame script");
    sc = conf::check::parse_file(file);
  } catch (const std::exception& e) {
    fmt::print(stderr, "{}\n", e.what());
    return kExitUsage;
  }
  std::string uri = uri_in;
  if (uri.empty()) {
    if (sc.device.empty()) {
      fmt::print(stderr, "mbconform {}: error: {} names no device: give --target URI\n", command, file);
      return kExitUsage;
    }
    uri = "ref:" + sc.device;
  }
  // A `wait` holds a live line (and the drive's state) that long; on ref:
  // it moves the virtual clock and costs nothing.
  if (!o.allow_long_waits && uri.rfind("ref:", 0) != 0)
    for (const auto& st : sc.steps)
      if (st.kind == conf::check::Step::Kind::wait && st.us > uint64_t(kMaxWaitSeconds) * 1'000'000) {
        fmt::print(stderr, "mbconform {}: error: {}:{}: wait {} s is longer than {} s: --allow-long-waits\n", command, file,
                   st.line, st.us / 1'000'000, kMaxWaitSeconds);
        return kExitUsage;
      }
  // Every frame goes through the session: the gate (the same opt-ins as
  // every command), the journal, the restore (conformance/session/session.h).
  std::optional<spec::Spec> named;
  Opened opened;
  try {
    named = named_spec(o);
    // The spec says what may be written; a script names its device.
    if (!named && !sc.device.empty() && uri.rfind("ref:", 0) != 0) named = spec::load_spec_by_id(sc.device);
    conf::Uri u = conf::parse_uri(uri);
    bool live = u.scheme != "ref" && u.scheme != "plugin";
    std::string out = !o.out.empty() ? o.out : live ? default_out_dir("replay") : std::string();
    if (live && !conf::out_dir_ok(out, ("mbconform " + std::string(command)).c_str())) return kExitUsage;
    conf::install_stop_signals();
    opened = open_session(named, uri, session_options(o, command, live ? out : ""), true);
  } catch (const std::exception& e) {
    fmt::print(stderr, "mbconform {}: error: {}\n", command, e.what());
    return kExitUsage;
  }
  conf::Session& session = *opened.session;
  std::vector<std::string> notes;
  if (std::string why = prepare_live(session, o, notes); !why.empty()) {
    fmt::print(stderr, "mbconform {}: error: {}\n", command, why);
    return kExitUsage;
  }
  // Through the session (a Link): its gate, its journal, its restore.
  conf::Progress progress(command, o.progress, o.quiet);
  conf::RunOptions ro;
  ro.on_case = [&](const conf::CaseResult&, size_t done, size_t total) { progress.update(done, total, "cases"); };
  auto r = conf::replay(session, sc, opened.spec.get(), ro);
  progress.clear();
  restore_and_say(session, command);
  using Outcome = conf::ReplayResult::Outcome;
  if (auto stop = session.stopped()) {
    fmt::print("{} on {}: INCOMPLETE: {} at line {}\n", file, uri, *stop, r.line);
    return kExitUsage;
  }
  // A live target that failed a step and then no longer answers (its
  // connection closed and cannot be opened again, the line gone) was lost.
  if (!r.target_lost && r.outcome == Outcome::failed && session.info().live)
    if (std::string why = session.reachable(); !why.empty()) {
      r.target_lost = true;
      r.message += "\n  then: " + why;
    }
  if (r.target_lost) {
    fmt::print("{} on {}: INCOMPLETE: the target was lost at line {}: {}\n", file, uri, r.line, r.message);
    return kExitUsage;
  }
  if (r.outcome != Outcome::cannot_run && r.line == 0 && !sc.cases.empty()) {
    // Cases: one line of counts, a line per failed case (as `run` counts them).
    auto n = conf::count(r.run);
    for (const auto& c : r.run.cases)
      if (c.outcome == conf::Outcome::fail || c.outcome == conf::Outcome::error)
        fmt::print("{} {} [{}] {}: {}\n", c.outcome == conf::Outcome::fail ? "FAIL" : "ERROR", c.id, conf::to_string(c.level),
                   c.clause, c.message);
    fmt::print("{} on {}: {} cases: {} pass, {} fail, {} observed, {} skip{}{}\n", file, uri, r.run.cases.size(), n.pass,
               n.fail, n.observed, n.skip, n.error ? fmt::format(", {} error", n.error) : "",
               sc.steps.empty() ? "" : fmt::format(" (and {} steps before the first case, every expectation met)", sc.steps.size()));
    if (!r.run.error.empty()) {
      fmt::print("{} on {}: INCOMPLETE: {}\n", file, uri, r.run.error);  // a lost target: no verdict on the rest
      return kExitUsage;
    }
    return n.must_failed > 0 ? kExitFailed : kExitOk;
  }
  switch (r.outcome) {
    case Outcome::met:
      fmt::print("{} on {}: {} steps, every expectation met\n", file, uri, sc.steps.size());
      return kExitOk;
    case Outcome::failed:
      fmt::print("{}:{}: not met on {}: {}\n", file, r.line, uri, r.message);
      return kExitFailed;
    case Outcome::cannot_run:
      fmt::print(stderr, "mbconform {}: error: {}:{}: cannot run on {}: {}\n", command, file, r.line, uri, r.message);
      return kExitUsage;
  }
  return kExitUsage;
}

void add_replay_command(CLI::App& app, int& exit_code) {
  auto file = std::make_shared<std::string>();
  auto o = std::make_shared<TargetOptions>();
  auto* cmd = app.add_subcommand("replay", "Replay a frame script (plan, counterexample, regression, reproducer) against a target");
  cmd->add_option("FILE", *file, "a frame script (conformance/check/README.md)")->required();
  cmd->add_option_function<std::string>("--target", [o](const std::string& t) { o->targets = {t}; },
                                        "target URI (default: ref: of the script's device)");
  cmd->add_option("--device", o->device, "ID: the spec of the target (default: the script's device)");
  cmd->add_option("--spec", o->spec_file, "FILE: a spec file describing the target");
  cmd->add_option("--out", o->out, "DIR: the journal of a live target (default reports/replay/<UTC date-time>/)");
  add_opt_ins(*cmd, *o);
  cmd->add_flag("--no-preflight", o->no_preflight, "live targets: skip the read-only check that the drive looks like the spec");
  cmd->add_flag("--progress", o->progress, "progress on stderr (cases done of the script's, rate, ETA) even when it is not a terminal");
  cmd->add_flag("-q,--quiet", o->quiet, "no progress");
  cmd->callback([file, o, &exit_code] {
    exit_code = replay_file(*file, o->targets.empty() ? "" : o->targets.front(), *o, "replay");
  });
}

}  // namespace mbc::cli
