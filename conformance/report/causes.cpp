// Failures grouped by cause (report.h's failure_causes): what the device did
// against what was due (the judge's Cause, result.h), with the function codes
// and registers each cause covers and one command that re-runs all of its
// cases. The HTML summary and report.json both show these groups.
#include <fmt/core.h>

#include <algorithm>
#include <regex>

#include "report/report.h"

namespace mbc::conf {
namespace {

// A failure with no judged step (a target error, a lost connection): its
// clause and message with the numbers taken out.
std::string fallback_key(const CaseResult& r) {
  // 0x0044, 80000, -1.5, hex bytes "01 03 00 44", register words "[07D1 0000]".
  static const std::regex numbers("0x[0-9A-Fa-f]+|\\b[0-9A-Fa-f]{2}( [0-9A-Fa-f]{2})+\\b|\\b[0-9A-F]{4}\\b|-?\\b[0-9]+(\\.[0-9]+)?\\b");
  std::string m = r.message;
  if (auto more = m.find(" (+"); more != std::string::npos) m.resize(more);
  return r.clause + ": " + std::regex_replace(m, numbers, "#");
}

}  // namespace

std::string shell_quote(const std::string& s) {
  if (!s.empty() && s.find_first_of(" '\"?&*$;|<>()\\^[]{}!`#~") == std::string::npos) return s;
  std::string q = "'";
  for (char c : s) q += c == '\'' ? std::string("'\\''") : std::string(1, c);
  return q + "'";
}

std::string replay_command(const DeviceRun& d, const std::vector<const CaseResult*>& cases) {
  std::string cmd = "mbconform run --target " + shell_quote(d.target_uri);
  if (d.target_uri.rfind("ref:", 0) != 0) cmd += " --device " + shell_quote(d.device_id);
  if (cases.size() == 1) return cmd + " --filter " + shell_quote(cases.front()->id);
  std::string re;
  for (const auto* r : cases) {
    std::string id;
    for (char c : r->id) id += std::string("\\^$.|?*+()[]{}").find(c) != std::string::npos ? std::string("\\") + c : std::string(1, c);
    re += (re.empty() ? "" : "|") + id;
  }
  return cmd + " --filter " + shell_quote("re:^(" + re + ")$");
}

std::vector<CauseGroup> failure_causes(const RunReport& rep, const DeviceRun& d) {
  std::vector<CauseGroup> out;
  std::vector<std::string> keys;
  for (const auto& r : d.cases) {
    if (!fails_run(r, rep)) continue;
    std::string key = r.cause ? r.cause->key() : fallback_key(r);
    size_t at = size_t(std::find(keys.begin(), keys.end(), key) - keys.begin());
    if (at == keys.size()) {
      keys.push_back(key);
      CauseGroup g;
      g.text = r.cause ? r.cause->text() : r.clause + " — " + r.title;
      if (r.cause) g.kind = r.cause->kind;
      out.push_back(std::move(g));
    }
    CauseGroup& g = out[at];
    g.cases.push_back(&r);
    if (r.register_address) g.registers.insert(*r.register_address);
    if (r.cause && r.cause->fc) g.function_codes.insert(*r.cause->fc);
  }
  for (auto& g : out) g.replay = replay_command(d, g.cases);
  std::stable_sort(out.begin(), out.end(), [](const CauseGroup& a, const CauseGroup& b) { return a.cases.size() > b.cases.size(); });
  return out;
}

}  // namespace mbc::conf
