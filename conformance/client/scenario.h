// Master-side conformance (`mbconform client`): the scenarios a Modbus
// client library is put through. A scenario is data, like a `run` case: an id,
// the clause it checks with its sentence quoted, a level, and steps. Each step
// is one request the adapter is asked to make, how the scenario server
// answers it (correctly, or with one named fault), and the set of adapter
// outcomes that pass. What the master put on the wire is judged as well
// (well formed, within the limits, the unit asked for, MBAP fields, CRC).
//
// Expected values come from the scenario server's data model (model.h) and
// the standard, never from a library.
#pragma once

#include <cstdint>
#include <optional>
#include <set>
#include <string>
#include <vector>

#include <nlohmann/json.hpp>

#include "modbus/framing.h"
#include "report/result.h"

namespace mbc::client {

// The framing a run speaks is modbus/'s descriptor: kTcp (Modbus TCP, TLS)
// or kRtu (RTU frames: RTU over TCP, a pty).

// How the scenario server answers the request a step provokes.
enum class Fault {
  none,              // the correct reply
  exception,         // exception `code` (MBAP v1.1b3 §7)
  wrong_transaction, // MBAP only: a reply with another transaction id and other values, then the right one
  wrong_unit,        // a reply from another unit with other values, then the right one
  wrong_function,    // a well-formed FC 04 reply to an FC 03 request, other values
  bad_crc,           // RTU only: the right reply, CRC inverted
  truncated,         // the first half of the right reply, then nothing
  trailing_bytes,    // the right reply with two bytes more (inside the MBAP length / the CRC)
  byte_count,        // one register less than asked, byte count saying so
  too_many,          // one register more than asked, byte count saying so
  split,             // the right reply in three pieces, 30 ms apart
  late,              // the reply, other values, 200 ms after the master's timeout
  silence,           // no reply at all (also a broadcast's correct answer)
  garbage_first,     // RTU only: line noise, a frame gap, then the right reply
};
const char* to_string(Fault);

// An adapter's answer to one request, reduced to what is judged.
struct Answer {
  std::string kind;  // ok | exception | timeout | invalid_reply | refused | unsupported | other | hang | exited
  int code = 0;      // exception code
  nlohmann::json values;
  std::string detail;
};

// The outcomes that pass one step. "ok" passes only with `values` (when set);
// "exception" only with `code`.
struct Passing {
  std::set<std::string> kinds;
  std::optional<nlohmann::json> values;
  int code = 0;
  bool accepts(const Answer&) const;
  std::string text() const;  // "ok [4096, 4097] | timeout"
};

struct ScenarioStep {
  nlohmann::json request;  // op and arguments (the runner adds "id")
  Fault fault = Fault::none;
  uint8_t code = 0;        // Fault::exception
  Passing pass;
  // Judge the request on the wire (well formed, the fields asked, the unit).
  bool judge_request = true;
  // The library should not send this request at all (over a limit): a
  // request on the wire is the failure, not judged for its fields.
  bool must_not_send = false;
};

struct Scenario {
  std::string id;           // "client/reply/bad-crc"
  std::string family;       // "client-requests" | "client-replies" | "client-timing"
  std::string clause;       // "MB-SL v1.02 §2.5.1.2"
  conf::Level level = conf::Level::must;
  std::string title;
  std::string requirement;  // the sentence checked, quoted
  std::string op;           // the op every step uses (an adapter without it: unsupported)
  std::vector<ScenarioStep> steps;
};

// The standard's quantity limits (MBAP v1.1b3 §6), as modbus-standard.yaml
// states them: the over-limit scenarios ask for one more.
struct Limits {
  int read_coils = 0, read_holding_registers = 0, write_multiple_coils = 0, write_multiple_registers = 0,
      rw_write = 0;
};
// From spec/devices/modbus-standard.yaml. Throws std::runtime_error when it
// lacks one of them.
Limits standard_limits();

// Every scenario for a wire, in report order. `timing_on_pty`: the RTU run is
// on a pty (t1.5/t3.5 checks OBSERVED there, MUST on a real line).
std::vector<Scenario> scenarios(const Framing& wire, bool timing_on_pty, const Limits& limits);

// The run-wide checks computed over every request seen (transaction ids on
// TCP, t1.5 / t3.5 on a serial line): their headers; the runner fills in the outcome.
std::vector<Scenario> run_wide_checks(const Framing& wire, bool serial_line, bool timing_on_pty);

}  // namespace mbc::client
