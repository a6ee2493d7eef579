// The case generators: one per family beside this header (examples,
// registers, function_codes, framing, deviations, standard). Each turns the
// spec and the Modbus standard into Cases (check/check.h), every step
// carrying the outcome they predict (never the reference code's); the
// runner (runner/) runs them and knows nothing about where they came from.
#pragma once

#include <chrono>
#include <cstdint>
#include <optional>
#include <string>
#include <vector>

#include "check/check.h"
#include "modbus/hex.h"
#include "report/result.h"
#include "safety/safety.h"
#include "spec.h"
#include "targets/target.h"

namespace mbc::conf {

// The executable form of a case (Case, Step, Expect) is check/check.h:
// generators here only make them.
using check::Case;
using check::Expect;
using check::Reliance;
using check::Step;

// Cases generated on a server's probed or given data map (`run --map`,
// conformance/map/) rather than on a spec of its own device. What a map
// cannot tell (writability) is in the spec map::apply() makes of it, which
// the frame policy reads (policy/policy.h).
struct OnMap {};

// What a generator knows about where the cases will run.
struct GenContext {
  const spec::Spec& spec;
  TargetInfo target;        // unit, framing, raw/power/clock capabilities, live
  WritePolicy policy;
  const spec::Spec* standard = nullptr;  // modbus-standard, for the deviations family
  // Set: the spec is a map's. Every function is optional (MBAP v1.1b3 §5.1).
  std::optional<OnMap> map;
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
