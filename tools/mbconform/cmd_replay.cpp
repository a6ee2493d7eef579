// mbconform replay: any frame script (a case plan, a property counterexample
// or regression, a fuzz reproducer; conformance/script/README.md) against
// any target.
//
//   mbconform replay FILE [--target URI] [--device ID | --spec FILE]
//
// Exit 0: every expectation met; 1: one was not (the line is named);
// 2: the script cannot run there (raw bytes of another framing, a clock or a
// power cycle on a live target, an unreadable file, a target that cannot be opened).
#include <fmt/core.h>

#include "commands.h"
#include "options.h"
#include "script/script.h"
#include "targets/target.h"

namespace mbc::cli {

int replay_file(const std::string& file, const std::string& uri_in, const TargetOptions& o, const char* command) {
  conf::script::Script sc;
  try {
    sc = conf::script::parse_file(file);
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
  auto r = conf::script::replay(*target, sc, spec ? &*spec : nullptr);
  switch (r.outcome) {
    case conf::script::ReplayResult::Outcome::met:
      fmt::print("{} on {}: {} steps, every expectation met\n", file, uri, sc.steps.size());
      return kExitOk;
    case conf::script::ReplayResult::Outcome::failed:
      fmt::print("{}:{}: not met on {}: {}\n", file, r.line, uri, r.message);
      return kExitFailed;
    case conf::script::ReplayResult::Outcome::cannot_run:
      fmt::print(stderr, "mbconform {}: error: {}:{}: cannot run on {}: {}\n", command, file, r.line, uri, r.message);
      return kExitUsage;
  }
  return kExitUsage;
}

void add_replay_command(CLI::App& app, int& exit_code) {
  auto file = std::make_shared<std::string>();
  auto o = std::make_shared<TargetOptions>();
  auto* cmd = app.add_subcommand("replay", "Replay a frame script (plan, counterexample, regression, reproducer) against a target");
  cmd->add_option("FILE", *file, "a frame script (conformance/script/README.md)")->required();
  cmd->add_option_function<std::string>("--target", [o](const std::string& t) { o->targets = {t}; },
                                        "target URI (default: ref: of the script's device)");
  cmd->add_option("--device", o->device, "ID: the spec of the target (default: the script's device)");
  cmd->add_option("--spec", o->spec_file, "FILE: a spec file describing the target");
  cmd->callback([file, o, &exit_code] {
    exit_code = replay_file(*file, o->targets.empty() ? "" : o->targets.front(), *o, "replay");
  });
}

}  // namespace mbc::cli
