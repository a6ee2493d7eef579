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
// power cycle on a live target, an unreadable file, a target that cannot be opened).
#include <fmt/core.h>

#include "commands.h"
#include "options.h"
#include "check/text.h"
#include "report/report.h"
#include "runner/runner.h"
#include "session/link.h"
#include "targets/target.h"

namespace mbc::cli {

int replay_file(const std::string& file, const std::string& uri_in, const TargetOptions& o, const char* command) {
  conf::check::Script sc;
  try {
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
  std::optional<spec::Spec> spec;
  std::unique_ptr<conf::Target> target;
  try {
    auto named = named_spec(o);
    target = conf::open_target(uri);
    // The spec only adds the exception codes the device documents; a script
    // of a device nobody names is judged by the standard alone.
    std::string device = sc.device.empty() ? target->info().device_id : sc.device;
    if (named || !device.empty() || uri.rfind("ref:", 0) == 0) spec = spec_for(named, uri, device);
  } catch (const std::exception& e) {
    fmt::print(stderr, "mbconform {}: error: {}\n", command, e.what());
    return kExitUsage;
  }
  // A Target as a Link, no gate yet: the session (session/link.h) gives its
  // gated, journalled Link here.
  conf::DirectLink link(*target);
  auto r = conf::replay(link, sc, spec ? &*spec : nullptr);
  using Outcome = conf::ReplayResult::Outcome;
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
    if (!r.run.error.empty()) fmt::print(stderr, "mbconform {}: {}\n", command, r.run.error);
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
  cmd->callback([file, o, &exit_code] {
    exit_code = replay_file(*file, o->targets.empty() ? "" : o->targets.front(), *o, "replay");
  });
}

}  // namespace mbc::cli
