// A live server's data map, without writing a spec: blocks of mapped
// addresses per table, from a probe of the target (`--map auto`), a small
// map-only YAML file (`--map FILE`) or inline text (`--map 'holding=0-199,
// coils=0-199'`). apply() puts a map in place of a spec's registers, so the
// standard's cases (modbus-standard) run wherever the server's map allows.
// A probed fact is observed, never stated: a probe only reads, so it cannot
// tell whether an address is writable (apply() says so in the spec it makes,
// and the frame policy then needs --allow-writes for a write on a live target).
#pragma once

#include <chrono>
#include <cstdint>
#include <functional>
#include <optional>
#include <string>
#include <vector>

#include "cases/case.h"
#include "spec.h"
#include "session/link.h"
#include "targets/target.h"

namespace mbc::conf::map {

struct Block {
  spec::Table table = spec::Table::holding;
  uint16_t first = 0, last = 0;              // inclusive
  std::optional<spec::Access> access;        // unknown for probed blocks and inline ranges without ':rw'/':ro'
};

// How a table answered a read of an address outside its blocks.
struct Unmapped {
  spec::Table table = spec::Table::holding;
  std::string answer;  // "exception 02", "silence", "exception 01 (function not supported)", ...
  int seen = 0;        // how many probes got that answer
};

struct Map {
  std::string source;             // "probe of tcp://...", "file x.yaml", "inline"
  std::vector<Block> blocks;      // sorted by table, then address
  std::vector<Unmapped> unmapped; // probe only
  bool partial = false;           // the probe ran out of budget or time: addresses past `partial_at` were not probed
  std::string partial_at;
  std::string partial_by;         // "budget" or "time"
  int requests = 0;               // probe requests sent
  double seconds = 0;             // how long the probe took
  // Probe only: how the server departed from the standard while probed
  // (a read answered in full though its last items are past the table).
  std::vector<std::string> deviations;
  std::vector<std::string> notes;  // probe only: what the probe learned (reply and exception latency)
  bool access_known() const;      // every block states its access
  bool covers(spec::Table t, uint16_t address) const;
  std::string describe() const;   // "holding 0x0000-0x00C7, coils 0x0000-0x00C7, ..."
};

// The probe's request budget by default (--map-budget).
inline constexpr int kDefaultBudget = 2000;

// The most requests probe() sends with `budget` (for --plan: the probe is
// bounded by the budget whatever the target answers).
int planned_requests(int budget);

struct ProbeLimits {
  int budget = kDefaultBudget;                     // the most requests (--map-budget)
  std::optional<std::chrono::milliseconds> time;   // the longest the probe runs (--map-time)
  // After each request: how many were sent of the budget (progress).
  std::function<void(int sent, int budget)> on_request;
};

// Probes `target` at info().unit with bounded reads (FC 01/02/03/04, never a
// write). Which tables answer (exception 01: not supported); then each
// table's first kDenseSpan addresses one by one, a run of mapped ones grown
// with multi-item reads (4, 8, ... up to the standard's maximum quantity);
// then seeds where vendors put registers (round decimal and hex bases, a few
// words in: 1000s and 0x1000s, then 100s and 0x100s, then 10s and 0x10s),
// each hit followed back and on to the ends of its cluster. A real map has
// gaps (single registers among unmapped addresses), and a multi-item read
// over a gap fails, so single reads find what block reads cannot. An address
// is unmapped when a read of it gets an exception or silence; `unmapped`
// records which. Stops when the budget or the time runs out (partial).
Map probe(Link& target, const ProbeLimits& limits);
Map probe(Link& target, int budget = kDefaultBudget);
inline constexpr uint32_t kDenseSpan = 256;

// What a probe found and learned, one line each, for the run's notes and
// the terminal: requests and time, the unmapped answers, partial, deviations.
std::vector<std::string> probe_notes(const Map& map);

// 'holding=0-199,coils=0-199,discrete=0-199,input=0-199'; several ranges of
// a table are joined with '+' ('holding=0-99+200-299'); ':rw' or ':ro' after
// a range states its access. Throws std::invalid_argument naming the bad part.
Map parse_inline(const std::string& text);

// A map-only YAML file (conformance/README.md, "Maps"): throws
// std::runtime_error with "file:line:col: error: map: what".
Map load_file(const std::string& path);

// `text` as --map takes it: "auto" is handled by the caller; a path to an
// existing file, else inline text.
Map parse_option(const std::string& text);

// `base` with its registers replaced by the map's (holding u16, coils and
// discrete inputs bits, input registers u16; access as the block states it,
// else rw for holding/coils and ro for the read-only tables). Of the spec's
// examples it keeps those of the data-model functions (FC 01-06, 15, 16, 22,
// 23) that address only what the map covers, not to the broadcast address
// and not answered with exception 02 or 04 (the spec's own map and ranges): the answers to FC 07, 08, 11, 12, 17, 20, 21, 24 and 43 are the
// spec's own device's choices (exception status outputs, counters, server
// id, identification objects: MBAP v1.1b3 §6.7-6.21 leave their contents to
// the device; 07, 08, 11, 12 and 17 are serial line only), not the server's.
spec::Spec apply(const spec::Spec& base, const Map& map);

// "holding", "coils", "input", "discrete".
const char* table_name(spec::Table);

// A spec skeleton (spec/README.md's language) of what a probe found, for
// `mbconform spec discover`: the tables that answered, their blocks, the
// answer to unmapped addresses. Every fact in it is observed, and says so;
// what a probe cannot see (the line settings, writability, limits) is left
// unspecified or marked as a placeholder to state from the manual.
std::string skeleton_yaml(const Map& map, const std::string& device_id, uint8_t unit);

// The terms of generating cases on a map (GenContext::map, cases/case.h).
OnMap terms(const Map& map);

}  // namespace mbc::conf::map
