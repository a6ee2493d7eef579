// `mbconform scan`: finds every drive on a line, read-only (README.md).
//
// On a serial line (rtu://PATH) it tries line settings in order: the known
// specs' own (each spec's default baud and frame format), then the common
// ones, then the rest the specs list. At each setting it sweeps the units
// (1-247 unless narrowed) with a read; the first setting that gets an
// answer is the line's, and the scan stops trying others once its sweep
// is done (every drive on one line shares its settings). Through a gateway
// (tcp://, rtu-tcp://) there are no settings to find: units only.
//
// Each unit found is then identified against the known specs: FC 43/14
// (VendorName, ProductCode) where a spec says the drive answers it, else
// reads of registers whose readability the spec states, spread over its
// map. The best match, its score and a confidence go into the table with
// the exact `mbconform run` command for that unit.
//
// Every frame goes through a session with no spec (session/session.h), so
// the one frame policy holds: reads only, nothing written.
#pragma once

#include <chrono>
#include <cstdint>
#include <functional>
#include <optional>
#include <string>
#include <vector>

#include "spec.h"

namespace mbc::conf::scan {

// One serial line setting.
struct Setting {
  int baud = 19200;
  int data_bits = 8;
  char parity = 'E';
  int stop_bits = 1;
  std::string text() const;   // "19200 8E1"
  std::string query() const;  // "baud=19200&parity=E&data=8&stop=1"
  bool operator==(const Setting&) const = default;
};

// The settings to try, in order, for the known specs `specs`; `given`
// (baud, parity, data, stop from the URI) narrows them.
struct Given {
  std::optional<int> baud, data_bits, stop_bits;
  std::optional<char> parity;
};
std::vector<Setting> candidate_settings(const std::vector<const spec::Spec*>& specs, const Given& given = {});

struct Options {
  std::string uri;  // rtu:///dev/ttyUSB0[?baud=..], tcp://HOST:PORT, rtu-tcp://HOST:PORT
  int first_unit = 1, last_unit = 247;
  std::chrono::milliseconds timeout{100};  // the wait for each probe's reply
  std::chrono::milliseconds budget{std::chrono::minutes(10)};
  bool all_settings = false;  // keep trying settings after one answered
  // Called after each probe: requests sent so far, and what is being tried ("19200 8E1 unit 17").
  std::function<void(uint64_t requests, const std::string& at)> on_probe;
};

// How well a unit matches a spec.
struct Match {
  std::string spec_id;
  double score = 0;          // 0..1
  std::string evidence;      // "FC 43/14 VendorName ..., ProductCode ..." | "7 of 8 stated registers read"
};

struct Found {
  uint8_t unit = 0;
  std::optional<Setting> setting;  // serial lines only
  std::string answered;            // what the first probe got ("normal reply", "exception 02")
  std::optional<Match> best;       // none: no known spec matches
  std::vector<Match> others;       // the rest with a score, best first
  std::string confidence;          // high | medium | low | none
  std::string target;              // the unit as a run target: rtu://PATH?baud=..&unit=N, tcp://HOST:PORT?unit=N
  std::string command;             // the mbconform run command for this unit
};

struct Result {
  std::string uri;                 // the line scanned, as given
  std::vector<Found> units;
  std::vector<std::string> tried;  // the settings swept ("9600 8N1: nothing")
  uint64_t requests = 0;
  double seconds = 0;
  bool partial = false;
  std::string partial_why;         // "the budget of 10m ran out at 38400 8E1 unit 120"
  std::vector<std::string> notes;  // what the reader should know (a pty does not carry parity, ...)
};

// Scans; `specs` are the known specs to try and identify against. Throws
// std::invalid_argument on a bad URI, std::runtime_error when the line
// cannot be opened. Stops early (partial) on a stop signal or the budget.
Result scan(const Options& options, const std::vector<const spec::Spec*>& specs);

// The table printed at the end (with the settings tried and the notes), and the result as JSON (the scan file,
// `scan --out FILE`, which `run --scan-file FILE` qualifies).
std::string table(const Result& r);
std::string to_json(const Result& r);
// A scan file read back: the line, and each unit's target, spec, confidence
// and settings (`tried` and `notes` as written). Throws
// std::invalid_argument with one line naming `what` (the file) when it is not
// a scan file: not JSON, a unit outside 1-247, a target that is not that
// unit on that line.
Result from_json(const std::string& text, const std::string& what);

// "1-247" or "7": the units to sweep. Throws std::invalid_argument with one line.
std::pair<int, int> parse_units(const std::string& text);
// The line a URI is on: the serial port's path, or HOST:PORT of a gateway
// (two scans of one line are one line: `run` qualifies it one drive at a time).
std::string line_of(const std::string& uri);

}  // namespace mbc::conf::scan
