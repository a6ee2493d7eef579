#include "client/client_run.h"

#include <openssl/ssl.h>

#include <fmt/core.h>
#include <fmt/format.h>
#include <unistd.h>

#include <algorithm>
#include <cstdlib>
#include <filesystem>
#include <memory>
#include <stdexcept>
#include <thread>

#include "client/adapter.h"
#include "client/tls_front.h"
#include "client/model.h"
#include "modbus/framing.h"
#include "modbus/hex.h"
#include "modbus/judge.h"
#include "modbus/rtu.h"

namespace mbc::client {
namespace {

using nlohmann::json;
using std::chrono::milliseconds;
using conf::Outcome;

constexpr milliseconds kHelloWait{10000};   // an interpreter's start-up (node, python) on a loaded machine
constexpr milliseconds kConnectWait{5000};
constexpr milliseconds kHangMargin{3000};   // beyond the step's own delays: the adapter hangs
constexpr milliseconds kSettle{30};         // quiet after the server's last send, before the next step


json connect_message(const ClientOptions& o, const ScenarioServer& s) {
  json c{{"timeout_ms", o.timeout.count()}, {"retries", 0}};
  if (!o.tls_connect.is_null()) {
    c.update(o.tls_connect);
  } else if (o.transport == Transport::pty) {
    c.update({{"transport", "rtu"}, {"device", s.pty_path()}, {"baud", o.baud}, {"parity", "N"}, {"data", 8}, {"stop", 1}});
  } else {
    c.update({{"transport", to_string(o.transport)}, {"host", "127.0.0.1"}, {"port", s.port()}});
  }
  return json{{"connect", c}};
}

Answer answer_of(const json& j) {
  Answer a;
  if (j.value("ok", false)) {
    a.kind = "ok";
    a.values = j.contains("values") ? j["values"] : json::array();
    return a;
  }
  a.kind = j.value("error", std::string("other"));
  a.code = j.value("code", 0);
  a.detail = j.value("detail", std::string());
  static const std::set<std::string> known{"exception", "timeout", "invalid_reply", "refused", "unsupported", "other"};
  if (!known.count(a.kind)) {
    a.detail = "unknown error kind '" + a.kind + "'" + (a.detail.empty() ? "" : ": " + a.detail);
    a.kind = "other";
  }
  return a;
}

std::string answer_text(const Answer& a) {
  if (a.kind == "ok") return "ok " + a.values.dump();
  if (a.kind == "exception") return fmt::format("exception {:02X}", a.code);
  return a.kind + (a.detail.empty() ? "" : " (" + a.detail + ")");
}

// What the master put on the wire for one step, judged: the frame (MBAP
// fields or CRC), the unit, and the PDU against what the request asks for.
std::vector<std::string> judge_requests(const ScenarioStep& st, const std::vector<const SeenRequest*>& seen, Transport t) {
  std::vector<std::string> problems;
  if (st.must_not_send) {
    for (const auto* r : seen) {
      Unframed u = framing_of(t).unframe(r->adu);
      problems.push_back(fmt::format("sent anyway ({} bytes): {}", r->adu.size(), describe_pdu(u.pdu, true)));
    }
    return problems;
  }
  if (!st.judge_request || seen.empty()) return problems;
  const SeenRequest& r = *seen.front();
  Unframed u = framing_of(t).unframe(r.adu);
  if (!u.ok()) problems.push_back("frame: " + u.error);
  uint8_t unit = st.request.value("unit", model::kUnit);
  if (u.unit != unit) problems.push_back(fmt::format("unit {} on the wire, {} asked", u.unit, unit));
  Bytes want = model::expected_request(st.request);
  if (u.pdu != want)
    problems.push_back(fmt::format("PDU {} ({}), expected {} ({})", to_hex(u.pdu), describe_pdu(u.pdu, true), to_hex(want),
                                   describe_pdu(want, true)));
  ParsedRequest pr = parse_request(u.pdu);
  for (const auto& p : pr.problems) problems.push_back(p);
  if (!pr.request && !pr.error.empty()) problems.push_back(pr.error);
  return problems;
}

conf::CaseResult header(const Scenario& s) {
  conf::CaseResult r;
  r.id = s.id;
  r.family = s.family;
  r.clause = s.clause;
  r.level = s.level;
  r.title = s.title;
  r.requirement = s.requirement;
  return r;
}

void conclude(conf::CaseResult& r, const std::vector<std::string>& failures) {
  if (failures.empty()) {
    r.outcome = Outcome::pass;
    return;
  }
  std::string msg;
  for (const auto& f : failures) msg += (msg.empty() ? "" : "; ") + f;
  r.message = msg;
  r.outcome = r.level == conf::Level::observed ? Outcome::observed : Outcome::fail;
}

// The lower bound a perfect master on a real line needs for a step: its frames
// at the baud rate, plus every wait each passing outcome implies.
double step_bound(const ScenarioStep& st, const std::vector<const SeenRequest*>& seen, const std::vector<SentFrame>& sent,
                  const ClientOptions& o) {
  double s = 0;
  if (o.transport == Transport::pty) {
    for (const auto* r : seen) s += double(wire_time(r->adu.size(), o.baud).count()) / 1e6;
    for (const auto& f : sent) s += double(wire_time(f.bytes.size(), o.baud).count()) / 1e6;
  }
  if (st.pass.kinds == std::set<std::string>{"timeout"}) s += double(o.timeout.count()) / 1e3;
  if (st.fault == Fault::late) s += 0.2;
  return s;
}

class Session {
 public:
  Session(const ClientOptions& o, ScenarioServer& server, ClientRun& out) : o_(o), server_(server), out_(out) {}

  // Starts the adapter and says hello; false (out_.error set) when it cannot.
  bool start() {
    adapter_ = std::make_unique<Adapter>(o_.adapter);
    try {
      adapter_->start();
    } catch (const std::exception& e) {
      out_.error = fmt::format("adapter '{}' does not start: {}", o_.adapter, e.what());
      return false;
    }
    adapter_->send(json{{"hello", {{"protocol", 1}}}});
    auto h = adapter_->next(Clock::now() + kHelloWait, nullptr);
    if (!h) {
      keep_log();
      out_.error = fmt::format("adapter '{}' did not answer hello within {} s", o_.adapter, kHelloWait.count() / 1000);
      return false;
    }
    if (h->value("protocol", 0) != 1) {
      out_.error = fmt::format("adapter speaks protocol {}, mbconform speaks 1", h->value("protocol", json()).dump());
      return false;
    }
    out_.hello = *h;
    for (const auto& op : h->value("ops", json::array())) ops_.insert(op.get<std::string>());
    return true;
  }

  bool supports(const std::string& op) const { return ops_.count(op) > 0; }

  // Connects the adapter to the server; false (out_.error) on ready: false.
  bool connect() {
    server_.drop_connection();
    adapter_->send(connect_message(o_, server_));
    auto r = adapter_->next(Clock::now() + kConnectWait, &server_);
    if (r && r->value("ready", false)) return true;
    out_.error = r ? fmt::format("adapter not ready: {}", r->value("detail", std::string("(no detail)")))
                   : "adapter did not answer connect";
    return false;
  }

  void disconnect() {
    adapter_->send(json{{"disconnect", true}});
    adapter_->next(Clock::now() + kConnectWait, &server_);
    server_.drop_connection();
  }

  // Asks for one request; a hang kills and restarts the adapter.
  Answer ask(const json& request, milliseconds extra) {
    json msg = request;
    msg["id"] = ++id_;
    adapter_->send(msg);
    auto deadline = Clock::now() + 2 * o_.timeout + extra + kHangMargin;
    for (;;) {
      auto line = adapter_->next(deadline, &server_);
      if (!line) break;
      if (line->value("id", -1) == id_) return answer_of(*line);
      adapter_->log_note(fmt::format("answer to id {} while waiting for {}: {}", line->value("id", -1), id_, line->dump()));
    }
    Answer hang;
    hang.kind = "hang";
    hang.detail = "no answer within the time-out; the adapter was killed and restarted";
    // An adapter that closed its stdout has not hung: it ended, and says how.
    if (std::string how = adapter_->exited(milliseconds(500)); !how.empty()) {
      hang.kind = "exited";
      hang.detail = "the adapter " + how + " before answering; it was restarted";
    }
    keep_log();
    ++out_.restarts;
    restarted_ = start() && connect();
    return hang;
  }

  // Serves until the server has sent everything it scheduled, then a little quiet.
  void settle() {
    auto limit = Clock::now() + o_.timeout + milliseconds(1000);
    while (!server_.idle() && Clock::now() < limit) adapter_->next(std::min(limit, Clock::now() + kSettle), &server_);
    adapter_->next(Clock::now() + kSettle, &server_);
  }

  void close() {
    adapter_->send(json{{"op", "close"}});
    adapter_->finish(milliseconds(2000));
    keep_log();
  }

  const std::string& error() const { return out_.error; }
  void set_error(std::string e) { out_.error = std::move(e); }

  // The run's adapter log stays bounded across restarts too.
  void keep_log() {
    if (!adapter_) return;
    std::string more = adapter_->take_log();
    if (out_.adapter_log.size() + more.size() <= 4 * Adapter::kMaxLog) out_.adapter_log += more;
    else if (!log_full_) {
      out_.adapter_log += "[mbconform] the adapter log is full: the rest of the run's adapter output was dropped\n";
      log_full_ = true;
    }
  }

  bool restarted() {
    bool r = restarted_;
    restarted_ = false;
    return r;
  }

 private:
  const ClientOptions& o_;
  ScenarioServer& server_;
  ClientRun& out_;
  std::unique_ptr<Adapter> adapter_;
  std::set<std::string> ops_;
  int id_ = 0;
  bool restarted_ = false;
  bool log_full_ = false;
};

// One step for the report: the master's request, the outcomes that pass, what
// the server sent back ("silence" when nothing) and what the adapter reported.
conf::FrameRecord record(const std::string& step, const SeenRequest* req, const std::vector<SentFrame>& sent,
                         const Passing& pass, const Answer& answer, Transport t) {
  conf::FrameRecord f;
  f.step = step;
  if (req) {
    f.request = req->adu;
    f.request_decoded = describe_pdu(framing_of(t).unframe(req->adu).pdu, true);
  }
  f.expected_text = "the adapter reports: " + pass.text();
  if (!sent.empty()) {
    Bytes all;
    std::string what;
    for (const auto& s : sent) {
      all.insert(all.end(), s.bytes.begin(), s.bytes.end());
      what += (what.empty() ? "" : ", ") + s.what;
    }
    f.actual = all;
    f.actual_decoded = what + "; ";
  }
  f.actual_decoded += "the adapter reported: " + answer_text(answer);
  return f;
}

void run_wide(const Scenario& s, conf::CaseResult& r, const std::vector<std::vector<SeenRequest>>& per_scenario,
              const ClientOptions& o) {
  std::vector<std::string> failures;
  size_t n = 0;
  for (const auto& reqs : per_scenario) {
    for (size_t i = 0; i < reqs.size(); ++i) {
      ++n;
      if (s.id == "client/request/transaction-ids") {
        if (i == 0) continue;
        auto a = kTcp.unframe(reqs[i - 1].adu), b = kTcp.unframe(reqs[i].adu);
        if (a.transaction == b.transaction)
          failures.push_back(fmt::format("transaction id {} twice in a row", b.transaction));
      } else if (s.id == "client/timing/t1.5") {
        if (reqs[i].max_gap > char_gap(o.baud))
          failures.push_back(fmt::format("{} us silence inside a frame (t1.5 = {} us)", reqs[i].max_gap.count(),
                                         char_gap(o.baud).count()));
      } else if (reqs[i].gap_before && *reqs[i].gap_before < frame_gap(o.baud)) {
        failures.push_back(fmt::format("{} us before a frame (t3.5 = {} us)", reqs[i].gap_before->count(),
                                       frame_gap(o.baud).count()));
      }
    }
  }
  r.extra["requests_checked"] = n;
  if (failures.size() > 5) {
    size_t more = failures.size() - 5;
    failures.resize(5);
    failures.push_back(fmt::format("{} more", more));
  }
  conclude(r, failures);
}

// The wait after each broadcast before the master's next request, as the
// scenario server saw it (a pty delivers at once, so the wait is the
// master's own; a busy host only lengthens it).
void broadcast_turnaround(conf::CaseResult& r, const std::vector<SeenRequest>& reqs, const ClientOptions& o) {
  std::vector<std::string> waits;
  for (size_t i = 1; i < reqs.size(); ++i)
    if (!reqs[i - 1].adu.empty() && reqs[i - 1].adu[0] == 0 && reqs[i].gap_before)
      waits.push_back(fmt::format("{:.1f} ms", double(reqs[i].gap_before->count()) / 1000.0));
  std::string text = waits.empty() ? "no request followed a broadcast"
                                   : fmt::format("the master waited {} after the broadcast before its next request (t3.5 = {} us){}",
                                                 fmt::join(waits, ", "), frame_gap(o.baud).count(),
                                                 o.transport == Transport::pty ? "" : " (over TCP: the gateway's timing too)");
  r.message = r.message.empty() ? text : r.message + "; " + text;
  if (r.outcome == Outcome::pass) r.outcome = Outcome::observed;
}

}  // namespace

std::vector<Scenario> selected(const ClientOptions& o, const std::function<bool(const std::string&)>& keep) {
  std::vector<Scenario> out;
  auto add = [&](std::vector<Scenario> v) {
    for (auto& s : v)
      if (keep(s.id)) out.push_back(std::move(s));
  };
  add(scenarios(framing_of(o.transport), o.transport == Transport::pty, standard_limits()));
  // A pty is the only serial line here: its timing checks are OBSERVED.
  add(run_wide_checks(framing_of(o.transport), o.transport == Transport::pty, o.transport == Transport::pty));
  return out;
}

// The client side of Modbus/TCP Security: the adapter is pointed at servers it
// must not accept. The relay counts handshakes it completed: with TLS 1.2 and
// 1.3 alike, a client that refuses the server's certificate or version never
// finishes one. OBSERVED: the specification's sentences are not in this
// project's sources (security/security.h).
json op_read_one() {
  return json{{"op", "read_holding_registers"}, {"unit", model::kUnit}, {"address", 0}, {"count", 1}};
}

std::vector<conf::CaseResult> tls_client_checks(Session& session, ClientOptions& secure, int main_handshakes) {
  std::vector<conf::CaseResult> out;
  auto result = [](const std::string& id, const std::string& title, const std::string& requirement) {
    conf::CaseResult r;
    r.id = "client/security/" + id;
    r.family = "security";
    r.clause = "MB-TCP-Security v2.1 §8.1";
    r.level = conf::Level::observed;
    r.title = title;
    r.requirement = requirement;
    r.outcome = Outcome::observed;
    return r;
  };
  {
    auto r = result("sends-certificate", "the client sends its certificate when the server asks",
                    "mutual authentication: the client presents its x.509v3 certificate");
    r.message = main_handshakes > 0 ? fmt::format("sent: {} handshakes completed with a server that requires a client certificate", main_handshakes)
                                    : "not-sent: no handshake completed with a server that requires a client certificate";
    out.push_back(std::move(r));
  }
  struct Bad {
    const char* id;
    const char* server;
    int max_version;
    const char* title;
    const char* requirement;
  };
  const Bad bad[] = {
      {"verifies-server-certificate", "server-untrusted", 0, "the client refuses a server certificate no trusted CA signed",
       "the client authenticates the server by its certificate"},
      {"verifies-server-host", "server-wrong-host", 0, "the client refuses a server certificate for another host",
       "the server's certificate names the host the client connects to (RFC 6125)"},
      {"refuses-expired-server", "server-expired", 0, "the client refuses an expired server certificate",
       "RFC 5280 §6.1.3: the current time within the certificate's validity"},
      {"refuses-tls-1.1", "server", TLS1_1_VERSION, "the client refuses a server that speaks only TLS 1.1",
       "TLS 1.2 or later (§10.1)"},
  };
  nlohmann::json good = secure.tls_connect;
  for (const auto& b : bad) {
    auto r = result(b.id, b.title, b.requirement);
    try {
      TlsFront front(secure.tls_pki, b.server, 0, b.max_version);
      secure.tls_connect = front.connect_fields();
      std::string before = session.error();
      bool ready = session.connect();
      // The read makes a lazy client connect; its answer (or error) comes
      // after the handshake, and the relay's count may trail the adapter's
      // answer: both are waited for, a bounded time.
      if (ready) session.ask(op_read_one(), milliseconds(0));
      session.set_error(before);
      int n = front.handshakes();
      for (auto until = std::chrono::steady_clock::now() + milliseconds(1000); ready && !n && std::chrono::steady_clock::now() < until;) {
        std::this_thread::sleep_for(milliseconds(20));
        n = front.handshakes();
      }
      r.message = n ? fmt::format("accepted: the client completed the handshake with {}", b.server)
                    : fmt::format("refused: no handshake completed with {}{}", b.server, ready ? " (the adapter reported ready)" : "");
      if (ready) session.disconnect();
    } catch (const std::exception& e) {
      r.outcome = Outcome::skip;
      r.message = e.what();
    }
    out.push_back(std::move(r));
  }
  secure.tls_connect = good;
  return out;
}

ClientRun run_client(const ClientOptions& o, const std::vector<Scenario>& list) {
  ClientRun out;
  auto t0 = Clock::now();
  std::unique_ptr<ScenarioServer> server;
  std::string tmpdir;
  try {
    std::string path = o.pty_path;
    if (o.transport == Transport::pty && path.empty()) {
      char tmpl[] = "/tmp/mbconform-client-XXXXXX";
      if (!mkdtemp(tmpl)) throw std::runtime_error("mkdtemp failed");
      tmpdir = tmpl;
      path = tmpdir + "/tty";
    }
    server = std::make_unique<ScenarioServer>(o.transport, o.transport == Transport::pty ? path : "", o.baud);
  } catch (const std::exception& e) {
    out.error = std::string("scenario server: ") + e.what();
    return out;
  }
  auto cleanup = [&] {
    server.reset();
    if (!tmpdir.empty()) std::filesystem::remove_all(tmpdir);
  };
  // --transport tls: the adapter reaches the scenario server through TLS.
  ClientOptions secure = o;
  std::unique_ptr<TlsFront> front;
  if (!o.tls_pki.empty()) {
    try {
      front = std::make_unique<TlsFront>(o.tls_pki, "server", server->port());
      secure.tls_connect = front->connect_fields();
    } catch (const std::exception& e) {
      out.error = std::string("TLS: ") + e.what();
      cleanup();
      return out;
    }
  }
  Session session(secure, *server, out);
  if (!session.start()) {
    cleanup();
    return out;
  }
  out.run.device_id = fmt::format("{} {}", out.hello.value("library", std::string("?")), out.hello.value("version", std::string("?")));
  out.run.target_uri = fmt::format("client {} <- {}", front ? "tls" : to_string(o.transport), o.adapter);
  if (o.transport == Transport::pty) out.run.baud = o.baud;

  std::vector<std::vector<SeenRequest>> per_scenario;
  std::vector<const Scenario*> deferred;
  size_t done = 0;
  for (const auto& s : list) {
    if (s.steps.empty()) {  // a run-wide check: judged at the end
      deferred.push_back(&s);
      continue;
    }
    conf::CaseResult r = header(s);
    auto c0 = Clock::now();
    if (!session.supports(s.op)) {
      r.outcome = Outcome::skip;
      r.message = "unsupported: the adapter does not list op " + s.op;
    } else {
      server->clear();
      if (!session.connect()) {
        session.close();
        cleanup();
        return out;
      }
      std::vector<std::string> failures;
      json answers = json::array();
      for (size_t i = 0; i < s.steps.size(); ++i) {
        const ScenarioStep& st = s.steps[i];
        server->set_step(int(i), &st, o.timeout);
        size_t sent_before = server->sent().size();
        milliseconds extra = st.fault == Fault::late ? milliseconds(200) : milliseconds(0);
        Answer a = session.ask(st.request, extra);
        session.settle();
        std::vector<const SeenRequest*> seen;
        for (const auto& q : server->requests())
          if (q.step == int(i)) seen.push_back(&q);
        std::vector<SentFrame> sent(server->sent().begin() + ptrdiff_t(sent_before), server->sent().end());
        std::string label = fmt::format("step {}: {} ({})", i + 1, st.request.value("op", ""), to_string(st.fault));
        if (!st.pass.accepts(a))
          failures.push_back(fmt::format("{}: the adapter reported {}, passing: {}", label, answer_text(a), st.pass.text()));
        for (const auto& p : judge_requests(st, seen, o.transport)) failures.push_back(label + ": " + p);
        r.frames.push_back(record(label, seen.empty() ? nullptr : seen.front(), sent, st.pass, a, o.transport));
        answers.push_back({{"step", i + 1}, {"answer", answer_text(a)}});
        out.run.wire_time_bound_seconds += step_bound(st, seen, sent, o);
        for (const auto* q : seen) out.run.bytes_received += q->adu.size();
        for (const auto& f : sent) {
          out.run.frames_sent++;
          out.run.bytes_sent += f.bytes.size();
        }
        if (a.kind == "hang" || a.kind == "exited") break;
      }
      r.extra["answers"] = answers;
      if (!session.restarted()) session.disconnect();
      per_scenario.push_back(server->requests());
      if (o.on_wire) o.on_wire(server->requests(), server->sent());
      conclude(r, failures);
      if (s.id == "client/timing/broadcast-turnaround") broadcast_turnaround(r, server->requests(), o);
    }
    r.duration_ms = std::chrono::duration<double, std::milli>(Clock::now() - c0).count();
    out.run.cases.push_back(std::move(r));
    if (o.on_case) o.on_case(out.run.cases.back(), ++done, list.size());
  }
  for (const auto* s : deferred) {
    conf::CaseResult r = header(*s);
    run_wide(*s, r, per_scenario, o);
    out.run.cases.push_back(std::move(r));
    if (o.on_case) o.on_case(out.run.cases.back(), ++done, list.size());
  }
  if (front) {
    for (auto& r : tls_client_checks(session, secure, front->handshakes())) {
      out.run.cases.push_back(std::move(r));
      if (o.on_case) o.on_case(out.run.cases.back(), ++done, list.size());
    }
  }
  session.close();
  out.run.wall_seconds = std::chrono::duration<double>(Clock::now() - t0).count();
  cleanup();
  return out;
}

std::vector<std::string> plan_lines(const Scenario& s, Transport t) {
  std::vector<std::string> lines;
  for (size_t i = 0; i < s.steps.size(); ++i) {
    const auto& st = s.steps[i];
    uint8_t unit = st.request.value("unit", model::kUnit);
    Bytes adu = framing_of(t).frame(unit, model::expected_request(st.request), 0);
    std::string wire = to_hex(adu);
    if (t == Transport::tcp) wire = "* * " + wire.substr(6);  // the transaction id is the master's to choose
    lines.push_back(fmt::format("  {}. ask {}", i + 1, st.request.dump()));
    lines.push_back(fmt::format("     {} {}", st.must_not_send ? "must not send:" : "expect on the wire:", wire));
    lines.push_back(fmt::format("     server: {}; passing: {}", to_string(st.fault), st.pass.text()));
  }
  return lines;
}

}  // namespace mbc::client
