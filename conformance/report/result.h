// What a run found: plain data shared by the runner (`mbconform run`), the
// property tests (`mbconform props`) and the black-box fuzzer, and written by
// the report writers (report/*.cpp: JUnit XML, JSON, HTML, terminal).
#pragma once

#include <cstdint>
#include <map>
#include <optional>
#include <string>
#include <vector>

#include <nlohmann/json.hpp>

#include "modbus/hex.h"

namespace mbc::conf {

// MUST: the manual's or the standard's requirement; SHOULD: a recommendation;
// OBSERVED: behaviour the manual leaves open, recorded, never failed.
enum class Level { must, should, observed };
// error: the case could not be run (the target was lost before it); neither
// a pass nor a failure of the device.
enum class Outcome { pass, fail, skip, observed, error };
const char* to_string(Level);
const char* to_string(Outcome);

// How an exchange departed from its expectation: made by the one judge
// (check/judge.h's Mismatch), kept as this enum into every report.
enum class MismatchKind {
  answered,           // a reply where silence was expected
  malformed_framing,  // a reply whose framing is wrong (CRC, unit, transaction)
  silent,             // silence (or a closed connection) where a reply was expected
  malformed_reply,    // the reply PDU breaks MBAP v1.1b3 for the request
  unknown_exception,  // an exception code neither the standard nor the spec knows
  refused,            // an exception where a normal reply was expected
  different,          // a well-formed reply other than the expected one
};
const char* to_string(MismatchKind);

// Why a case failed, as a cause: what the device did against what was due,
// at the first step that missed, in words free of addresses and values
// ("exception 02" where "exception 01" is due; "silence" where "a normal
// reply" is due), so one fault at 35 registers is one cause. The report
// groups failures by (kind, due, did) and keeps the function codes and
// registers each cause covers.
struct Cause {
  MismatchKind kind = MismatchKind::different;
  std::string due;            // "exception 01", "silence", "the stated value", "a normal reply"
  std::string did;            // "exception 02", "a reply", "another value", "a reply 2 bytes longer"
  std::optional<uint8_t> fc;  // the function code of the request that missed
  std::string text() const;   // "exception 02 where exception 01 is due"
  std::string key() const;    // what groups causes: kind, due, did
};

// One frame exchanged by a case, kept for the report.
struct FrameRecord {
  std::string step;                 // what the step does ("write 0x0020 = 1000")
  Bytes request;                    // as sent on the wire (framed)
  std::optional<Bytes> expected;    // the exact reply expected, when one is
  std::string expected_text;        // the expectation in words ("exception 03", "silence")
  std::optional<Bytes> actual;      // as received; nullopt = silence
  std::string request_decoded, actual_decoded;
  std::string expected_decoded;     // `expected` decoded, when set
  double latency_us = 0;
};

struct CaseResult {
  std::string id;           // stable: "<device>/<family>/<...>", "prop.<invariant>.<device>"
  std::string family;       // examples | registers | function-codes | framing | deviations | properties | ...
  std::string clause;       // manual section ("57HS-R §6.2.4") or standard clause ("MBAP v1.1b3 §6.3")
  Level level = Level::must;
  std::string title;
  std::string requirement;  // the sentence checked, quoted where possible
  Outcome outcome = Outcome::skip;
  std::string message;      // why it failed / was skipped / what was observed
  std::optional<uint16_t> register_address;  // for the per-register table
  std::vector<FrameRecord> frames;
  std::vector<std::string> errata;  // erratum ids the case relies on
  double duration_ms = 0;
  // Set when the case failed and a quirks file (--quirks) declares the
  // deviation: the reason given there. Counted apart, never a failure.
  std::string quirk;
  // A skipped case that a flag would let run ("--allow-writes"): what the
  // frame policy or the generator named. A MUST skipped for want of one
  // makes the run PARTIAL (verdict()).
  std::string opt_in;
  // Set when the case failed (or, OBSERVED, differed) on a step: its cause.
  std::optional<Cause> cause;
  nlohmann::json extra = nlohmann::json::object();  // e.g. props: cases, seed, counterexample
};

// What the report says of a device beyond its cases (report/device_facts.cpp
// fills it from the spec; the report adds what the run's own frames read:
// the FC 43 objects, the firmware registers' values).
struct DeviceFacts {
  std::string title;                                          // "SIHONG 57HS-R integrated stepper (57HS56JSR, ...)"
  std::vector<std::pair<std::string, std::string>> identity;  // the spec's FC 43 objects: VendorName, ProductCode, ...
  std::vector<uint16_t> firmware_registers;                   // holding registers whose names say firmware/version
  std::string line;                                           // the spec's line settings: "19200 baud 8E1 (default), unit 1"
  std::map<uint16_t, std::string> register_names;             // address -> name (holding first, then the other tables)
  std::map<std::string, std::string> errata;                  // id -> "§6.2: printed X, read as Y (why)"
};

// One device (one target) in a run.
struct DeviceRun {
  std::string device_id;
  std::string target_uri;
  std::string spec_path;
  std::vector<CaseResult> cases;
  std::vector<double> latencies_us;  // every answered exchange
  uint64_t frames_sent = 0, bytes_sent = 0, bytes_received = 0;
  uint64_t silences = 0;             // exchanges that got no reply (each cost a wait the wire-time bound does not count)
  double wall_seconds = 0;
  std::optional<int> baud;          // for the wire-time bound
  double wire_time_bound_seconds = 0;  // bytes at the baud rate + 3.5 char gaps
  std::vector<std::string> restore_failures;  // registers a live run could not put back
  // What the safety rules kept out of the snapshot (registers a drive would
  // not read before the run), one line each, with address ranges.
  std::vector<std::string> safety_notes;
  // Every broadcast write sent (unit 0: every drive on the line took it).
  std::vector<std::string> broadcast_writes;
  std::vector<std::string> notes;   // how the run was set up (a probed map, a partial map)
  DeviceFacts facts;
  bool interrupted = false;
  // Set when the run against this target had to stop (the target kept
  // throwing: a lost connection, a device that cannot go on); the cases it
  // could not run are Outcome::error.
  std::string error;
};

struct RunReport {
  std::string command;      // "run" | "props" | "fuzz"
  std::string started_at;   // ISO 8601 UTC
  std::string version;
  std::vector<DeviceRun> devices;
  bool interrupted = false;
  // --fail-on should: a failed SHOULD case fails the run (exit 1, a JUnit
  // <failure>); by default it is reported, and fails neither.
  bool fail_on_should = false;
};

// Whether a failed case fails the run: a MUST, or a SHOULD under --fail-on should.
bool fails_run(const CaseResult&, const RunReport&);

// The flag a skip reason names ("... needs --allow-writes" -> "--allow-writes"), or "".
std::string opt_in_named(const std::string& why);

// What a run comes to, one word for every report (terminal, HTML, JSON,
// JUnit) and the exit code (tools/mbconform/cmd_run.cpp):
//   incomplete  a target was lost or the run was stopped            exit 2
//   fail        a case that fails the run failed                    exit 1
//   partial     none failed, but MUST cases were skipped for want   exit 0, or 3
//               of an opt-in (a flag the user did not give)         with --require-complete
//   pass        every MUST case ran and passed                      exit 0
struct Verdict {
  enum class Kind { pass, partial, fail, incomplete } kind = Kind::pass;
  size_t failed = 0;  // cases that fail the run
  size_t should_failed = 0;  // failed SHOULD cases that do not
  // The opt-ins MUST cases were skipped for want of, each with how many
  // MUST cases it would enable (also set when the verdict is fail: the run
  // is partial as well).
  std::vector<std::pair<std::string, size_t>> missing;
  std::string incomplete;  // incomplete_line()'s text, when incomplete
  const char* word() const;  // "PASS" | "PARTIAL" | "FAIL" | "INCOMPLETE"
  // The verdict in words: "PARTIAL: every MUST case that ran passed; 41 MUST
  // cases did not run: --allow-writes would enable 41 (rerun with it)".
  std::string line() const;
};
Verdict verdict(const RunReport&);

}  // namespace mbc::conf
