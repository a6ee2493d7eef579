// mbconform restore: puts a drive back from the journal a command left
// (conformance/session/journal.h) after a crash, a SIGKILL or a second
// SIGINT, then verifies what it restored.
//
//   mbconform restore reports/run/20261201T120000Z/journal.txt [--target URI] [--device ID | --spec FILE] [--force-identity]
//
// The target is the journal's (as the command opened it) unless --target
// names another way to reach the same drive; the spec is the journal's
// device unless --device/--spec names one. Before anything is written the
// journal's header (device, unit, spec file, the identity the drive gave)
// is checked against the target; --force-identity restores anyway. What was
// restored and verified is appended to the journal (session/README.md).
// Exit codes: 0 every journaled address holds its original value (or was
// left alone since an earlier restore); 1 some could not be restored
// (listed); 2 the journal or the target cannot be used, or is not the
// journal's drive.
#include <fmt/core.h>

#include "commands.h"
#include "loader.h"
#include "options.h"
#include "session/journal.h"
#include "session/session.h"

namespace mbc::cli {
namespace {

struct RestoreArgs {
  std::string journal, target, device, spec_file;
  bool force_identity = false;
  bool quiet = false;
};

int run_restore(const RestoreArgs& a) {
  conf::JournalContents c;
  try {
    c = conf::read_journal(a.journal);
  } catch (const std::exception& e) {
    fmt::print(stderr, "mbconform restore: error: {}\n", e.what());
    return kExitUsage;
  }
  std::string uri = a.target.empty() ? c.header["target"] : a.target;
  if (uri.empty()) {
    fmt::print(stderr, "mbconform restore: error: {} names no target: give --target URI\n", a.journal);
    return kExitUsage;
  }
  spec::Spec s;
  std::unique_ptr<conf::Target> target;
  conf::Journal record;
  try {
    TargetOptions o;
    o.device = a.device.empty() && a.spec_file.empty() ? c.header["device"] : a.device;
    o.spec_file = a.spec_file;
    if (o.device.empty() && o.spec_file.empty())
      throw std::runtime_error(a.journal + " names no device: give --device ID or --spec FILE");
    s = *named_spec(o);
    // The journal's URI has the line settings filled in; a --target without them gets the spec's.
    target = conf::open_target(conf::line_settings(uri, &s).uri);
    record = conf::Journal::append_to(a.journal);
  } catch (const std::exception& e) {
    fmt::print(stderr, "mbconform restore: error: {}\n", e.what());
    return kExitUsage;
  }
  if (std::string why = conf::journal_mismatch(*target, s, c); !why.empty()) {
    if (!a.force_identity) {
      fmt::print(stderr, "mbconform restore: error: {}: {}; nothing written (--force-identity restores anyway)\n", a.journal, why);
      return kExitUsage;
    }
    fmt::print(stderr, "mbconform restore: warning: {} (--force-identity: restoring anyway)\n", why);
  }
  if (!a.quiet)
    fmt::print("restoring {} address(es) of {} on {} from {}\n", c.originals.size() + c.commands.size(), s.device.id,
               target->info().uri, a.journal);
  std::fflush(stdout);
  conf::RestoreReport r = conf::restore_journal(*target, s, c, record);
  for (const auto& f : r.not_restored) fmt::print("NOT RESTORED: {}\n", f);
  if (!a.quiet) {
    for (const auto& u : r.unread) fmt::print("note: {}\n", u);
    for (const auto& n : r.notes) fmt::print("note: {}\n", n);
  }
  fmt::print("{} kept, {} written back, {} verified, {} not restored{}\n", r.kept, r.restored, r.verified, r.not_restored.size(),
             r.gave_up ? " (the target did not answer)" : "");
  if (r.gave_up && r.verified == 0 && r.kept > 0) return kExitUsage;
  return r.not_restored.empty() ? kExitOk : kExitFailed;
}

}  // namespace

void add_restore_command(CLI::App& app, int& exit_code) {
  auto a = std::make_shared<RestoreArgs>();
  auto* cmd = app.add_subcommand("restore", "Put a drive back from the journal a command left (after a crash or SIGKILL), and verify");
  cmd->add_option("JOURNAL", a->journal, "the journal (the path each command prints when it starts)")->required();
  cmd->add_option("--target", a->target, "how to reach the drive (default: the journal's target)");
  cmd->add_option("--device", a->device, "ID: the drive's spec (default: the journal's device)");
  cmd->add_option("--spec", a->spec_file, "FILE: a spec file for the drive")->excludes(cmd->get_option("--device"));
  cmd->add_flag("--force-identity", a->force_identity,
                "restore although the journal's device, unit, spec file or the drive's identity differ from the target's");
  cmd->add_flag("-q,--quiet", a->quiet, "print only what was not restored and the counts");
  cmd->callback([a, &exit_code] { exit_code = run_restore(*a); });
}

}  // namespace mbc::cli
