// tcp://HOST:PORT?unit=N: Modbus TCP (MB Messaging on TCP/IP v1.0b). The
// connection is libmodbus's (modbus_new_tcp_pi + modbus_connect: name
// resolution, connect timeout, TCP_NODELAY). Requests carry a transaction id
// of their own (libmodbus 3.1.6's modbus_send_raw_request always sends 0,
// which cannot tell a late reply from the current one, nor check that the
// server echoes the id, §3.1.3). Replies are read here, byte for byte, and
// checked against the request's MBAP header; raw means whole MBAP ADUs.
#include <fmt/core.h>
#include <modbus/modbus.h>

#include <algorithm>
#include <cerrno>
#include <deque>
#include <stdexcept>
#include <thread>

#include "modbus/mbap.h"
#include "targets/kinds.h"
#include "targets/live_link.h"

namespace mbc::conf {
namespace {

using namespace live;

constexpr uint16_t kDefaultPort = 502;  // MB TCP v1.0b §3.1.2: the registered port
constexpr milliseconds kDefaultTimeout{1000};
// The end of a reply whose MBAP length is unusable: the connection's silence.
constexpr milliseconds kReplyEndSilence{20};
// The longest wait for a gateway's own 0A/0B, however slow it was before.
constexpr microseconds kGatewayWaitCap{std::chrono::seconds(30)};
// Transaction ids of requests whose reply did not come in time; their late
// replies are recognised and dropped.
constexpr size_t kStaleMemory = 16;

class TcpTarget final : public Target {
 public:
  explicit TcpTarget(const Uri& u) : window_(kDefaultTimeout, false, std::nullopt) {
    std::string base = fmt::format("tcp://{}:{}", u.host, u.port ? u.port : kDefaultPort);
    check_params(u, base, {"unit", "timeout", "silence", "gateway"});
    if (u.host.empty()) throw std::invalid_argument(fmt::format("target 'tcp:{}': needs HOST[:PORT], e.g. tcp://192.168.1.20:502", u.path));
    // MB TCP v1.0b §4.4.1.1: the unit id addresses a device behind a gateway;
    // 0 is broadcast on the serial side, so it is never the default.
    int unit = int_param(u, base, "unit", 1, 1, 255);
    timeout_ = milliseconds(int_param(u, base, "timeout", int(kDefaultTimeout.count()), 1, 60000));
    std::optional<milliseconds> fixed;
    if (u.param("silence")) fixed = milliseconds(int_param(u, base, "silence", 0, 1, 60000));
    window_ = SilenceWindow(timeout_, false, fixed);
    info_.uri = fmt::format("{}?unit={}", base, unit);
    info_.kind = TargetKind::tcp;
    info_.framing = framing_of(info_.kind);
    info_.unit = uint8_t(unit);
    info_.live = is_live(info_.kind);
    info_.raw = true;
    // gateway=1: a Modbus TCP gateway in front of the device; it stays in
    // the URI, which check/exchange.cpp reads (a gateway found by its 0A/0B
    // is added to it the same way).
    if (auto g = u.param("gateway")) {
      if (*g != "0" && *g != "1") throw std::invalid_argument(fmt::format("target '{}': gateway={}: expected 0 or 1", base, *g));
      gateway_ = *g == "1";
      if (gateway_) info_.uri += "&gateway=1";
    }
    std::string port = std::to_string(u.port ? u.port : kDefaultPort);
    ctx_ = modbus_new_tcp_pi(u.host.c_str(), port.c_str());
    if (!ctx_) throw std::invalid_argument(fmt::format("target '{}': {}", info_.uri, modbus_strerror(errno)));
    auto ms = timeout_.count();
    modbus_set_response_timeout(ctx_, uint32_t(ms / 1000), uint32_t(ms % 1000) * 1000);
    try {
      connect();
    } catch (...) {
      modbus_free(ctx_);
      throw;
    }
  }
  ~TcpTarget() override {
    modbus_close(ctx_);
    modbus_free(ctx_);
  }

  const TargetInfo& info() const override { return info_; }
  microseconds silence_window() const override { return window_.window(); }
  void set_wait(Wait w) override { wait_ = w; }
  uint64_t late_replies() const override { return window_.late_count(); }
  bool reconnect() override {
    modbus_close(ctx_);
    connected_ = false;
    try {
      connect();
      return true;
    } catch (const std::runtime_error&) {
      return false;
    }
  }

  Reply transact(uint8_t unit, std::span<const uint8_t> pdu) override {
    uint16_t tid = next_tid_++;
    Bytes adu = mbap_frame(tid, unit, pdu);
    // Only well-formed exchanges with a unit time the device (a broadcast has no reply).
    return exchange(adu, Mbap{tid, 0, 0, unit}, std::nullopt, unit != 0, unit == info_.unit);
  }

  Reply send_raw(std::span<const uint8_t> bytes, std::optional<size_t> gap_after) override {
    return exchange(Bytes(bytes.begin(), bytes.end()), parse_mbap(bytes), gap_after, false, false);
  }

  bool pipelines() const override { return true; }

  // Up to `depth` requests out at once, each with its own transaction id; a
  // reply is matched by its id whatever the order (a gateway may answer
  // units out of order). A request still unanswered once the connection
  // stayed silent for the wait after the last request or reply is silent.
  // Latency is timed from when the server could start on the request (its
  // sending, or the reply before it), so queueing does not widen the window.
  std::vector<Reply> transact_all(std::span<const Request> requests, size_t depth) override {
    std::vector<Reply> out(requests.size());
    if (requests.empty()) return out;
    struct Pending {
      size_t index;
      Mbap sent;
      Clock::time_point at;
    };
    std::deque<Pending> pending;  // in the order sent
    depth = std::max<size_t>(depth, 1);
    size_t next = 0;
    if (!connected_) connect();
    int fd = modbus_get_socket(ctx_);
    if (drain(fd) > 0) window_.late_reply();
    in_.clear();
    Clock::time_point last_event = Clock::now(), last_reply{};
    auto settle = [&](const Pending& p, Bytes frame, Clock::time_point at) {
      Reply& r = out[p.index];
      r.frame = std::move(frame);
      r.latency = std::chrono::duration_cast<microseconds>(at - std::max(p.at, last_reply));
      judge_mbap(r, p.sent);
      if (r.frame.empty()) remember_stale(p.sent.transaction, p.at);
      if (r.pdu && p.sent.unit != 0) window_.record(r.latency, !r.pdu->empty() && ((*r.pdu)[0] & 0x80));
    };
    while (next < requests.size() || !pending.empty()) {
      while (next < requests.size() && pending.size() < depth) {
        if (!connected_) {
          connect();
          fd = modbus_get_socket(ctx_);
        }
        const Request& q = requests[next];
        uint16_t tid = next_tid_++;
        out[next].request = mbap_frame(tid, q.unit, q.pdu);
        write_all(fd, out[next].request, info_.uri);
        last_event = Clock::now();
        pending.push_back({next, Mbap{tid, 0, 0, q.unit}, last_event});
        ++next;
      }
      auto wait = wait_ == Wait::reply ? microseconds(timeout_) : window_.window();
      auto first_by = last_event + wait;
      ReadResult rr = read_frame(fd, in_, first_by, kReplyEndSilence, first_by + timeout_, whole_adu);
      auto now = Clock::now();
      if (whole_adu(in_)) {
        Mbap h = *parse_mbap(in_);
        Bytes frame(in_.begin(), in_.begin() + ptrdiff_t(h.adu_size()));
        in_.erase(in_.begin(), in_.begin() + ptrdiff_t(h.adu_size()));
        auto it = std::find_if(pending.begin(), pending.end(), [&](const Pending& p) { return p.sent.transaction == h.transaction; });
        if (it == pending.end() && is_stale(h, std::nullopt)) {
          window_.late_reply(stale_latency(h.transaction));
        } else {
          if (it == pending.end()) it = pending.begin();  // an id nobody sent: the oldest request's reply, judged so
          settle(*it, std::move(frame), rr.last_byte);
          last_reply = rr.last_byte;
          pending.erase(it);
        }
        last_event = now;
      } else {
        // Silence, or bytes that never made a whole ADU: those go to the
        // oldest request (a framing error), the rest are silent.
        if (!in_.empty() && !pending.empty()) {
          settle(pending.front(), in_, rr.last_byte);
          pending.pop_front();
          in_.clear();
        }
        for (const auto& p : pending) settle(p, {}, now);
        pending.clear();
      }
      if (rr.closed) {
        for (const auto& p : pending) settle(p, {}, now);
        pending.clear();
        modbus_close(ctx_);
        connected_ = false;
      }
    }
    return out;
  }

  void advance(std::chrono::microseconds) override {
    throw std::logic_error(info_.uri + ": a live device has no virtual clock");
  }
  void power_cycle() override { throw std::logic_error(info_.uri + ": a live device cannot be power-cycled from here"); }

 private:
  void connect() {
    if (modbus_connect(ctx_) == -1)
      throw std::runtime_error(fmt::format("target '{}': cannot connect: {}", info_.uri, modbus_strerror(errno)));
    connected_ = true;
    in_.clear();
  }

  static bool whole_adu(std::span<const uint8_t> b) {
    auto h = parse_mbap(b);
    return h && h->length_ok() && b.size() >= h->adu_size();
  }

  // Latency runs from the start of the request's last write to the reply's last byte.
  // `addressed`: a well-formed request to the target's unit (Wait::automatic waits for its reply).
  Reply exchange(const Bytes& adu, std::optional<Mbap> sent, std::optional<size_t> gap_after, bool timed,
                 bool addressed) {
    if (!connected_) connect();  // the server closed it after the last exchange (e.g. a bad MBAP length)
    int fd = modbus_get_socket(ctx_);
    if (drain(fd) > 0) window_.late_reply();
    in_.clear();
    size_t split = gap_after ? std::min(*gap_after, adu.size()) : adu.size();
    auto t0 = Clock::now();
    write_all(fd, std::span(adu).first(split), info_.uri);
    if (split < adu.size()) {
      std::this_thread::sleep_for(kReplyEndSilence);  // two TCP segments
      t0 = Clock::now();
      write_all(fd, std::span(adu).subspan(split), info_.uri);
    }
    Reply r;
    r.request = adu;
    bool for_reply = wait_ == Wait::reply || (wait_ == Wait::automatic && addressed);
    auto first_by = t0 + (for_reply ? microseconds(timeout_) : window_.window());
    // Through a gateway a request the device leaves unanswered is answered
    // 0A/0B by the gateway after its retries: wait for that (as long as the
    // gateway took before, twice over; until the first one, the timeout)
    // rather than let it come late and cancel the verdicts since. Not capped
    // at the timeout: a gateway that gives up after 4 tries of 500 ms answers
    // after 2 s, past the default 1 s (bench/bench_gateway.cpp found it).
    if (gateway_ && !for_reply && addressed)
      first_by = t0 + std::min<microseconds>(kGatewayWaitCap, std::max(window_.window(), gateway_answer_ ? 2 * *gateway_answer_
                                                                                                          : microseconds(timeout_)));
    ReadResult rr;
    for (;;) {
      rr = read_frame(fd, in_, first_by, kReplyEndSilence, first_by + timeout_, whole_adu);
      if (!whole_adu(in_) || !is_stale(*parse_mbap(in_), sent)) break;
      window_.late_reply(stale_latency(parse_mbap(in_)->transaction));
      gateway_seen(std::span<const uint8_t>(in_).subspan(kMbapHeader, parse_mbap(in_)->adu_size() - kMbapHeader),
                   stale_latency(parse_mbap(in_)->transaction).value_or(microseconds(timeout_)));
      in_.erase(in_.begin(), in_.begin() + ptrdiff_t(parse_mbap(in_)->adu_size()));
    }
    size_t take = whole_adu(in_) ? parse_mbap(in_)->adu_size() : in_.size();
    r.frame.assign(in_.begin(), in_.begin() + ptrdiff_t(take));
    in_.clear();
    r.latency = std::chrono::duration_cast<microseconds>((r.frame.empty() ? Clock::now() : rr.last_byte) - t0);
    if (rr.closed) {
      r.closed = r.frame.empty();
      modbus_close(ctx_);
      connected_ = false;
    }
    judge_mbap(r, sent);
    if (sent && r.frame.empty()) remember_stale(sent->transaction, t0);
    if (r.pdu && gateway_seen(*r.pdu, r.latency)) return r;  // not a latency of the device
    if (r.pdu && timed) window_.record(r.latency, !r.pdu->empty() && ((*r.pdu)[0] & 0x80));
    return r;
  }

  // A gateway's own answer, 0A or 0B (MBAP v1.1b3 §7): a gateway is in
  // front of the device, and the time it took to give up is how long a
  // silence is waited for from now on.
  bool gateway_seen(std::span<const uint8_t> pdu, microseconds after) {
    if (pdu.size() != 2 || !(pdu[0] & 0x80) || (pdu[1] != 0x0A && pdu[1] != 0x0B)) return false;
    if (!gateway_) info_.uri += "&gateway=1";
    gateway_ = true;
    gateway_answer_ = std::max(gateway_answer_.value_or(microseconds(0)), after);
    return true;
  }

  bool is_stale(const Mbap& got, const std::optional<Mbap>& sent) const {
    if (sent && got.transaction == sent->transaction) return false;
    return std::any_of(stale_.begin(), stale_.end(), [&](const auto& s) { return s.first == got.transaction; });
  }
  // How long after its request a late reply was found.
  std::optional<microseconds> stale_latency(uint16_t tid) const {
    for (const auto& [id, at] : stale_)
      if (id == tid) return std::chrono::duration_cast<microseconds>(Clock::now() - at);
    return std::nullopt;
  }
  void remember_stale(uint16_t tid, Clock::time_point sent_at) {
    stale_.emplace_back(tid, sent_at);
    if (stale_.size() > kStaleMemory) stale_.pop_front();
  }

  // MB TCP v1.0b §3.1.3: the server copies the transaction and unit ids, the
  // protocol id is 0, the length counts the unit id and the PDU.
  static void judge_mbap(Reply& r, const std::optional<Mbap>& sent) {
    if (r.frame.empty()) return;
    Unframed u = mbap_unframe(r.frame);  // header whole, protocol 0, length right (modbus/mbap.h)
    if (!u.ok()) r.framing_error = "reply: " + u.error;
    else if (sent && u.transaction != sent->transaction)
      r.framing_error = fmt::format("reply transaction id {}, request was {}", u.transaction, sent->transaction);
    else if (sent && u.unit != sent->unit)
      r.framing_error = fmt::format("reply unit id {}, request went to {}", u.unit, sent->unit);
    else r.pdu = std::move(u.pdu);
  }

  TargetInfo info_;
  modbus_t* ctx_ = nullptr;
  bool connected_ = false;
  milliseconds timeout_{kDefaultTimeout};
  SilenceWindow window_;
  bool gateway_ = false;                        // a gateway in front of the device (given, or found by its 0A/0B)
  std::optional<microseconds> gateway_answer_;  // the longest a gateway took to answer 0A/0B
  uint16_t next_tid_ = 1;
  std::deque<std::pair<uint16_t, Clock::time_point>> stale_;
  Wait wait_ = Wait::automatic;
  Bytes in_;
};

}  // namespace

std::unique_ptr<Target> make_tcp_target(const Uri& u) { return std::make_unique<TcpTarget>(u); }

}  // namespace mbc::conf
