// The options the commands that reach a target share (run, props, fuzz,
// replay, restore), wired in one place: which target(s), which spec
// describes them (--device / --spec), the one table of opt-ins the frame
// policy reads (conformance/policy/README.md: --allow-motion,
// --allow-eeprom-writes, --allow-broadcast, --allow-writes,
// --allow-disruptive; and --allow-long-waits), and where the results and the
// journal go (--out; checked before the first frame). A new option every one
// of them takes goes here.
#pragma once

#include <CLI/CLI.hpp>

#include <chrono>
#include <cstdint>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "policy/policy.h"
#include "session/session.h"
#include "spec.h"

namespace mbc::cli {

struct TargetOptions {
  std::vector<std::string> targets;  // URIs; `run` and `props` default to every reference device
  std::string device, spec_file;     // --device ID | --spec FILE
  std::string out;                   // --out DIR
  conf::WritePolicy policy;          // --allow-motion, --allow-eeprom-writes, --allow-broadcast, --allow-writes, --allow-disruptive
  std::string pcap;                  // --pcap FILE: every exchange as pcapng (conformance/capture/pcap_tap.h)
  bool allow_long_waits = false;     // --allow-long-waits: a frame script's `wait` over kMaxWait
  bool progress = false;             // --progress: progress on stderr even when it is not a terminal
  bool quiet = false;                // -q: no progress (commands that had no quiet flag of their own)
  bool no_preflight = false;         // --no-preflight: skip the identity check of a live drive
};

// The checks before the first write on a live target: it answers (one line
// naming the line settings otherwise), it looks like the spec (unless
// --no-preflight), and the journal keeps every value the command may write.
// Empty when the command may go on, else the line to print (exit 2).
// `notes` gets the identity read and what could not be kept.
std::string prepare_live(conf::Session& session, const TargetOptions& o, std::vector<std::string>& notes);

// The longest `wait` a frame script may hold a live line without --allow-long-waits.
inline constexpr int kMaxWaitSeconds = 60;

// The opt-ins (README.md, "Live drives"): the same flags, the same meaning, in every command.
void add_opt_ins(CLI::App& cmd, TargetOptions& o);
// --target (repeatable when `many`, else once and required), --device,
// --spec, the opt-ins and --out (described by `out_help`).
void add_target_options(CLI::App& cmd, TargetOptions& o, bool many, const std::string& out_help);

// The reference devices a command runs on when no target is named.
std::vector<std::string> default_targets();
const std::vector<std::string>& targets_or_default(TargetOptions& o);

// The spec named by --device or --spec, if any. Throws std::runtime_error
// (after printing a bad spec file's diagnostics to stderr).
std::optional<spec::Spec> named_spec(const TargetOptions& o);
// The spec of `uri`: the named one, else the one a ref: target carries, else
// `device_id` (a target that names its device). Throws std::runtime_error.
spec::Spec spec_for(const std::optional<spec::Spec>& named, const std::string& uri, const std::string& device_id = "");

// The session's options for `command` writing into `out_dir` (the journal's directory).
conf::SessionOptions session_options(const TargetOptions& o, const std::string& command, const std::string& out_dir);

// A session with the spec it was opened with (the spec outlives the session).
struct Opened {
  std::unique_ptr<spec::Spec> spec;
  std::unique_ptr<conf::Session> session;
};
// Opens `uri` through a session: the spec is `named`, else the one a ref:
// target carries, else (a plugin) the device the target names. Prints the
// journal's path on stderr when there is one. Throws std::exception with
// one line to print. `spec_optional`: a live target without a spec opens
// with none (then the gate lets no write through).
Opened open_session(const std::optional<spec::Spec>& named, const std::string& uri, conf::SessionOptions options,
                    bool spec_optional = false);

// Restores through `session` (if it journaled anything) and prints what
// could not be put back, and where the journal is; the lines not restored.
std::vector<std::string> restore_and_say(conf::Session& session, const char* command);

// Every file a command reads whole has a cap: a quirks file, a frame script,
// a props regression, a CSV map (/dev/zero once grew a reader to 7 GB).
inline constexpr uintmax_t kMaxQuirksBytes = 1u << 20;
inline constexpr uintmax_t kMaxTextFileBytes = 16u << 20;
// Throws std::runtime_error with one line unless `path` is a regular file of
// at most `cap` bytes; `what` names it ("--quirks").
void check_readable(const std::string& path, uintmax_t cap, const char* what);

}  // namespace mbc::cli
