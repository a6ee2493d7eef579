// Model-based (stateful) testing: random sequences of valid and invalid
// frames with time advancing and power cycles, each checked against a model
// of the device written from the spec (register image, access, ranges,
// exception policy, persistence, broadcast) and the Modbus standard, never
// from the reference code. The model interprets any frame, so the same
// checker replays the regression files (regressions/*.txt).
#pragma once

#include <optional>
#include <string>
#include <vector>

#include "cases/facts.h"
#include "properties/properties.h"

namespace mbc::conf::props {

Invariant stateful_invariant();

// What the spec's policy lets a device answer to a request's breaches (any
// of them: cases/facts.h classify). `breaches` is not empty.
Expected refusal_of(const std::vector<facts::Breach>& breaches);

// A regression file: what it was found with, and its steps.
struct Regression {
  std::string path;
  std::string device_id;
  std::string fault;  // the fault it was found with ("" = none); replay must still catch it
  std::string note;   // the comment lines
  std::vector<Step> steps;
};
// A regression file is a frame script (conformance/check/README.md) with a
// `device` line; `fault` names the broken device it was found with. Throws
// check::ParseError (file:line:col) or std::runtime_error.
Regression parse_regression(const std::string& path);
std::string format_regression(const std::string& device_id, const std::string& fault, const std::string& comment,
                              const std::vector<Step>& steps);

// Replays steps through the model on the session's target; returns the
// first disagreement, or "" when every reply and the final image agree.
std::string replay(Session& session, const std::vector<Step>& steps);

}  // namespace mbc::conf::props
