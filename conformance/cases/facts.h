// The one way a case generator reads a fact a case relies on. Each accessor
// returns the fact and records it, with its basis (stated, inferred,
// observed, either), in the Reliance list it is given (a Case's or an
// Expect's). settle_level() then applies the rule of issue 13 / spec/README.md:
//   MUST only when every fact relied on is stated (manual or standard);
//   relying on an inferred or observed fact makes the case OBSERVED, and its
//   requirement names the inference; an `either` fact keeps the level, the
//   expectation accepting each reading.
#pragma once

#include <optional>
#include <string>
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
spec::PolicyEntry policy(Relies&, const spec::Spec&, spec::Violation);

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
