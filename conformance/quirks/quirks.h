// A library's declared deviations (`--quirks FILE`): case ids (globs) or
// finding kinds, each with the reason it is known. A CI gate stays green on
// those and fails on anything new; the reports list the declared quirks in a
// section of their own, and the ones that no longer occur. One format and
// one parser for `run`, `fuzz` (finding kinds) and `client` (its
// conformance/client/deviations/*.yaml). Format: conformance/README.md,
// "Quirks files": a YAML list (an empty file is an empty list)
//
//   - case: "modbus-standard/function-codes/fc*/quantity-0"
//     reason: "answers 02, not 03: src/modbus.c:..."
//   - kind: "unanswered-request"
//     reason: "..."
#pragma once

#include <string>
#include <vector>

#include "report/result.h"

namespace mbc::conf::quirks {

struct Quirk {
  enum class By { case_id, kind } by = By::case_id;
  std::string pattern;  // a glob ('*' crosses '/'), or an exact id / kind
  std::string reason;   // why it is known: the clause, and the library's line that explains it
  int line = 0;         // where it is declared
  bool used = false;    // set by apply() (and client::apply_quirks) when it matched a failure
};

struct Quirks {
  std::string path;
  std::vector<Quirk> list;
  // The first quirk declared for a case id / a finding kind, or nullptr.
  const Quirk* for_case(const std::string& id) const;
  const Quirk* for_kind(const std::string& kind) const;
  bool empty() const { return list.empty(); }
};

// Throws std::runtime_error "FILE:LINE:COL: error: quirks: what" for a file
// that cannot be read or does not follow the format.
Quirks load(const std::string& path);

// Marks every failed case of `run` that a case quirk declares (CaseResult::
// quirk = the reason, Quirk::used); notes the case quirks that matched
// nothing (the library may have fixed them) in run.notes.
void apply(Quirks&, DeviceRun& run);

}  // namespace mbc::conf::quirks
