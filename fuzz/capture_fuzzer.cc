// The capture reader, pairing and judge (conformance/capture/): any bytes are
// a pcap, a pcapng or a serial log, judged against modbus-standard. Beyond
// "no crash, no hang, no unbounded memory", the counts must add up: every
// request is either paired or unanswered, every reply either paired or
// unsolicited, the per-function-code counts sum to the totals, and a case is
// "not seen" exactly when no exchange reached it.
#include <cstddef>
#include <cstdint>
#include <string>

#include "capture/check.h"
#include "fuzz_support.h"

namespace {
using namespace mbc;
constexpr const char* kHarness = "capture_fuzzer";
}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  static const spec::Spec& standard = fuzz::spec_by_id("modbus-standard");
  conf::capture::Options o;
  o.read.ports.push_back(1502);  // the seeds' serve traces and RTU over TCP
  auto r = conf::capture::check_capture_bytes(std::span(data, size), standard, o);
  const auto& c = r.coverage;
  auto ctx = [&](const std::string& what) {
    return what + ": " + std::to_string(c.requests) + " requests, " + std::to_string(c.replies) + " replies, " +
           std::to_string(c.exchanges) + " paired, " + std::to_string(c.unanswered) + " unanswered, " +
           std::to_string(c.unsolicited) + " unsolicited; " + r.stats.format + " " + r.stats.error;
  };
  MBC_FUZZ_CHECK(c.requests == c.exchanges + c.unanswered, kHarness, ctx("a request neither paired nor unanswered"));
  MBC_FUZZ_CHECK(c.replies == c.exchanges + c.unsolicited, kHarness, ctx("a reply neither paired nor unsolicited"));
  uint64_t by_fc = 0, exc = 0;
  for (const auto& [fc, n] : c.requests_by_fc) by_fc += n;
  for (const auto& [fc, n] : c.exceptions_by_fc) exc += n;
  MBC_FUZZ_CHECK(by_fc == c.requests, kHarness, ctx("requests per function code do not sum to the requests"));
  MBC_FUZZ_CHECK(exc == c.exceptions && c.exceptions <= c.replies, kHarness, ctx("exception counts disagree"));
  MBC_FUZZ_CHECK(c.requests + c.replies == r.stats.frames, kHarness, ctx("frames read != requests + replies"));
  MBC_FUZZ_CHECK(r.findings.size() <= o.findings_kept && r.findings.size() <= r.finding_count, kHarness, ctx("findings unbounded"));
  MBC_FUZZ_CHECK(r.stats.error.find('\n') == std::string::npos, kHarness, ctx("an error of more than one line"));
  for (const auto& k : r.run.cases) {
    uint64_t seen = k.extra.value("exchanges_seen", uint64_t(0));
    MBC_FUZZ_CHECK((seen == 0) == (k.outcome == conf::Outcome::skip), kHarness, ctx(k.id + ": 'not seen' and its count disagree"));
    MBC_FUZZ_CHECK(k.frames.size() <= o.frames_per_case, kHarness, ctx(k.id + ": frames unbounded"));
  }
  return 0;
}
