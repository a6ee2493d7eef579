#include <algorithm>
#include <csignal>
#include <cstdio>
#include <exception>
#include <string>

#include "commands.h"
#include "conventions.h"

int main(int argc, char** argv) {
  // A file grown past RLIMIT_FSIZE (a quota, `ulimit -f`) is a full disk to
  // every command: write() fails with EFBIG and the command's own error path
  // runs (the reports written as .part and dropped, one line, the drive
  // restored), where SIGXFSZ's default action would end the process with
  // the drive not restored and a torn .part left behind.
  std::signal(SIGXFSZ, SIG_IGN);
  // Named, so that every usage line names the program ("Usage: mbconform run [OPTIONS]").
  CLI::App app{"mbconform: Modbus conformance and fuzz test suite for motor drives", "mbconform"};
  app.require_subcommand(1);
  int exit_code = mbc::cli::kExitOk;
  mbc::cli::add_spec_commands(app, exit_code);
  mbc::cli::add_serve_command(app, exit_code);
  mbc::cli::add_run_command(app, exit_code);
  mbc::cli::add_props_command(app, exit_code);
  mbc::cli::add_fuzz_command(app, exit_code);
  mbc::cli::add_client_command(app, exit_code);
  mbc::cli::add_replay_command(app, exit_code);
  mbc::cli::add_capture_command(app, exit_code);
  mbc::cli::add_restore_command(app, exit_code);
  mbc::cli::add_scan_command(app, exit_code);
  mbc::cli::add_global_options(app);
  mbc::cli::add_conventions(app, exit_code);
  std::vector<std::string> args(argv + 1, argv + argc);
  std::string command = "mbconform";  // the command the words name ("mbconform spec check")
  if (auto rc = mbc::cli::check_args(app, args, &command)) return *rc;
  try {
    std::reverse(args.begin(), args.end());  // CLI11 takes the words last first
    app.parse(args);
  } catch (const CLI::ParseError& e) {
    if (e.get_exit_code() == 0) return app.exit(e);  // --help, --version
    // One line, named like every other error: "mbconform fuzz: error: ...".
    std::fprintf(stderr, "%s: error: %s (%s --help)\n", command.c_str(), e.what(), command.c_str());
    return mbc::cli::kExitUsage;
  } catch (const std::exception& e) {
    std::fprintf(stderr, "mbconform: error: %s\n", e.what());
    return mbc::cli::kExitUsage;
  }
  return exit_code;
}
