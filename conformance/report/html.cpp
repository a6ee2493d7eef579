// report.html: one self-contained page (no scripts, no external files). It
// opens with the qualification summary (html_summary.cpp: verdict, identity,
// counts, failures by cause, errata, skipped families); below it, per
// device: every failing case with its frames in hex, the bytes that differ
// marked, and decoded beside the manual section; the register table with
// names, coloured by the worst result of the register's cases; OBSERVED
// deviations; a latency histogram drawn with CSS bars. Printed, the summary
// takes at most two A4 pages and the details start on a page of their own.
#include <fmt/core.h>
#include <fmt/format.h>

#include <algorithm>
#include <cmath>
#include <map>

#include "report/html_util.h"
#include "report/report.h"

namespace mbc::conf {
namespace {

using html::esc;

int severity(Outcome o) {
  switch (o) {
    case Outcome::fail: return 3;
    case Outcome::observed: return 2;
    case Outcome::pass: return 1;
    case Outcome::skip: return 0;
    case Outcome::error: return 0;
  }
  return 0;
}

std::string histogram(const std::vector<double>& lat) {
  if (lat.empty()) return "<p>No answered exchanges.</p>";
  // Log-spaced buckets from 1 µs: latencies span in-process (µs) to serial lines (ms).
  std::map<int, size_t> buckets;
  for (double us : lat) buckets[std::max(0, int(std::floor(std::log2(std::max(us, 1.0)))))]++;
  size_t top = 0;
  for (auto& [b, n] : buckets) top = std::max(top, n);
  std::string h = "<table class=hist>";
  for (auto& [b, n] : buckets) {
    auto label = [](double us) { return us >= 1000 ? fmt::format("{:g} ms", us / 1000) : fmt::format("{:g} µs", us); };
    h += fmt::format("<tr><td>{} – {}</td><td><div class=bar style=\"width:{:.1f}%\"></div></td><td>{}</td></tr>",
                     label(std::pow(2.0, b)), label(std::pow(2.0, b + 1)), 100.0 * double(n) / double(top), n);
  }
  return h + "</table>";
}

}  // namespace

std::string html_report(const RunReport& rep) {
  std::string h = R"(<!DOCTYPE html><html lang=en><head><meta charset=utf-8><title>mbconform run</title><style>
body{font:14px/1.4 system-ui,sans-serif;margin:2em;max-width:80em}
table{border-collapse:collapse;margin:.5em 0}td,th{border:1px solid #ccc;padding:2px 6px;text-align:left;vertical-align:top}
.pass{background:#d7f5d7}.fail{background:#f8c8c8}.skip{background:#eee}.observed{background:#fff0c0}
code,pre{font:12px ui-monospace,monospace}pre{white-space:pre-wrap;margin:0}
.bar{background:#4a7;height:1em}.hist td:nth-child(2){width:30em}.regs td{font-size:12px}
.verdict{font-size:20px;padding:.6em 1em;border-radius:4px;margin-bottom:1em}.verdict b{font-size:26px;margin-right:.5em}
.verdict.pass{background:#2e7d32;color:#fff}.verdict.fail{background:#c62828;color:#fff}.verdict.incomplete{background:#ef6c00;color:#fff}.verdict.partial{background:#f9a825;color:#000}
.verdict small{font-size:13px;opacity:.9}.facts th{width:12em;background:#f6f6f6}.counts td,.counts th{text-align:right}
.device-summary{border-top:2px solid #999;margin-top:1em}.device-summary h2 small{font-weight:normal;color:#666}
.causes code{font-size:11px;word-break:break-all}.causes code.replay{display:block;max-height:4.5em;overflow:auto}ul{margin:.3em 0}mark{background:#f44;color:#fff}
.detail{border-top:3px double #999;margin-top:2em}
@page{size:A4;margin:12mm}
@media print{body{margin:0;font-size:10px;max-width:none}.verdict{font-size:14px;-webkit-print-color-adjust:exact;print-color-adjust:exact}
 .verdict b{font-size:18px}.pass,.fail,.observed,.skip,mark{-webkit-print-color-adjust:exact;print-color-adjust:exact}
 h2{font-size:14px;margin:.4em 0}h3{font-size:12px;margin:.4em 0}code,pre{font-size:9px}.causes code{font-size:8px}.causes code.replay{max-height:3.6em;overflow:hidden}
 tr,li{break-inside:avoid}h2,h3{break-after:avoid}.detail{break-before:page}}
</style></head><body>)";
  h += html::summary(rep);
  h += fmt::format("<div class=detail><h1>Details</h1><p>mbconform {} · started {} · version {}{}</p>", esc(rep.command),
                   esc(rep.started_at), esc(rep.version), rep.interrupted ? " · <b>interrupted: partial results</b>" : "");
  h += "<table><tr><th>device</th><th>target</th><th>cases</th><th>pass</th><th>fail</th><th>MUST failed</th>"
       "<th>observed</th><th>skip</th><th>wall</th><th>wire-time bound</th></tr>";
  for (const auto& d : rep.devices) {
    Counts c = count(d);
    h += fmt::format("<tr><td><a href=\"#{0}\">{0}</a></td><td><code>{1}</code></td><td>{2}</td><td class=pass>{3}</td><td class={8}>{4}</td>"
                     "<td class={8}>{5}</td><td class=observed>{6}</td><td class=skip>{7}</td><td>{9:.3f} s</td><td>{10}</td></tr>",
                     esc(d.device_id), esc(d.target_uri), c.total(), c.pass, c.fail, c.must_failed, c.observed, c.skip,
                     c.fail ? "fail" : "pass", d.wall_seconds,
                     d.baud ? fmt::format("{:.3f} s at {} baud", d.wire_time_bound_seconds, *d.baud) : "n/a (no line rate)");
  }
  h += "</table>";

  for (const auto& d : rep.devices) {
    h += fmt::format("<h2 id=\"{0}\">{0}</h2><p>Spec <code>{1}</code> · {2} frames, {3} bytes sent, {4} received</p>",
                     esc(d.device_id), esc(d.spec_path), d.frames_sent, d.bytes_sent, d.bytes_received);
    if (!d.error.empty()) h += "<p class=fail><b>Run stopped:</b> " + esc(d.error) + "</p>";
    for (const auto& n : d.notes) h += "<p>" + esc(n) + "</p>";
    if (!d.restore_failures.empty()) {
      h += "<p class=fail><b>Could not restore:</b></p><ul>";
      for (const auto& f : d.restore_failures) h += "<li>" + esc(f) + "</li>";
      h += "</ul>";
    }
    if (!d.safety_notes.empty()) {
      h += "<p><b>Not kept before the run:</b></p><ul>";
      for (const auto& f : d.safety_notes) h += "<li>" + esc(f) + "</li>";
      h += "</ul>";
    }
    if (!d.broadcast_writes.empty()) {
      h += "<p class=observed><b>Broadcast writes sent (every drive on the line received them):</b></p><ul>";
      for (const auto& f : d.broadcast_writes) h += "<li>" + esc(f) + "</li>";
      h += "</ul>";
    }
    h += "<h3 class=failures>Failing cases</h3>";
    bool any = false;
    for (const auto& r : d.cases) {
      if (r.outcome != Outcome::fail || !r.quirk.empty()) continue;
      any = true;
      h += fmt::format("<div class=fail><p><b>{}</b> [{}] <i>{}</i><br>{}<br>Requirement: {}<br>{}{}</p>", esc(r.id),
                       to_string(r.level), esc(r.clause), esc(r.title), esc(r.requirement), esc(r.message),
                       r.errata.empty() ? "" : "<br>Errata: " + esc(fmt::format("{}", fmt::join(r.errata, ", "))));
      h += "<table><tr><th>step</th><th>request</th><th>expected</th><th>actual</th><th>difference</th></tr>";
      for (const auto& f : r.frames)
        h += fmt::format("<tr><td>{}</td><td><code>{}</code><pre>{}</pre></td><td>{}<pre>{}</pre></td><td><code>{}</code><pre>{}</pre></td><td>{}</td></tr>",
                         esc(f.step), to_hex(f.request), esc(f.request_decoded), esc(f.expected_text),
                         f.expected ? to_hex(*f.expected) + "\n" + esc(f.expected_decoded) : "", f.actual ? to_hex(*f.actual) : "silence",
                         esc(f.actual_decoded), f.expected ? html::byte_diff(*f.expected, f.actual) : "");
      h += "</table></div>";
    }
    if (!any) h += "<p>None.</p>";

    // Registers: the worst outcome of each register's cases.
    std::map<uint16_t, std::vector<const CaseResult*>> by_reg;
    for (const auto& r : d.cases)
      if (r.register_address) by_reg[*r.register_address].push_back(&r);
    h += "<h3>Registers</h3><table class=regs><tr><th>address</th><th>name</th><th>cases</th></tr>";
    for (const auto& [addr, rs] : by_reg) {
      int worst = 0;
      for (auto* r : rs) worst = std::max(worst, severity(r->outcome));
      const char* cls = worst == 3 ? "fail" : worst == 2 ? "observed" : worst == 1 ? "pass" : "skip";
      std::string cells;
      for (auto* r : rs) {
        std::string leaf = r->id.substr(r->id.rfind('/') + 1);
        cells += fmt::format("<span class={} title=\"{}\">{}</span> ", to_string(r->outcome), esc(r->title + ": " + r->message), esc(leaf));
      }
      auto name = d.facts.register_names.find(addr);
      h += fmt::format("<tr><td class={}><code>0x{:04X}</code></td><td>{}</td><td>{}</td></tr>", cls, addr,
                       name == d.facts.register_names.end() ? "" : esc(name->second), cells);
    }
    h += "</table>";

    h += "<h3>Observed (behaviour the manual leaves open, deviations from the standard)</h3><table><tr><th>case</th><th>clause</th><th>what came</th></tr>";
    for (const auto& r : d.cases)
      if (r.outcome == Outcome::observed)
        h += fmt::format("<tr><td>{}</td><td>{}</td><td>{}</td></tr>", esc(r.id), esc(r.clause), esc(r.message));
    h += "</table>";
    bool quirks = false;
    for (const auto& r : d.cases)
      if (r.outcome == Outcome::fail && !r.quirk.empty()) {
        if (!quirks) h += "<h3>Declared quirks (--quirks: known deviations, not failures)</h3><table><tr><th>case</th><th>clause</th><th>declared</th><th>what came</th></tr>";
        quirks = true;
        h += fmt::format("<tr><td>{}</td><td>{}</td><td>{}</td><td>{}</td></tr>", esc(r.id), esc(r.clause), esc(r.quirk), esc(r.message));
      }
    if (quirks) h += "</table>";
    h += "<h3>Skipped</h3><table>";
    for (const auto& r : d.cases)
      if (r.outcome == Outcome::skip || r.outcome == Outcome::error)
        h += fmt::format("<tr><td>{}</td><td>{}{}</td></tr>", esc(r.id), r.outcome == Outcome::error ? "not run: " : "", esc(r.message));
    h += "</table><h3>Latency</h3>" + histogram(d.latencies_us);
  }
  h += "</div></body></html>\n";
  return h;
}

}  // namespace mbc::conf
