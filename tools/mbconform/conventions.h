// The command line's shared conventions, one place for each: the version,
// the default output root (reports/<command>/<UTC time>/), the --map-time
// option, the exit codes every --help prints, usage lines that name the
// program, "did you mean" for a mistyped subcommand or option, and the man
// page and shell completion generated from the commands' own definitions.
#pragma once

#include <CLI/CLI.hpp>
#include <chrono>
#include <optional>
#include <string>
#include <vector>

#include "report/result.h"

namespace mbc::cli {

// The version, one source: CMake's project(VERSION) (tools/CMakeLists.txt
// passes it as MBCONFORM_VERSION). `mbconform --version` prints kVersionLine,
// and every report.json carries it.
inline constexpr const char* kVersion = MBCONFORM_VERSION;
inline constexpr const char* kVersionLine = "mbconform " MBCONFORM_VERSION;

// reports/<command>/<UTC date-time>/ (e.g. reports/run/20261201T230501Z),
// created here and new: a second run started in the same second gets
// reports/run/20261201T230501Z-2 (conf::claim_new_dir). Where a command
// writes when no --out is given; call it only when the command will write.
std::string default_out_dir(const std::string& command);

// The one duration parser of every option that takes a time (--duration,
// --deadline, --map-time, ...): "500ms", "20s", "5m", "1h" (a bare number is
// seconds); nullopt when malformed, not finite, or outside [min, max]. No
// option takes more than kMaxDuration: a deadline added to the clock must
// not overflow it (9999999h once wrapped --map-time to "nothing mapped").
inline constexpr std::chrono::milliseconds kMaxDuration{31LL * 24 * 3600 * 1000};
std::optional<std::chrono::milliseconds> parse_duration(const std::string& text,
                                                        std::chrono::milliseconds min = std::chrono::milliseconds(1),
                                                        std::chrono::milliseconds max = kMaxDuration);
// The one line for a bad one: "--deadline '9999999h': expected a duration
// from 1 ms to 31 days, e.g. 500ms, 90s, 10m, 2h".
std::string duration_error(const std::string& option, const std::string& text,
                           std::chrono::milliseconds min = std::chrono::milliseconds(1),
                           std::chrono::milliseconds max = kMaxDuration);


// --map-time DURATION: the longest the map probe runs.
void add_map_time_option(CLI::App* cmd, std::optional<std::chrono::milliseconds>& into);

// --fail-on must|should: which failed level fails the run (exit 1, JUnit <failure>).
void add_fail_on_option(CLI::App* cmd, bool& fail_on_should);
// A case that fails the run failed (report/result.h fails_run).
bool run_failed(const conf::RunReport& report);

// The footer every --help ends with.
const char* exit_codes_footer();

// After every command is added: the exit codes at the end of every --help,
// `--version`, `help [COMMAND...]` (and `help --man`, the man page),
// `completion bash`.
void add_conventions(CLI::App& app, int& exit_code);

// The man page (roff), written from the commands' definitions: every command
// shown, its usage line, arguments and options (manual.cpp).
std::string man_page(const CLI::App& app);
// A bash completion script for every command and option of `app`.
std::string bash_completion(const CLI::App& app);
// `completion bash`: prints bash_completion(app).
void add_completion_command(CLI::App& app, int& exit_code);

// Before parsing: a mistyped command or option is one line with the nearest
// known one ("did you mean"), and -q means --quiet where a command has it.
// Returns the exit code when argv cannot be parsed, else nullopt (argv may
// have been rewritten in `args`).
std::optional<int> check_args(CLI::App& app, std::vector<std::string>& args, std::string* command = nullptr);

// The nearest of `known` to `word` (edit distance at most 2, or a prefix),
// empty when none is near.
std::string nearest(const std::string& word, const std::vector<std::string>& known);

}  // namespace mbc::cli
