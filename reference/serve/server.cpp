#include "serve/server.h"

#include <arpa/inet.h>
#include <fcntl.h>
#include <netdb.h>
#include <netinet/in.h>
#include <netinet/tcp.h>
#include <poll.h>

#include <type_traits>
#include <pty.h>
#include <termios.h>
#include <signal.h>
#include <sys/epoll.h>
#include <sys/inotify.h>
#include <sys/prctl.h>
#include <sys/resource.h>
#include <sys/signalfd.h>
#include <sys/socket.h>
#include <sys/stat.h>
#include <time.h>
#include <termios.h>
#include <unistd.h>

#include <array>
#include <cerrno>
#include <chrono>
#include <csignal>
#include <cstdio>
#include <cstring>
#include <deque>
#include <filesystem>
#include <stdexcept>

#include <fmt/core.h>

#include "modbus/crc16.h"
#include "modbus/mbap.h"
#include "modbus/rtu.h"
#include "serve/eeprom_store.h"
#include "serve/endpoint.h"
#include "serve/trace.h"

namespace mbc::serve {

using Clock = std::chrono::steady_clock;
using std::chrono::duration_cast;
using std::chrono::microseconds;
using std::chrono::milliseconds;


Endpoint parse_endpoint(Transport t, const std::string& text) {
  Endpoint e;
  e.transport = t;
  if (t == Transport::pty) {
    if (text.empty()) throw std::invalid_argument("--pty needs a path");
    e.path = text;
    return e;
  }
  std::string host, port = text;
  if (!text.empty() && text.front() == '[') {  // [v6]:PORT
    auto close = text.find("]:");
    if (close == std::string::npos) throw std::invalid_argument("'" + text + "': expected [HOST]:PORT");
    host = text.substr(1, close - 1);
    port = text.substr(close + 2);
  } else if (auto colon = text.rfind(':'); colon != std::string::npos) {
    host = text.substr(0, colon);
    port = text.substr(colon + 1);
  }
  if (!host.empty()) e.host = host;
  if (port.empty() || port.size() > 5 || port.find_first_not_of("0123456789") != std::string::npos ||
      std::stoul(port) > 65535)
    throw std::invalid_argument("'" + text + "': expected [HOST:]PORT with PORT 0..65535");
  e.port = uint16_t(std::stoul(port));
  return e;
}

DeviceArg parse_device_arg(const std::string& text) {
  DeviceArg d;
  auto at = text.find('@');
  d.id = text.substr(0, at);
  if (d.id.empty()) throw std::invalid_argument("'" + text + "': expected ID[@SLAVE]");
  if (at != std::string::npos) {
    std::string s = text.substr(at + 1);
    // MB-SL v1.02 §2.2: individual slave addresses are 1..247.
    if (s.empty() || s.size() > 3 || s.find_first_not_of("0123456789") != std::string::npos || std::stoi(s) < 1 ||
        std::stoi(s) > 247)
      throw std::invalid_argument("'" + text + "': the slave id must be 1..247");
    d.slave = uint8_t(std::stoi(s));
  }
  return d;
}

namespace {

// A master may hand RTU-over-TCP bytes to the network in more than one
// segment; a frame whose length the function code does not settle is taken
// complete after this much silence (t3.5 at serial rates is too short for TCP).
constexpr milliseconds kTcpFrameGap{10};
// The loop wakes at least this often so the virtual clock drives the axes.
constexpr milliseconds kMaxSleep{50};
// Bytes of a TCP connection's input held at once: what the kernel holds
// beyond it is read once frames have been consumed (a client streaming
// requests is served at the rate it reads, and the buffer never grows).
constexpr size_t kInputBound = 16 * 1024;
// Reply bytes queued for one connection: past it, nothing more is read from
// that client until it reads its replies (or goes idle and is dropped).
constexpr size_t kOutputBound = 64 * 1024;
// Output buffer capacity a connection keeps once its replies are all sent:
// a batch of ordinary replies fits; a backlog's growth is given back.
constexpr size_t kKeptOutput = 16 * 1024;
// After accept fails for want of descriptors (EMFILE, ENFILE), listeners rest
// this long instead of waking the loop for the same failure again.
constexpr milliseconds kAcceptBackoff{100};
// Bytes read from one connection in one poll round, on every transport: a
// client that streams cannot keep the loop from the others (nor from a stop
// signal).
constexpr size_t kReadPerRound = 16 * 1024;
// Descriptors kept free beside the connections: listeners, ptys, stdio, the
// EEPROM files written while serving.
constexpr size_t kSpareDescriptors = 16;

[[noreturn]] void fail(const std::string& what) {
  throw std::runtime_error(fmt::format("{}: {}", what, std::strerror(errno)));
}

// A paced reply (--line-rate) held in a link's output until its line time
// has passed; it and everything queued after it wait.
struct Held {
  size_t begin;  // where the reply starts in Link::out
  Clock::time_point not_before;
};

// One byte stream carrying frames: an accepted TCP connection or a pty master.
struct Link {
  Link(int fd, Transport t, std::string name) : fd(fd), transport(t), name(std::move(name)) {}

  int fd = -1;
  Transport transport = Transport::tcp;
  std::string name;  // "tcp 127.0.0.1:40112", for the trace
  Bytes in;
  size_t overflow = 0;  // bytes past kMaxRtuAdu in the current RTU frame
  Clock::time_point last_rx;
  // The modelled line (--line): when the request's last character has been
  // clocked in, whether a silence over t1.5 split it, and until when the
  // master-ward direction is busy (echo, noise, reply).
  Clock::time_point wire_end{};
  bool gapped = false;
  Clock::time_point tx_end{};
  // An RTU frame past kMaxRtuAdu is noise until the line falls silent (MB-SL
  // v1.02 §2.5.1.1): such a stream is read once per frame gap, so a client
  // flooding bytes costs bounded time, not the loop's every round.
  Clock::time_point rest_until{};
  // Replies in order, the first out_sent of them sent: every reply a batch
  // of requests produced leaves in one send.
  Bytes out;
  size_t out_sent = 0;
  std::deque<Held> held;  // paced replies not yet due, in `out` order
  bool closed = false;
  bool eof = false;       // the peer shut its side: answer what came, then close
  bool write_blocked = false;  // the last send said EAGAIN: wait for EPOLLOUT, never retry in a loop
  bool registered = false;     // with the loop's epoll set
  uint32_t armed = 0;          // the events it is registered for
  std::optional<std::string> role;  // a TLS client's role, when a roles file decides (tls_door.h)

  bool rtu() const { return transport != Transport::tcp; }
  bool socket() const { return transport != Transport::pty; }
  size_t out_bytes() const { return out.size() - out_sent; }
  // Its replies pile up unread: consume and read nothing more for now.
  bool backed_up() const { return out_bytes() >= kOutputBound; }
  // The end of the bytes that may be sent now: up to the first held reply
  // still short of its time (the ones past it are released).
  size_t due_end(Clock::time_point now) {
    while (!held.empty() && held.front().not_before <= now) held.pop_front();
    return held.empty() ? out.size() : held.front().begin;
  }
  bool has_due(Clock::time_point now) { return out_sent < due_end(now); }
  // Sent bytes are dropped when all are out, or once they are most of the
  // buffer (a client that reads slowly but never catches up). A buffer a
  // backlog grew is given back once drained: thousands of connections must
  // not each keep the memory of their worst moment.
  void drop_sent() {
    if (out_sent == out.size()) {
      out.clear();
      out_sent = 0;
      if (out.capacity() > kKeptOutput) out.shrink_to_fit();
    } else if (out_sent >= 4096 && out_sent * 2 >= out.size()) {
      out.erase(out.begin(), out.begin() + ptrdiff_t(out_sent));
      for (auto& h : held) h.begin -= out_sent;
      out_sent = 0;
    }
  }
  bool wants_input(Clock::time_point now) const {
    return !eof && !backed_up() && now >= rest_until && (rtu() || in.size() < kInputBound);
  }
};

struct Listener {
  int fd = -1;
  Transport transport = Transport::tcp;
};

struct PtyEndpoint {
  int slave = -1;  // kept open so the master never sees a hang-up between clients
  std::string link_path;
  std::string device_path;
  // The line as serve opened it (raw), put back when the last client closes
  // the pty: the next one finds it as the first did (clients_closed()).
  termios initial{};
  int watch = -1;   // its inotify watch (opens and closes of device_path), or -1
  int clients = 0;  // opens of the slave by clients not yet closed
  bool watch_closed = false;  // a close seen in the events being read
};

}  // namespace

struct Server::Impl {
  faults::FaultyBus bus;  // the correct devices when opt.faults is empty
  Bytes reply_buf;         // every reply is made here first (answer_into)
  Options opt;
  std::vector<Listener> listeners;
  std::unique_ptr<TlsDoor> tls_door;  // --tls: its wake_fd() is polled as a listener
  std::vector<PtyEndpoint> ptys;
  std::vector<Link> links;
  std::vector<std::string> listening;  // "listening ..." lines, in endpoint order
  std::vector<StoredImage> saved;      // per device: the image last written to disk
  Clock::time_point clock_at;          // the bus clock stands at this real time
  int stop_fd = -1;                    // SIGINT and SIGTERM, read as a descriptor (signalfd)
  int pty_watch_fd = -1;               // inotify: clients opening and closing the served ptys
  bool stopping = false;
  Clock::time_point accept_resume;     // listeners rest until then after EMFILE
  size_t max_links = 0;                // opt.max_connections, lowered to what RLIMIT_NOFILE leaves room for
  std::unique_ptr<PcapTrace> pcap;     // --pcap

  Impl(ref::Bus b, Options o) : bus(std::move(b), o.faults), opt(std::move(o)) {
    if (!opt.pcap.empty()) pcap = std::make_unique<PcapTrace>(opt.pcap);
  }

  ~Impl() {
    if (epfd >= 0) ::close(epfd);
    if (stop_fd >= 0) ::close(stop_fd);
    if (pty_watch_fd >= 0) ::close(pty_watch_fd);
    for (auto& l : listeners) ::close(l.fd);
    for (auto& l : links)
      if (!l.closed) ::close(l.fd);
    for (auto& p : ptys) {
      std::error_code ec;
      if (std::filesystem::read_symlink(p.link_path, ec) == p.device_path) std::filesystem::remove(p.link_path, ec);
      ::close(p.slave);
    }
  }

  // ---- EEPROM ----

  std::string eeprom_path(const ref::Device& d) const { return eeprom_file(opt.eeprom_dir, d.spec().device.id, d.slave_id()); }

  void restore_eeprom() {
    if (opt.eeprom_dir.empty()) return;
    std::filesystem::create_directories(opt.eeprom_dir);
    for (auto& d : bus.devices()) {
      if (auto image = load_eeprom(eeprom_path(*d))) {
        d->load_stored_image(*image);
        d->power_cycle();  // persistent registers come back from the stored image
      }
      saved.push_back(d->stored_image());
    }
  }

  // Writes the images that changed since the last save (or all of them).
  void save_eeprom_images(bool all) {
    if (opt.eeprom_dir.empty()) return;
    auto& devices = bus.devices();
    for (size_t i = 0; i < devices.size(); ++i) {
      const auto& d = *devices[i];
      if (!all && d.stored_image() == saved[i]) continue;
      save_eeprom(eeprom_path(d), d.spec().device.id, d.slave_id(), d.stored_image());
      saved[i] = d.stored_image();
    }
  }

  // ---- endpoints ----

  static size_t open_descriptors() {
    std::error_code ec;
    size_t n = 0;
    for (auto it = std::filesystem::directory_iterator("/proc/self/fd", ec); !ec && it != std::filesystem::directory_iterator();
         it.increment(ec))
      ++n;
    return n ? n : 64;  // no /proc: assume a few dozen
  }

  void open_socket(const Endpoint& e) {
    TcpListener l = listen_tcp(to_string(e.transport), e.host, e.port);
    listeners.push_back({l.fd, e.transport});
    listening.push_back(fmt::format("listening {} {}", to_string(e.transport), l.bound));
  }

  void open_pty(const Endpoint& e) {
    RawPty p = open_raw_pty(e.path);
    PtyEndpoint pe{p.slave, e.path, p.name};  // ~Impl closes the slave and removes the link
    tcgetattr(p.slave, &pe.initial);
    // A client's termios outlives it on a pty (serve holds the slave), and
    // Linux's pty driver drops PARENB: a client that asks 9600-8E1 of a pty
    // the last one left at 9600-8E1 changes nothing the kernel keeps, and
    // glibc's tcsetattr then reports the parity it did not get as EINVAL.
    // So the line is put back as opened when its last client closes
    // (SIGKILL too), seen through inotify.
    if (pty_watch_fd < 0) pty_watch_fd = inotify_init1(IN_NONBLOCK | IN_CLOEXEC);
    if (pty_watch_fd >= 0) pe.watch = inotify_add_watch(pty_watch_fd, p.name.c_str(), IN_OPEN | IN_CLOSE);
    if (pe.watch < 0)
      std::fputs(fmt::format("pty {}: cannot watch its clients ({}): a client reopening it at a parity may get EINVAL\n",
                             e.path, std::strerror(errno)).c_str(), stderr);
    ptys.push_back(std::move(pe));
    links.emplace_back(p.master, Transport::pty, "pty " + e.path);
    listening.push_back(fmt::format("listening pty {}", e.path));
  }

  // Clients opened and closed served ptys: a pty none holds open any more
  // gets the termios it was opened with. The events are counted first, so a
  // client that opened it meanwhile keeps what it set.
  void pty_clients_changed() {
    alignas(inotify_event) char buf[4096];
    for (ssize_t n; (n = ::read(pty_watch_fd, buf, sizeof buf)) > 0;)
      for (char* at = buf; at < buf + n;) {
        const auto* ev = reinterpret_cast<const inotify_event*>(at);
        at += sizeof(inotify_event) + ev->len;
        for (auto& p : ptys) {
          if (p.watch != ev->wd) continue;
          if (ev->mask & IN_OPEN) ++p.clients;
          if ((ev->mask & IN_CLOSE) && p.clients > 0) --p.clients;
          if (ev->mask & IN_CLOSE) p.watch_closed = true;
        }
      }
    for (auto& p : ptys) {
      if (p.watch_closed && p.clients == 0) tcsetattr(p.slave, TCSANOW, &p.initial);
      p.watch_closed = false;
    }
  }

  void open_tls(const Endpoint& e) {
    if (!tls_door) {
      tls_door = std::make_unique<TlsDoor>(opt.tls);
      listeners.push_back({tls_door->wake_fd(), Transport::tls});
    }
    listening.push_back(tls_door->listen(e.host, e.port));
  }

  // TLS connections the door let in become Modbus TCP links.
  void adopt_tls(Clock::time_point now) {
    for (auto& a : tls_door->take()) {
      Link l(a.fd, Transport::tcp, a.name);
      l.role = a.role;
      l.last_rx = now;
      if (opt.trace) std::fputs((trace_time() + l.name + " connected\n").c_str(), stderr);
      links.push_back(std::move(l));
    }
  }

  void open() {
    // Stop signals stay blocked (in every thread started after this) and
    // arrive as a descriptor the loop waits on beside the sockets: one that
    // comes between two waits is never lost, and no wait swaps the signal
    // mask (a mask handed to each wait cost every wake-up a pass through the
    // kernel's signal code). A peer that closed must not kill us.
    sigset_t stop;
    sigemptyset(&stop);
    sigaddset(&stop, SIGINT);
    sigaddset(&stop, SIGTERM);
    sigprocmask(SIG_BLOCK, &stop, nullptr);
    stop_fd = signalfd(-1, &stop, SFD_NONBLOCK | SFD_CLOEXEC);
    if (stop_fd < 0) fail("signalfd");
    std::signal(SIGPIPE, SIG_IGN);
    // Room for the connection cap: the soft descriptor limit (often 1024)
    // raised toward the hard one. A lower hard limit stays as it is; EMFILE
    // is then handled by backing off (accept_all).
    rlimit nofile{};
    if (getrlimit(RLIMIT_NOFILE, &nofile) == 0 && nofile.rlim_cur != RLIM_INFINITY) {
      rlim_t want = rlim_t(opt.max_connections) + 64;
      if (nofile.rlim_cur < want) {
        nofile.rlim_cur = nofile.rlim_max == RLIM_INFINITY ? want : std::min(want, nofile.rlim_max);
        setrlimit(RLIMIT_NOFILE, &nofile);
      }
    }

    for (const auto& e : opt.endpoints) {
      if (e.transport == Transport::pty)
        open_pty(e);
      else if (e.transport == Transport::tls)
        open_tls(e);
      else
        open_socket(e);
    }
    // The cap the descriptors allow: eviction of the connection unused the
    // longest must happen before accept runs out of descriptors, or no
    // newcomer is ever served once idle connections fill the table.
    max_links = opt.max_connections;
    if (getrlimit(RLIMIT_NOFILE, &nofile) == 0 && nofile.rlim_cur != RLIM_INFINITY) {
      size_t in_use = open_descriptors();
      size_t room = nofile.rlim_cur > in_use + kSpareDescriptors ? size_t(nofile.rlim_cur) - in_use - kSpareDescriptors : 1;
      if (!max_links || room < max_links) max_links = room;
    }
    if (tls_door) tls_door->start();  // its thread inherits the blocked stop signals
    if (!opt.quiet)
      for (const auto& line : listening) std::fputs((line + "\n").c_str(), stdout);
    std::fflush(stdout);
  }

  // ---- frames ----

  // `what` is built only when tracing: decoding every frame for nobody cost
  // a tenth of a one-client exchange.
  template <class What>
  void trace(const Link& l, const char* dir, std::span<const uint8_t> bytes, What&& describe) {
    if (pcap && !bytes.empty()) pcap->frame(l.fd, !l.rtu(), l.name, dir[0] == 't', bytes);
    if (!opt.trace) return;
    std::string what;
    if constexpr (std::is_invocable_v<What>) what = describe();
    else what = std::string(describe);
    std::string line = bytes.empty() ? fmt::format("{}{} {} {}\n", trace_time(), l.name, dir, what)
                                     : fmt::format("{}{} {} {} | {}\n", trace_time(), l.name, dir, to_hex(bytes), what);
    std::fputs(line.c_str(), stderr);
  }

  // The engine's reply leaves after the line time a real RS-485 bus would
  // take: a pty or socket delivers the request at once, where a line would
  // still be clocking it in, so both frames' characters count, plus the
  // inter-frame gap after the reply (MB-SL §2.5.1.1). The time runs from the
  // request's end (its last bytes plus the gap that ends it, found by
  // silence), not from when this loop woke to see it: a late wake-up is not
  // line time, and must not be paid twice.
  // The reply is l.out from `begin` on.
  void pace_reply(Link& l, size_t request_bytes, size_t begin, Clock::time_point now) {
    if (!l.rtu() || !opt.line_rate) return;
    Clock::time_point at = std::min(now, l.last_rx + rtu_gap(l)) +
                           wire_time(request_bytes + (l.out.size() - begin), *opt.line_rate) + frame_gap(*opt.line_rate);
    if (at > now) l.held.push_back({begin, at});
  }

  // A reference device that fails internally (a bug, or a state only an
  // injected fault reaches) drops that one frame, says why on stderr, and
  // the server goes on serving every other client.
  // The reply `handle` writes into the server's one reply buffer (the
  // engine's *_into calls: nothing allocated per reply), or none. A device
  // that throws costs its frame, not the server.
  template <class F>
  std::optional<std::span<const uint8_t>> answer_into(Link& l, F&& handle) {
    if (reply_buf.empty()) reply_buf.resize(std::max<size_t>(bus.max_reply_pdu() + kRtuAddress + kRtuCrc, 1024));
    try {
      size_t n = handle(std::span<uint8_t>(reply_buf));
      if (n == 0) return std::nullopt;
      return std::span<const uint8_t>(reply_buf.data(), n);
    } catch (const std::exception& e) {
      std::fputs(fmt::format("{} !! device error, frame dropped: {}\n", l.name, e.what()).c_str(), stderr);
      return std::nullopt;
    }
  }

  // The format the master set on a served pty (its baud rate, read from the
  // pty's termios; the rest as the line's: a pty does not carry them), when
  // the line is modelled and the master's rate differs from it.
  std::optional<LineFormat> master_line(const Link& l) const {
    if (!opt.line || l.transport != Transport::pty) return std::nullopt;
    termios t{};
    if (tcgetattr(l.fd, &t) != 0) return std::nullopt;
    int baud = baud_of_speed(unsigned(cfgetispeed(&t)));
    if (baud == 0 || baud == opt.line->baud) return std::nullopt;
    LineFormat m = *opt.line;
    m.baud = baud;
    return m;
  }

  void handle_rtu_frame(Link& l, Clock::time_point now) {
    if (l.overflow) {
      trace(l, "rx", l.in, [&] { return fmt::format("dropped: {} bytes, over the {}-byte RTU limit", l.in.size() + l.overflow, kMaxRtuAdu); });
    } else {
      // A master at another baud rate than the served line's: what the
      // line's UART makes of its characters (uart.h), both ways.
      std::optional<LineFormat> master = master_line(l);
      if (master) {
        Bytes sent = l.in;
        l.in = resample(sent, *master, *opt.line);
        trace(l, "~~", {}, [&] {
          return fmt::format("{} bytes sent at {} baud to a {} line, read as {} bytes", sent.size(), master->baud, opt.line->text(), l.in.size());
        });
      }
      // MB-SL v1.02 §2.5.1.1: a frame with a silence over t1.5 inside it
      // is incomplete and is discarded.
      if (l.gapped && !opt.behaviour.has(LineFault::keep_gapped_request)) {
        trace(l, "rx", l.in, "dropped: a silence over t1.5 inside the frame");
        l.in.clear();
        l.gapped = false;
        return;
      }
      trace(l, "rx", l.in, [&] { return describe_rtu(l.in, Direction::request); });
      auto reply = answer_into(l, [&](std::span<uint8_t> out) { return bus.handle_rtu_into(l.in, out); });
      if (reply) {
        trace(l, "tx", *reply, [&] { return describe_rtu(*reply, Direction::reply); });
        size_t begin = l.out.size();
        Bytes heard;
        if (master) heard = resample(*reply, *opt.line, *master);
        std::span<const uint8_t> out = master ? std::span<const uint8_t>(heard) : *reply;
        if (modelled(l)) {
          send_reply_on_line(l, out);
        } else {
          l.out.insert(l.out.end(), out.begin(), out.end());
          pace_reply(l, l.in.size(), begin, now);
        }
      } else {
        trace(l, "--", {}, "no reply");
      }
    }
    l.in.clear();
    l.overflow = 0;
    l.gapped = false;
  }

  // Modbus TCP: frames are delimited by the MBAP length, never by timing.
  // Consumed frames are erased once at the end (linear in the input), and
  // consuming stops while the client leaves its replies unread.
  void handle_mbap_frames(Link& l, Clock::time_point now) {
    size_t at = 0;
    while (!l.backed_up()) {
      std::span<const uint8_t> rest(l.in.data() + at, l.in.size() - at);
      auto h = parse_mbap(rest);
      if (!h) break;
      if (!h->length_ok()) {  // the stream cannot be re-synchronised: drop the connection
        trace(l, "rx", rest, [&] { return fmt::format("MBAP length {} out of 2..254: closing", h->length); });
        l.closed = true;
        return;
      }
      if (rest.size() < h->adu_size()) break;
      std::span<const uint8_t> adu = rest.first(h->adu_size());
      auto pdu = adu.subspan(kMbapHeader);
      auto head = [&] { return fmt::format("tid {} unit {} ", h->transaction, h->unit); };
      if (h->protocol != 0) {  // MB TCP §3.1.3: protocol 0 is Modbus; anything else is not ours
        trace(l, "rx", adu, [&] { return fmt::format("{}protocol {}: not Modbus, ignored", head(), h->protocol); });
      } else {
        trace(l, "rx", adu, [&] { return head() + describe_pdu(pdu, Direction::request); });
        std::string refused;
        if (l.role && tls_door) refused = tls_door->refusal(*l.role, pdu);
        if (!refused.empty()) trace(l, "!!", {}, [&] { return refused; });
        // MB-TCP-Security v2.1 §8.3: a request the role may not make is
        // refused with exception 01 (Illegal Function).
        auto reply = answer_into(l, [&](std::span<uint8_t> out) -> size_t {
          if (refused.empty()) return bus.handle_pdu_into(h->unit, pdu, out);
          out[0] = uint8_t(pdu[0] | 0x80);
          out[1] = 0x01;
          return 2;
        });
        if (reply) {
          size_t begin = l.out.size();
          append_mbap_reply(l.out, *h, *reply);
          trace(l, "tx", std::span<const uint8_t>(l.out).subspan(begin),
                [&] { return head() + describe_pdu(*reply, Direction::reply); });
        } else {
          trace(l, "--", {}, "no reply");
        }
      }
      at += h->adu_size();
    }
    l.in.erase(l.in.begin(), l.in.begin() + ptrdiff_t(at));
  }

  // The line is modelled on this link: bytes take their character time (--line).
  bool modelled(const Link& l) const { return opt.line && l.transport == Transport::pty; }

  // When a byte whose last bit arrives at `t` reaches the master: then, or
  // when the master's USB adapter's latency timer next runs out.
  Clock::time_point delivered(Clock::time_point t) const {
    const auto tick = duration_cast<Clock::duration>(opt.behaviour.latency_timer);
    if (tick.count() <= 0) return t;
    auto since = t.time_since_epoch();
    return Clock::time_point(((since + tick - Clock::duration(1)) / tick) * tick);
  }

  // Queues `bytes` for the master on a modelled line, the first starting on
  // the wire at `start` (or when the line is free), each released when its
  // last bit has arrived. Returns when the last one ends.
  Clock::time_point send_paced(Link& l, std::span<const uint8_t> bytes, Clock::time_point start) {
    const microseconds c = opt.line->char_time();
    Clock::time_point t = std::max(start, l.tx_end);
    size_t begin = l.out.size();
    l.out.insert(l.out.end(), bytes.begin(), bytes.end());
    for (size_t k = 0; k < bytes.size(); ++k) {
      t += c;
      l.held.push_back({begin + k, delivered(t)});
    }
    l.tx_end = t;
    return t;
  }

  // A reply on a modelled line: t3.5 after the request ended (one character
  // time with early-reply), plus the turnaround delay; noise first with
  // line-noise; a silence between t1.5 and t3.5 halfway with reply-gap.
  void send_reply_on_line(Link& l, std::span<const uint8_t> reply) {
    const LineFormat& f = *opt.line;
    const LineBehaviour& b = opt.behaviour;
    Clock::time_point start = l.wire_end + (b.has(LineFault::early_reply) ? f.char_time() : f.t35()) + b.turnaround;
    if (b.has(LineFault::line_noise)) {
      static constexpr uint8_t kNoise[] = {0x00, 0xFF, 0x5A};
      start = send_paced(l, kNoise, start) + f.t35();
    }
    if (b.has(LineFault::reply_gap) && reply.size() >= 2) {
      size_t half = reply.size() / 2;
      Clock::time_point end = send_paced(l, reply.first(half), start);
      send_paced(l, reply.subspan(half), end + (f.t15() + f.t35()) / 2);
      return;
    }
    send_paced(l, reply, start);
  }

  microseconds rtu_gap(const Link& l) const {
    if (modelled(l)) return opt.line->t35();
    microseconds gap = frame_gap(opt.baud);
    return l.transport == Transport::rtu_tcp ? std::max<microseconds>(gap, kTcpFrameGap) : gap;
  }

  // An RTU frame is complete after t3.5 of silence; on TCP also as soon as
  // the bytes form exactly the request the function code announces.
  bool rtu_frame_complete(const Link& l, Clock::time_point now) const {
    if (l.in.empty() && !l.overflow) return false;
    if (now - l.last_rx >= rtu_gap(l)) return true;
    // early-reply: the device takes a request whose length and CRC are
    // whole as soon as its last character is in.
    if (modelled(l) && opt.behaviour.has(LineFault::early_reply) && !l.overflow && now >= l.wire_end)
      return rtu_adu_complete(l.in, Direction::request);
    if (l.transport != Transport::rtu_tcp || l.overflow) return false;
    return rtu_adu_complete(l.in, Direction::request);
  }

  // Answers the link's complete frames; false when there were none.
  bool answer(Link& l, Clock::time_point now) {
    if (l.rtu()) {
      if (!rtu_frame_complete(l, now)) return false;
      handle_rtu_frame(l, now);
      return true;
    }
    if (l.in.empty()) return false;
    handle_mbap_frames(l, now);
    return true;
  }

  // Frames the wake-ups did not answer: RTU frames ended by silence, MBAP
  // frames left while a client's replies piled up.
  void process_input(Clock::time_point now) {
    bool handled = false;
    for (auto& l : links)
      if (!l.closed) handled |= answer(l, now);
    if (handled) save_changed_images();
  }

  void save_changed_images() {
    try {
      save_eeprom_images(false);
    } catch (const std::exception& e) {  // keep serving; the shutdown save reports again
      std::fprintf(stderr, "mbconform serve: %s\n", e.what());
    }
  }

  // ---- I/O ----

  void read_link(Link& l, Clock::time_point now) {
    uint8_t buf[4096];
    for (size_t budget = kReadPerRound; budget > 0 && l.wants_input(now);) {
      size_t room = std::min(budget, l.rtu() ? sizeof buf : std::min(sizeof buf, kInputBound - l.in.size()));
      ssize_t n = ::read(l.fd, buf, room);
      if (n > 0) {
        // Bytes after a silence of t3.5 start a new frame (MB-SL v1.02
        // §2.5.1.1): the one before is complete even if no wake-up saw the gap.
        if (l.rtu() && rtu_frame_complete(l, now) && now - l.last_rx >= rtu_gap(l)) {
          handle_rtu_frame(l, now);
          save_changed_images();
        }
        // A 2-wire adapter on the master's side hears its own request as it
        // goes out: the master reads it back first (serve --echo).
        if (modelled(l)) {
          // The line clocks the bytes in one character time each, after
          // what it still carries; a silence over t1.5 splits the frame.
          const Clock::time_point start = std::max(now, l.wire_end);
          if (!l.in.empty() && start - l.wire_end > opt.line->t15()) l.gapped = true;
          if (opt.echo) send_paced(l, std::span<const uint8_t>(buf, size_t(n)), start);
          l.wire_end = start + opt.line->char_time() * n;
          l.last_rx = l.wire_end;
        } else {
          if (opt.echo && l.transport == Transport::pty) l.out.insert(l.out.end(), buf, buf + n);
          l.last_rx = now;
        }
        budget -= size_t(n);
        size_t keep = size_t(n);
        if (l.rtu()) {
          keep = std::min(keep, kMaxRtuAdu - std::min(kMaxRtuAdu, l.in.size()));
          l.overflow += size_t(n) - keep;
        }
        l.in.insert(l.in.end(), buf, buf + keep);
        if (l.overflow) {
          l.rest_until = now + rtu_gap(l);
          return;
        }
        // A short read drained what the kernel held; poll is level-triggered
        // and reports anything newer, so skip the read that would say EAGAIN
        // (one syscall per request, a fifth of a one-client exchange).
        if (size_t(n) < room) return;
        continue;
      }
      if (n < 0 && errno == EINTR) continue;
      if (n < 0 && (errno == EAGAIN || errno == EWOULDBLOCK)) return;
      // An error on a pty master (EIO) means no client: wait for the next.
      if (!l.socket()) return;
      // 0: the peer shut its sending side (maybe only that: a half-closed
      // socket still gets the replies to what it sent); an error: gone.
      if (n == 0) l.eof = true;
      else l.closed = true;
      return;
    }
  }

  // Everything due in one send (a partial one is followed by the send that
  // says EAGAIN).
  void write_link(Link& l, Clock::time_point now) {
    if (l.write_blocked || l.out_sent == l.out.size()) return;  // blocked: until the loop sees EPOLLOUT
    for (size_t end = l.due_end(now); l.out_sent < end;) {
      const uint8_t* p = l.out.data() + l.out_sent;
      ssize_t n = l.socket() ? ::send(l.fd, p, end - l.out_sent, MSG_NOSIGNAL) : ::write(l.fd, p, end - l.out_sent);
      if (n < 0) {
        if (errno == EINTR) continue;
        if (errno == EAGAIN || errno == EWOULDBLOCK) {
          l.write_blocked = true;
          break;
        }
        if (l.socket()) l.closed = true;
        l.out.clear();  // pty without a reader: the reply is lost, as on a bus nobody listens to
        l.out_sent = 0;
        l.held.clear();
        return;
      }
      l.out_sent += size_t(n);
    }
    l.drop_sent();
  }

  size_t socket_links() const {
    size_t n = 0;
    for (const auto& l : links) n += l.socket() && !l.closed;
    return n;
  }

  // At the cap, the connection unused the longest makes room (Implementation
  // Guide V1.0b §4.2.1.2: "the oldest unused connection is closed").
  void make_room() {
    Link* oldest = nullptr;
    for (auto& l : links)
      if (l.socket() && !l.closed && (!oldest || l.last_rx < oldest->last_rx)) oldest = &l;
    if (!oldest) return;
    if (opt.trace) std::fputs((trace_time() + oldest->name + " closed: connection cap, unused the longest\n").c_str(), stderr);
    oldest->closed = true;
    // Its descriptor comes free now, for the newcomer of this same burst of accepts.
    if (pcap) pcap->closed(oldest->fd);
    ::close(oldest->fd);
    oldest->fd = -1;
  }

  void accept_all(const Listener& s, Clock::time_point now) {
    if (s.transport == Transport::tls) return adopt_tls(now);
    for (;;) {
      sockaddr_storage ss{};
      socklen_t len = sizeof ss;
      int fd = accept4(s.fd, reinterpret_cast<sockaddr*>(&ss), &len, SOCK_NONBLOCK | SOCK_CLOEXEC);
      if (fd < 0) {
        // Out of descriptors: the pending connection stays queued and poll
        // would report it at once, forever. Rest the listeners a while.
        if (errno == EMFILE || errno == ENFILE || errno == ENOBUFS || errno == ENOMEM) {
          accept_resume = now + kAcceptBackoff;
          if (opt.trace) std::fprintf(stderr, "accept: %s: not accepting for %lld ms\n", std::strerror(errno),
                                      (long long)kAcceptBackoff.count());
        }
        return;  // EAGAIN, or an aborted connection
      }
      if (max_links && socket_links() >= max_links) make_room();
      int one = 1;
      setsockopt(fd, IPPROTO_TCP, TCP_NODELAY, &one, sizeof one);  // replies are small and wanted now
      setsockopt(fd, SOL_SOCKET, SO_KEEPALIVE, &one, sizeof one);  // Guide §4.3.2: find peers that vanished
      Link l(fd, s.transport, fmt::format("{} {}", to_string(s.transport), sockaddr_text(ss)));
      l.last_rx = now;
      if (opt.trace) std::fputs((trace_time() + l.name + " connected\n").c_str(), stderr);
      links.push_back(std::move(l));
    }
  }

  // A half-closed peer whose replies are out, and a connection idle past the
  // timeout, are closed.
  void retire_links(Clock::time_point now) {
    for (auto& l : links) {
      if (l.closed || !l.socket()) continue;
      if (l.eof && l.out_bytes() == 0 && (!l.rtu() || l.in.empty())) l.closed = true;
      if (opt.idle_timeout_s > 0 && now - l.last_rx >= std::chrono::seconds(opt.idle_timeout_s)) {
        if (opt.trace) std::fputs((trace_time() + l.name + " closed: idle\n").c_str(), stderr);
        l.closed = true;
      }
    }
  }

  void drop_closed_links() {
    std::erase_if(links, [&](Link& l) {
      if (!l.closed) return false;
      if (opt.trace) std::fputs((trace_time() + l.name + " closed\n").c_str(), stderr);
      if (l.fd >= 0) {
        if (pcap) pcap->closed(l.fd);
        ::close(l.fd);
      }
      return true;
    });
  }

  // How long until something is due: an RTU gap ending or a paced reply. To
  // the microsecond: a wait rounded up to whole milliseconds cost up to a
  // millisecond twice per exchange, a third of the exchange at 115200 baud.
  timespec poll_timeout(Clock::time_point now) const {
    Clock::time_point wake = now + kMaxSleep;
    for (const auto& l : links) {
      if (l.rtu() && (!l.in.empty() || l.overflow)) wake = std::min(wake, l.last_rx + rtu_gap(l));
      if (modelled(l) && opt.behaviour.has(LineFault::early_reply) && !l.in.empty() && l.wire_end > now)
        wake = std::min(wake, l.wire_end);
      if (l.rest_until > now) wake = std::min(wake, l.rest_until);
      // A reply already due waits for EPOLLOUT, not for a timer: a client that
      // does not read must not turn the loop into a busy one.
      if (!l.held.empty() && l.held.front().not_before > now) wake = std::min(wake, l.held.front().not_before);
    }
    auto us = std::max<int64_t>(0, duration_cast<microseconds>(wake - now).count());
    return timespec{time_t(us / 1000000), long(us % 1000000) * 1000L};
  }

  void advance_clock(Clock::time_point now) {
    auto dt = duration_cast<microseconds>(now - clock_at);
    if (dt.count() <= 0) return;
    bus.advance(uint64_t(dt.count()));
    clock_at += dt;
  }

  // ---- readiness ----
  // epoll, level-triggered: a round costs the connections that are ready,
  // not every connection (1000 idle ones made each poll() round scan them
  // all). A listener's key is kListenerKey | its index; the stop signals',
  // kStopKey; a link's, its fd, mapped to its index by `slot` (rebuilt as
  // interest is updated).
  static constexpr uint64_t kListenerKey = uint64_t(1) << 32;
  static constexpr uint64_t kStopKey = uint64_t(1) << 33;
  static constexpr uint64_t kPtyWatchKey = uint64_t(1) << 34;
  int epfd = -1;
  std::vector<epoll_event> ready = std::vector<epoll_event>(256);
  std::vector<size_t> slot;  // fd -> index in links
  bool listeners_armed = false;

  void watch(int fd, uint64_t key, uint32_t events, bool add) {
    epoll_event e{};
    e.events = events;
    e.data.u64 = key;
    if (epoll_ctl(epfd, add ? EPOLL_CTL_ADD : EPOLL_CTL_MOD, fd, &e) != 0) fail("epoll_ctl");
  }

  // Registers each link for what it wants now (input while it may read, the
  // socket's room while a reply is due), listeners unless they rest.
  void update_interest(Clock::time_point now) {
    if (epfd < 0) {
      epfd = epoll_create1(EPOLL_CLOEXEC);
      if (epfd < 0) fail("epoll_create1");
      for (size_t i = 0; i < listeners.size(); ++i) watch(listeners[i].fd, kListenerKey | i, 0, true);
      watch(stop_fd, kStopKey, EPOLLIN, true);
      if (pty_watch_fd >= 0) watch(pty_watch_fd, kPtyWatchKey, EPOLLIN, true);
    }
    bool accepting = now >= accept_resume;
    if (accepting != listeners_armed) {
      for (size_t i = 0; i < listeners.size(); ++i) watch(listeners[i].fd, kListenerKey | i, accepting ? uint32_t(EPOLLIN) : 0u, false);
      listeners_armed = accepting;
    }
    for (size_t k = 0; k < links.size(); ++k) {
      Link& l = links[k];
      bool due = l.has_due(now);
      uint32_t want = (l.wants_input(now) ? uint32_t(EPOLLIN) : 0u) | (due ? uint32_t(EPOLLOUT) : 0u);
      if (!l.registered || want != l.armed) {
        watch(l.fd, uint64_t(l.fd), want, !l.registered);
        l.registered = true;
        l.armed = want;
      }
      if (size_t(l.fd) >= slot.size()) slot.resize(size_t(l.fd) + 1);
      slot[size_t(l.fd)] = k;
    }
  }

  // How late this host's timers fire. clock_getres says 1 ns with
  // high-resolution timers, a tick (4 ms at HZ=250) on a kernel or virtual
  // machine without them; timer slack, a busy host or a hypervisor add their
  // own. A paced line (--line, --line-rate) cannot wait on a timer that late
  // for characters of a millisecond: it wakes early by the most its recent
  // timed waits were late (at least the resolution) and polls to the
  // deadline, spending CPU only while a paced reply is going out.
  microseconds timer_resolution = [] {
    timespec res{};
    if (clock_getres(CLOCK_MONOTONIC, &res) != 0) return microseconds(0);
    return duration_cast<microseconds>(std::chrono::seconds(res.tv_sec) + std::chrono::nanoseconds(res.tv_nsec));
  }();
  static constexpr size_t kLateWindow = 32;
  static constexpr microseconds kMostEarly{5000};  // a host later than this is too busy to pace a line
  std::array<microseconds, kLateWindow> late_seen{};
  size_t late_at = 0;
  bool have_epoll_pwait2 = true;

  microseconds wake_early() const {
    if (!opt.line && !opt.line_rate) return microseconds(0);
    microseconds most = timer_resolution > microseconds(20) ? timer_resolution : microseconds(0);
    for (auto l : late_seen) most = std::max(most, l);
    return std::min(most, kMostEarly);
  }

  // Waits until something is ready, a timer is due or a stop signal came.
  int wait_ready(Clock::time_point now) {
    timespec ts = poll_timeout(now);
    const microseconds early = wake_early();
    int64_t us = int64_t(ts.tv_sec) * 1000000 + ts.tv_nsec / 1000;
    if (early.count() > 0) {
      us = std::max<int64_t>(0, us - early.count());
      ts = timespec{time_t(us / 1000000), long(us % 1000000) * 1000L};
    }
    int rc = epoll_or_ppoll(ts);
    if (rc == 0 && us > 0 && (opt.line || opt.line_rate)) {
      auto late = duration_cast<microseconds>(Clock::now() - (now + microseconds(us)));
      late_seen[late_at++ % kLateWindow] = std::max(microseconds(0), late);
    }
    return rc;
  }

  int epoll_or_ppoll(const timespec& ts) {
    if (have_epoll_pwait2) {
      int rc = epoll_pwait2(epfd, ready.data(), int(ready.size()), &ts, nullptr);
      if (rc >= 0 || errno != ENOSYS) return rc;
      have_epoll_pwait2 = false;  // a kernel before 5.11, or a seccomp profile that predates it
    }
    // ppoll waits to the nanosecond on the epoll set (readable when an event
    // is ready); epoll_wait then collects without waiting. epoll_wait's own
    // timeout is in whole milliseconds: a millisecond late twice per exchange.
    pollfd p{epfd, POLLIN, 0};
    int rc = ppoll(&p, 1, &ts, nullptr);
    if (rc <= 0) return rc;
    return epoll_wait(epfd, ready.data(), int(ready.size()), 0);
  }

  int run() {
    // Paced replies and RTU gaps are timers of a few hundred microseconds; the
    // default 50 us of timer slack would be added to each.
    if (opt.line_rate || opt.line) prctl(PR_SET_TIMERSLACK, 1000UL);
    Clock::time_point now = clock_at = Clock::now();
    while (!stopping) {
      process_input(now);
      for (auto& l : links)
        if (!l.closed) write_link(l, now);
      retire_links(now);
      drop_closed_links();

      update_interest(now);
      int rc = wait_ready(now);
      if (rc < 0 && errno != EINTR) fail("epoll_wait");
      // One reading of the clock per round, after the wait: what the round
      // does next takes microseconds.
      now = Clock::now();
      // Paced replies that fell due go out before the clock's and the
      // frames' work, which is no line time.
      for (auto& l : links)
        if (!l.closed && !l.held.empty()) write_link(l, now);
      // A request read below meets the devices at this time, not at the last round's.
      advance_clock(now);
      bool answered = false;
      // accept_all appends links (registered next round) and may close one
      // for a newcomer, whose descriptor a newcomer may reuse at once: a
      // ready link is the one `slot` named when interest was updated.
      const size_t polled = links.size();
      for (int e = 0; e < std::max(rc, 0); ++e) {
        const uint64_t key = ready[size_t(e)].data.u64;
        const uint32_t ev = ready[size_t(e)].events;
        if (key == kStopKey) {
          stopping = true;
          continue;
        }
        if (key == kPtyWatchKey) {
          pty_clients_changed();
          continue;
        }
        if (key & kListenerKey) {
          if (ev & EPOLLIN) accept_all(listeners[size_t(key & 0xFFFFFFFF)], now);
          continue;
        }
        size_t k = size_t(key) < slot.size() ? slot[size_t(key)] : polled;
        if (k >= polled) continue;
        Link& l = links[k];
        if (l.closed || l.fd != int(key)) continue;  // closed for a newcomer by accept_all above
        // What came is answered at once, and the replies leave in one send:
        // this client works on its next request while the loop serves the
        // others (answering after all the reads kept every client waiting
        // for the last one's).
        bool fresh = false;
        if (ev & (EPOLLIN | EPOLLHUP | EPOLLERR)) {
          read_link(l, now);
          if (!l.closed) fresh = answer(l, now);
          answered |= fresh;
        }
        if ((ev & EPOLLERR) && l.socket()) l.closed = true;
        // A hang-up or error: the next send says what happened (EPIPE closes it).
        if (ev & (EPOLLOUT | EPOLLHUP | EPOLLERR)) l.write_blocked = false;
        if (!l.closed && (fresh || (ev & EPOLLOUT))) write_link(l, now);
      }
      if (answered) save_changed_images();
    }
    save_eeprom_images(true);
    return 0;
  }
};

Server::Server(ref::Bus bus, Options options) : impl_(std::make_unique<Impl>(std::move(bus), std::move(options))) {
  impl_->restore_eeprom();
}
Server::~Server() = default;
void Server::open() { impl_->open(); }
int Server::run() { return impl_->run(); }

}  // namespace mbc::serve
