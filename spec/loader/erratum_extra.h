// What the language says of an erratum beyond spec.h's Erratum (issue 37):
// its class (contradiction, typo, nit), what a `contests: []` erratum is
// `about`, the standard's clause that decides it (`decided_by`), and the
// `area` of addresses whose registers cite it. The loader records them for
// each spec it loads (by the spec's path, so copies of a Spec and the
// variants of readings.h find them too).
//
// Also the one test of whether a fact moves a case relying on it to
// OBSERVED: inferred, observed, or printed two ways in words only (readings
// no single expectation can hold both of: readable or not, accepted or
// refused). The loader marks the latter by giving the `either` basis a
// `why` (spec/README.md, "Readings in words").
#pragma once

#include <cstdint>
#include <map>
#include <optional>
#include <string>
#include <utility>
#include <vector>

#include "spec.h"

namespace mbc::spec {

struct ErratumExtra {
  // contradiction (the default: two printed things that cannot both hold),
  // typo (a misprint whose intended text is beyond doubt), nit (an omission
  // or loose wording). Reports count each class apart.
  std::string cls = "contradiction";
  // With `contests: []`: the parts of its citers it concerns, none a fact a
  // case relies on (unit, scale, name, note, printed, labels, does, crc).
  std::vector<std::string> about;
  // The standard's clause that decides between a printed text and the
  // frames that settle it.
  std::string decided_by;
  std::optional<std::pair<uint16_t, uint16_t>> area;
};

// The extras of erratum `id` of `s` (defaults when none were recorded).
ErratumExtra erratum_extra(const Spec& s, const std::string& id);
// The loader records a spec's extras under its path.
void record_erratum_extras(const std::string& path, std::map<std::string, ErratumExtra> extras);

// Printed two ways in words: no expectation holds both readings.
inline bool words_only(const FactBasis& b) { return b.basis == Basis::either && !b.why.empty(); }
// A fact that makes a case relying on it OBSERVED.
inline bool demotes(const FactBasis& b) { return b.is_inferred() || words_only(b); }

}  // namespace mbc::spec
