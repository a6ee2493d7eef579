#include "report/result.h"

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

bool fails_run(const CaseResult& r, const RunReport& rep) {
  if (r.outcome != Outcome::fail || !r.quirk.empty()) return false;
  return r.level == Level::must || (r.level == Level::should && rep.fail_on_should);
}

}  // namespace mbc::conf
