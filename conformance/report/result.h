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

}  // namespace mbc::conf
