// Running the scenarios against one adapter: start it, say hello, and for
// each scenario connect it to the scenario server, ask for each step's
// request, judge the answer and what came over the wire, disconnect. The
// result is a conf::DeviceRun, so `run`'s report writers serve unchanged.
#pragma once

#include <chrono>
#include <functional>
#include <string>
#include <vector>

#include <nlohmann/json.hpp>

#include "client/scenario.h"
#include "client/server.h"
#include "report/result.h"

namespace mbc::client {

struct ClientOptions {
  std::string adapter;       // the command line
  Transport transport = Transport::tcp;
  int baud = 19200;          // pty: the nominal rate (t1.5 / t3.5); sent to the adapter
  std::chrono::milliseconds timeout{500};  // the master's response time-out (connect.timeout_ms)
  std::string pty_path;      // pty: where the link is made (default: a temporary directory)
  // --transport tls (Modbus/TCP Security): make_pki.sh's files (tls_front.h).
  // The scenarios run as over tcp, inside TLS; client-side security checks follow.
  std::string tls_pki;
  nlohmann::json tls_connect;  // set by run_client: the adapter's connect fields
  std::function<void(const conf::CaseResult&, size_t done, size_t total)> on_case;
  // After each scenario: every request the server saw and every frame it
  // sent (`mbconform client --pcap`, conformance/capture/pcap_tap.h).
  std::function<void(const std::vector<SeenRequest>&, const std::vector<SentFrame>&)> on_wire;
};

struct ClientRun {
  conf::DeviceRun run;
  nlohmann::json hello;      // the adapter's answer to hello
  std::string adapter_log;   // its stderr, and mbconform's notes on the protocol
  std::string error;         // set when the run could not be done (exit 2)
  int restarts = 0;          // adapter restarts after a hang
};

// The scenarios (and run-wide checks) selected for `o.transport`.
std::vector<Scenario> selected(const ClientOptions& o, const std::function<bool(const std::string&)>& keep);

// Runs `list` (from selected()). Never throws for what the adapter does;
// setup failures land in ClientRun::error.
ClientRun run_client(const ClientOptions& o, const std::vector<Scenario>& list);

// One line per step, for --plan: the request asked, the frame a correct
// master sends, how the server answers, what passes.
std::vector<std::string> plan_lines(const Scenario& s, Transport t);

}  // namespace mbc::client
