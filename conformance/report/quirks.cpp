#include "report/quirks.h"

#include <fmt/core.h>
#include <fnmatch.h>

#include <algorithm>
#include <filesystem>
#include <fstream>
#include <sstream>
#include <stdexcept>

#include "spec_path.h"
#include "yaml_json.h"

namespace mbc::conf::quirks {
namespace {

bool matches(const Quirk& q, const std::string& what) {
  return q.pattern == what || fnmatch(q.pattern.c_str(), what.c_str(), 0) == 0;
}

const Quirk* first_match(const std::vector<Quirk>& list, Quirk::By by, const std::string& what) {
  for (const auto& q : list)
    if (q.by == by && matches(q, what)) return &q;
  return nullptr;
}

namespace fs = std::filesystem;

// Where the declared deviations are: beside the installed specs
// (share/mbconform/{deviations,quirks}, cmake/Install.cmake), or in the
// source tree the built-in specs come from (spec/ -> conformance/peers/).
std::vector<fs::path> quirks_dirs() {
  auto [dir, origin] = spec::builtin_spec_dir();
  fs::path base = origin == "installed" ? fs::path(dir) : fs::path(dir).parent_path() / "conformance" / "peers";
  return {base / "deviations", base / "quirks"};
}

}  // namespace

std::vector<std::string> known_names() {
  std::vector<std::string> out;
  std::error_code ec;
  for (const auto& d : quirks_dirs())
    for (const auto& e : fs::directory_iterator(d, ec))
      if (e.path().extension() == ".yaml") out.push_back(e.path().stem().string());
  std::sort(out.begin(), out.end());
  return out;
}

std::string find(const std::string& name_or_path) {
  std::error_code ec;
  const std::string& n = name_or_path;
  bool path_like = n.find('/') != std::string::npos || (n.size() > 5 && n.compare(n.size() - 5, 5, ".yaml") == 0);
  if (path_like || fs::exists(n, ec)) return n;
  std::vector<std::string> found;
  for (const auto& d : quirks_dirs())
    if (fs::is_regular_file(d / (n + ".yaml"), ec)) found.push_back((d / (n + ".yaml")).string());
  if (found.size() == 1) return found.front();
  if (found.size() > 1) throw std::runtime_error(fmt::format("--quirks {}: two files have that name: {} and {}", n, found[0], found[1]));
  std::string names;
  for (const auto& k : known_names()) names += (names.empty() ? "" : ", ") + k;
  throw std::runtime_error(fmt::format("--quirks {}: no such file, and no declared deviations of that name{}", n,
                                       names.empty() ? " (none are installed)" : " (known: " + names + ")"));
}

const Quirk* Quirks::for_case(const std::string& id) const { return first_match(list, Quirk::By::case_id, id); }
const Quirk* Quirks::for_kind(const std::string& kind) const { return first_match(list, Quirk::By::kind, kind); }

Quirks load(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  if (!in) throw std::runtime_error(fmt::format("{}:0:0: error: quirks: cannot read the file", path));
  std::stringstream ss;
  ss << in.rdbuf();
  spec::Diagnostics diags;
  auto doc = spec::yaml_to_json(ss.str(), path, diags);
  if (!doc) throw std::runtime_error(diags.empty() ? path + ":0:0: error: yaml: unreadable" : diags.front().str());
  auto fail = [&](const std::string& pointer, const std::string& what) {
    spec::SourceLoc at = doc->where(pointer);
    return std::runtime_error(fmt::format("{}:{}:{}: error: quirks: {}", path, at.line, at.col, what));
  };
  Quirks out;
  out.path = path;
  const auto& list = doc->root;
  if (list.is_null()) return out;
  if (!list.is_array()) throw fail("", "expected a list of {case: ID | kind: KIND, reason: TEXT}");
  for (size_t i = 0; i < list.size(); ++i) {
    std::string at = fmt::format("/{}", i);
    const auto& e = list[i];
    if (!e.is_object()) throw fail(at, "expected {case: ID | kind: KIND, reason: TEXT}");
    for (const auto& [k, v] : e.items()) {
      if (k != "case" && k != "kind" && k != "reason") throw fail(at + "/" + k, fmt::format("unknown key '{}' (case, kind, reason)", k));
      if (!v.is_string() || v.get<std::string>().empty()) throw fail(at + "/" + k, fmt::format("'{}' must be a non-empty string", k));
    }
    if (e.contains("case") == e.contains("kind")) throw fail(at, "give exactly one of 'case' (a case id or glob) and 'kind'");
    if (!e.contains("reason")) throw fail(at, "every quirk needs a 'reason': why the deviation is known");
    Quirk q;
    q.by = e.contains("case") ? Quirk::By::case_id : Quirk::By::kind;
    q.pattern = e[q.by == Quirk::By::case_id ? "case" : "kind"].get<std::string>();
    q.reason = e["reason"].get<std::string>();
    q.line = doc->where(at).line;
    out.list.push_back(std::move(q));
  }
  return out;
}

std::vector<std::string> apply(Quirks& q, DeviceRun& run) {
  for (auto& r : run.cases) {
    if (r.outcome != Outcome::fail) continue;
    if (const Quirk* k = q.for_case(r.id)) {
      r.quirk = k->reason;
      q.list[size_t(k - q.list.data())].used = true;
    }
  }
  std::vector<std::string> gone;
  for (const Quirk& k : q.list) {
    if (k.by != Quirk::By::case_id || k.used) continue;
    // Did a case it names run and come out without the deviation?
    const CaseResult* ran = nullptr;
    for (const auto& r : run.cases)
      if ((r.outcome == Outcome::pass || r.outcome == Outcome::observed) && matches(k, r.id)) {
        ran = &r;
        break;
      }
    if (ran) {
      gone.push_back(fmt::format("declared quirk {}:{} '{}' is gone: {} ran and did not fail (the library changed; update {})",
                                 q.path, k.line, k.pattern, ran->id, q.path));
      run.notes.push_back(gone.back());
    } else {
      run.notes.push_back(fmt::format("declared quirk {}:{} '{}' did not occur (no case it names ran)", q.path, k.line, k.pattern));
    }
  }
  return gone;
}

}  // namespace mbc::conf::quirks
