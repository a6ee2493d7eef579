#include "targets/live_link.h"

#include <fmt/core.h>
#include <poll.h>
#include <sys/socket.h>
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <charconv>
#include <cstring>
#include <stdexcept>

#include "targets/percentile.h"

namespace mbc::conf::live {

int int_param(const Uri& u, const std::string& uri, const std::string& key, int fallback, int lo, int hi) {
  auto v = u.param(key);
  if (!v) return fallback;
  int n = 0;
  auto [end, ec] = std::from_chars(v->data(), v->data() + v->size(), n);
  if (ec != std::errc{} || end != v->data() + v->size() || n < lo || n > hi)
    throw std::invalid_argument(fmt::format("target '{}': {}={}: expected an integer {}..{}", uri, key, *v, lo, hi));
  return n;
}

void check_params(const Uri& u, const std::string& uri, std::initializer_list<const char*> known) {
  for (const auto& param : u.query) {
    const std::string& k = param.first;  // not a structured binding: clang < 16 cannot capture one in a lambda
    if (std::none_of(known.begin(), known.end(), [&](const char* n) { return k == n; })) {
      std::string list;
      for (const char* n : known) list += std::string(list.empty() ? "" : ", ") + n;
      throw std::invalid_argument(fmt::format("target '{}': unknown parameter '{}' (known: {})", uri, k, list));
    }
  }
}

// ---- silence window ----

SilenceWindow::SilenceWindow(milliseconds timeout, bool line_model, std::optional<milliseconds> fixed, microseconds frame_gap)
    : timeout_(timeout), line_model_(line_model), frame_gap_(frame_gap), fixed_(fixed) {}

void SilenceWindow::Estimate::record(microseconds latency) {
  ring[count % kMaxSamples] = latency.count();
  ++count;
  size_t n = std::min(count, kMaxSamples);
  if (n < kMinSamples) return;
  std::vector<int64_t> v(ring.begin(), ring.begin() + ptrdiff_t(n));
  p99 = microseconds(percentile(std::span(v), 99));
}

void SilenceWindow::record(microseconds latency, bool exception, microseconds line) {
  // A reply faster than the line time (a pty or gateway that does not pace) has no excess.
  (exception ? exception_ : normal_).record(std::max(latency - line, microseconds(0)));
}

std::optional<microseconds> SilenceWindow::p99() const {
  if (!normal_.p99) return exception_.p99;
  if (!exception_.p99) return normal_.p99;
  return std::max(*normal_.p99, *exception_.p99);
}

void SilenceWindow::late_reply(std::optional<microseconds> seen) {
  ++late_;
  if (seen) late_floor_ = std::max(late_floor_, 2 * *seen);
  else widen_ = std::min(widen_ * 2, 1 << 10);
}

std::optional<microseconds> SilenceWindow::margin() const {
  auto p = p99();
  if (!p || !line_model_) return std::nullopt;
  microseconds floor = samples() >= kTrustedSamples ? std::max<microseconds>(frame_gap_, microseconds(1)) : kLineFloor;
  return std::max<microseconds>(kExcessMultiple * *p, floor);
}

microseconds SilenceWindow::window(microseconds line) const {
  if (fixed_) return *fixed_;
  auto p = p99();
  if (!p) return timeout_;
  microseconds w = line_model_ ? line + *margin() : std::max<microseconds>(kLatencyMultiple * *p, kFloor);
  return std::min(std::max(w * widen_, late_floor_), timeout_);
}

// ---- byte streams ----

ReadResult read_frame(int fd, std::vector<uint8_t>& buf, Clock::time_point first_byte_by, microseconds end_silence,
                      Clock::time_point hard_deadline, const std::function<bool(std::span<const uint8_t>)>& complete,
                      std::vector<Reply::Arrival>* arrivals) {
  ReadResult r;
  r.last_byte = Clock::now();
  while (buf.empty() || !complete(buf)) {
    Clock::time_point until = buf.empty() ? first_byte_by : r.last_byte + end_silence;
    until = std::min(until, hard_deadline);
    auto left = std::chrono::duration_cast<microseconds>(until - Clock::now());
    if (left.count() <= 0) break;
    pollfd p{fd, POLLIN, 0};
    timespec ts{time_t(left.count() / 1000000), long(left.count() % 1000000) * 1000};
    int rc = ppoll(&p, 1, &ts, nullptr);
    if (rc < 0) {
      if (errno == EINTR) continue;
      throw std::runtime_error(fmt::format("poll: {}", std::strerror(errno)));
    }
    if (rc == 0) break;  // silence
    uint8_t chunk[512];
    ssize_t n = read(fd, chunk, sizeof chunk);
    if (n < 0) {
      if (errno == EINTR || errno == EAGAIN) continue;
      r.closed = true;  // ECONNRESET, EIO (a pty whose other side went away)
      break;
    }
    if (n == 0) {
      r.closed = true;
      break;
    }
    buf.insert(buf.end(), chunk, chunk + n);
    r.last_byte = Clock::now();
    if (arrivals) arrivals->push_back({r.last_byte, size_t(n)});
  }
  return r;
}

size_t drain(int fd, std::vector<uint8_t>* kept) {
  size_t total = 0;
  for (;;) {
    pollfd p{fd, POLLIN, 0};
    if (poll(&p, 1, 0) <= 0 || !(p.revents & POLLIN)) return total;
    uint8_t chunk[512];
    ssize_t n = read(fd, chunk, sizeof chunk);
    if (n <= 0) return total;
    total += size_t(n);
    if (kept) kept->insert(kept->end(), chunk, chunk + n);
  }
}

void write_all(int fd, std::span<const uint8_t> bytes, const std::string& what) {
  size_t at = 0;
  while (at < bytes.size()) {
    // MSG_NOSIGNAL: a peer that closed the socket is an error here, not a SIGPIPE.
    ssize_t n = send(fd, bytes.data() + at, bytes.size() - at, MSG_NOSIGNAL);
    if (n < 0 && errno == ENOTSOCK) n = write(fd, bytes.data() + at, bytes.size() - at);
    if (n < 0) {
      if (errno == EINTR) continue;
      if (errno == EAGAIN) {
        pollfd p{fd, POLLOUT, 0};
        poll(&p, 1, 100);
        continue;
      }
      throw std::runtime_error(fmt::format("{}: write: {}", what, std::strerror(errno)));
    }
    at += size_t(n);
  }
}

}  // namespace mbc::conf::live
