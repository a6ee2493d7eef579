#include "client/server.h"

#include <arpa/inet.h>
#include <fcntl.h>
#include <netinet/in.h>
#include <netinet/tcp.h>
#include <sys/socket.h>
#include <sys/stat.h>
#include <termios.h>
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <cstring>
#include <stdexcept>

#include "client/model.h"
#include "modbus/framing.h"
#include "modbus/mbap.h"
#include "modbus/rtu.h"
#include "modbus/function_codes.h"
#include "modbus/pdu.h"
#include "serve/endpoint.h"

namespace mbc::client {
namespace {

using std::chrono::microseconds;
using std::chrono::milliseconds;

using serve::set_nonblocking;  // and close-on-exec

// The bytes a faulty reply carries in place of the right ones.
constexpr uint8_t kNoise[] = {0xFF, 0x00, 0xF0};
constexpr milliseconds kSecondReply{20};  // wrong transaction / unit: the right reply follows
constexpr milliseconds kSplitGap{30};
constexpr milliseconds kLateBy{200};
// RTU over TCP has no timing; a frame whose length the function code does not
// tell ends after this much quiet (the pty uses t3.5).
constexpr milliseconds kStreamQuiet{50};

}  // namespace


ScenarioServer::ScenarioServer(Transport t, std::string pty_path, int baud)
    : transport_(t), pty_path_(std::move(pty_path)), baud_(baud) {
  if (t == Transport::pty) {
    serve::RawPty p = serve::open_raw_pty(pty_path_);
    pty_master_ = p.master;
    pty_slave_ = p.slave;
    return;
  }
  serve::TcpListener l = serve::listen_tcp(to_string(t), "127.0.0.1", 0, 4);
  listen_fd_ = l.fd;
  port_ = l.port;
}

ScenarioServer::~ScenarioServer() {
  for (int fd : {listen_fd_, conn_fd_, pty_master_, pty_slave_})
    if (fd >= 0) ::close(fd);
  if (!pty_path_.empty()) ::unlink(pty_path_.c_str());
}

void ScenarioServer::set_step(int index, const ScenarioStep* step, milliseconds master_timeout) {
  step_index_ = index;
  step_ = step;
  master_timeout_ = master_timeout;
  answered_in_step_ = 0;
}

void ScenarioServer::clear() {
  requests_.clear();
  sent_.clear();
}

void ScenarioServer::drop_connection() {
  if (conn_fd_ >= 0) ::close(conn_fd_);
  conn_fd_ = -1;
  pending_.clear();
  buf_.clear();
  arrivals_.clear();
  // A closed serial port keeps nothing: what is still queued on the pty, in
  // either direction, belongs to no one now.
  if (pty_slave_ >= 0) tcflush(pty_slave_, TCIOFLUSH);
}

int ScenarioServer::data_fd() const { return transport_ == Transport::pty ? pty_master_ : conn_fd_; }

void ScenarioServer::fill_poll(std::vector<pollfd>& fds) const {
  if (listen_fd_ >= 0) fds.push_back({listen_fd_, POLLIN, 0});
  if (data_fd() >= 0) fds.push_back({data_fd(), POLLIN, 0});
}

void ScenarioServer::on_poll(const std::vector<pollfd>& fds) {
  for (const auto& p : fds) {
    if (!p.revents) continue;
    if (p.fd == listen_fd_) accept_one();
    else if (p.fd == data_fd()) read_some();
  }
}

void ScenarioServer::accept_one() {
  int fd = accept4(listen_fd_, nullptr, nullptr, SOCK_NONBLOCK | SOCK_CLOEXEC);
  if (fd < 0) return;
  drop_connection();  // one master at a time: a new connection replaces the old one
  int one = 1;
  setsockopt(fd, IPPROTO_TCP, TCP_NODELAY, &one, sizeof one);
  conn_fd_ = fd;
}

void ScenarioServer::read_some() {
  uint8_t chunk[1024];
  for (;;) {
    ssize_t n = ::read(data_fd(), chunk, sizeof chunk);
    if (n > 0) {
      auto now = Clock::now();
      buf_.insert(buf_.end(), chunk, chunk + n);
      arrivals_.insert(arrivals_.end(), size_t(n), now);
      continue;
    }
    if (n == 0 && transport_ != Transport::pty) {  // the master closed the connection
      ::close(conn_fd_);
      conn_fd_ = -1;
    }
    break;  // EAGAIN, EIO (no one has the pty open), or closed
  }
  take_frames(false);
}

std::optional<Clock::time_point> ScenarioServer::next_due() const {
  std::optional<Clock::time_point> due;
  for (const auto& p : pending_)
    if (!due || p.due < *due) due = p.due;
  if (!buf_.empty()) {
    auto at = arrivals_.back() + quiet();
    if (!due || at < *due) due = at;
  }
  return due;
}

microseconds ScenarioServer::quiet() const {
  return transport_ == Transport::pty ? std::max<microseconds>(frame_gap(baud_), milliseconds(5)) : kStreamQuiet;
}

void ScenarioServer::on_time() {
  auto now = Clock::now();
  std::vector<Pending> due, later;
  for (auto& p : pending_) (p.due <= now ? due : later).push_back(std::move(p));
  pending_ = std::move(later);
  std::stable_sort(due.begin(), due.end(), [](const Pending& a, const Pending& b) { return a.due < b.due; });
  for (const auto& p : due) send_now(p);
  if (!buf_.empty()) {
    if (now - arrivals_.back() >= quiet()) take_frames(true);
  }
}

// Splits buf_ into request frames: MBAP by its length field, RTU by the
// length its function code implies, or (gap_seen) whatever came before a silence.
void ScenarioServer::take_frames(bool gap_seen) {
  while (!buf_.empty()) {
    std::optional<size_t> len;
    if (transport_ != Transport::tcp) len = rtu_adu_length(buf_, Direction::request);
    else if (auto h = parse_mbap(buf_)) len = h->adu_size();
    size_t take = 0;
    if (len && *len <= buf_.size()) take = *len;
    else if (gap_seen) take = buf_.size();
    else return;
    SeenRequest r;
    r.adu.assign(buf_.begin(), buf_.begin() + ptrdiff_t(take));
    r.first = arrivals_.front();
    r.last = arrivals_[take - 1];
    for (size_t i = 1; i < take; ++i)
      r.max_gap = std::max(r.max_gap, std::chrono::duration_cast<microseconds>(arrivals_[i] - arrivals_[i - 1]));
    if (any_traffic_) r.gap_before = std::chrono::duration_cast<microseconds>(r.first - last_traffic_);
    r.step = step_index_;
    buf_.erase(buf_.begin(), buf_.begin() + ptrdiff_t(take));
    arrivals_.erase(arrivals_.begin(), arrivals_.begin() + ptrdiff_t(take));
    last_traffic_ = r.last;
    any_traffic_ = true;
    requests_.push_back(r);
    answer(requests_.back());
  }
}

Bytes ScenarioServer::frame_reply(uint8_t unit, uint16_t transaction, const Bytes& pdu) const {
  return (transport_ == Transport::tcp ? kTcp : kRtu).frame(unit, pdu, transaction);
}

void ScenarioServer::schedule(microseconds after, Bytes bytes, std::string what) {
  pending_.push_back({Clock::now() + after, std::move(bytes), std::move(what)});
}

void ScenarioServer::send_now(const Pending& p) {
  int fd = data_fd();
  if (fd < 0) return;
  size_t off = 0;
  while (off < p.bytes.size()) {
    ssize_t n = ::write(fd, p.bytes.data() + off, p.bytes.size() - off);
    if (n > 0) off += size_t(n);
    else if (n < 0 && errno == EAGAIN) {
      pollfd w{fd, POLLOUT, 0};
      ::poll(&w, 1, 100);
    } else {
      break;
    }
  }
  last_traffic_ = Clock::now();
  any_traffic_ = true;
  sent_.push_back({p.bytes, last_traffic_, p.what});
}

// The step's fault applies to the first request of the step; any later one
// (a retry the library was asked not to make) gets the correct reply.
void ScenarioServer::answer(const SeenRequest& seen) {
  const Framing& f = transport_ == Transport::tcp ? kTcp : kRtu;
  Unframed u = f.unframe(seen.adu);
  if (u.pdu.empty()) return;  // nothing a server could answer
  ParsedRequest pr = parse_request(u.pdu);
  Fault fault = step_ && answered_in_step_ == 0 ? step_->fault : Fault::none;
  ++answered_in_step_;
  if (!u.ok() && f.checksum_length) return;  // a bad CRC: a serial device stays silent (MB-SL v1.02 §2.4.2)
  if (!pr.request) {
    schedule(microseconds(0), frame_reply(u.unit, u.transaction, exception_reply(u.pdu[0], ex::illegal_data_value)),
             "exception 03 (request not decoded)");
    return;
  }
  const Request& req = *pr.request;
  if (u.unit == 0 && f.checksum_length) return;  // a broadcast is never answered (MB-SL v1.02 §2.1)
  if (!pr.problems.empty() && fault == Fault::none) fault = Fault::exception;
  Bytes right = model::reply_to(req);
  auto put = [&](microseconds after, Bytes adu, const char* what) { schedule(after, std::move(adu), what); };
  uint8_t code = step_ && step_->code ? step_->code : ex::illegal_data_value;
  switch (fault) {
    case Fault::none: put(microseconds(0), frame_reply(u.unit, u.transaction, right), "reply"); break;
    case Fault::exception:
      put(microseconds(0), frame_reply(u.unit, u.transaction, exception_reply(req.function, code)), "exception reply");
      break;
    case Fault::wrong_transaction:
      put(microseconds(0), frame_reply(u.unit, uint16_t(u.transaction + 1), model::reply_to(req, true)),
          "reply with another transaction id, other values");
      put(kSecondReply, frame_reply(u.unit, u.transaction, right), "the right reply");
      break;
    case Fault::wrong_unit:
      put(microseconds(0), frame_reply(uint8_t(u.unit + 1), u.transaction, model::reply_to(req, true)),
          "reply from another unit, other values");
      put(kSecondReply, frame_reply(u.unit, u.transaction, right), "the right reply");
      break;
    case Fault::wrong_function: {
      Request other = req;
      other.function = fc::read_input_registers;
      put(microseconds(0), frame_reply(u.unit, u.transaction, model::reply_to(other, true)), "FC 04 reply");
      break;
    }
    case Fault::bad_crc: {
      Bytes adu = frame_reply(u.unit, u.transaction, right);
      adu[adu.size() - 1] ^= 0xFF;
      adu[adu.size() - 2] ^= 0xFF;
      put(microseconds(0), adu, "reply with a bad CRC");
      break;
    }
    case Fault::truncated: {
      Bytes adu = frame_reply(u.unit, u.transaction, right);
      adu.resize(adu.size() / 2);
      put(microseconds(0), adu, "first half of the reply");
      break;
    }
    case Fault::trailing_bytes: {
      Bytes pdu = right;
      pdu.push_back(0x00);
      pdu.push_back(0x00);
      put(microseconds(0), frame_reply(u.unit, u.transaction, pdu), "reply with two trailing bytes");
      break;
    }
    case Fault::byte_count:
    case Fault::too_many: {
      Request other = req;
      other.quantity = uint16_t(req.quantity + (fault == Fault::too_many ? 1 : -1));
      put(microseconds(0), frame_reply(u.unit, u.transaction, model::reply_to(other)),
          fault == Fault::too_many ? "one register more" : "one register short");
      break;
    }
    case Fault::split: {
      Bytes adu = frame_reply(u.unit, u.transaction, right);
      size_t a = adu.size() / 3, b = 2 * adu.size() / 3;
      put(microseconds(0), Bytes(adu.begin(), adu.begin() + ptrdiff_t(a)), "reply, piece 1/3");
      put(kSplitGap, Bytes(adu.begin() + ptrdiff_t(a), adu.begin() + ptrdiff_t(b)), "reply, piece 2/3");
      put(2 * kSplitGap, Bytes(adu.begin() + ptrdiff_t(b), adu.end()), "reply, piece 3/3");
      break;
    }
    case Fault::late:
      put(master_timeout_ + kLateBy, frame_reply(u.unit, u.transaction, model::reply_to(req, true)),
          "late reply, other values");
      break;
    case Fault::silence: break;
    case Fault::garbage_first: {
      put(microseconds(0), Bytes(std::begin(kNoise), std::end(kNoise)), "line noise");
      auto gap = std::max<microseconds>(4 * frame_gap(baud_), milliseconds(10));
      put(gap, frame_reply(u.unit, u.transaction, right), "the right reply");
      break;
    }
  }
}

}  // namespace mbc::client
