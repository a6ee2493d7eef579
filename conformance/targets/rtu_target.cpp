// rtu:///dev/ttyUSB0?baud=&parity=&data=&stop=&unit=  (also a pty path) and
// rtu-tcp://HOST:PORT?unit=: RTU ADUs (slave, PDU, CRC) on a serial line
// through libmodbus, or on a raw TCP socket to a serial gateway (libmodbus
// has no RTU-over-TCP backend). Well-formed requests on the serial line go
// out through libmodbus (modbus_send_raw_request adds the CRC); malformed
// ones are written to the same fd (modbus_get_socket). Replies are read here,
// byte for byte, so that a bad CRC or a wrong length reaches the judge
// (libmodbus 3.1.6 drops such replies and misreads function codes it does
// not know, e.g. FC 08).
#include <fcntl.h>
#include <fmt/core.h>
#include <modbus/modbus.h>
#include <netdb.h>
#include <netinet/in.h>
#include <netinet/tcp.h>
#include <poll.h>
#include <sys/socket.h>
#include <termios.h>
#include <unistd.h>

#include <cerrno>
#include <cstring>
#include <deque>
#include <filesystem>
#include <fstream>
#include <optional>
#include <stdexcept>
#include <thread>
#include <utility>

#include "modbus/crc16.h"
#include "modbus/function_codes.h"
#include "modbus/judge.h"
#include "modbus/pdu.h"
#include "modbus/rtu.h"
#include "targets/kinds.h"
#include "targets/live_link.h"

namespace mbc::conf {
namespace {

}  // namespace

std::optional<int> usb_latency_ms(const std::string& device, const std::string& sysfs) {
  std::error_code ec;
  auto real = std::filesystem::canonical(device, ec);
  if (ec) return std::nullopt;
  std::ifstream f(sysfs + "/bus/usb-serial/devices/" + real.filename().string() + "/latency_timer");
  int ms = 0;
  if (!(f >> ms)) return std::nullopt;
  return ms;
}

std::vector<std::string> usb_latency_notes(const std::string& device, const std::string& sysfs) {
  auto timer = usb_latency_ms(device, sysfs);
  if (!timer) return {};
  std::error_code ec;
  const std::string name = std::filesystem::canonical(device, ec).filename().string();
  const int ms = *timer;
  if (ms <= 1)
    return {fmt::format("{}: USB latency timer {} ms: reply times are as fine as the line's", name, ms)};
  return {fmt::format("{}: USB latency timer {} ms: the adapter hands bytes over in batches up to {} ms apart, so reply "
                      "times are coarse by that much and a gap inside a frame cannot be seen; for 1 ms: echo 1 > "
                      "{}/bus/usb-serial/devices/{}/latency_timer",
                      name, ms, ms, sysfs, name)};
}

namespace {

using namespace live;

// MB-SL v1.02 §2.5.1: the standard's default line is 19200 baud, even parity.
constexpr int kDefaultBaud = 19200;
constexpr char kDefaultParity = 'E';
// A reply whose length the function code does not settle ends when the line
// is silent this long: t3.5 is far shorter than the gaps a USB adapter's
// latency timer or a TCP gateway put inside one frame.
constexpr milliseconds kReplyEndSilenceFloor{20};
// A frame split by `gap_after` pauses so that the receiver sees two frames:
// more than t3.5 of silence ends a frame (MB-SL v1.02 §2.5.1.1). On a serial
// line the pause is t3.5 plus the margin the silence window learnt over the
// line time (live::SilenceWindow::margin: twice the p99 of this host's and
// the device's latency over the line time, at least another t3.5), for a
// receiver that sees the pause shortened by its own wake-up jitter; never
// longer than 3 x t3.5 and kSplitGapFloor, the pause before anything was
// learnt (any receiver, a USB adapter's latency timer or a pty, sees two
// frames). Toward a gateway, whose
// own gap (serve's RTU over TCP: 10 ms) the network adds to, longer. A
// receiver that a busy host held up past the pause reads both parts at once
// and answers: the runner and the fuzzer then send it again with a pause of
// check::kSplitGapRecheck (check/check.h), so that race gives no verdict.
constexpr milliseconds kSplitGapFloor{20};
constexpr milliseconds kSplitGapGatewayFloor{50};
constexpr milliseconds kDefaultTimeout{1000};
// Unanswered requests whose late replies are still told from the current
// request's own: a device (or host) held up for a few windows in a row, and
// the frames between that had to stay silent.
constexpr size_t kUnansweredKept = 16;

// RTU over TCP: connects a raw socket (bounded by `timeout`).
int connect_tcp(const std::string& host, uint16_t port, milliseconds timeout, const std::string& uri) {
  addrinfo hints{};
  hints.ai_socktype = SOCK_STREAM;
  addrinfo* res = nullptr;
  std::string service = std::to_string(port);
  if (int rc = getaddrinfo(host.c_str(), service.c_str(), &hints, &res); rc != 0)
    throw std::runtime_error(fmt::format("target '{}': cannot resolve {}: {}", uri, host, gai_strerror(rc)));
  std::string why = "no address";
  int fd = -1;
  for (addrinfo* a = res; a && fd < 0; a = a->ai_next) {
    fd = socket(a->ai_family, a->ai_socktype | SOCK_NONBLOCK | SOCK_CLOEXEC, a->ai_protocol);
    if (fd < 0) continue;
    int rc = connect(fd, a->ai_addr, a->ai_addrlen);
    if (rc < 0 && errno == EINPROGRESS) {
      pollfd p{fd, POLLOUT, 0};
      int err = ETIMEDOUT;
      if (poll(&p, 1, int(timeout.count())) == 1) {
        socklen_t len = sizeof err;
        getsockopt(fd, SOL_SOCKET, SO_ERROR, &err, &len);
      }
      rc = err == 0 ? 0 : -1;
      errno = err;
    }
    if (rc < 0) {
      why = std::strerror(errno);
      close(fd);
      fd = -1;
    }
  }
  freeaddrinfo(res);
  if (fd < 0) throw std::runtime_error(fmt::format("target '{}': cannot connect to {}:{}: {}", uri, host, port, why));
  int one = 1;
  setsockopt(fd, IPPROTO_TCP, TCP_NODELAY, &one, sizeof one);
  return fd;
}

// The longest reply an RTU request can get, in bytes (slave, PDU, CRC): an
// exception (5 bytes, MBAP v1.1b3 §7), or the reply the standard gives its
// function code, whichever is longer: a read's for the quantity asked
// (§6.1-6.4, §6.17), the fixed length of a write's, a counter's or a mask
// write's echo (§6.5-6.7, §6.9, §6.11, §6.12, §6.16), both whatever the
// request's own length (a truncated, padded or over-long frame). Where the
// standard fixes no length (diagnostics' echo of its data, §6.8; file
// records, FIFO, device identification; unknown codes; a read whose
// quantity is cut off) an echo as long as the request. A window for an
// expected silence waits this long for a reply a non-conforming device might
// still send: a line delivers a frame's first byte early, but a pty or a
// gateway may hand it over whole.
size_t longest_reply(std::span<const uint8_t> adu) {
  constexpr size_t exception_reply = kRtuAddress + 2 + kRtuCrc;
  std::optional<size_t> by_code;
  if (adu.size() >= 2 && !(adu[1] & kExceptionBit)) {
    uint8_t code = adu[1];
    size_t q = adu.size() >= 8 ? size_t(adu[4]) << 8 | adu[5] : 0;
    bool bits = code == fc::read_coils || code == fc::read_discrete_inputs;
    bool words = code == fc::read_holding_registers || code == fc::read_input_registers ||
                 code == fc::read_write_multiple_registers;
    if ((bits || words) && adu.size() >= 8) by_code = kRtuAddress + 2 + (bits ? (q + 7) / 8 : 2 * q) + kRtuCrc;
    else if (code != fc::diagnostics) by_code = rtu_adu_length(adu.first(2), Direction::reply);
  }
  return std::min(std::max(exception_reply, by_code.value_or(adu.size())), kMaxRtuAdu);
}

// Whether no device may answer `adu` sent with `split` (MB-SL v1.02 §2.1:
// broadcast, another slave id; §2.4.2: a bad CRC or length, a pause inside
// the frame). Its window waits for the shortest reply, an exception, not the
// longest: a device that answers it anyway, later, is found by its late
// reply (Reply::late, late_replies(), which also widens the window) at the
// next exchange, where a long wait for what should never come cost every
// such frame the wire time of a reply of up to 256 bytes.
bool forbidden_to_answer(std::span<const uint8_t> adu, uint8_t unit, bool split) {
  return split || adu.empty() || adu[0] != unit || !crc_ok(adu) || rtu_adu_length(adu, Direction::request) != adu.size();
}
constexpr size_t kShortestReply = kRtuAddress + 2 + kRtuCrc;  // an exception (MBAP v1.1b3 §7)

class RtuTarget final : public Target {
 public:
  explicit RtuTarget(const Uri& u) : window_(kDefaultTimeout, false, std::nullopt) {
    uri_text_ = u.scheme + "://" + (u.host.empty() ? u.path : u.host + ":" + std::to_string(u.port));
    serial_ = u.scheme == "rtu";
    if (serial_)
      check_params(u, uri_text_, {"unit", "baud", "parity", "data", "stop", "timeout", "silence", "gap", "echo", "rs485", "rts", "rts_delay"});
    else
      check_params(u, uri_text_, {"unit", "baud", "timeout", "silence", "gap", "echo"});
    // The adapter's local echo (2-wire RS-485 adapters hear their own
    // request): echo=1 strips and checks it, echo=0 takes none; by default a
    // serial line finds it by itself (a frame that starts with the request
    // whole, where no reply could be the request).
    if (auto e = u.param("echo")) {
      if (*e != "0" && *e != "1" && *e != "auto")
        throw std::invalid_argument(fmt::format("target '{}': echo={}: expected 0, 1 or auto", uri_text_, *e));
      echo_ = *e == "1" ? Echo::on : *e == "0" ? Echo::off : Echo::automatic;
    } else {
      echo_ = serial_ ? Echo::automatic : Echo::off;
    }
    if (auto k = u.param("rs485"); k && *k != "kernel")
      throw std::invalid_argument(fmt::format("target '{}': rs485={}: expected kernel", uri_text_, *k));
    if (auto r = u.param("rts"); r && *r != "up" && *r != "down")
      throw std::invalid_argument(fmt::format("target '{}': rts={}: expected up or down", uri_text_, *r));
    if (u.param("rts_delay") && !u.param("rts"))
      throw std::invalid_argument(fmt::format("target '{}': rts_delay= needs rts=up or rts=down", uri_text_));
    int unit = int_param(u, uri_text_, "unit", 1, 1, 247);  // MB-SL v1.02 §2.2: slave addresses 1..247
    milliseconds timeout{int_param(u, uri_text_, "timeout", int(kDefaultTimeout.count()), 1, 60000)};
    std::optional<milliseconds> fixed;
    if (u.param("silence")) fixed = milliseconds(int_param(u, uri_text_, "silence", 0, 1, 60000));
    std::optional<int> baud;
    if (serial_ || u.param("baud")) baud = int_param(u, uri_text_, "baud", kDefaultBaud, 300, 4000000);

    info_.kind = u.scheme == "rtu" ? TargetKind::rtu : TargetKind::rtu_tcp;
    info_.framing = framing_of(info_.kind);
    info_.unit = uint8_t(unit);
    info_.live = is_live(info_.kind);
    info_.raw = true;
    info_.baud = baud;
    frame_gap_ = baud ? frame_gap(*baud) : microseconds(0);
    end_silence_ = std::max<microseconds>(frame_gap_, kReplyEndSilenceFloor);
    split_gap_ = std::max<microseconds>(3 * frame_gap_, serial_ ? kSplitGapFloor : kSplitGapGatewayFloor);
    gap_fixed_ = u.param("gap").has_value();
    if (gap_fixed_) split_gap_ = milliseconds(int_param(u, uri_text_, "gap", 0, 1, 10000));
    window_ = SilenceWindow(timeout, baud.has_value(), fixed, frame_gap_);
    timeout_ = timeout;

    if (serial_) {
      if (u.path.empty()) throw std::invalid_argument(fmt::format("target '{}': needs a device path, e.g. rtu:///dev/ttyUSB0", uri_text_));
      std::string parity = u.param("parity").value_or(std::string(1, kDefaultParity));
      if (parity != "N" && parity != "E" && parity != "O")
        throw std::invalid_argument(fmt::format("target '{}': parity={}: expected N, E or O", uri_text_, parity));
      int data = int_param(u, uri_text_, "data", 8, 7, 8);
      int stop = int_param(u, uri_text_, "stop", 1, 1, 2);
      info_.uri = fmt::format("{}?baud={}&parity={}&data={}&stop={}&unit={}", uri_text_, *baud, parity, data, stop, unit);
      ctx_ = modbus_new_rtu(u.path.c_str(), *baud, parity[0], data, stop);
      if (!ctx_) throw std::invalid_argument(fmt::format("target '{}': {}", uri_text_, modbus_strerror(errno)));
      if (modbus_connect(ctx_) == -1) {
        std::string why = modbus_strerror(errno);
        modbus_free(ctx_);
        ctx_ = nullptr;
        throw std::runtime_error(fmt::format("target '{}': cannot open {}: {}", uri_text_, u.path, why));
      }
      fd_ = modbus_get_socket(ctx_);
      set_direction_control(u);
      info_.notes = usb_latency_notes(u.path);
      info_.latency_timer_ms = usb_latency_ms(u.path);
    } else {
      if (u.host.empty() || u.port == 0)
        throw std::invalid_argument(fmt::format("target '{}': needs HOST:PORT, e.g. rtu-tcp://192.168.1.20:4001", uri_text_));
      host_ = u.host;
      port_ = u.port;
      info_.uri = fmt::format("{}?unit={}", uri_text_, unit);
      fd_ = connect_tcp(host_, port_, timeout, uri_text_);
    }
  }

  ~RtuTarget() override {
    if (ctx_) {
      modbus_close(ctx_);
      modbus_free(ctx_);
    } else if (fd_ >= 0) {
      close(fd_);
    }
  }

  const TargetInfo& info() const override { return info_; }
  microseconds silence_window() const override { return window_.window(last_line_); }
  void set_wait(Wait w) override { wait_ = w; }
  uint64_t late_replies() const override { return window_.late_count(); }
  // RTU over TCP: a new socket to the gateway. A serial line: the device
  // opened again (an adapter that was replugged, a pty whose other side is
  // still there), what waits on it dropped; false when it cannot be opened.
  // The fuzzer's fresh targets on a live line are this (Session::restart).
  bool reconnect() override {
    if (serial_) {
      modbus_close(ctx_);
      fd_ = -1;
      if (modbus_connect(ctx_) == -1) return false;
      fd_ = modbus_get_socket(ctx_);
      drain(fd_);
      return true;
    }
    if (fd_ >= 0) close(fd_);
    fd_ = -1;
    try {
      fd();
      return true;
    } catch (const std::runtime_error&) {
      return false;
    }
  }

  Reply transact(uint8_t unit, std::span<const uint8_t> pdu) override {
    Bytes adu = rtu_frame(unit, pdu);
    // Only well-formed exchanges with a slave time the device (a broadcast has no reply).
    bool timed = unit != 0;
    bool addressed = unit == info_.unit;
    if (ctx_ && !pdu.empty() && pdu.size() <= kMaxPdu) {
      return exchange(adu, unit, timed, addressed, !addressed, [&] {
        Bytes raw{unit};
        raw.insert(raw.end(), pdu.begin(), pdu.end());
        auto t = Clock::now();
        if (modbus_send_raw_request(ctx_, raw.data(), int(raw.size())) < 0)
          throw std::runtime_error(fmt::format("target '{}': send: {}", info_.uri, modbus_strerror(errno)));
        return t;
      });
    }
    return exchange(adu, unit, timed, addressed, !addressed, [&] {
      auto t = Clock::now();
      write_all(fd(), adu, info_.uri);
      return t;
    });
  }

  Reply send_raw(std::span<const uint8_t> bytes, std::optional<size_t> gap_after) override {
    Bytes adu(bytes.begin(), bytes.end());
    uint8_t slave = adu.empty() ? info_.unit : adu[0];
    bool split_frame = gap_after && *gap_after < adu.size();
    return exchange(adu, slave, false, false, forbidden_to_answer(adu, info_.unit, split_frame), [&] {
      size_t split = gap_after ? std::min(*gap_after, adu.size()) : adu.size();
      auto t = Clock::now();
      write_all(fd(), std::span(adu).first(split), info_.uri);
      if (split < adu.size()) {
        if (serial_) tcdrain(fd_);  // the first part is on the wire before the pause starts
        std::this_thread::sleep_for(pause());
        t = Clock::now();
        write_all(fd(), std::span(adu).subspan(split), info_.uri);
      }
      return t;
    });
  }

  std::optional<microseconds> split_gap() const override { return gap_fixed_ ? std::nullopt : std::optional(pause()); }
  // Kept until set again (the runner's re-run of a case whose split frame
  // was answered sets a longer pause, then the one it had).
  void set_split_gap(microseconds gap) override {
    if (gap_fixed_) return;
    if (gap.count() > 0) split_set_ = gap;
    else split_set_.reset();  // zero: the target's own pause again
  }

  void advance(std::chrono::microseconds) override {
    throw std::logic_error(info_.uri + ": a live device has no virtual clock");
  }
  void power_cycle() override { throw std::logic_error(info_.uri + ": a live device cannot be power-cycled from here"); }

 private:
  // The pause inside a split frame (kSplitGapFloor): as the user fixed it
  // (gap=) or the caller set it, else on a serial line derived from the
  // line's t3.5 and the margin learnt once there is one.
  microseconds pause() const {
    if (gap_fixed_) return split_gap_;
    if (split_set_) return *split_set_;
    auto m = window_.margin();
    if (!serial_ || !m) return split_gap_;
    return std::min(split_gap_, frame_gap_ + std::max(*m, frame_gap_));
  }

  // The socket of an RTU-over-TCP gateway that closed it is reopened.
  int fd() {
    if (fd_ < 0 && serial_) throw std::runtime_error(fmt::format("target '{}': the serial line could not be opened again", info_.uri));
    if (fd_ < 0) fd_ = connect_tcp(host_, port_, timeout_, info_.uri);
    return fd_;
  }

  // `send` writes the request and returns when its last part started out.
  // Latency runs from there (on a serial line: from when the request left
  // the UART) to the reply's last byte.
  // `addressed`: a well-formed request to the target's unit (Wait::automatic waits for its reply).
  // `forbidden`: a frame no device may answer (forbidden_to_answer).
  template <class Send>
  Reply exchange(const Bytes& adu, uint8_t slave, bool timed, bool addressed, bool forbidden, Send send) {
    Reply r;
    Bytes waiting;
    if (drain(fd(), &waiting) > 0) take_late(waiting, r);
    r.sent_at = Clock::now();
    auto* arrivals = serial_ ? &r.arrivals : nullptr;
    auto t0 = send();
    if (serial_) {
      tcdrain(fd_);
      t0 = Clock::now();
    }
    r.request = adu;
    bool for_reply = wait_ == Wait::reply || (wait_ == Wait::automatic && addressed);
    last_line_ = line_time(adu.size(), forbidden ? kShortestReply : longest_reply(adu));
    auto first_by = t0 + (for_reply ? window_.timeout() : window_.window(last_line_));
    auto wire = info_.baud ? wire_time(kMaxRtuAdu, *info_.baud) : microseconds(0);
    auto hard = first_by + window_.timeout() + 2 * wire;
    // Behind the adapter's echo the reply is complete as soon as it is
    // whole (not after the end-of-frame silence).
    auto complete = [&](std::span<const uint8_t> b) {
      if (rtu_adu_complete(b, Direction::reply)) return true;
      return echo_ != Echo::off && b.size() > adu.size() && std::equal(adu.begin(), adu.end(), b.begin()) &&
             rtu_adu_complete(b.subspan(adu.size()), Direction::reply);
    };
    ReadResult rr = read_frame(fd_, r.frame, first_by, end_silence_, hard, complete, arrivals);
    if (echo_ != Echo::off && !rr.closed && strip_echo(adu, r))
      if (r.frame.empty()) rr = read_frame(fd_, r.frame, first_by, end_silence_, hard, complete, arrivals);  // the reply follows
    // An earlier request's reply came after its window closed and after
    // this request went out: counted as late (as if drained before it), and
    // this request still waits for its own reply, now behind it on the line.
    while (!rr.closed) {
      Unanswered which;
      size_t late = late_reply_at_front(r.frame, adu, which);
      if (late == 0) break;
      count_late(which, Bytes(r.frame.begin(), r.frame.begin() + ptrdiff_t(late)), r);
      r.frame.erase(r.frame.begin(), r.frame.begin() + ptrdiff_t(late));
      first_by = std::max(first_by, Clock::now() + (for_reply ? window_.timeout() : window_.window(last_line_)));
      hard = first_by + window_.timeout() + 2 * wire;
      rr = read_frame(fd_, r.frame, first_by, end_silence_, hard, complete, arrivals);
    }
    if (!rr.closed) take_late_front(adu, r);
    // Bytes that ended in a silence and are no frame (line noise before the
    // reply, where the line is slow enough that t3.5 ends the read): the
    // reply may still follow; it is waited for as long as a silence is.
    if (!rr.closed && !r.frame.empty() && !whole_frame(r.frame) && serial_) {
      Bytes more;
      auto until = std::min(std::max(first_by, Clock::now()), Clock::now() + window_.window(last_line_));
      ReadResult next = read_frame(fd_, more, until, end_silence_, hard, complete, arrivals);
      if (!more.empty()) {
        r.frame.insert(r.frame.end(), more.begin(), more.end());
        rr = next;
      }
    }
    split_noise(adu, r);
    r.latency = std::chrono::duration_cast<microseconds>((r.frame.empty() ? Clock::now() : rr.last_byte) - t0);
    if (r.frame.empty()) silent_at_ = t0;
    // Replies come in order: theirs would have come first. A reply taken
    // that answers one of them as well may have been theirs: then this
    // request's own reply is owed, and may come with the next one (for that
    // next exchange only; a device that answers twice is still caught).
    owed_.reset();
    if (!r.frame.empty()) {
      if (auto n = whole_frame(r.frame); n && *n == r.frame.size())
        for (const auto& u : unanswered_)
          if (answers(u.request, r.frame)) owed_ = Unanswered{adu, t0};
      unanswered_.clear();
    }
    else unanswered_.push_back({adu, t0});
    if (unanswered_.size() > kUnansweredKept) unanswered_.pop_front();
    if (rr.closed) {
      if (serial_) throw std::runtime_error(fmt::format("target '{}': the serial line closed", info_.uri));
      r.closed = r.frame.empty();
      close(fd_);
      fd_ = -1;
    }
    decode_rtu_reply(r, slave);
    if (r.pdu && timed) window_.record(r.latency, !r.pdu->empty() && ((*r.pdu)[0] & 0x80), line_time(adu.size(), r.frame.size()));
    return r;
  }

  struct Unanswered;

  // Strips the adapter's echo of `adu` from the front of the frame read;
  // whether it did. A frame that is the request alone is the device's reply
  // where a reply may equal its request (FC 05, 06, 08, 22: MBAP v1.1b3 §6.5,
  // §6.6, §6.8, §6.16), unless echo=1.
  bool strip_echo(const Bytes& adu, Reply& r) {
    const bool starts = r.frame.size() >= adu.size() && std::equal(adu.begin(), adu.end(), r.frame.begin());
    if (!starts) return false;
    const uint8_t fc = adu.size() > 1 ? adu[1] : 0;
    const bool may_equal = fc == 0x05 || fc == 0x06 || fc == 0x08 || fc == 0x16;
    // Found by itself, a frame that is the request alone is an echo only
    // where no reply could be the request: FC 05/06/08/22 need echo=1.
    if (r.frame.size() == adu.size() && may_equal && echo_ == Echo::automatic) return false;
    r.frame.erase(r.frame.begin(), r.frame.begin() + ptrdiff_t(adu.size()));
    r.echo_bytes = adu.size();
    return true;
  }

  // Bytes in front of a reply that are no frame (line noise between frames,
  // a frame cut short): what read_frame took in before the reply is kept as
  // noise when the rest is a whole frame, CRC right, that answers `adu`, and
  // the bytes in front are no frame of their own (MB-SL v1.02 §2.5.1.1: t3.5
  // of silence ends a frame, so bytes before one belong to no reply; a USB
  // adapter may hand both over in one batch, so the silence itself is not
  // required).
  static void split_noise(const Bytes& adu, Reply& r) {
    if (r.frame.size() <= kShortestReply || whole_frame(r.frame) == r.frame.size()) return;
    for (size_t k = 1; k + kShortestReply <= r.frame.size(); ++k) {
      auto rest = std::span<const uint8_t>(r.frame).subspan(k);
      auto front = std::span<const uint8_t>(r.frame).first(k);
      // Noise is no frame: not one ending in its CRC (an echo with echo=0, a reply sent twice), nor one in front.
      if (k >= kRtuAddress + 1 + kRtuCrc && (crc_ok(front) || whole_frame(front))) break;
      if (whole_frame(rest) == rest.size() && answers(adu, rest)) {
        r.noise.assign(r.frame.begin(), r.frame.begin() + ptrdiff_t(k));
        r.frame.erase(r.frame.begin(), r.frame.begin() + ptrdiff_t(k));
        return;
      }
    }
  }

  // rs485=kernel: the driver switches the transceiver (TIOCSRS485, through
  // libmodbus); rts=up|down: libmodbus raises (or lowers) RTS to send,
  // waiting rts_delay=US before and after. For adapters without automatic
  // direction control (docs in conformance/targets/README.md).
  void set_direction_control(const Uri& u) {
    if (auto k = u.param("rs485")) {
      if (modbus_rtu_set_serial_mode(ctx_, MODBUS_RTU_RS485) == -1)
        throw std::runtime_error(fmt::format("target '{}': rs485=kernel: the driver of {} does not take TIOCSRS485 ({}); "
                                             "use rts=up if the adapter's direction follows RTS",
                                             uri_text_, u.path, modbus_strerror(errno)));
    }
    if (auto r = u.param("rts")) {
      if (modbus_rtu_set_rts(ctx_, *r == "up" ? MODBUS_RTU_RTS_UP : MODBUS_RTU_RTS_DOWN) == -1)
        throw std::runtime_error(fmt::format("target '{}': rts={}: {}", uri_text_, *r, modbus_strerror(errno)));
      if (u.param("rts_delay")) modbus_rtu_set_rts_delay(ctx_, int_param(u, uri_text_, "rts_delay", 0, 0, 100000));
    }
  }

  // Whether `reply` (a whole ADU) answers the request `req` (as framed) as
  // the standard says (judge_reply): from the same slave id, or for a
  // broadcast from 0 or, with `any_slave`, from any (a device that wrongly
  // answers one may give its own id).
  static bool answers(std::span<const uint8_t> req, std::span<const uint8_t> reply, bool any_slave = false) {
    auto pdu = [](std::span<const uint8_t> a) { return kRtu.pdu_bytes(a); };
    return req.size() >= kRtuAddress + 1 + kRtuCrc && reply.size() >= kRtuAddress + 1 + kRtuCrc &&
           (req[0] == reply[0] || (req[0] == 0 && any_slave)) && judge_reply(pdu(req), pdu(reply)).ok();
  }

  // The request among those that went unanswered since the last reply that
  // `reply` (a whole ADU, CRC right) answers; it and those before it are
  // forgotten (replies come in order). `any_slave`: as answers(); only
  // before the next request went out, where a reply from the unit cannot be
  // that request's own, malformed.
  std::optional<Unanswered> answered_by(std::span<const uint8_t> reply, bool any_slave) {
    for (size_t i = 0; i < unanswered_.size(); ++i)
      if (answers(unanswered_[i].request, reply, any_slave)) {
        Unanswered u = unanswered_[i];
        unanswered_.erase(unanswered_.begin(), unanswered_.begin() + ptrdiff_t(i + 1));
        return u;
      }
    return std::nullopt;
  }

  // The length of the whole ADU, CRC right, at the front of `bytes`, if any.
  static std::optional<size_t> whole_frame(std::span<const uint8_t> bytes) {
    auto n = rtu_adu_length(bytes, Direction::reply);
    if (!n || *n > bytes.size() || !crc_ok(bytes.first(*n))) return std::nullopt;
    return n;
  }

  // The length of the frame at the front of `frame` when it is a late reply
  // (`which`) and does not answer `request` (else it is taken as request's
  // own, as before); else 0. Late: it answers one of the requests that went
  // unanswered since the last reply (answered_by), or the one owed (owed_:
  // the last reply taken answered an earlier request too, so that request's
  // own came after it, here after the next request went out).
  size_t late_reply_at_front(const Bytes& frame, const Bytes& request, Unanswered& which) {
    if (unanswered_.empty() && !owed_) return 0;
    auto n = whole_frame(frame);
    if (!n) return 0;
    auto reply = std::span(frame).first(*n);
    if (answers(request, reply)) return 0;
    if (auto u = answered_by(reply, false)) which = *u;
    else if (owed_ && answers(owed_->request, reply)) which = *std::exchange(owed_, std::nullopt);
    else return 0;
    return *n;
  }

  // Two whole frames read at once (a USB adapter hands its buffer over in
  // chunks; a busy host reads late), the second answering `request`: replies
  // come in order, so the first is a late reply, to one of the requests left
  // unanswered or the one owed (owed_), and the second is this request's
  // own. With nothing unanswered or owed it stays: a device that answered
  // twice (trailing bytes).
  void take_late_front(const Bytes& request, Reply& r) {
    auto n = whole_frame(r.frame);
    if (!n || *n == r.frame.size()) return;
    auto rest = std::span<const uint8_t>(r.frame).subspan(*n);
    auto m = whole_frame(rest);
    if (!m || !answers(request, rest.first(*m))) return;
    Bytes first(r.frame.begin(), r.frame.begin() + ptrdiff_t(*n));
    if (auto u = answered_by(first, false)) count_late(*u, std::move(first), r);
    else if (owed_) count_late(*std::exchange(owed_, std::nullopt), std::move(first), r);
    else return;
    r.frame.erase(r.frame.begin(), r.frame.begin() + ptrdiff_t(*n));
  }

  // A late frame whose request is not known: it widens the window (by `seen`
  // when known) and is handed to the caller without a request.
  void count_late_unknown(Bytes frame, std::optional<microseconds> seen, Reply& r) {
    window_.late_reply(seen);
    r.late.push_back({std::move(frame), {}, microseconds(0)});
  }

  // A late reply to `which`: it widens the window past the time it took,
  // so that the runner's re-run of the cases judged since sees it in time,
  // and is handed to the caller with its request: one to a frame that had
  // to stay silent (broadcast, another slave id, a corrupted frame) is the
  // device's fault (MB-SL v1.02 §2.1, §2.4.2), not only its pace.
  void count_late(const Unanswered& which, Bytes frame, Reply& r) {
    auto seen = std::chrono::duration_cast<microseconds>(Clock::now() - which.sent);
    window_.late_reply(seen);
    r.late.push_back({std::move(frame), which.request, seen});
  }

  // Bytes that came after their window closed, found before the next
  // request goes out: each whole frame that answers one of the requests
  // left unanswered is that one's late reply; what is left belongs to the
  // last exchange judged silent at the latest, so took at most this long.
  void take_late(const Bytes& waiting, Reply& r) {
    std::span<const uint8_t> rest(waiting);
    while (!rest.empty()) {
      auto n = whole_frame(rest);
      std::optional<Unanswered> which;
      if (n) which = answered_by(rest.first(*n), true);
      if (!which) break;
      count_late(*which, Bytes(rest.begin(), rest.begin() + ptrdiff_t(*n)), r);
      rest = rest.subspan(*n);
    }
    if (rest.empty()) return;
    std::optional<microseconds> seen;
    if (silent_at_) seen = std::chrono::duration_cast<microseconds>(Clock::now() - *silent_at_);
    count_late_unknown(Bytes(rest.begin(), rest.end()), seen, r);
  }

  // The line time of an exchange at the line's baud: each frame's characters
  // and the t3.5 before it (MB-SL v1.02 §2.5.1.1); zero without a baud.
  microseconds line_time(size_t request, size_t reply) const {
    if (!info_.baud) return microseconds(0);
    return wire_time(request + reply, *info_.baud) + 2 * frame_gap_;
  }

  TargetInfo info_;
  std::string uri_text_;
  bool serial_ = false;
  modbus_t* ctx_ = nullptr;
  int fd_ = -1;
  std::string host_;
  uint16_t port_ = 0;
  SilenceWindow window_;
  milliseconds timeout_{kDefaultTimeout};
  microseconds frame_gap_{0}, end_silence_{0}, split_gap_{0};
  enum class Echo { off, on, automatic } echo_ = Echo::off;
  bool gap_fixed_ = false;  // the user set `gap=`: kept as given
  std::optional<microseconds> split_set_;  // set_split_gap's
  microseconds last_line_{0};  // the line time the last window was computed for
  std::optional<Clock::time_point> silent_at_;  // when the request of the last silent exchange went out
  // Requests to this unit that went unanswered since the last reply, and when each went out.
  struct Unanswered {
    Bytes request;
    Clock::time_point sent;
  };
  std::deque<Unanswered> unanswered_;
  // The request of the last exchange when the reply it took answered an
  // earlier, unanswered request too: its own reply may follow.
  std::optional<Unanswered> owed_;
  Wait wait_ = Wait::automatic;
};

}  // namespace

std::unique_ptr<Target> make_rtu_target(const Uri& u) { return std::make_unique<RtuTarget>(u); }

}  // namespace mbc::conf
