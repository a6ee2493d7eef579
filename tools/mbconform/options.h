// The options `run`, `props` and `fuzz` share, wired in one place: which
// target(s), which spec describes them (--device / --spec), what a live
// drive may be written (--allow-motion, --allow-eeprom-writes,
// --allow-broadcast), and where the results go (--out; each command checks
// it with conf::out_dir_ok before its first frame). A new option every one
// of them takes goes here.
#pragma once

#include <CLI/CLI.hpp>

#include <optional>
#include <string>
#include <vector>

#include "safety/safety.h"
#include "spec.h"

namespace mbc::cli {

struct TargetOptions {
  std::vector<std::string> targets;  // URIs; `run` and `props` default to every reference device
  std::string device, spec_file;     // --device ID | --spec FILE
  std::string out;                   // --out DIR
  conf::WritePolicy policy;          // --allow-motion, --allow-eeprom-writes, --allow-broadcast
  std::string pcap;                  // --pcap FILE: every exchange as pcapng (conformance/capture/pcap_tap.h)
};

// --target (repeatable when `many`, else once and required), --device,
// --spec, the safety flags and --out (described by `out_help`).
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

// The time now in UTC, strftime-formatted (report names, report headers).
std::string utc_now(const char* format);

}  // namespace mbc::cli
