// The mbconform subcommands. Exit codes (documented in README.md):
//   0 success (or PARTIAL); 1 checks failed (spec errors, failing MUST cases); 2 could not run;
//   3 PARTIAL under --require-complete.
#pragma once

#include <CLI/CLI.hpp>

namespace mbc::cli {

inline constexpr int kExitOk = 0;
inline constexpr int kExitFailed = 1;
inline constexpr int kExitUsage = 2;
// A PARTIAL run (MUST cases skipped for want of an opt-in) under --require-complete.
inline constexpr int kExitPartial = 3;
// `--require-complete`, the same words in every command that has a PARTIAL verdict (run, props).
void add_require_complete_flag(CLI::App& cmd, bool& require_complete);

// Registers `spec check|dump|errata|list` on `app`; the result code is
// written to `exit_code` when one of them runs.
void add_spec_commands(CLI::App& app, int& exit_code);
// `--spec-dir DIR` (repeatable; spec/loader/spec_path.h), accepted before or
// after any subcommand. Call after every subcommand has been added.
void add_global_options(CLI::App& app);
// `serve`: reference devices on Modbus TCP, RTU over TCP and a pty (cmd_serve.cpp).
void add_serve_command(CLI::App& app, int& exit_code);
// `run`: conformance cases against any target, reports (cmd_run.cpp).
void add_run_command(CLI::App& app, int& exit_code);
// `props`: RapidCheck properties of the profile invariants against any target (cmd_props.cpp).
void add_props_command(CLI::App& app, int& exit_code);
// `fuzz`: black-box structure-aware fuzzing of any target (cmd_fuzz.cpp).
void add_fuzz_command(CLI::App& app, int& exit_code);
// `client`: a master library, through its adapter, against scenario servers (cmd_client.cpp).
void add_client_command(CLI::App& app, int& exit_code);
// `replay`: a frame script (conformance/check/README.md) against any target (cmd_replay.cpp).
void add_replay_command(CLI::App& app, int& exit_code);
// `check-capture`: a recorded capture judged against a spec (cmd_capture.cpp, conformance/capture/).
void add_capture_command(CLI::App& app, int& exit_code);

// `scan`: every drive on a line, read-only (cmd_scan.cpp, conformance/scan/).
void add_scan_command(CLI::App& app, int& exit_code);

// `restore`: a drive put back from a command's journal (cmd_restore.cpp).
void add_restore_command(CLI::App& app, int& exit_code);

struct TargetOptions;
// Replays the frame script `file` on `uri` (default: ref: of the script's
// device); the spec is --device/--spec, else the script's `device`. Prints
// what came of it; returns the exit code (0 met, 1 not met, 2 could not run).
int replay_file(const std::string& file, const std::string& uri, const TargetOptions& o, const char* command);

}  // namespace mbc::cli
