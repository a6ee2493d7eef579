// mbconform serve: reference devices on Modbus TCP, RTU over TCP and a pty.
#include <algorithm>
#include <iostream>
#include <string_view>

#include <fmt/core.h>

#include "commands.h"
#include "loader.h"
#include "faults/faults.h"
#include "serve/server.h"

namespace mbc::cli {
namespace {

struct ServeArgs {
  std::vector<std::string> devices, tcp, rtu_tcp, pty, tls;
  serve::TlsOptions tls_options;
  std::vector<std::pair<mbc::Transport, std::string>> endpoints;  // in command-line order
  std::string eeprom_dir;
  std::optional<int> baud, line_rate;
  std::string line;  // --line 19200-8E1
  bool echo = false;
  int latency_timer_ms = 0;
  double turnaround_ms = 0;
  bool trace = false, quiet = false;
  std::string pcap;
  std::vector<std::string> faults;  // --fault NAME[,NAME], repeatable
  bool list_faults = false;
  int idle_timeout_s = serve::Options{}.idle_timeout_s;
  size_t max_connections = serve::Options{}.max_connections;
};

// Argument mistakes become CLI::ValidationError: message + exit 2.
serve::Options options_from(const ServeArgs& a, std::optional<int> first_device_baud) {
  serve::Options o;
  try {
    for (const auto& [transport, text] : a.endpoints) o.endpoints.push_back(serve::parse_endpoint(transport, text));
  } catch (const std::invalid_argument& e) {
    throw CLI::ValidationError("endpoint", e.what());
  }
  if (o.endpoints.empty()) throw CLI::ValidationError("serve", "give at least one of --tcp, --rtu-tcp, --pty, --tls");
  o.eeprom_dir = a.eeprom_dir;
  o.trace = a.trace;
  o.quiet = a.quiet;
  o.pcap = a.pcap;
  o.echo = a.echo;
  o.line_rate = a.line_rate;
  o.idle_timeout_s = a.idle_timeout_s;
  o.max_connections = a.max_connections;
  o.tls = a.tls_options;
  // One --fault for both kinds: the line's (serve/uart.h) and the devices' (faults.h).
  try {
    for (const auto& f : a.faults) {
      std::string device_faults;
      for (size_t at = 0; at <= f.size();) {
        size_t comma = std::min(f.find(',', at), f.size());
        std::string name = f.substr(at, comma - at);
        if (auto lf = serve::line_fault_named(name)) o.behaviour.faults.push_back(*lf);
        else device_faults += (device_faults.empty() ? "" : ",") + name;
        at = comma + 1;
      }
      for (auto x : faults::parse_faults(device_faults).list()) o.faults.add(x);
    }
  } catch (const std::invalid_argument& e) {
    throw CLI::ValidationError("--fault", e.what());
  }
  // The nominal pty rate: as given, else the first device's default (its
  // manual's), else the standard's required default 19200 (MB-SL v1.02 §3.2).
  o.baud = a.baud.value_or(first_device_baud.value_or(19200));
  if (!a.line.empty()) {
    o.line = serve::parse_line_format(a.line);
    if (!o.line) throw CLI::ValidationError("--line", "'" + a.line + "': expected BAUD-FORMAT, as 19200-8E1 or 9600-8N2");
    if (a.baud && *a.baud != o.line->baud) throw CLI::ValidationError("--line", "--baud says another rate than --line");
    // The line's rate is the frame gap's and the replies' pace.
    o.baud = o.line->baud;
    if (!o.line_rate) o.line_rate = o.line->baud;
  }
  o.behaviour.latency_timer = std::chrono::milliseconds(a.latency_timer_ms);
  o.behaviour.turnaround = std::chrono::microseconds(int64_t(a.turnaround_ms * 1000));
  if (!o.line && (a.latency_timer_ms || a.turnaround_ms > 0 || !o.behaviour.faults.empty()))
    throw CLI::ValidationError("--line", "--latency-timer, --turnaround and the line faults need --line BAUD-FORMAT");
  return o;
}

ref::Bus bus_from(const std::vector<std::string>& args) {
  if (args.empty()) throw CLI::ValidationError("--device", "give at least one --device ID[@SLAVE]");
  ref::Bus bus;
  for (const auto& text : args) {
    serve::DeviceArg d;
    try {
      d = serve::parse_device_arg(text);
    } catch (const std::invalid_argument& e) {
      throw CLI::ValidationError("--device", e.what());
    }
    if (bus.find(d.slave)) throw CLI::ValidationError("--device", fmt::format("two devices with slave id {}", d.slave));
    spec::Spec s;
    try {
      s = spec::load_spec_by_id(d.id);
    } catch (const std::exception& e) {
      throw CLI::ValidationError("--device", fmt::format("'{}': {}", d.id, e.what()));
    }
    bus.add(std::make_unique<ref::Device>(std::move(s), d.slave));
  }
  return bus;
}

}  // namespace

void add_serve_command(CLI::App& app, int& exit_code) {
  static ServeArgs a;
  auto* cmd = app.add_subcommand("serve", "Serve reference devices on Modbus TCP, RTU over TCP and a pty");
  // Required unless --list-faults: bus_from() says so.
  cmd->add_option("--device", a.devices, "ID[@SLAVE]: a device on the bus (slave 1 if omitted); repeatable");
  auto* tcp = cmd->add_option("--tcp", a.tcp, "[HOST:]PORT: Modbus TCP (HOST 127.0.0.1 if omitted; PORT 0 picks one)");
  auto* rtu_tcp = cmd->add_option("--rtu-tcp", a.rtu_tcp, "[HOST:]PORT: RTU frames over TCP");
  auto* pty = cmd->add_option("--pty", a.pty, "PATH: RTU on a pseudo-terminal, PATH a symlink to it");
  auto* tls = cmd->add_option("--tls", a.tls, "[HOST:]PORT: Modbus/TCP Security (MBAP in TLS, port 802); needs --cert, --key, --ca");
  cmd->add_option("--cert", a.tls_options.files.cert, "FILE: --tls: the server's certificate chain (PEM)");
  cmd->add_option("--key", a.tls_options.files.key, "FILE: --tls: its private key (PEM, mode 600)");
  cmd->add_option("--ca", a.tls_options.files.ca, "FILE: --tls: the CA(s) that sign client certificates (PEM)");
  cmd->add_option("--roles", a.tls_options.roles_file,
                  "FILE: --tls: the function codes and addresses each certificate role may use (README)");
  cmd->add_option("--eeprom", a.eeprom_dir, "DIR: keep persistent registers in DIR/<id>@<slave>.json");
  cmd->add_option("--baud", a.baud, "nominal pty baud rate: the frame gap (default: the first device's)")
      ->check(CLI::Range(300, 4000000));
  cmd->add_option("--line-rate", a.line_rate, "pace RTU replies at the wire time of this baud rate")
      ->check(CLI::Range(300, 4000000));
  cmd->add_option("--line", a.line,
                  "BAUD-FORMAT (19200-8E1): the serial line a --pty stands for; a master at another baud rate gets what a "
                  "UART at the wrong rate makes of it (garbage or silence); replies paced at its rate");
  cmd->add_flag("--echo", a.echo, "--pty: echo each request back before its reply, as a 2-wire RS-485 adapter without echo "
                                  "suppression does to its master");
  cmd->add_option("--latency-timer", a.latency_timer_ms,
                  "MS: --line: the master's USB adapter hands received bytes over when its latency timer runs out "
                  "(FTDI: 16 by default): replies arrive in batches")
      ->check(CLI::Range(1, 255));
  cmd->add_option("--turnaround", a.turnaround_ms, "MS: --line: the device waits this long after t3.5 before it replies")
      ->check(CLI::Range(0.0, 10000.0));
  cmd->add_flag("--trace", a.trace, "log every frame to stderr, timestamped (the serial log format check-capture reads)");
  cmd->add_option("--pcap", a.pcap, "FILE: also write every frame as pcapng (Wireshark; conformance/capture/README.md)");
  cmd->add_option("--fault", a.faults,
                  "NAME[,NAME]: serve deliberately broken devices (every device served); repeatable; see --list-faults");
  cmd->add_option("--idle-timeout", a.idle_timeout_s, "SECONDS: close a TCP connection silent this long (0: never)")
      ->capture_default_str()
      ->check(CLI::Range(0, 86400 * 365));
  cmd->add_option("--max-connections", a.max_connections,
                  "N: TCP connections at once; at the cap the one unused the longest is closed")
      ->capture_default_str()
      ->check(CLI::Range(1, 1000000));
  cmd->add_flag("-q,--quiet", a.quiet, "print no `listening` lines (use fixed ports); errors still go to stderr");
  cmd->add_flag("--list-faults", a.list_faults, "print the faults --fault takes, one per line, and exit");
  cmd->callback([&exit_code, cmd, tcp, rtu_tcp, pty, tls] {
    if (a.list_faults) {
      // The name column as wide as the longest name.
      size_t width = 0;
      for (const auto& f : faults::all_faults()) width = std::max(width, std::string_view(f.name).size());
      for (const auto& f : serve::line_faults()) width = std::max(width, std::string_view(f.name).size());
      for (const auto& f : faults::all_faults()) fmt::print("{:<{}} {}\n", f.name, width, f.description);
      for (const auto& f : serve::line_faults()) fmt::print("{:<{}} {}\n", f.name, width, f.description);
      exit_code = 0;
      return;
    }
    // Endpoints open and print their "listening" lines in command-line order.
    size_t next_tcp = 0, next_rtu_tcp = 0, next_pty = 0, next_tls = 0;
    for (const CLI::Option* opt : cmd->parse_order()) {
      if (opt == tcp) a.endpoints.emplace_back(mbc::Transport::tcp, a.tcp.at(next_tcp++));
      if (opt == rtu_tcp) a.endpoints.emplace_back(mbc::Transport::rtu_tcp, a.rtu_tcp.at(next_rtu_tcp++));
      if (opt == pty) a.endpoints.emplace_back(mbc::Transport::pty, a.pty.at(next_pty++));
      if (opt == tls) a.endpoints.emplace_back(mbc::Transport::tls, a.tls.at(next_tls++));
    }
    if (a.tls.empty() && (!a.tls_options.files.cert.empty() || !a.tls_options.roles_file.empty()))
      throw CLI::ValidationError("--cert/--key/--ca/--roles", "only with --tls");
    ref::Bus bus = bus_from(a.devices);
    serve::Options o = options_from(a, bus.devices().front()->spec().serial.baud_default);
    serve::Server server(std::move(bus), std::move(o));
    try {
      server.open();
    } catch (const std::runtime_error& e) {  // an endpoint, a TLS file, the roles file: one line, exit 2
      fmt::print(stderr, "mbconform serve: error: {}\n", e.what());
      exit_code = kExitUsage;
      return;
    }
    exit_code = server.run();
  });
}

}  // namespace mbc::cli
