// mbconform fuzz: black-box, structure-aware fuzzing of any target (the
// engine is conformance/blackbox/engine.h; this file wires its options).
//
//   mbconform fuzz --target URI [--device ID | --spec FILE] --duration 30s [--out DIR] [--seed S]
//                  [--batch N] [--quirks FILE] [--allow-motion] [--allow-eeprom-writes]
//   mbconform fuzz --replay FILE --target URI          (the same as mbconform replay)
//
// Fuzzing goes on until --duration runs out. Each distinct finding (its kind
// and the function code it came on) is reduced by delta debugging on fresh
// targets to a minimal sequence of frames and saved once, as a frame script
// (conformance/check/README.md) in DIR, with the command that replays it.
// Findings whose kind (or signature, "KIND fcNN") a quirks file declares
// (--quirks, conformance/README.md) are left aside and counted.
// Exit 0: nothing found; 1: a finding; 2: could not run.
//
// Live drives get back the values they had (conformance/safety/safety.h).
#include <fmt/core.h>

#include <filesystem>
#include <fstream>

#include "blackbox/engine.h"
#include "commands.h"
#include "options.h"
#include "quirks/quirks.h"
#include "report/report.h"
#include "safety/safety.h"
#include "targets/target.h"

namespace mbc::cli {
namespace {

namespace fs = std::filesystem;

struct FuzzArgs {
  TargetOptions t;
  std::string duration = "10s", replay, quirks_file;
  std::optional<uint64_t> seed;
  int batch = 50;
};

std::optional<std::chrono::milliseconds> parse_duration(const std::string& text) {
  size_t used = 0;
  double v = 0;
  try {
    v = std::stod(text, &used);
  } catch (...) {
    return std::nullopt;
  }
  std::string unit = text.substr(used);
  double ms = unit == "ms" ? v : unit == "" || unit == "s" ? v * 1e3 : unit == "m" ? v * 60e3 : unit == "h" ? v * 3600e3 : -1;
  if (ms < 0 || v < 0) return std::nullopt;
  return std::chrono::milliseconds(int64_t(ms));
}

fs::path save(const fs::path& dir, const conf::blackbox::Plan& plan, const conf::blackbox::Reported& r, const std::string& uri) {
  fs::path file;
  for (int i = 1;; ++i) {
    file = dir / fmt::format("finding-{}-{}.txt", r.finding.kind, i);
    if (!fs::exists(file)) break;
  }
  std::string replay = fmt::format("mbconform replay {} --target '{}'", file.string(), uri);
  std::ofstream(file) << conf::check::format(conf::blackbox::reproducer(plan, r, replay));
  return file;
}

int run_fuzz(FuzzArgs& a) {
  const std::string uri = a.t.targets.front();
  if (!a.replay.empty()) return replay_file(a.replay, uri, a.t, "fuzz");
  if (!conf::out_dir_ok(a.t.out, "mbconform fuzz")) return kExitUsage;
  auto duration = parse_duration(a.duration);
  if (!duration) {
    fmt::print(stderr, "mbconform fuzz: --duration '{}': expected e.g. 500ms, 20s, 5m, 1h\n", a.duration);
    return kExitUsage;
  }
  std::unique_ptr<conf::Target> target;
  spec::Spec s;
  conf::blackbox::Plan plan;
  conf::quirks::Quirks quirks;
  try {
    if (!a.quirks_file.empty()) quirks = conf::quirks::load(a.quirks_file);
    auto named = named_spec(a.t);
    target = conf::open_target(uri);
    s = spec_for(named, uri, target->info().device_id);
    plan = conf::blackbox::make_plan(s, target->info(), a.t.policy);
  } catch (const std::exception& e) {
    fmt::print(stderr, "mbconform fuzz: {}\n", e.what());
    return kExitUsage;
  }
  const conf::TargetInfo info = target->info();
  conf::blackbox::Open open = [&] { return conf::open_target(uri); };
  // A live drive gets back the values it had (conformance/safety/safety.h).
  std::optional<conf::Snapshot> snapshot;
  if (info.live) {
    snapshot = conf::Snapshot::take(*target, s, a.t.policy);
    for (const auto& f : snapshot->failures()) fmt::print(stderr, "mbconform fuzz: snapshot: {}\n", f);
  }
  conf::blackbox::Options o;
  o.duration = *duration;
  o.seed = a.seed.value_or(uint64_t(std::chrono::steady_clock::now().time_since_epoch().count()));
  o.batch = a.batch;
  o.isolate = info.kind == "plugin";
  o.journal = (fs::path(a.t.out) / ".journal").string();
  if (!quirks.empty()) o.declared = [&](const std::string& sig) { return quirks.for_kind(sig) != nullptr; };
  fmt::print("fuzzing {} as {} for {}, seed {}, batches of {} frames ({} readable, {} writable registers)\n", info.uri,
             s.device.id, a.duration, o.seed, a.batch, plan.readable.size(), plan.writable.size());
  std::fflush(stdout);

  auto out = conf::blackbox::fuzz(std::move(target), open, plan, o, [&](const conf::blackbox::Reported& r) {
    fmt::print("FINDING {} after {} steps: {}\n", r.finding.kind, r.history, r.finding.message);
    if (!r.reproduced)
      fmt::print("the finding does not reproduce on a fresh target (timing, state outside the frames, or the target is gone); "
                 "saving the last {} steps unreduced\n", r.steps.size());
    fs::path file = save(a.t.out, plan, r, uri);
    fmt::print("reproducer of {} step(s) ({} fresh-target runs): {}\n", r.steps.size(), r.runs, file.string());
    fmt::print("replay: mbconform replay {} --target '{}'\n", file.string(), uri);
    std::fflush(stdout);
  });

  if (snapshot) {
    try {
      auto t = open();
      for (const auto& f : snapshot->restore(*t)) fmt::print(stderr, "mbconform fuzz: NOT RESTORED: {}\n", f);
    } catch (const std::exception& e) {
      fmt::print(stderr, "mbconform fuzz: could not restore the drive's registers: {}\n", e.what());
    }
  }
  if (out.declared) fmt::print("{} finding(s) of a kind {} declares left aside\n", out.declared, a.quirks_file);
  if (out.target_lost) fmt::print("the target could not be opened again: fuzzing stopped before --duration ran out\n");
  if (out.findings.empty()) {
    fmt::print("no finding: {} frames in {} batches, every probe answered\n", out.frames, out.batches);
    return out.target_lost ? kExitUsage : kExitOk;
  }
  fmt::print("{} distinct finding(s), {} repeat(s) not saved again, {} frames in {} round(s); reproducers in {}\n",
             out.findings.size(), out.repeats, out.frames, out.rounds, a.t.out);
  return kExitFailed;
}

}  // namespace

void add_fuzz_command(CLI::App& app, int& exit_code) {
  auto args = std::make_shared<FuzzArgs>();
  args->t.out = "fuzz-findings";
  auto* cmd = app.add_subcommand("fuzz", "Black-box structure-aware fuzzing of a target; saves minimal reproducers");
  add_target_options(*cmd, args->t, false, "DIR: reproducers, one per distinct finding (default fuzz-findings)");
  cmd->add_option("--duration", args->duration, "How long to fuzz: 500ms, 20s, 5m, 1h (default 10s)");
  cmd->add_option("--seed", args->seed, "Random seed (default: from the clock, printed)");
  cmd->add_option("--batch", args->batch, "Frames between two liveness probes (default 50)")->check(CLI::Range(1, 100000));
  cmd->add_option("--quirks", args->quirks_file, "a quirks file (conformance/README.md): findings of the kinds it declares "
                  "('kind: KIND' or 'KIND fcNN', globs) are left aside");
  cmd->add_option("--replay", args->replay, "Replay a reproducer FILE instead of fuzzing (as mbconform replay)");
  cmd->callback([args, &exit_code] { exit_code = run_fuzz(*args); });
}

}  // namespace mbc::cli
