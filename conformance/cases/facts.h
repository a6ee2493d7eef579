// The one way a case generator reads a fact a case relies on. Each accessor
// returns the fact and records it, with its basis (stated, inferred,
// observed, either), in the Reliance list it is given (a Case's or an
// Expect's). settle_level() then applies the rule of issue 13 / spec/README.md:
//   MUST only when every fact relied on is stated (manual or standard);
//   relying on an inferred or observed fact makes the case OBSERVED, and its
//   requirement names the inference; an `either` fact keeps the level, the
//   expectation accepting each reading.
#pragma once

#include <cstdint>
#include <functional>
#include <optional>
#include <span>
#include <string>
#include <utility>
#include <vector>

#include "cases/case.h"

namespace mbc::conf::facts {

using Relies = std::vector<Reliance>;

// Register facts.
bool readable(Relies&, const spec::Register&);   // access allows a read (fact `read`)
bool writable(Relies&, const spec::Register&);   // access allows a write (fact `write`)
const std::optional<spec::Range>& range(Relies&, const spec::Register&);
std::optional<double> default_value(Relies&, const spec::Register&);
spec::WordOrder word_order(Relies&, const spec::Register&);
spec::DataType type(Relies&, const spec::Register&);
spec::TakesEffect takes_effect(Relies&, const spec::Register&);
const spec::Persistence& persistence(Relies&, const spec::Register&);

// A function code the case sends, as one the device supports (fact `supported`).
void supported(Relies&, const spec::FunctionCode&);

// A function code's limit ("max_quantity", "max_read_quantity", "max_write_quantity").
std::optional<int> limit(Relies&, const spec::FunctionCode&, const char* which);

// The exception policy for a kind of violation (either: `readings` set).
// quantity_zero is optional in the spec language (spec/README.md): where a
// spec leaves it out, the quantity_over_limit policy answers it (the
// standard checks both in one test, "0x0001 <= Quantity <= N": MBAP v1.1b3
// §6.1-6.4, §6.11, §6.12), and that is the fact recorded.
spec::PolicyEntry policy(Relies&, const spec::Spec&, spec::Violation);

// Whether a raw value lies in the register's stated values: its range, every
// reading of a range printed two ways, its enumeration's values; a float
// without a range takes any value. nullopt when the readings disagree about
// it (inside one, outside another). Records the fact `range`.
std::optional<bool> in_range(Relies&, const spec::Spec&, const spec::Register&, uint32_t raw);

// ---- classifying a request: the one oracle of the exception rules ----------
//
// What a request breaks, from the spec and the standard (MBAP v1.1b3 §6 per
// function code, §7 exception codes), and so what its reply may be. Used by
// the case generators (policy_expect), the properties' model
// (properties/stateful.cpp) and check-capture's judge (capture/judge.cpp);
// the reference engine (reference/) keeps its own: the oracle stays apart
// from the implementation.

// One breach: the violation, each reading of the spec's policy for it (one;
// more when the manual prints it two ways), and the facts it rests on (the
// policy and what makes the request break it: an access, a range, a limit).
struct Breach {
  spec::Violation violation = spec::Violation::unsupported_function;
  spec::PolicyEntry policy;                  // as policy() gives it (basis, section, erratum)
  std::vector<spec::PolicyEntry> readings;   // policy.readings, or policy alone
  Relies relies;
};

struct Classified {
  // The breaches of the first check that fails, in the order a server makes
  // the checks (MBAP v1.1b3 §4.5 Figure 9 and the per-function figures of §6:
  // the function code (01); the quantity and byte count (03); the addresses
  // and their access (02); the values written). Several breaches of one
  // check (an address range that is partly a gap, partly past the map) are
  // all listed: the order among them is no manual's.
  std::vector<Breach> breaches;
  // A valid request whose value may be out of range or not (a write of part
  // of a two-word value whose other word is not known: classify's `known`; a
  // range printed two ways that disagree about it): a normal reply, or the
  // value_out_of_range refusal of this breach, is allowed.
  std::optional<Breach> maybe;
  Relies relies;  // the facts the request's validity rests on (no breach)
  std::vector<std::pair<spec::Table, uint16_t>> registers;  // the mapped registers it addresses (first 256)

  bool valid() const { return breaches.empty(); }
  // What the reply may be. A valid request: a normal reply (and with
  // `maybe` its refusal). A breach: each reading of each breach's policy;
  // an unspecified one allows any exception or silence.
  bool allows_normal() const { return breaches.empty(); }
  bool allows_silence() const;
  bool allows_exception(uint8_t code) const;
  // Whether some breach's policy leaves the answer open (unspecified).
  bool open() const;
};

// The word at an address the request does not carry, when the caller knows it.
using KnownWord = std::function<std::optional<uint16_t>(spec::Table, uint16_t)>;

// Classifies a request PDU (function code first) for a device with spec `s`.
Classified classify(const spec::Spec& s, std::span<const uint8_t> pdu, const KnownWord& known = {});

// A printed example frame (either: printed or resolved).
const spec::Example& example(Relies&, const spec::Example&);

// Every reliance of a case (its own and its steps' expectations'), and one
// described: check/check.h.
using check::all_relies;
using check::describe;

// The case's level from what it relies on; names inferences in the
// requirement. Idempotent.
void settle_level(Case&);


}  // namespace mbc::conf::facts
