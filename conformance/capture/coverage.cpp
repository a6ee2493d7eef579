// coverage.json and coverage.html: what a capture exercised (function codes,
// units, registers, how often) and its latency distribution, drawn as an
// inline SVG (no scripts, no external files).
#include <fmt/core.h>

#include <cmath>
#include <filesystem>
#include <fstream>
#include <stdexcept>

#include "capture/check.h"
#include "modbus/function_codes.h"

namespace mbc::conf::capture {
namespace {

std::string esc(const std::string& s) {
  std::string out;
  for (char c : s) {
    switch (c) {
      case '&': out += "&amp;"; break;
      case '<': out += "&lt;"; break;
      case '>': out += "&gt;"; break;
      case '"': out += "&quot;"; break;
      default: out += c;
    }
  }
  return out;
}

const char* table_name(int t) {
  switch (spec::Table(t)) {
    case spec::Table::holding: return "holding";
    case spec::Table::input: return "input";
    case spec::Table::coil: return "coils";
    case spec::Table::discrete_input: return "discrete";
  }
  return "?";
}

std::string us_label(double us) {
  if (us >= 1e6) return fmt::format("{:.3g} s", us / 1e6);
  if (us >= 1e3) return fmt::format("{:.3g} ms", us / 1e3);
  return fmt::format("{:.3g} us", us);
}

// Bars per log-spaced bucket, between the first and last bucket used.
std::string latency_svg(const Coverage& c) {
  if (!c.latency_count) return "<p>No paired exchange, no latency.</p>";
  int lo = Coverage::kBuckets, hi = -1;
  uint64_t top = 0;
  for (int i = 0; i < Coverage::kBuckets; ++i)
    if (c.latency_buckets[size_t(i)]) lo = std::min(lo, i), hi = std::max(hi, i), top = std::max(top, c.latency_buckets[size_t(i)]);
  const int w = 720, h = 220, left = 50, bottom = 40, top_pad = 10;
  int n = hi - lo + 1;
  double bw = double(w - left - 10) / n;
  std::string s = fmt::format(
      "<svg xmlns=\"http://www.w3.org/2000/svg\" width=\"{}\" height=\"{}\" role=\"img\" "
      "aria-label=\"latency distribution\"><rect width=\"100%\" height=\"100%\" fill=\"#fff\"/>",
      w, h);
  double plot_h = h - bottom - top_pad;
  for (int i = lo; i <= hi; ++i) {
    uint64_t v = c.latency_buckets[size_t(i)];
    double bh = plot_h * double(v) / double(top);
    double x = left + (i - lo) * bw;
    s += fmt::format("<rect x=\"{:.1f}\" y=\"{:.1f}\" width=\"{:.1f}\" height=\"{:.1f}\" fill=\"#4a7ebb\"><title>{} - {}: {}</title></rect>",
                     x + 1, top_pad + plot_h - bh, std::max(bw - 2, 1.0), bh, us_label(std::pow(10.0, i / 10.0)),
                     us_label(std::pow(10.0, (i + 1) / 10.0)), v);
    if ((i - lo) % std::max(1, n / 6) == 0)
      s += fmt::format("<text x=\"{:.1f}\" y=\"{}\" font-size=\"11\">{}</text>", x, h - bottom + 15, us_label(std::pow(10.0, i / 10.0)));
  }
  s += fmt::format("<line x1=\"{}\" y1=\"{}\" x2=\"{}\" y2=\"{}\" stroke=\"#333\"/>", left, top_pad + plot_h, w - 10, top_pad + plot_h);
  s += fmt::format("<text x=\"2\" y=\"{}\" font-size=\"11\">{}</text>", top_pad + 10, top);
  s += fmt::format("<text x=\"{}\" y=\"{}\" font-size=\"11\">request to reply (log scale); bar height: exchanges</text>", left,
                   h - 5);
  return s + "</svg>";
}

}  // namespace

nlohmann::json coverage_json(const Result& r) {
  const Coverage& c = r.coverage;
  nlohmann::json j;
  j["format"] = r.stats.format;
  j["packets"] = r.stats.packets;
  j["frames"] = r.stats.frames;
  j["conversations"] = r.stats.streams;
  j["requests"] = c.requests;
  j["replies"] = c.replies;
  j["exceptions"] = c.exceptions;
  j["exchanges"] = c.exchanges;
  j["unanswered"] = c.unanswered;
  j["unsolicited"] = c.unsolicited;
  auto by = [](const std::map<int, uint64_t>& m) {
    nlohmann::json o = nlohmann::json::object();
    for (const auto& [k, v] : m) o[std::to_string(k)] = v;
    return o;
  };
  j["requests_by_function"] = by(c.requests_by_fc);
  j["exceptions_by_function"] = by(c.exceptions_by_fc);
  j["requests_by_unit"] = by(c.requests_by_unit);
  nlohmann::json regs = nlohmann::json::array();
  for (const auto& [k, v] : c.registers)
    regs.push_back({{"table", table_name(k.first)}, {"address", k.second}, {"reads", v[0]}, {"writes", v[1]}});
  j["registers"] = regs;
  nlohmann::json lat;
  lat["count"] = c.latency_count;
  if (c.latency_count) {
    lat["min_us"] = c.latency_min_us;
    lat["max_us"] = c.latency_max_us;
    lat["mean_us"] = c.latency_sum_us / double(c.latency_count);
    lat["p50_us"] = c.latency_percentile(0.5);
    lat["p90_us"] = c.latency_percentile(0.9);
    lat["p99_us"] = c.latency_percentile(0.99);
  }
  nlohmann::json buckets = nlohmann::json::array();
  for (int i = 0; i < Coverage::kBuckets; ++i)
    if (c.latency_buckets[size_t(i)])
      buckets.push_back({{"from_us", std::pow(10.0, i / 10.0)}, {"to_us", std::pow(10.0, (i + 1) / 10.0)},
                         {"count", c.latency_buckets[size_t(i)]}});
  lat["buckets"] = buckets;
  j["latency"] = lat;
  j["findings_total"] = r.finding_count;
  nlohmann::json fs = nlohmann::json::array();
  for (const auto& f : r.findings) fs.push_back({{"packet", f.packet}, {"what", f.what}});
  j["findings"] = fs;
  if (!r.stats.error.empty()) j["error"] = r.stats.error;
  return j;
}

std::string coverage_html(const Result& r, const std::string& title) {
  const Coverage& c = r.coverage;
  std::string h = "<!doctype html><html><head><meta charset=utf-8><title>" + esc(title) +
                  "</title><style>body{font-family:sans-serif;max-width:60em;margin:1em auto}"
                  "table{border-collapse:collapse}td,th{border:1px solid #ccc;padding:2px 6px;text-align:right}"
                  "th{background:#eee}.err{color:#a00}</style></head><body>";
  h += "<h1>" + esc(title) + "</h1>";
  if (!r.stats.error.empty()) h += "<p class=err>INCOMPLETE: " + esc(r.stats.error) + "</p>";
  h += fmt::format("<p>{} packets, {} Modbus frames, {} conversation(s): {} requests, {} replies ({} exceptions), "
                   "{} paired, {} without a reply, {} replies without a request.</p>",
                   r.stats.packets, r.stats.frames, r.stats.streams, c.requests, c.replies, c.exceptions, c.exchanges,
                   c.unanswered, c.unsolicited);
  h += "<h2>Latency</h2>";
  if (c.latency_count)
    h += fmt::format("<p>{} exchanges: min {}, median {}, p90 {}, p99 {}, max {}.</p>", c.latency_count,
                     us_label(c.latency_min_us), us_label(c.latency_percentile(0.5)), us_label(c.latency_percentile(0.9)),
                     us_label(c.latency_percentile(0.99)), us_label(c.latency_max_us));
  h += latency_svg(c);
  h += "<h2>Function codes</h2><table><tr><th>FC</th><th>name</th><th>requests</th><th>exception replies</th></tr>";
  std::map<int, std::pair<uint64_t, uint64_t>> fcs;
  for (const auto& [k, v] : c.requests_by_fc) fcs[k].first = v;
  for (const auto& [k, v] : c.exceptions_by_fc) fcs[k].second = v;
  for (const auto& [k, v] : fcs)
    h += fmt::format("<tr><td>{:02X}</td><td style=text-align:left>{}</td><td>{}</td><td>{}</td></tr>", k,
                     esc(function_name(uint8_t(k))), v.first, v.second);
  h += "</table><h2>Units</h2><table><tr><th>unit</th><th>requests</th></tr>";
  for (const auto& [k, v] : c.requests_by_unit) h += fmt::format("<tr><td>{}</td><td>{}</td></tr>", k, v);
  h += "</table><h2>Registers the spec maps</h2>";
  if (c.registers.empty()) h += "<p>None addressed.</p>";
  else {
    h += "<table><tr><th>table</th><th>address</th><th>reads</th><th>writes</th></tr>";
    for (const auto& [k, v] : c.registers)
      h += fmt::format("<tr><td>{}</td><td>0x{:04X}</td><td>{}</td><td>{}</td></tr>", table_name(k.first), k.second, v[0], v[1]);
    h += "</table>";
  }
  if (r.finding_count) {
    h += fmt::format("<h2>Reading findings ({})</h2><ul>", r.finding_count);
    for (const auto& f : r.findings) h += fmt::format("<li>packet {}: {}</li>", f.packet, esc(f.what));
    h += "</ul>";
  }
  return h + "</body></html>\n";
}

void write_coverage(const Result& r, const std::string& dir) {
  std::filesystem::create_directories(dir);
  std::ofstream j(dir + "/coverage.json");
  j << coverage_json(r).dump(1) << "\n";
  std::ofstream h(dir + "/coverage.html");
  h << coverage_html(r, "Coverage: " + r.run.target_uri);
  if (!j || !h) throw std::runtime_error("cannot write coverage.json / coverage.html into " + dir);
}

}  // namespace mbc::conf::capture
