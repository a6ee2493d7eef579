// A conformance case is data: a stable id tied to the clause it checks, the
// requirement quoted, and the steps to run, each carrying the outcome the
// spec and the Modbus standard predict (never the reference code's). One
// generator per family lives beside this header (examples, registers,
// function_codes, framing, deviations); the runner (runner/) executes cases
// against any Target and knows nothing about where they came from.
#pragma once

#include <chrono>
#include <cstdint>
#include <optional>
#include <string>
#include <vector>

#include "modbus/hex.h"
#include "report/result.h"
#include "safety/safety.h"
#include "spec.h"
#include "targets/target.h"

namespace mbc::conf {

// A fact a case relies on, and where it comes from (spec/README.md, "Where
// each fact comes from"). Recorded by the accessors of cases/facts.h only.
struct Reliance {
  std::string fact;         // "register 0x0BB8 read", "exception_policy.crc_error", "FC 16 max_quantity"
  spec::FactBasis basis;
};

// What a step expects back.
struct Expect {
  enum class Kind {
    none,        // nothing checked (setup, or an OBSERVED step that only records)
    exact,       // the reply PDU is exactly `pdu` (and, when `adu` is set and the target frames RTU, the ADU)
    exception,   // an exception reply with `code` to the request's function code
    silence,     // no reply at all
    normal,      // a well-formed normal reply (MBAP v1.1b3 §6), any values
    registers,   // a well-formed read reply holding exactly `words`
    unchanged,   // a read reply equal to the one step `memo` got
    answered,    // any reply to the request's function code: normal, or an exception (any code); not silence
  } kind = Kind::none;
  Bytes pdu;
  std::optional<Bytes> adu;
  uint8_t code = 0;
  std::vector<uint16_t> words;
  int memo = -1;         // index of the earlier step whose reply this must equal
  std::string text;      // the expectation in words, for reports ("exception 03 (policy value_out_of_range, §6.2.4)")
  // The facts this expectation was built from (cases/facts.h); a case
  // relies on its steps' facts too.
  std::vector<Reliance> relies;
  // The source prints two readings: the reply may meet this expectation or
  // any of `either` (each with its `reading` named); the runner records which.
  std::vector<Expect> either;
  std::string reading;   // this reading's name ("silence (the text)")
};

struct Step {
  enum class Kind { pdu, raw, advance, power_cycle } kind = Kind::pdu;
  std::string what;                     // "write 0x0020 = 1000 (FC 06)"
  uint8_t unit = 0;                     // pdu: the slave/unit addressed (0 = broadcast)
  Bytes pdu;                            // pdu steps
  Bytes adu;                            // raw steps: the bytes on the wire
  std::optional<size_t> gap_after;      // raw steps: an inter-character gap after that many bytes
  std::chrono::microseconds dt{0};      // advance steps
  Expect expect;
  // pdu writes (FC 06/16): when >= 0, the value words are the registers the
  // read at step `words_from` got, filled in by the runner (a broadcast that
  // writes back what the target held). Not sent when that read failed.
  int words_from = -1;
  // A setup step (restoring a given state): its failure fails the case with
  // "setup:" but it is not the requirement itself.
  bool setup = false;
  // The device's documentation says this request may go unanswered: a reply
  // it expects is waited for the silence window, not the timeout.
  bool may_go_unanswered = false;
};

struct Case {
  std::string id;           // "<device>/<family>/<section-or-register>/<n>"
  std::string family;       // examples | registers | function-codes | framing | standard | deviations
  std::string clause;       // "57HS-R §6.2.4", "MBAP v1.1b3 §6.3", "MB-SL v1.02 §2.4.1"
  Level level = Level::must;
  std::string title;
  std::string requirement;  // the sentence checked
  std::vector<Step> steps;
  std::vector<std::string> errata;
  // The facts the case relies on beyond its steps' expectations
  // (cases/facts.h). settle_level() turns an inferred one into OBSERVED.
  std::vector<Reliance> relies;
  // Set by settle_level() when an inferred fact moved the case off MUST/SHOULD.
  std::optional<Level> level_if_stated;
  std::optional<uint16_t> register_address;  // for the per-register table
  // Registers (holding, address + words) the case writes: the runner reads
  // them before and writes them back after, so cases do not leak state.
  std::vector<std::pair<uint16_t, int>> touches;
  // Set when the case cannot run on this target (capability, safety); the
  // runner reports skip with this reason.
  std::string skip_reason;
  // Every function is optional (MBAP v1.1b3 §5.1): when set (cases on a
  // server's probed or given map, not on a spec of its own), an exception 01
  // to a step that expected something else means the server does not
  // implement that function, and the case does not apply (skip), rather than
  // fails.
  bool functions_optional = false;
};

// What a generator knows about where the cases will run.
struct GenContext {
  const spec::Spec& spec;
  TargetInfo target;        // unit, framing, raw/power/clock capabilities, live
  WritePolicy policy;
  const spec::Spec* standard = nullptr;  // modbus-standard, for the deviations family
};

std::vector<Case> examples_cases(const GenContext&);        // examples.cpp
std::vector<Case> register_cases(const GenContext&);        // registers.cpp
std::vector<Case> function_code_cases(const GenContext&);   // function_codes.cpp
std::vector<Case> framing_cases(const GenContext&);         // framing.cpp
std::vector<Case> deviation_cases(const GenContext&);       // deviations.cpp
std::vector<Case> standard_cases(const GenContext&);        // standard.cpp: the standard's own checks, on any map

// Every family, in report order, each case's level settled (cases/facts.h).
std::vector<Case> all_cases(const GenContext&);

}  // namespace mbc::conf
