// mbconform client: master-side conformance. A Modbus client library, driven
// by an adapter (conformance/client/README.md), against scenario servers that
// answer correctly or with one named fault each; the same reports as `run`.
//
//   mbconform client --adapter build/bin/libmodbus_adapter
//   mbconform client --adapter '/usr/bin/python3 conformance/peers/adapters/pymodbus/pymodbus_adapter.py' --transport pty
//   mbconform client --list --transport rtu-tcp
//
// Exit codes: 0 every MUST scenario passed; 1 one failed (or a quirk named
// in --quirks is gone: its cases ran and passed); 2 the run could not be done.
#include <fmt/core.h>
#include <fnmatch.h>
#include <unistd.h>

#include <ctime>
#include <filesystem>
#include <fstream>

#include "capture/pcap_tap.h"
#include "client/client_run.h"
#include "client/model.h"
#include "commands.h"
#include "conventions.h"
#include "options.h"
#include "report/quirks.h"
#include "report/report.h"
#include "session/progress.h"
#include "report/utc_now.h"

namespace mbc::cli {
namespace {

struct ClientArgs {
  std::string adapter, transport = "tcp", filter, out, quirks, pty, pki, pcap;
  int baud = 19200, timeout_ms = 500;
  bool list = false, plan = false, junit_only = false, quiet = false, progress = false;
  bool fail_on_should = false;  // --fail-on should
};

// A glob ('client/reply/*') or a substring of the case id.
bool keep(const std::string& filter, const std::string& id) {
  if (filter.find_first_of("*?[") != std::string::npos) return fnmatch(filter.c_str(), id.c_str(), 0) == 0;
  return id.find(filter) != std::string::npos;
}

int run(const ClientArgs& a) {
  client::ClientOptions o;
  if (a.transport == "tcp") o.transport = mbc::Transport::tcp;
  else if (a.transport == "rtu-tcp") o.transport = mbc::Transport::rtu_tcp;
  else if (a.transport == "pty") o.transport = mbc::Transport::pty;
  else if (a.transport == "tls") o.transport = mbc::Transport::tcp;  // MBAP inside TLS (client/tls_front.h)
  else {
    fmt::print(stderr, "mbconform client: error: --transport {}: expected tcp, rtu-tcp, pty or tls\n", a.transport);
    return kExitUsage;
  }
  if ((a.transport == "tls") != !a.pki.empty()) {
    fmt::print(stderr, "mbconform client: error: --transport tls and --pki DIR go together\n");
    return kExitUsage;
  }
  o.tls_pki = a.pki;
  o.adapter = a.adapter;
  o.baud = a.baud;
  o.timeout = std::chrono::milliseconds(a.timeout_ms);
  o.pty_path = a.pty;
  if (!a.pcap.empty()) o.on_wire = [w = conf::capture::client_pcap(a.pcap, o.transport == mbc::Transport::tcp, "client " + a.transport)](
                                      const auto& seen, const auto& sent) {
    std::vector<conf::capture::ClientFrame> f;
    for (const auto& q : seen) f.emplace_back(q.last, true, q.adu);
    for (const auto& s : sent) f.emplace_back(s.at, false, s.bytes);
    w(std::move(f));
  };
  std::vector<client::Scenario> list;
  try {
    list = client::selected(o, [&](const std::string& id) { return a.filter.empty() || keep(a.filter, id); });
  } catch (const std::exception& e) {
    fmt::print(stderr, "mbconform client: error: {}\n", e.what());
    return kExitUsage;
  }
  if (a.list) {
    for (const auto& s : list) fmt::print("{}  {}  {}  {}\n", s.id, conf::to_string(s.level), s.clause, s.title);
    return kExitOk;
  }
  if (a.plan) {
    fmt::print("# mbconform client over {} ({} scenarios, unit {}, master time-out {} ms)\n", a.transport, list.size(),
               int(client::model::kUnit), a.timeout_ms);
    for (const auto& s : list) {
      fmt::print("{}  [{}] {}\n", s.id, conf::to_string(s.level), s.clause);
      if (s.steps.empty()) fmt::print("  (judged over every request of the run)\n");
      for (const auto& l : client::plan_lines(s, o.transport)) fmt::print("{}\n", l);
    }
    return kExitOk;
  }
  if (a.adapter.empty()) {
    fmt::print(stderr, "mbconform client: error: --adapter 'COMMAND ARGS' is required (or --list / --plan)\n");
    return kExitUsage;
  }
  conf::quirks::Quirks quirks;
  if (!a.quirks.empty()) {
    try {
      std::string file = conf::quirks::find(a.quirks);  // a path, or a declared library's name
      check_readable(file, kMaxQuirksBytes, "--quirks");
      quirks = conf::quirks::load(file);
    } catch (const std::exception& e) {
      fmt::print(stderr, "{}\n", e.what());
      return kExitUsage;
    }
  }
  // A failure is printed as it comes on a terminal (else the summary lists
  // it, once); progress goes to stderr (session/progress.h).
  bool tty = isatty(STDOUT_FILENO) && !a.quiet;
  conf::Progress progress("client", a.progress, a.quiet || a.list || a.plan);
  o.on_case = [&](const conf::CaseResult& r, size_t done, size_t total) {
    if (r.outcome == conf::Outcome::fail && tty) {
      progress.clear();
      fmt::print("{}\n", conf::progress_line(r, done, total));
      std::fflush(stdout);
    }
    progress.update(done, total, "scenarios");
  };
  conf::RunReport report;
  report.command = "client";
  report.started_at = conf::utc_now();
  report.version = kVersionLine;
  report.fail_on_should = a.fail_on_should;
  client::ClientRun cr = client::run_client(o, list);
  progress.clear();
  if (!cr.error.empty()) {
    fmt::print(stderr, "mbconform client: error: {}\n", cr.error);
    if (!cr.adapter_log.empty()) fmt::print(stderr, "adapter log:\n{}", cr.adapter_log);
    return kExitUsage;
  }
  std::vector<std::string> gone = quirks.empty() ? std::vector<std::string>{} : conf::quirks::apply(quirks, cr.run);
  report.devices.push_back(cr.run);
  std::string out = a.out.empty() ? default_out_dir("client") : a.out;
  try {
    conf::write_reports(report, out, a.junit_only);
    if (!a.junit_only) {
      // The adapter's side of the run: what it said it is, what it logged, the quirks.
      nlohmann::json j;
      std::ifstream(out + "/report.json") >> j;
      nlohmann::json q = nlohmann::json::array();
      for (const auto& k : quirks.list) q.push_back({{"case", k.pattern}, {"reason", k.reason}, {"matched", k.used}});
      j["adapter"] = {{"command", a.adapter}, {"hello", cr.hello}, {"restarts", cr.restarts}, {"log", cr.adapter_log}};
      j["quirks"] = q;
      std::ofstream(out + "/report.json") << j.dump(1) << "\n";
    }
    std::ofstream(out + "/adapter.log") << cr.adapter_log;
  } catch (const std::exception& e) {
    fmt::print(stderr, "mbconform client: error: {}\n", e.what());
    return kExitUsage;
  }
  fmt::print("{}", conf::summary_table(report));
  int rc = run_failed(report) ? kExitFailed : kExitOk;
  if (!gone.empty()) rc = kExitFailed;  // named in the summary's notes
  if (cr.restarts) fmt::print("the adapter hung and was restarted {} time(s)\n", cr.restarts);
  fmt::print("reports: {}\n", out);
  return rc;
}

}  // namespace

void add_client_command(CLI::App& app, int& exit_code) {
  auto a = std::make_shared<ClientArgs>();
  auto* cmd = app.add_subcommand("client", "Test a Modbus master library, through its adapter, against scenario servers");
  cmd->add_option("--adapter", a->adapter, "the adapter's command line (conformance/client/README.md), run with /bin/sh -c");
  cmd->add_option("--transport", a->transport, "tcp (default) | rtu-tcp | pty | tls");
  cmd->add_option("--pki", a->pki, "DIR: --transport tls: ca.crt, server.crt/.key, operator.crt/.key (conformance/tests/security/make_pki.sh)");
  cmd->add_option("--baud", a->baud, "pty: the nominal baud rate (t1.5, t3.5, wire-time bound); default 19200");
  cmd->add_option("--timeout-ms", a->timeout_ms, "the master's response time-out sent to the adapter; default 500")
      ->check(CLI::Range(1, 60000));  // range-checked as every duration is (conventions.h's parse_duration)
  cmd->add_option("--pcap", a->pcap, "FILE: also write every frame of every scenario as pcapng (conformance/capture/README.md)");
  cmd->add_option("--pty", a->pty, "pty: where to link the pty the adapter opens (default: a temporary directory)");
  cmd->add_option("--filter", a->filter, "select scenarios by id: a glob ('client/reply/*') or a substring");
  cmd->add_flag("--list", a->list, "print the scenarios (id, level, clause, title) and exit");
  cmd->add_flag("--plan", a->plan, "print every request expected and every answer the server gives, without running");
  cmd->add_option("--out", a->out, "report directory (default reports/client/<UTC date-time>/)");
  cmd->add_option("--quirks", a->quirks, "FILE|NAME: a quirks file, a YAML list of {case: ID-or-glob, reason} (conformance/README.md), or the name of a library's declared deviations (libmodbus-tcp): known deviations, reported apart");
  cmd->add_flag("--junit-only", a->junit_only, "write only junit.xml");
  add_fail_on_option(cmd, a->fail_on_should);
  cmd->add_flag("-q,--quiet", a->quiet, "no progress and no failure printed as it comes (the summary and the reports stay)");
  cmd->add_flag("--progress", a->progress, "progress on stderr (done/total, rate, elapsed, ETA) even when it is not a terminal");
  cmd->callback([a, &exit_code] { exit_code = run(*a); });
}

}  // namespace mbc::cli
