// A library's declared deviations (`--quirks FILE`): case ids (globs) or
// finding kinds, each with the reason it is known. A CI gate stays green on
// those and fails on anything new; the reports list the declared quirks in a
// section of their own, and the ones that no longer occur. One format and
// one parser for `run`, `fuzz` (finding kinds) and `client` (its
// conformance/peers/deviations/*.yaml). Format: conformance/README.md,
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
  bool used = false;    // set by apply() when it matched a failure
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

// The file `--quirks` names: a path as given when it names a file (or holds
// a '/' or ends in .yaml), else the declared deviations that come with
// mbconform, by name: NAME.yaml in deviations/ (libraries as masters:
// libmodbus-tcp, pymodbus-rtu, ...) or quirks/ (as servers: jsmodbus, ...)
// of share/mbconform of an installed mbconform, else of this source tree's
// conformance/peers/. Throws std::runtime_error naming the known names
// (and the nearest) when there is no such file.
std::string find(const std::string& name_or_path);
// The names find() knows, sorted.
std::vector<std::string> known_names();

// The one way a quirks file changes a run, for `run` and `client` alike.
// Every failed case a case quirk declares stays a failure, reported apart as
// a declared quirk (CaseResult::quirk = the reason; Quirk::used): it does not
// fail the gate. A case quirk whose cases ran and none failed is a deviation
// gone (the library changed): its line is returned, the command prints it and
// exits 1, and it is in run.notes. A case quirk that names no case that ran
// (a --filter, a skipped case) is only noted.
std::vector<std::string> apply(Quirks&, DeviceRun& run);

}  // namespace mbc::conf::quirks
