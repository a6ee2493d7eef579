// Pairing, judging and counting a capture's frames; the cases of the report.
#include "capture/check.h"

#include <fmt/core.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <deque>
#include <unordered_map>

#include "cases/facts.h"
#include "modbus/function_codes.h"
#include "modbus/judge.h"
#include "modbus/limits.h"
#include "modbus/rtu.h"

namespace mbc::conf::capture {
namespace {

// One case being filled: its verdicts so far.
struct Tally {
  uint64_t seen = 0, failed = 0;
  std::vector<Reliance> relies;
  // The verdicts' shared fact lists already merged (held, so that no other
  // list can take the address of one).
  std::vector<std::shared_ptr<const std::vector<Reliance>>> merged;
  std::vector<FrameRecord> frames;
  std::string first_failure, last_message;
};

uint8_t unit_of(Carrier c, const Bytes& adu) {
  if (c == Carrier::mbap) return adu.size() > 6 ? adu[6] : 0;
  return adu.empty() ? 0 : adu[0];
}
size_t pdu_at(Carrier c) { return c == Carrier::mbap ? kMbapHeader : 1; }
int fc_of(Carrier c, const Bytes& adu) {
  size_t at = pdu_at(c);
  return adu.size() > at ? adu[at] : -1;
}
std::span<const uint8_t> pdu_of(Carrier c, const Bytes& adu) {
  size_t at = pdu_at(c), tail = c == Carrier::rtu ? 2 : 0;
  if (adu.size() < at + tail) return {};
  return std::span(adu).subspan(at, adu.size() - at - tail);
}

class Checker : public FrameSink {
 public:
  Checker(const spec::Spec& s, const Options& o, Result& r) : spec_(s), opt_(o), r_(r) {
    for (auto& c : covered_) c.assign(0x10000, false);
    for (const auto& reg : s.registers)
      for (uint32_t a = reg.address; a <= reg.last_address() && a <= 0xFFFF; ++a) covered_[size_t(reg.table)][a] = true;
    for (const auto& k : catalogue(s)) order_.push_back(k.packed()), tallies_[k.packed()], keys_[k.packed()] = k;
  }

  void frame(const Frame& f) override {
    Conv& c = convs_[f.stream];
    c.name = std::string(f.conversation);
    // Timed serial lines: the silence before this frame, from the end of the
    // one before (a log's time is the frame's end; its start is that minus
    // its wire time).
    std::optional<int64_t> gap;
    if (f.timed_line) {
      int64_t start = int64_t(f.time_us) - int64_t(wire_time(f.adu.size(), opt_.judge.baud).count());
      if (c.last_end) gap = start - *c.last_end;
      c.last_end = int64_t(f.time_us);
    }
    if (f.to_server) request(c, f, gap);
    else reply(c, f, gap);
  }

  void finding(const Finding& x) override {
    ++r_.finding_count;
    if (r_.findings.size() < opt_.findings_kept) r_.findings.push_back(x);
  }

  void stream_end(uint32_t stream) override {
    auto it = convs_.find(stream);
    if (it == convs_.end()) return;
    for (auto& p : it->second.pending) unanswered(p, false);
    convs_.erase(it);
  }

  void finish() {
    for (auto& [id, c] : convs_)
      for (auto& p : c.pending) unanswered(p, false);
    convs_.clear();
  }

  std::vector<CaseResult> cases() const {
    std::vector<CaseResult> out;
    std::vector<uint64_t> order = order_;
    for (const auto& [k, t] : tallies_)
      if (std::find(order_.begin(), order_.end(), k) == order_.end()) order.push_back(k);
    for (uint64_t k : order) {
      const Tally& t = tallies_.at(k);
      CaseText text = case_text(spec_.device.id, keys_.at(k));
      Case c;  // for the level rule only (cases/facts.h)
      c.id = text.id;
      c.level = text.level;
      c.requirement = text.requirement;
      c.relies = t.relies;
      facts::settle_level(c);
      CaseResult cr;
      cr.id = text.id;
      cr.family = "capture";
      cr.clause = text.clause;
      cr.level = c.level;
      cr.title = text.title;
      cr.requirement = c.requirement;
      cr.register_address = text.register_address;
      cr.frames = t.frames;
      cr.extra["exchanges_seen"] = t.seen;
      cr.extra["exchanges_failed"] = t.failed;
      if (t.seen == 0) {
        cr.outcome = Outcome::skip;
        cr.message = keys_.at(k).check == Check::gap_t15
                         ? "not seen: the log has one timestamp per frame, not per character"
                         : "not seen: the capture never exercised it";
      } else if (t.failed == 0) {
        cr.outcome = Outcome::pass;
        cr.message = fmt::format("{} exchange(s) seen, all as expected", t.seen);
        if (keys_.at(k).check == Check::latency && r_.coverage.latency_count)
          cr.message = fmt::format("{} latencies recorded: median {:.0f} us, p99 {:.0f} us", t.seen,
                                   r_.coverage.latency_percentile(0.5), r_.coverage.latency_percentile(0.99));
      } else {
        cr.outcome = cr.level == Level::observed ? Outcome::observed : Outcome::fail;
        cr.message = fmt::format("{} of {} exchange(s) not as expected; first: {}", t.failed, t.seen, t.first_failure);
      }
      out.push_back(std::move(cr));
    }
    return out;
  }

 private:
  struct Pending {
    Frame frame;
    std::optional<int64_t> gap;
  };
  struct Conv {
    std::string name;
    std::deque<Pending> pending;
    std::optional<int64_t> last_end;
  };

  void request(Conv& c, const Frame& f, std::optional<int64_t> gap) {
    Coverage& cv = r_.coverage;
    ++cv.requests;
    int fc = fc_of(f.carrier, f.adu);
    if (fc >= 0) cv.requests_by_fc[fc]++;
    cv.requests_by_unit[unit_of(f.carrier, f.adu)]++;
    count_registers(f);
    if (f.carrier == Carrier::rtu && !c.pending.empty()) {
      // RTU is one request at a time: a new request means the last got no reply.
      for (auto& p : c.pending) unanswered(p, false);
      c.pending.clear();
    }
    if (c.pending.size() >= opt_.max_pending) {
      unanswered(c.pending.front(), true);
      c.pending.pop_front();
    }
    c.pending.push_back({f, gap});
    c.pending.back().frame.conversation = {};  // the reader's name outlives only the call
  }

  void reply(Conv& c, const Frame& f, std::optional<int64_t> gap) {
    Coverage& cv = r_.coverage;
    ++cv.replies;
    int fc = fc_of(f.carrier, f.adu);
    if (fc >= 0 && (fc & 0x80)) {
      ++cv.exceptions;
      cv.exceptions_by_fc[fc & 0x7F]++;
    }
    // A reply answers a request of its own function code (MBAP v1.1b3 §4.1;
    // exceptions add 0x80): one that matches no waiting request is left
    // unsolicited (OBSERVED) rather than paired by guess, so a capture that
    // lost frames or reuses transaction ids never fails a device.
    int reply_fc = fc & 0x7F;
    auto same_fc = [&](const Pending& p) { return fc_of(p.frame.carrier, p.frame.adu) == reply_fc; };
    auto match = c.pending.end();
    if (f.carrier == Carrier::mbap) {
      uint16_t tid = be16(f.adu, 0);
      match = std::find_if(c.pending.begin(), c.pending.end(), [&](const Pending& p) {
        return p.frame.carrier == Carrier::mbap && be16(p.frame.adu, 0) == tid && same_fc(p);
      });
    } else if (!c.pending.empty() && same_fc(c.pending.front())) {
      match = c.pending.begin();  // by order; the unit is judged (framing/unit-echo)
    }
    if (match == c.pending.end()) {
      ++cv.unsolicited;
      tally(judge_unsolicited(f), nullptr, &f);
      return;
    }
    Exchange x = exchange(*match);
    x.reply = f.adu;
    x.reply_packet = f.packet;
    x.reply_time_us = f.time_us;
    x.gap_before_reply_us = gap;
    c.pending.erase(match);
    ++cv.exchanges;
    if (f.time_us >= x.request_time_us) latency(double(f.time_us - x.request_time_us));
    judge(x);
  }

  Exchange exchange(const Pending& p) const {
    Exchange x;
    x.stream = p.frame.stream;
    x.conversation = convs_.count(p.frame.stream) ? convs_.at(p.frame.stream).name : std::string();
    x.carrier = p.frame.carrier;
    x.request_packet = p.frame.packet;
    x.request_time_us = p.frame.time_us;
    x.request = p.frame.adu;
    x.timed_line = p.frame.timed_line;
    x.gap_before_request_us = p.gap;
    return x;
  }

  void unanswered(const Pending& p, bool abandoned) {
    ++r_.coverage.unanswered;
    Exchange x = exchange(p);
    x.abandoned = abandoned;
    judge(x);
  }

  void judge(const Exchange& x) {
    for (const auto& v : judge_exchange(spec_, x, opt_.judge)) tally(v, &x, nullptr);
  }

  void tally(const Verdict& v, const Exchange* x, const Frame* lone) {
    uint64_t k = v.key.packed();
    auto [it, fresh] = tallies_.try_emplace(k);
    if (fresh) keys_[k] = v.key;
    Tally& t = it->second;
    ++t.seen;
    // The same request's facts come as the same shared list: merged once.
    if (v.relies && t.relies.size() < 16 && t.merged.size() < 64 &&
        std::find(t.merged.begin(), t.merged.end(), v.relies) == t.merged.end()) {
      t.merged.push_back(v.relies);
      for (const auto& r : *v.relies)
        if (std::none_of(t.relies.begin(), t.relies.end(), [&](const Reliance& q) { return q.fact == r.fact; }))
          t.relies.push_back(r);
    }
    if (!v.pass) {
      if (t.failed++ == 0) t.first_failure = v.message;
      if (t.frames.size() < opt_.frames_per_case) t.frames.push_back(record(v, x, lone));
    }
  }

  FrameRecord record(const Verdict& v, const Exchange* x, const Frame* lone) const {
    FrameRecord fr;
    fr.expected_text = v.message;
    if (x) {
      fr.step = fmt::format("packet {} ({})", x->request_packet, x->conversation);
      fr.request = x->request;
      fr.request_decoded = describe_pdu(pdu_of(x->carrier, x->request), true);
      if (x->reply) {
        fr.actual = *x->reply;
        fr.actual_decoded = describe_pdu(pdu_of(x->carrier, *x->reply), false);
        fr.latency_us = double(x->reply_time_us - std::min(x->reply_time_us, x->request_time_us));
      }
    } else if (lone) {
      fr.step = fmt::format("packet {} ({})", lone->packet, lone->conversation);
      fr.actual = lone->adu;
      fr.actual_decoded = describe_pdu(pdu_of(lone->carrier, lone->adu), false);
    }
    return fr;
  }

  void count_registers(const Frame& f) {
    auto pdu = pdu_of(f.carrier, f.adu);
    if (pdu.empty()) return;
    ParsedRequest pr = parse_request(pdu);
    if (!pr.request) return;
    const Request& r = *pr.request;
    uint8_t fc = pdu[0];
    int table = int(spec::table_for_function(fc));
    auto add = [&](uint32_t first, uint32_t n, int rw) {
      n = std::min<uint32_t>(n, 2000);
      for (uint32_t a = first; a < first + n && a <= 0xFFFF; ++a) {
        // Only addresses the spec maps are kept (bounded by the map).
        if (!covered_[size_t(table)][a]) continue;
        r_.coverage.registers[{table, uint16_t(a)}][rw]++;
      }
    };
    switch (fc) {
      case 1: case 2: case 3: case 4: add(r.address, r.quantity, 0); break;
      case 5: case 6: case 22: add(r.address, 1, 1); break;
      case 15: case 16: add(r.address, r.quantity, 1); break;
      case 23: add(r.address, r.quantity, 0), add(r.write_address, r.write_quantity, 1); break;
      default: break;
    }
  }

  void latency(double us) {
    Coverage& cv = r_.coverage;
    int b = std::clamp(int(std::floor(10 * std::log10(std::max(us, 1.0)))), 0, Coverage::kBuckets - 1);
    cv.latency_buckets[size_t(b)]++;
    cv.latency_min_us = cv.latency_count ? std::min(cv.latency_min_us, us) : us;
    cv.latency_max_us = std::max(cv.latency_max_us, us);
    cv.latency_sum_us += us;
    ++cv.latency_count;
    // A sample for report.html's histogram: every latency while few, then
    // one in `stride` (bounded memory on any capture).
    auto& lat = r_.run.latencies_us;
    if (cv.latency_count % stride_ == 0) lat.push_back(us);
    if (lat.size() >= 20000) {
      std::vector<double> half;
      for (size_t i = 1; i < lat.size(); i += 2) half.push_back(lat[i]);
      lat.swap(half);
      stride_ *= 2;
    }
  }

  const spec::Spec& spec_;
  const Options& opt_;
  Result& r_;
  uint64_t stride_ = 1;
  std::array<std::vector<bool>, 4> covered_;  // addresses the spec maps, per table
  std::vector<uint64_t> order_;
  std::unordered_map<uint64_t, Tally> tallies_;
  std::unordered_map<uint64_t, CheckKey> keys_;
  std::unordered_map<uint32_t, Conv> convs_;
};

Result check(const spec::Spec& s, const Options& o, const std::string& what,
             const std::function<ReadStats(FrameSink&)>& read) {
  Result r;
  auto t0 = std::chrono::steady_clock::now();
  Checker c(s, o, r);
  r.stats = read(c);
  c.finish();
  r.run.device_id = s.device.id;
  r.run.target_uri = "capture:" + what;
  r.run.spec_path = s.path;
  r.run.cases = c.cases();
  r.run.frames_sent = r.coverage.requests;
  r.run.silences = r.coverage.unanswered;
  r.run.wall_seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  r.run.notes.push_back(fmt::format("{} {}: {} packets, {} Modbus frames in {} conversation(s); {} requests, {} replies "
                                    "({} exceptions), {} paired, {} without a reply, {} replies without a request",
                                    r.stats.format.empty() ? "file" : r.stats.format, what, r.stats.packets,
                                    r.stats.frames, r.stats.streams, r.coverage.requests, r.coverage.replies,
                                    r.coverage.exceptions, r.coverage.exchanges, r.coverage.unanswered,
                                    r.coverage.unsolicited));
  r.run.notes.push_back("A capture proves only what was sent: a case it never exercised is 'not seen' (skip), never a pass. "
                        "Coverage and the latency plot: coverage.html, coverage.json.");
  if (r.finding_count)
    r.run.notes.push_back(fmt::format("{} reading finding(s) (bytes that were not Modbus, segments not captured); first: "
                                      "packet {}: {}",
                                      r.finding_count, r.findings.front().packet, r.findings.front().what));
  if (!r.stats.error.empty()) r.run.error = r.stats.error;
  return r;
}

}  // namespace

double Coverage::latency_percentile(double p) const {
  if (!latency_count) return 0;
  uint64_t want = uint64_t(std::ceil(p * double(latency_count))), seen = 0;
  for (int i = 0; i < kBuckets; ++i) {
    seen += latency_buckets[size_t(i)];
    if (seen >= want && seen > 0) return std::min(latency_max_us, std::pow(10.0, double(i + 1) / 10));
  }
  return latency_max_us;
}

Result check_capture(const std::string& path, const spec::Spec& s, const Options& o) {
  return check(s, o, path, [&](FrameSink& sink) { return read_capture(path, o.read, sink); });
}

Result check_capture_bytes(std::span<const uint8_t> data, const spec::Spec& s, const Options& o) {
  return check(s, o, "(memory)", [&](FrameSink& sink) { return read_capture_bytes(data, o.read, sink); });
}

}  // namespace mbc::conf::capture
