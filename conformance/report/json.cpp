// report.json (everything) and the files on disk.
#include <fmt/core.h>

#include <fcntl.h>
#include <unistd.h>

#include <cerrno>
#include <cstring>
#include <filesystem>
#include <stdexcept>

#include "report/report.h"

namespace mbc::conf {
namespace {

nlohmann::json frame_json(const FrameRecord& f) {
  nlohmann::json j;
  j["step"] = f.step;
  j["request"] = to_hex(f.request);
  j["request_decoded"] = f.request_decoded;
  j["expected"] = f.expected ? nlohmann::json(to_hex(*f.expected)) : nlohmann::json(nullptr);
  j["expected_text"] = f.expected_text;
  j["expected_decoded"] = f.expected_decoded;
  j["actual"] = f.actual ? nlohmann::json(to_hex(*f.actual)) : nlohmann::json(nullptr);
  j["actual_decoded"] = f.actual_decoded;
  j["latency_us"] = f.latency_us;
  return j;
}

// Whole or not at all: written to NAME.part and renamed over NAME once every
// byte went out (a full disk must not leave a torn report that reads as a
// whole one; an ofstream also dropped the error of its last flush).
void write_file(const std::filesystem::path& p, const std::string& text) {
  const std::string part = p.string() + ".part";
  int fd = ::open(part.c_str(), O_WRONLY | O_CREAT | O_TRUNC | O_CLOEXEC, 0644);
  int err = fd < 0 ? errno : 0;
  for (size_t at = 0; !err && at < text.size();) {
    ssize_t n = ::write(fd, text.data() + at, text.size() - at);
    if (n < 0 && errno == EINTR) continue;
    if (n <= 0) err = n < 0 ? errno : ENOSPC;
    else at += size_t(n);
  }
  if (fd >= 0 && ::close(fd) != 0 && !err) err = errno;
  if (!err && ::rename(part.c_str(), p.c_str()) != 0) err = errno;
  if (err) {
    ::unlink(part.c_str());
    throw std::runtime_error(fmt::format("cannot write {}: {}", p.string(), std::strerror(err)));
  }
}

}  // namespace

Counts count(const DeviceRun& d) {
  Counts c;
  for (const auto& r : d.cases) {
    switch (r.outcome) {
      case Outcome::pass: ++c.pass; break;
      case Outcome::fail:
        if (!r.quirk.empty()) {
          ++c.quirks;
          break;
        }
        ++c.fail;
        if (r.level == Level::must) ++c.must_failed;
        break;
      case Outcome::skip: ++c.skip; break;
      case Outcome::observed: ++c.observed; break;
      case Outcome::error: ++c.error; break;
    }
  }
  return c;
}

std::string incomplete_line(const RunReport& rep) {
  std::string why;
  for (const auto& d : rep.devices) {
    size_t not_run = count(d).error;
    if (!d.error.empty())
      why += fmt::format("{}{}: {}{}", why.empty() ? "" : "; ", d.device_id, d.error,
                         not_run ? fmt::format(" ({} cases not run)", not_run) : "");
  }
  if (rep.interrupted) why += std::string(why.empty() ? "" : "; ") + "interrupted";
  return why.empty() ? "" : "INCOMPLETE: " + why;
}

nlohmann::json report_json(const RunReport& rep) {
  nlohmann::json j;
  j["command"] = rep.command;
  j["started_at"] = rep.started_at;
  j["version"] = rep.version;
  j["interrupted"] = rep.interrupted;
  j["incomplete"] = incomplete_line(rep);
  Verdict v = verdict(rep);
  j["verdict"] = v.word();
  j["verdict_line"] = v.line();
  j["missing_opt_ins"] = nlohmann::json::array();  // [{"flag": "--allow-writes", "must_cases": 41}]
  for (const auto& [flag, n] : v.missing) j["missing_opt_ins"].push_back({{"flag", flag}, {"must_cases", n}});
  j["devices"] = nlohmann::json::array();
  for (const auto& d : rep.devices) {
    nlohmann::json dj;
    dj["device_id"] = d.device_id;
    dj["target_uri"] = d.target_uri;
    dj["spec_path"] = d.spec_path;
    Counts c = count(d);
    dj["counts"] = {{"pass", c.pass}, {"fail", c.fail}, {"skip", c.skip}, {"observed", c.observed},
                    {"error", c.error}, {"quirks", c.quirks}, {"must_failed", c.must_failed}, {"total", c.total()}};
    dj["frames_sent"] = d.frames_sent;
    dj["silences"] = d.silences;
    dj["bytes_sent"] = d.bytes_sent;
    dj["bytes_received"] = d.bytes_received;
    dj["wall_seconds"] = d.wall_seconds;
    dj["baud"] = d.baud ? nlohmann::json(*d.baud) : nlohmann::json(nullptr);
    dj["wire_time_bound_seconds"] = d.wire_time_bound_seconds;
    dj["latencies_us"] = d.latencies_us;
    dj["restore_failures"] = d.restore_failures;
    dj["safety_notes"] = d.safety_notes;
    dj["broadcast_writes"] = d.broadcast_writes;
    dj["notes"] = d.notes;
    dj["interrupted"] = d.interrupted;
    dj["error"] = d.error;
    // The failures by cause: what the device did against what was due.
    dj["causes"] = nlohmann::json::array();
    for (const auto& g : failure_causes(rep, d)) {
      nlohmann::json gj{{"cause", g.text}, {"kind", g.kind ? nlohmann::json(to_string(*g.kind)) : nlohmann::json(nullptr)},
                        {"function_codes", g.function_codes}, {"registers", g.registers}, {"replay", g.replay}};
      gj["cases"] = nlohmann::json::array();
      for (const auto* r : g.cases) gj["cases"].push_back(r->id);
      dj["causes"].push_back(std::move(gj));
    }
    dj["cases"] = nlohmann::json::array();
    for (const auto& r : d.cases) {
      nlohmann::json cj;
      cj["id"] = r.id;
      cj["family"] = r.family;
      cj["clause"] = r.clause;
      cj["level"] = to_string(r.level);
      cj["title"] = r.title;
      cj["requirement"] = r.requirement;
      cj["outcome"] = to_string(r.outcome);
      cj["message"] = r.message;
      if (!r.quirk.empty()) cj["quirk"] = r.quirk;
      if (!r.opt_in.empty()) cj["opt_in"] = r.opt_in;
      if (r.cause)
        cj["cause"] = {{"kind", to_string(r.cause->kind)}, {"due", r.cause->due}, {"did", r.cause->did},
                       {"function_code", r.cause->fc ? nlohmann::json(*r.cause->fc) : nlohmann::json(nullptr)},
                       {"text", r.cause->text()}};
      cj["register"] = r.register_address ? nlohmann::json(*r.register_address) : nlohmann::json(nullptr);
      cj["errata"] = r.errata;
      cj["duration_ms"] = r.duration_ms;
      cj["frames"] = nlohmann::json::array();
      for (const auto& f : r.frames) cj["frames"].push_back(frame_json(f));
      if (!r.extra.empty()) cj["extra"] = r.extra;
      dj["cases"].push_back(std::move(cj));
    }
    j["devices"].push_back(std::move(dj));
  }
  return j;
}

void write_reports(const RunReport& rep, const std::string& dir, bool junit_only) {
  std::filesystem::path d(dir);
  std::error_code ec;
  std::filesystem::create_directories(d, ec);
  if (ec) throw std::runtime_error(fmt::format("cannot create {}: {}", dir, ec.message()));
  // All or none: when one cannot be written, the ones this call wrote go too.
  std::vector<std::filesystem::path> written;
  auto put = [&](const char* name, const std::string& text) {
    write_file(d / name, text);
    written.push_back(d / name);
  };
  try {
    put("junit.xml", junit_xml(rep));
    if (junit_only) return;
    put("report.json", report_json(rep).dump(1) + "\n");
    put("report.html", html_report(rep));
  } catch (...) {
    for (const auto& p : written) std::filesystem::remove(p, ec);
    throw;
  }
}

}  // namespace mbc::conf
