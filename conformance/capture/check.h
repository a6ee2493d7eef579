// check-capture: a recorded capture judged against a device's spec, without
// sending a frame. Frames come from the reader (frames.h), are paired
// (by transaction id on Modbus TCP, by order and unit on RTU), judged one
// exchange at a time (judge.h) and counted (coverage). The result is a
// DeviceRun, so `run`'s three reports are written from it unchanged, plus
// coverage.json / coverage.html (coverage.cpp).
#pragma once
#include <array>
#include <cstdint>
#include <map>
#include <optional>
#include <string>
#include <vector>

#include "capture/frames.h"
#include "capture/judge.h"
#include "report/result.h"
#include "spec.h"

namespace mbc::conf::capture {

struct Options {
  ReadOptions read;
  JudgeOptions judge;          // --unit, --baud
  size_t max_pending = 32;     // requests waiting for their reply, per conversation
  size_t frames_per_case = 3;  // exchanges a case keeps for the report
  size_t findings_kept = 200;  // reading findings listed (all are counted)
};

// What the capture exercised, whatever the verdicts.
struct Coverage {
  uint64_t requests = 0, replies = 0, exceptions = 0, exchanges = 0, unanswered = 0, unsolicited = 0;
  std::map<int, uint64_t> requests_by_fc;    // every request seen, by function code
  std::map<int, uint64_t> exceptions_by_fc;  // exception replies, by function code (without 0x80)
  std::map<int, uint64_t> requests_by_unit;
  // Reads and writes per register (table, wire address); bounded by the map's size.
  std::map<std::pair<int, uint16_t>, std::array<uint64_t, 2>> registers;  // [0] reads, [1] writes
  // Latency (request to reply, capture timestamps): log-spaced buckets,
  // 10 per decade from 1 us (bucket i holds [10^(i/10), 10^((i+1)/10)) us).
  static constexpr int kBuckets = 90;
  std::array<uint64_t, kBuckets> latency_buckets{};
  uint64_t latency_count = 0;
  double latency_min_us = 0, latency_max_us = 0, latency_sum_us = 0;
  double latency_percentile(double p) const;  // from the buckets (upper edge)
};

struct Result {
  DeviceRun run;
  Coverage coverage;
  ReadStats stats;
  std::vector<Finding> findings;  // the first `findings_kept`
  uint64_t finding_count = 0;
};

// Reads, pairs and judges `path` against `spec`.
Result check_capture(const std::string& path, const spec::Spec& spec, const Options&);
Result check_capture_bytes(std::span<const uint8_t> data, const spec::Spec& spec, const Options&);

// coverage.json and coverage.html (a latency plot in inline SVG) into `dir`.
nlohmann::json coverage_json(const Result&);
std::string coverage_html(const Result&, const std::string& title);
void write_coverage(const Result&, const std::string& dir);

}  // namespace mbc::conf::capture
