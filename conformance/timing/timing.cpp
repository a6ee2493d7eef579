#include "timing/timing.h"

#include <fmt/core.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <filesystem>
#include <map>
#include <random>
#include <stdexcept>
#include <thread>

#include "modbus/function_codes.h"
#include "modbus/hex.h"
#include "modbus/pdu.h"
#include "modbus/rtu.h"
#include "targets/percentile.h"

namespace mbc::conf::timing {
namespace {

using Clock = std::chrono::steady_clock;
constexpr const char* kClause = "MB-SL v1.02 §2.5.1.1";

double us(Clock::duration d) { return double(std::chrono::duration_cast<std::chrono::nanoseconds>(d).count()) / 1000.0; }

std::string ms(double micros) { return fmt::format("{:.2f} ms", micros / 1000.0); }

double median(std::vector<double> v) {
  return v.empty() ? 0 : percentile(std::span(v), 50);
}

}  // namespace

LineFacts line_facts(const TargetInfo& info) {
  LineFacts f;
  f.serial = info.kind == conf::TargetKind::rtu && info.baud.has_value();
  f.latency_timer_ms = info.latency_timer_ms;
  if (!info.baud) return f;
  try {
    std::error_code ec;
    auto real = std::filesystem::canonical(parse_uri(info.uri).path, ec);
    f.pty = !ec && real.string().rfind("/dev/pts/", 0) == 0;
  } catch (const std::exception&) {
  }
  f.baud = *info.baud;
  int bits = kBitsPerChar;  // MB-SL v1.02 §2.5.1: 11 bits a character (8E1, 8O1, 8N2)
  try {
    Uri u = parse_uri(info.uri);
    int data = std::stoi(u.param("data").value_or("8"));
    int stop = std::stoi(u.param("stop").value_or("1"));
    bool parity = u.param("parity").value_or("E") != "N";
    bits = 1 + data + (parity ? 1 : 0) + stop;
  } catch (const std::exception&) {
  }
  f.char_us = bits * 1e6 / f.baud;
  f.t15 = char_gap(f.baud);
  f.t35 = frame_gap(f.baud);
  return f;
}

Timed measure(const Reply& r, size_t request_bytes, const LineFacts& f) {
  Timed m;
  m.echo = r.echo_bytes;
  m.noise = r.noise;

  size_t total = 0;
  for (const auto& a : r.arrivals) total += a.bytes;
  const size_t first = r.echo_bytes + r.noise.size();  // the reply's first byte in the stream read
  if (r.frame.empty() || !r.pdu || !r.late.empty() || f.char_us <= 0 || total != first + r.frame.size()) return m;
  m.usable = true;
  const double c = f.char_us;
  // The request ends on the line no sooner than its characters after its
  // writing began (a host that wrote late ends it later: the turnaround
  // only looks longer).
  const auto sent = r.sent_at;
  const double request_end = double(request_bytes) * c;
  // Each read at `at` holding bytes up to `upto` (exclusive): the byte at
  // index i had started by at - (upto - i) x c (its own and the later
  // characters' time), or later.
  size_t upto = 0;
  std::optional<double> prev_at;  // the read before, when it held reply bytes
  double first_read = 0;
  size_t after_first = 0;  // reply bytes read after the first read that held any
  for (const auto& a : r.arrivals) {
    size_t from = upto;
    upto += a.bytes;
    double at = us(a.at - sent);
    if (upto <= first) continue;  // echo or noise only
    ++m.reads;
    if (from <= first && !prev_at) {
      m.turnaround = at - double(upto - first) * c - request_end;
      first_read = at;
    } else {
      after_first += std::min(upto, first + r.frame.size()) - std::max(from, first);
    }
    size_t reply_bytes_here = std::min(upto, first + r.frame.size()) - std::max(from, first);
    if (prev_at && from >= first) m.inner_gap = std::max(m.inner_gap, at - *prev_at - double(reply_bytes_here) * c);
    prev_at = at;
  }
  // Paced: the reply's characters took at least their line time after the
  // request's (two characters' slack), and came spread over reads as the
  // line clocked them (at least half their line time between the first read
  // and the last): a pty without a line model hands a frame over at once,
  // which a busy host may still deliver later than its line time.
  double last = us(r.arrivals.back().at - sent);
  m.paced = last >= request_end + double(r.noise.size() + r.frame.size()) * c - 2 * c && m.reads > 1 &&
            last - first_read >= 0.5 * double(after_first) * c;
  return m;
}

std::optional<int> batch_period_ms(const std::vector<Reply>& replies) {
  std::vector<int64_t> at;
  for (const auto& r : replies)
    for (const auto& a : r.arrivals) at.push_back(std::chrono::duration_cast<std::chrono::microseconds>(a.at.time_since_epoch()).count());
  // Enough reads that chance does not put most on a grid (at most 1 in 4
  // falls there by chance: 70 % of 16 or more, about 1 in 3000 per period).
  if (at.size() < 16) return std::nullopt;
  for (int period = 16; period >= 2; --period) {
    const int64_t p = period * 1000;
    // A read comes up to `tol` after its batch (more for the long periods,
    // where a busy host's lateness matters less); by chance one falls there
    // with probability tol / p: at most 1/4 (then 70 % must), 1/8 from 12 ms
    // (then half must).
    const int64_t tol = period >= 12 ? 1500 : std::min<int64_t>(p / 4, 1000);
    const double needed = period >= 12 ? 0.5 : 0.7;
    size_t on = 0;
    for (int64_t t : at) on += (t % p) < tol;
    if (double(on) >= needed * double(at.size())) return period;
  }
  return std::nullopt;
}

std::vector<CheckListing> check_listing() {
  return {
      {"gapped-request", kClause, "a request with a silence over t1.5 inside it is discarded",
       "If a silent interval of more than 1.5 character times occurs between two characters, the message frame is "
       "declared incomplete and should be discarded by the receiver (these two timers must be strictly respected when "
       "the baud rate is equal or lower than 19200 Bps; fixed 750 us above)",
       Level::must},
      {"reply-gap", kClause, "no silence over t1.5 inside a reply",
       "The entire message frame must be transmitted as a continuous stream of characters", Level::must},
      {"reply-after-t3.5", kClause, "the reply starts at least t3.5 after the request",
       "Message frames are separated by a silent interval of at least 3.5 character times", Level::must},
      {"request-at-t3.5", kClause, "a request sent t3.5 after the drive's reply is answered",
       "Message frames are separated by a silent interval of at least 3.5 character times (so t3.5 of silence "
       "ends a frame and the next may start)",
       Level::must},
      {"response-time/fcNN", "MB-SL v1.02 §2.4.1", "response time per function code: p50, p99, max",
       "The response time-out ... must be set large enough to allow any slave time to process the request and return "
       "the response (a manual's stated response time is MUST where one is stated)",
       Level::observed},
      {"echo", kClause, "the adapter's own echo of the request", "(how the line was seen: recorded)", Level::observed},
      {"line-noise", kClause, "bytes before a reply that are no frame", "(how the line was seen: recorded)", Level::observed},
      {"read-batching", kClause, "replies handed over in batches (a USB latency timer)", "(how the line was seen: recorded)",
       Level::observed},
  };
}

namespace {

struct Probe {
  uint8_t fc;
  Bytes pdu;
};

// The first readable register of each table the profile reads.
std::vector<Probe> probes(const spec::Spec& s) {
  std::vector<Probe> out;
  auto has = [&](int fc) { return s.profile.function(fc) != nullptr; };
  const std::pair<spec::Table, uint8_t> tables[] = {{spec::Table::holding, fc::read_holding_registers},
                                                    {spec::Table::input, fc::read_input_registers},
                                                    {spec::Table::coil, fc::read_coils},
                                                    {spec::Table::discrete_input, fc::read_discrete_inputs}};
  for (const auto& [table, code] : tables) {
    if (!has(code)) continue;
    for (const auto& reg : s.registers) {
      if (reg.table != table || reg.access == spec::Access::wo || reg.access == spec::Access::command) continue;
      out.push_back({code, read_request(code, reg.address, uint16_t(std::max<int>(1, reg.words)))});
      break;
    }
  }
  return out;
}

CaseResult result(const spec::Spec& s, const std::string& what, Level level) {
  CaseResult c;
  c.family = "timing";
  c.id = s.device.id + "/timing/" + what;
  for (const auto& l : check_listing())
    if (l.id == what || (what.rfind("response-time/", 0) == 0 && l.id == "response-time/fcNN")) {
      c.clause = l.clause;
      c.title = l.title;
      c.requirement = l.requirement;
    }
  c.level = level;
  return c;
}

void record(CaseResult& c, const Reply& r, const std::string& step, const std::string& expected) {
  FrameRecord fr;
  fr.step = step;
  fr.request = r.request;
  fr.expected_text = expected;
  if (!r.frame.empty()) fr.actual = r.frame;
  fr.latency_us = double(r.latency.count());
  c.frames.push_back(std::move(fr));
}

void verdict(CaseResult& c, bool measurable, bool ok, std::string text) {
  if (!measurable) {
    c.level = Level::observed;
    c.outcome = Outcome::observed;
  } else {
    c.outcome = ok ? Outcome::pass : Outcome::fail;
  }
  c.message = std::move(text);
}

}  // namespace

std::vector<CaseResult> check_line(Link& t, const spec::Spec& s, const Options& o) {
  const TargetInfo& info = t.info();
  // Every frame through the Link (a live run's session: its frame policy and
  // journal); a read waits for its reply, the gapped request the window.
  auto ask = [&](const Bytes& pdu) { return reply_or_throw(t.transact(info.unit, pdu, Target::Wait::reply), info); };
  const LineFacts f = line_facts(info);
  std::vector<CaseResult> out;
  auto list = probes(s);
  if (list.empty()) {
    CaseResult c = result(s, "response-time/none", Level::observed);
    c.outcome = Outcome::skip;
    c.message = "the profile reads no table (FC 01-04): nothing to time without a write";
    out.push_back(std::move(c));
    return out;
  }
  const auto t35 = f.t35;
  // A pause of random length between exchanges: requests sent in a steady
  // rhythm would put the replies' reads on a grid of their own, which
  // batch_period_ms would take for a latency timer's.
  std::minstd_rand jitter(uint32_t(Clock::now().time_since_epoch().count()));
  auto between = [&] {
    std::this_thread::sleep_for(std::max<microseconds>(2 * t35, std::chrono::milliseconds(2)) + microseconds(jitter() % 17000));
  };

  // ---- sampling: the response time of each read ----
  std::map<uint8_t, std::vector<Timed>> by_fc;
  std::map<uint8_t, std::vector<Reply>> replies;
  std::vector<Reply> all;
  for (const auto& p : list)
    for (int k = 0; k < o.samples; ++k) {
      between();
      Reply r = ask(p.pdu);
      by_fc[p.fc].push_back(measure(r, r.request.size(), f));
      all.push_back(r);
      replies[p.fc].push_back(std::move(r));
    }
  std::vector<Timed> timed;
  for (const auto& [fc_, v] : by_fc)
    for (const auto& m : v)
      if (m.usable) timed.push_back(m);
  size_t paced = size_t(std::count_if(timed.begin(), timed.end(), [](const Timed& m) { return m.paced; }));

  // What this line lets one measure.
  std::optional<int> batch = f.latency_timer_ms;
  std::string batch_source = "the adapter's latency timer (sysfs)";
  if (!batch || *batch <= 1) {
    if (auto found = batch_period_ms(all)) {
      batch = found;
      batch_source = "found in the reads' arrival times";
    }
  }
  const double resolution = batch && *batch > 1 ? *batch * 1000.0 : 0.0;  // how late a read may show a byte
  std::string why_not;  // empty: the line can measure character timing
  if (!f.serial)
    why_not = info.kind == conf::TargetKind::rtu_tcp ? "RTU over TCP: the gateway re-times the frames, so their timing is the gateway's"
                                     : "not a serial line";
  else if (timed.empty())
    why_not = "no reply could be timed";
  else if (!f.pty)
    ;  // a UART clocks every byte out at the line's rate
  else if (paced * 4 < timed.size())
    why_not = fmt::format("the pty's replies did not come as {} baud carries them ({} of {} spread over their line time): "
                          "the line does not pace bytes (a pty without a line model, or one that paces whole replies), so "
                          "their timing is not the drive's",
                          f.baud, paced, timed.size());
  auto coarse = [&](microseconds silence) -> std::string {
    if (resolution <= 0 || resolution + f.char_us < double(silence.count())) return "";
    return fmt::format("this host sees the line's bytes in batches {} ms apart ({}), coarser than {} us: a silence that "
                       "short cannot be seen{}",
                       *batch, batch_source, silence.count(),
                       f.latency_timer_ms ? "; for 1 ms: echo 1 > /sys/bus/usb-serial/devices/<tty>/latency_timer" : "");
  };
  // A line that is no serial line, or gave no reply, says so first; then batches
  // coarser than the silence judged (which also hide pacing); then no pacing.
  auto first_reason = [&](const std::string& coarser) {
    if (!f.serial || timed.empty() || coarser.empty()) return why_not;
    return coarser;
  };
  auto figures = [&](std::vector<double> v) {
    if (v.empty()) return std::string("no figures");
    std::vector<double> a = v, b = v;
    double mx = *std::max_element(v.begin(), v.end());
    return fmt::format("p50 {}, p99 {}, max {} ({} replies)", ms(percentile(std::span(a), 50)), ms(percentile(std::span(b), 99)),
                       ms(mx), v.size());
  };

  // ---- the drive discards a request with a silence over t1.5 inside it ----
  {
    CaseResult c = result(s, "gapped-request", Level::must);
    std::string why = why_not;
    auto old = t.split_gap();
    if (why.empty() && !old) why = "the pause inside a split frame is fixed (gap=)";
    const Bytes pdu = list.front().pdu;
    const Bytes adu = rtu_frame(info.unit, pdu);
    const size_t half = adu.size() / 2;
    // The first half's line time, then a silence three quarters of the way
    // from t1.5 to t3.5: a receiver held up reading the first half sees the
    // silence shorter, one held up reading the second longer (over t3.5 the
    // frame is two, discarded all the same), so the margin lies below.
    const double mid = double(f.t15.count()) + 0.75 * double((f.t35 - f.t15).count());
    const auto pause = microseconds(int64_t(double(half) * f.char_us + mid));
    int answered = 0, sent = 0;
    if (why.empty()) {
      t.set_split_gap(pause);
      for (int k = 0; k < o.tries; ++k) {
        between();
        Reply g;
        try {
          g = reply_or_throw(t.send_raw(adu, half, Target::Wait::window), info);
        } catch (const Refused& e) {  // the frame policy's refusal (session/): no verdict
          why = std::string("the gapped request could not be sent: ") + e.what();
          break;
        }
        between();
        Reply next = ask(pdu);  // a late reply to the gapped request shows in front of this one's
        ++sent;
        // Answered: a reply decoded in time, or one found late that answers this very frame (not stray bytes
        // such as the rest of an adapter's echo).
        bool yes = g.pdu.has_value() ||
                   std::any_of(next.late.begin(), next.late.end(), [&](const LateReply& l) { return l.request == adu; });
        answered += yes ? 1 : 0;
        record(c, g, fmt::format("the request with a {:.0f} us silence after byte {}", mid, half), "silence");
      }
      t.set_split_gap(microseconds(0));  // the target's own pause again
    }
    if (sent == 0 && why.empty()) why = "no gapped request was sent";
    verdict(c, why.empty(), answered * 2 <= sent,
            why.empty() ? fmt::format("{} of {} requests with a {} silence inside (t1.5 = {} us, t3.5 = {} us) were answered{}", answered,
                                      sent, ms(mid), f.t15.count(), f.t35.count(),
                                      answered * 2 > sent ? ": the drive takes a frame with a silence over t1.5 inside it" : "")
                        : "not measured: " + why);
    out.push_back(std::move(c));
  }

  // ---- no silence over t1.5 inside a reply ----
  {
    CaseResult c = result(s, "reply-gap", Level::must);
    std::string why = first_reason(coarse(f.t15));
    bool split = std::any_of(timed.begin(), timed.end(), [](const Timed& m) { return m.reads > 1; });
    if (why.empty() && !split)
      why = "every reply came in one read (the line hands frames over whole), so a silence inside one cannot be seen";
    std::vector<double> gaps;
    for (const auto& m : timed) gaps.push_back(m.inner_gap);
    double med = median(gaps);
    double worst = gaps.empty() ? 0 : *std::max_element(gaps.begin(), gaps.end());
    bool ok = med <= double(f.t15.count()) + f.char_us / 2;  // half a character for rounding
    verdict(c, why.empty(), ok,
            (why.empty() ? "" : "not judged: " + why + "; ") +
                fmt::format("the longest silence inside a reply: median {:.0f} us, max {:.0f} us over {} replies (t1.5 = {} us){}",
                            med, worst, gaps.size(), f.t15.count(),
                            ok ? "" : ": the drive pauses inside its reply longer than t1.5"));
    out.push_back(std::move(c));
  }

  // ---- the reply starts at least t3.5 after the request ----
  {
    CaseResult c = result(s, "reply-after-t3.5", Level::must);
    std::string why = first_reason(coarse(f.t35));
    std::vector<double> ta;
    for (const auto& m : timed) ta.push_back(m.turnaround);
    double med = median(ta);
    double least = ta.empty() ? 0 : *std::min_element(ta.begin(), ta.end());
    bool ok = med >= double(f.t35.count()) - f.char_us / 2;
    verdict(c, why.empty(), ok,
            (why.empty() ? "" : "not judged: " + why + "; ") +
                fmt::format("from the request's end to the reply's first character: median {:.0f} us, least {:.0f} us over {} "
                            "replies (t3.5 = {} us){}",
                            med, least, ta.size(), f.t35.count(),
                            ok ? "" : ": the drive replies sooner than t3.5 after the request"));
    out.push_back(std::move(c));
  }

  // ---- a request sent t3.5 after a reply is answered ----
  {
    CaseResult c = result(s, "request-at-t3.5", Level::must);
    std::string why = first_reason(coarse(f.t35));
    const Bytes pdu = list.front().pdu;
    // A try counts when this host sent within t3.5 + max(t3.5, 2 ms) of the reply's last read.
    const double bound = double(f.t35.count()) + std::max(double(f.t35.count()), 2000.0);
    int counted = 0, silent = 0;
    std::vector<double> pauses;
    if (why.empty()) {
      for (int k = 0; k < 2 * o.tries; ++k) {
        between();
        Reply a = ask(pdu);
        if (a.silent() || a.arrivals.empty()) continue;
        std::this_thread::sleep_until(a.arrivals.back().at + f.t35);
        Reply b = ask(pdu);
        double pause = us(b.sent_at - a.arrivals.back().at);
        if (pause > bound) continue;
        ++counted;
        pauses.push_back(pause);
        silent += b.silent() ? 1 : 0;
        record(c, b, fmt::format("the request {:.0f} us after the reply's end", pause), "a reply");
      }
      if (counted == 0) why = fmt::format("this host could not send within {} of a reply's end", ms(bound));
    }
    verdict(c, why.empty(), silent == 0,
            why.empty() ? fmt::format("{} of {} requests sent {:.0f}..{:.0f} us after the drive's reply (t3.5 = {} us) were "
                                      "answered{}",
                                      counted - silent, counted, pauses.empty() ? 0 : *std::min_element(pauses.begin(), pauses.end()),
                                      pauses.empty() ? 0 : *std::max_element(pauses.begin(), pauses.end()), f.t35.count(),
                                      silent ? ": the drive needs a longer silence than t3.5 before a request" : "")
                        : "not measured: " + why);
    out.push_back(std::move(c));
  }

  // ---- response time per function code ----
  for (const auto& [code, v] : by_fc) {
    std::vector<double> ta, lat;
    for (const auto& m : v)
      if (m.usable) ta.push_back(m.turnaround);
    for (const auto& r : replies[code])
      if (r.pdu) lat.push_back(double(r.latency.count()));
    const auto stated = s.timing.response_time_ms;
    CaseResult c = result(s, fmt::format("response-time/fc{:02d}", code), stated ? Level::must : Level::observed);
    if (stated) c.clause = s.device.id + " " + s.timing.section;
    for (const auto& r : replies[code]) {
      record(c, r, fmt::format("FC {:02d}", code), "a reply");
      if (c.frames.size() >= 3) break;
    }
    std::string text;
    bool measurable = why_not.empty() && !ta.empty();
    if (measurable) {
      double med = median(ta);
      text = fmt::format("FC {:02d}: from the request's end to the reply's start {} (t3.5 = {} us)", code, figures(ta),
                         f.t35.count());
      // Named beyond what a busy host adds (twice t3.5, at least 5 ms).
      if (med > double(f.t35.count()) + std::max(2.0 * double(f.t35.count()), 5000.0) + resolution)
        text += fmt::format("; a turnaround of about {} beyond t3.5", ms(med - double(f.t35.count())));
      if (resolution > 0) text += fmt::format("; coarse by up to {} ms ({})", *batch, batch_source);
    } else {
      text = fmt::format("FC {:02d}: request sent to last byte read {}{}", code, figures(lat),
                         why_not.empty() ? "" : " (" + why_not + ")");
    }
    bool ok = true;
    if (stated) {
      double med = measurable ? median(ta) : 0;
      ok = med <= *stated * 1000.0 + resolution;
      text += fmt::format("; the manual states {} ms ({})", *stated, s.timing.section);
    } else {
      text += "; the manual states no response time";
    }
    verdict(c, stated && measurable, ok, text);
    out.push_back(std::move(c));
  }

  // ---- how the line was seen: echo, noise, batching ----
  {
    CaseResult c = result(s, "echo", Level::observed);
    size_t n = size_t(std::count_if(timed.begin(), timed.end(), [](const Timed& m) { return m.echo > 0; }));
    c.outcome = Outcome::observed;
    c.message = n ? fmt::format("local echo: the request came back first in {} of {} replies (the adapter hears itself); stripped", n,
                                timed.size())
                  : fmt::format("no echo in {} replies", timed.size());
    out.push_back(std::move(c));
  }
  {
    CaseResult c = result(s, "line-noise", Level::observed);
    std::vector<const Timed*> noisy;
    for (const auto& m : timed)
      if (!m.noise.empty()) noisy.push_back(&m);
    c.outcome = Outcome::observed;
    c.message = noisy.empty() ? fmt::format("no bytes before the reply in {} replies", timed.size())
                              : fmt::format("line noise: {} of {} replies had bytes before them that were no frame ({})",
                                            noisy.size(), timed.size(), to_hex(noisy.front()->noise));
    out.push_back(std::move(c));
  }
  {
    CaseResult c = result(s, "read-batching", Level::observed);
    c.outcome = Outcome::observed;
    c.message = resolution > 0 ? fmt::format("batched reads: bytes reach this host in batches {} ms apart ({}): reply times "
                                             "are coarse by that much",
                                             *batch, batch_source)
                               : "no batching: bytes reach this host as the line delivers them";
    out.push_back(std::move(c));
  }
  return out;
}

}  // namespace mbc::conf::timing
