// mbconform fuzz: black-box, structure-aware fuzzing of any target (the
// engine is conformance/blackbox/engine.h; this file wires its options).
//
//   mbconform fuzz --target URI [--device ID | --spec FILE] --duration 30s [--out DIR] [--seed S]
//                  [--batch N] [--pipeline N] [--quirks FILE] [--allow-motion] [--allow-eeprom-writes]
//   mbconform fuzz --replay FILE --target URI          (the same as mbconform replay)
//
// Fuzzing goes on until --duration runs out. Each distinct finding (its kind
// and the function code it came on) is reduced by delta debugging on fresh
// targets to a minimal sequence of frames and saved once, as a frame script
// (conformance/check/README.md) in DIR, with the command that replays it;
// one whose reduction a stop or the time allowed cut off is saved as far as
// the reduction got, and says so: a finding is never dropped.
// Findings whose kind (or signature, "KIND fcNN") a quirks file declares
// (--quirks, conformance/README.md) are left aside and counted.
// Exit 0: nothing found; 1: a finding; 2: could not run, or not to the end (a stop, a target lost: INCOMPLETE).
//
// Live drives get back the values they had (conformance/safety/safety.h).
#include <fmt/core.h>

#include <filesystem>
#include <fstream>

#include "blackbox/engine.h"
#include "capture/pcap_tap.h"
#include "commands.h"
#include "conventions.h"
#include "options.h"
#include "report/quirks.h"
#include "report/report.h"
#include "safety/safety.h"
#include "session/session.h"
#include "session/progress.h"
#include "session/signals.h"
#include "targets/target.h"

namespace mbc::cli {
namespace {

namespace fs = std::filesystem;

struct FuzzArgs {
  TargetOptions t;
  std::string duration = "10s", replay, quirks_file;
  std::optional<uint64_t> seed;
  int batch = 50;
  int pipeline = int(conf::blackbox::Options{}.depth);
  bool quiet = false;
};

// --duration's bounds: shorter sends no batch of frames; longer than a
// month is a typo (9999999h once overflowed the clock and sent nothing).
constexpr std::chrono::milliseconds kMinDuration{100};
// After --duration: the reduction of a last finding and the restore, so the
// command ends within --duration + 10 s even when the target is gone.
constexpr std::chrono::seconds kAfterDuration{6};

fs::path save(const fs::path& dir, const conf::blackbox::Plan& plan, const conf::blackbox::Reported& r, const std::string& uri) {
  fs::path file;
  for (int i = 1;; ++i) {
    file = dir / fmt::format("finding-{}-{}.txt", conf::blackbox::to_string(r.finding.kind), i);
    if (!fs::exists(file)) break;
  }
  std::string replay = fmt::format("mbconform replay {} --target '{}'", file.string(), uri);
  std::ofstream(file) << conf::check::format(conf::blackbox::reproducer(plan, r, replay));
  return file;
}

int run_fuzz(FuzzArgs& a) {
  const std::string uri = a.t.targets.front();
  if (!a.replay.empty()) return replay_file(a.replay, uri, a.t, "fuzz");
  auto duration = parse_duration(a.duration, kMinDuration, kMaxDuration);
  if (!duration) {
    fmt::print(stderr, "mbconform fuzz: error: {}\n", duration_error("--duration", a.duration, kMinDuration, kMaxDuration));
    return kExitUsage;
  }
  if (a.t.out.empty()) a.t.out = default_out_dir("fuzz");
  if (!conf::out_dir_ok(a.t.out, "mbconform fuzz")) return kExitUsage;
  conf::install_stop_signals();
  Opened opened;
  conf::blackbox::Plan plan;
  conf::quirks::Quirks quirks;
  const auto started = std::chrono::steady_clock::now();
  conf::Progress progress(fmt::format("fuzz {}", uri), a.t.progress, a.quiet);
  try {
    if (!a.quirks_file.empty()) {
      std::string file = conf::quirks::find(a.quirks_file);  // a path, or a declared library's name
      check_readable(file, kMaxQuirksBytes, "--quirks");
      quirks = conf::quirks::load(file);
    }
    auto named = named_spec(a.t);
    // Every frame goes through the session: its gate, its journal (in --out), its restore.
    auto so = session_options(a.t, "fuzz", a.t.out);
    so.deadline = started + *duration + kAfterDuration;
    so.on_frame = [&progress, d = *duration](uint64_t n) { progress.update_timed(n, "frames", d); };
    opened = open_session(named, uri, std::move(so));
    plan = conf::blackbox::make_plan(*opened.spec, opened.session->info(), a.t.policy);
  } catch (const std::exception& e) {
    fmt::print(stderr, "mbconform fuzz: error: {}\n", e.what());
    return kExitUsage;
  }
  conf::Session& session = *opened.session;
  const spec::Spec& s = *opened.spec;
  const conf::TargetInfo info = session.info();
  for (const auto& n : info.notes) fmt::print(stderr, "note: {}\n", n);  // how it was opened (a USB latency timer, ...)
  // Fresh runs (a later round, a reduction) start the session's target afresh:
  // every frame still goes through the session's policy and journal.
  conf::blackbox::Open open = [&] { session.restart(); };
  std::vector<std::string> notes;
  if (std::string why = prepare_live(session, a.t, notes); !why.empty()) {
    fmt::print(stderr, "mbconform fuzz: error: {}\n", why);
    return kExitUsage;
  }
  for (const auto& n : notes) fmt::print(stderr, "mbconform fuzz: {}\n", n);
  conf::blackbox::Options o;
  o.duration = *duration;
  o.seed = a.seed.value_or(uint64_t(std::chrono::steady_clock::now().time_since_epoch().count()));
  o.batch = a.batch;
  o.depth = size_t(a.pipeline);
  o.isolate = info.kind == conf::TargetKind::plugin;
  o.journal = (fs::path(a.t.out) / ".journal").string();
  if (!quirks.empty()) o.declared = [&](const std::string& sig) { return quirks.for_kind(sig) != nullptr; };
  o.stopped = [&] { return session.stopped().has_value(); };
  fmt::print("fuzzing {} as {} for {}, seed {}, batches of {} frames ({} readable, {} writable registers)\n", info.uri,
             s.device.id, a.duration, o.seed, a.batch, plan.readable.size(), plan.writable.size());
  std::fflush(stdout);

  size_t saved = 0;
  auto out = conf::blackbox::fuzz(session, open, plan, o, [&](const conf::blackbox::Reported& r) {
    // A finding whose reduction a stop or the deadline cut off is saved as
    // far as it got: it was seen on the target, and is never dropped.
    ++saved;
    progress.clear();
    fmt::print("FINDING {} after {} steps: {}\n", conf::blackbox::to_string(r.finding.kind), r.history, r.finding.message);
    if (r.cut_off)
      fmt::print("its reduction was cut off ({}); saving {} step(s), {}\n", session.stopped().value_or("stopped"),
                 r.steps.size(), r.reproduced ? "which reproduce it on a fresh target" : "the last ones sent, unreduced");
    else if (!r.reproduced)
      fmt::print("the finding does not reproduce on a fresh target (timing, state outside the frames, or the target is gone); "
                 "saving the last {} steps unreduced\n", r.steps.size());
    fs::path file = save(a.t.out, plan, r, uri);
    fmt::print("reproducer of {} step(s) ({} fresh-target runs): {}\n", r.steps.size(), r.runs, file.string());
    fmt::print("replay: mbconform replay {} --target '{}'\n", file.string(), uri);
    std::fflush(stdout);
  });

  progress.clear();
  restore_and_say(session, "fuzz");
  if (conf::stop_requested()) {
    fmt::print("INCOMPLETE: stopped by {} after {} frames in {} batches; {} distinct finding(s) saved in {}\n",
               conf::signal_name(conf::stop_signal()), out.frames, out.batches, saved, a.t.out);
    return kExitUsage;
  }
  const bool ran_out = session.stopped().has_value();  // the deadline: --duration + the reduction's time
  if (out.declared) fmt::print("{} finding(s) of a kind {} declares left aside\n", out.declared, a.quirks_file);
  if (ran_out) fmt::print("the time allowed (--duration + {} s) ran out; what was left of a reduction was cut off\n", kAfterDuration.count());
  if (out.counters.wire_time_bound_seconds > 0) {
    fmt::print("{} exchanges ({} silent) in {:.2f} s against a wire-time bound of {:.2f} s at {} baud: {:.2f}x\n",
               out.counters.frames_sent, out.counters.silences, out.seconds, out.counters.wire_time_bound_seconds, *info.baud,
               out.seconds / out.counters.wire_time_bound_seconds);
    // A silence takes at least the time a reply may take to be told apart:
    // the same bound with the p99 reply latency of this run per silent exchange.
    fmt::print("with each silence counted at the p99 reply latency ({:.2f} ms): a bound of {:.2f} s: {:.2f}x\n",
               out.reply_latency_p99_seconds * 1e3, out.bound_with_silences_seconds(),
               out.seconds / out.bound_with_silences_seconds());
  }
  if (out.target_lost && !ran_out) {
    // A lost target is no verdict on what was not sent (the findings before it stand, and are saved).
    fmt::print("INCOMPLETE: the target was lost (it could not be opened again) after {} frames, before --duration ran out; "
               "{} distinct finding(s) saved{}\n",
               out.frames, saved, saved ? " in " + a.t.out : "");
    return kExitUsage;
  }
  if (saved == 0) {
    fmt::print("no finding: {} frames in {} batches, every probe answered ({:.0f} frames/s)\n", out.frames, out.batches,
               out.frames_per_second());
    return kExitOk;
  }
  fmt::print("{} distinct finding(s), {} repeat(s) not saved again, {} frames in {} round(s) ({:.0f} frames/s, reductions "
             "left out); reproducers in {}\n",
             saved, out.repeats, out.frames, out.rounds, out.frames_per_second(), a.t.out);
  return kExitFailed;
}

}  // namespace

void add_fuzz_command(CLI::App& app, int& exit_code) {
  auto args = std::make_shared<FuzzArgs>();

  auto* cmd = app.add_subcommand("fuzz", "Black-box structure-aware fuzzing of a target; saves minimal reproducers");
  add_target_options(*cmd, args->t, false, "DIR: reproducers, one per distinct finding (default reports/fuzz/<UTC date-time>/)");
  cmd->add_option("--duration", args->duration, "How long to fuzz: 500ms, 20s, 5m, 1h (default 10s)");
  cmd->add_option("--seed", args->seed, "Random seed (default: from the clock, printed)");
  cmd->add_option("--batch", args->batch, "Frames between two liveness probes (default 50)")->check(CLI::Range(1, 100000));
  cmd->add_option("--pipeline", args->pipeline, "Modbus TCP: requests out at once, paired by transaction id (default 16; "
                  "1: one exchange at a time)")->check(CLI::Range(1, 256));
  cmd->add_option("--quirks", args->quirks_file, "FILE|NAME: a quirks file (conformance/README.md) or a declared library's name (jsmodbus): findings of the kinds it declares "
                  "('kind: KIND' or 'KIND fcNN', globs) are left aside");
  cmd->add_flag("-q,--quiet", args->quiet, "no progress on stderr");
  cmd->add_option("--replay", args->replay, "Replay a reproducer FILE instead of fuzzing (as mbconform replay)");
  cmd->callback([args, &exit_code] { exit_code = run_fuzz(*args); });
}

}  // namespace mbc::cli
