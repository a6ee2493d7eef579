#include "report/result.h"

#include "report/report.h"

#include <fmt/core.h>

#include <algorithm>
#include <regex>

namespace mbc::conf {

const char* to_string(Level l) {
  switch (l) {
    case Level::must: return "MUST";
    case Level::should: return "SHOULD";
    case Level::observed: return "OBSERVED";
  }
  return "?";
}

const char* to_string(Outcome o) {
  switch (o) {
    case Outcome::pass: return "pass";
    case Outcome::fail: return "fail";
    case Outcome::skip: return "skip";
    case Outcome::observed: return "observed";
    case Outcome::error: return "error";
  }
  return "?";
}

const char* to_string(MismatchKind k) {
  switch (k) {
    case MismatchKind::answered: return "answered";
    case MismatchKind::malformed_framing: return "malformed-framing";
    case MismatchKind::silent: return "silent";
    case MismatchKind::malformed_reply: return "malformed-reply";
    case MismatchKind::unknown_exception: return "unknown-exception";
    case MismatchKind::refused: return "refused";
    case MismatchKind::different: return "different";
  }
  return "?";
}

std::string Cause::text() const { return fmt::format("{} where {} is due", did, due); }
std::string Cause::key() const { return fmt::format("{}|{}|{}", to_string(kind), due, did); }

bool fails_run(const CaseResult& r, const RunReport& rep) {
  if (r.outcome != Outcome::fail || !r.quirk.empty()) return false;
  return r.level == Level::must || (r.level == Level::should && rep.fail_on_should);
}

std::string opt_in_named(const std::string& why) {
  static const std::regex flag("--[a-z][a-z-]*[a-z]");
  std::smatch m;
  return std::regex_search(why, m, flag) ? m.str() : "";
}

const char* Verdict::word() const {
  switch (kind) {
    case Kind::pass: return "PASS";
    case Kind::partial: return "PARTIAL";
    case Kind::fail: return "FAIL";
    case Kind::incomplete: return "INCOMPLETE";
  }
  return "?";
}

std::string Verdict::line() const {
  size_t not_run = 0;
  std::string flags;
  for (const auto& [flag, n] : missing) {
    not_run += n;
    flags += fmt::format("{}{} would enable {}", flags.empty() ? "" : ", ", flag, n);
  }
  std::string partial = not_run ? fmt::format("{} MUST case{} did not run for want of an opt-in: {}", not_run,
                                              not_run == 1 ? "" : "s", flags)
                                : "";
  std::string should = should_failed ? fmt::format("; {} SHOULD case{} failed (not failing the run without --fail-on should)",
                                                   should_failed, should_failed == 1 ? "" : "s")
                                     : "";
  switch (kind) {
    case Kind::incomplete: return incomplete;
    case Kind::fail:
      return fmt::format("FAIL: {} case{} that must pass failed{}{}", failed, failed == 1 ? "" : "s",
                         partial.empty() ? "" : "; and " + partial, should);
    case Kind::partial: return fmt::format("PARTIAL: every MUST case that ran passed, but {}{}", partial, should);
    case Kind::pass: return "PASS: every MUST case passed" + should;
  }
  return "";
}

Verdict verdict(const RunReport& rep) {
  Verdict v;
  std::vector<std::pair<std::string, size_t>>& m = v.missing;
  v.incomplete = incomplete_line(rep);
  for (const auto& d : rep.devices) {
    for (const auto& r : d.cases) {
      if (fails_run(r, rep)) ++v.failed;
      else if (r.outcome == Outcome::fail && r.level == Level::should && r.quirk.empty()) ++v.should_failed;
      if (r.outcome == Outcome::skip && r.level == Level::must && !r.opt_in.empty()) {
        auto it = std::find_if(m.begin(), m.end(), [&](const auto& e) { return e.first == r.opt_in; });
        if (it == m.end()) m.emplace_back(r.opt_in, 1);
        else ++it->second;
      }
    }
  }
  std::stable_sort(m.begin(), m.end(), [](const auto& a, const auto& b) { return a.second > b.second; });
  if (!v.incomplete.empty()) {
    v.kind = Verdict::Kind::incomplete;
  } else if (v.failed) {
    v.kind = Verdict::Kind::fail;
  } else if (!m.empty()) {
    v.kind = Verdict::Kind::partial;
  }
  return v;
}

}  // namespace mbc::conf
