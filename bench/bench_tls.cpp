// `serve --tls` under the idle-connection attack (issue 41): a good client's
// latency beside an attacker that opens and then holds N idle TLS
// connections, against the same good client alone (the baseline of the same
// run), as ratios.
//
// Each round: (1) the good client alone: FC 03 x10 on its own TLS
// connection every 5 ms for 5 s; (2) an attacker process (source
// 127.0.0.2, as from another host) opens N mutually authenticated TLS
// connections one after another while the good client keeps asking
// ("opening"); (3) the attacker holds them, idle, for 5 s ("held"); the
// attacker then closes them. Measured per phase: the share of the good
// client's requests answered (an unanswered one counts as its 500 ms
// timeout), its p50 and p99, and serve's CPU share (/proc/PID/stat).
// Rounds are interleaved, the medians of the rounds kept.
//
// Targets (issue 41): under both phases, at least 99% answered and p99 at
// most 10 ms. A baseline whose p99 is already above 10 ms means the machine
// was too busy to measure: the run is invalid (exit 3); exit 1 when a target
// is not met.
//
// Usage (from the source root; the PKI is made with
// conformance/tests/security/make_pki.sh in a temporary directory):
//   build/bin/mbc_bench_tls [build/bin/mbconform] [--idle 1024] [--rounds 3] [--nofile 4096]
//                           [--attacker-nice N]
// --nofile: serve's RLIMIT_NOFILE (4096: the 1024 connections fit, three
// descriptors each; 1024: the least recently used makes room).
// --attacker-nice: the attacker process's nice value (default 0; on one
// machine the attacker's own handshakes take CPU a remote attacker would not).
#include <openssl/err.h>
#include <openssl/ssl.h>

#include <arpa/inet.h>
#include <netinet/in.h>
#include <netinet/tcp.h>
#include <poll.h>
#include <signal.h>
#include <sys/resource.h>
#include <sys/socket.h>
#include <sys/wait.h>
#include <unistd.h>

#include <algorithm>
#include <atomic>
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <stdexcept>
#include <string>
#include <thread>
#include <vector>

#include "targets/percentile.h"

namespace {

using Clock = std::chrono::steady_clock;
constexpr int kRegs = 10;
constexpr auto kPollPeriod = std::chrono::milliseconds(5);
constexpr auto kPollFor = std::chrono::seconds(5);
constexpr int kTimeoutMs = 500;

double seconds(Clock::time_point a, Clock::time_point b) { return std::chrono::duration<double>(b - a).count(); }

double cpu_seconds(pid_t pid) {
  FILE* f = std::fopen(("/proc/" + std::to_string(pid) + "/stat").c_str(), "r");
  if (!f) return 0;
  char buf[1024] = {};
  size_t n = std::fread(buf, 1, sizeof buf - 1, f);
  std::fclose(f);
  buf[n] = 0;
  const char* p = std::strrchr(buf, ')');
  unsigned long utime = 0, stime = 0;
  if (!p || std::sscanf(p + 2, "%*c %*d %*d %*d %*d %*d %*u %*u %*u %*u %*u %lu %lu", &utime, &stime) != 2) return 0;
  return double(utime + stime) / double(sysconf(_SC_CLK_TCK));
}

SSL_CTX* client_ctx(const std::string& pki) {
  SSL_CTX* ctx = SSL_CTX_new(TLS_client_method());
  if (!ctx || SSL_CTX_load_verify_locations(ctx, (pki + "/ca.crt").c_str(), nullptr) != 1 ||
      SSL_CTX_use_certificate_chain_file(ctx, (pki + "/operator.crt").c_str()) != 1 ||
      SSL_CTX_use_PrivateKey_file(ctx, (pki + "/operator.key").c_str(), SSL_FILETYPE_PEM) != 1)
    throw std::runtime_error("cannot load the client certificate from " + pki);
  SSL_CTX_set_verify(ctx, SSL_VERIFY_PEER, nullptr);
  return ctx;
}

struct Conn {
  int fd = -1;
  SSL* ssl = nullptr;
  void close() {
    if (ssl) SSL_free(ssl);
    if (fd >= 0) ::close(fd);
    ssl = nullptr;
    fd = -1;
  }
};

// A blocking TLS connection from `source` (127.0.0.x) with a receive timeout.
Conn tls_connect(SSL_CTX* ctx, int port, const char* source, int timeout_ms) {
  Conn c;
  c.fd = socket(AF_INET, SOCK_STREAM | SOCK_CLOEXEC, 0);
  if (c.fd < 0) return c;
  sockaddr_in a{};
  a.sin_family = AF_INET;
  inet_pton(AF_INET, source, &a.sin_addr);
  bind(c.fd, reinterpret_cast<sockaddr*>(&a), sizeof a);
  a.sin_port = htons(uint16_t(port));
  inet_pton(AF_INET, "127.0.0.1", &a.sin_addr);
  timeval tv{timeout_ms / 1000, (timeout_ms % 1000) * 1000};
  setsockopt(c.fd, SOL_SOCKET, SO_RCVTIMEO, &tv, sizeof tv);
  setsockopt(c.fd, SOL_SOCKET, SO_SNDTIMEO, &tv, sizeof tv);
  int one = 1;
  setsockopt(c.fd, IPPROTO_TCP, TCP_NODELAY, &one, sizeof one);
  if (connect(c.fd, reinterpret_cast<sockaddr*>(&a), sizeof a) != 0) {
    c.close();
    return c;
  }
  c.ssl = SSL_new(ctx);
  SSL_set_fd(c.ssl, c.fd);
  if (SSL_connect(c.ssl) != 1) {
    ERR_clear_error();
    c.close();
  }
  return c;
}

struct PollStats {
  int sent = 0, answered = 0, reconnects = 0;
  double p50_ms = 0, p99_ms = 0, cpu = 0;
  double share() const { return double(answered) / std::max(1, sent); }
};

// FC 03 x10 every kPollPeriod until `until` says stop (checked before each
// request); one TLS connection, opened again when it fails.
template <class Until>
PollStats poll_run(SSL_CTX* ctx, int port, pid_t serve, Until until) {
  PollStats st;
  Conn c = tls_connect(ctx, port, "127.0.0.1", kTimeoutMs);
  if (!c.ssl) throw std::runtime_error("the good client cannot connect");
  std::vector<double> lat;
  const double c0 = cpu_seconds(serve);
  const auto w0 = Clock::now();
  uint16_t tid = 0;
  for (auto next = Clock::now(); !until(); next += kPollPeriod) {
    std::this_thread::sleep_until(next);
    ++tid;
    const uint8_t req[] = {uint8_t(tid >> 8), uint8_t(tid), 0, 0, 0, 6, 1, 3, 0, 0, 0, kRegs};
    ++st.sent;
    auto t0 = Clock::now();
    bool ok = c.ssl && SSL_write(c.ssl, req, sizeof req) == int(sizeof req);
    uint8_t reply[9 + 2 * kRegs];
    size_t got = 0;
    while (ok) {
      int n = SSL_read(c.ssl, reply + got, int(sizeof reply - got));
      if (n <= 0) {
        ok = false;
        break;
      }
      got += size_t(n);
      if (got < sizeof reply) continue;
      if (reply[0] == req[0] && reply[1] == req[1]) break;
      got = 0;  // a late reply to a request that timed out
    }
    double ms = std::chrono::duration<double, std::milli>(Clock::now() - t0).count();
    if (ok) {
      ++st.answered;
      lat.push_back(ms);
    } else {
      lat.push_back(kTimeoutMs);
      ERR_clear_error();
      c.close();
      c = tls_connect(ctx, port, "127.0.0.1", kTimeoutMs);
      ++st.reconnects;
    }
  }
  st.cpu = (cpu_seconds(serve) - c0) / std::max(1e-9, seconds(w0, Clock::now()));
  c.close();
  if (!lat.empty()) {
    st.p50_ms = mbc::conf::percentile(std::span(lat), 50);
    st.p99_ms = mbc::conf::percentile(std::span(lat), 99);
  }
  return st;
}

PollStats poll_for(SSL_CTX* ctx, int port, pid_t serve, Clock::duration d) {
  const auto end = Clock::now() + d;
  return poll_run(ctx, port, serve, [end] { return Clock::now() >= end; });
}

// `mbconform serve --tls` under RLIMIT_NOFILE `nofile`; the port from its "listening tls" line.
struct TlsServe {
  pid_t pid = -1;
  int port = 0;
  TlsServe(const std::string& exe, const std::string& pki, rlim_t nofile) {
    int p[2];
    if (pipe(p) != 0) throw std::runtime_error("pipe failed");
    pid = fork();
    if (pid == 0) {
      dup2(p[1], 1);
      close(p[0]);
      close(p[1]);
      rlimit l{nofile, nofile};
      setrlimit(RLIMIT_NOFILE, &l);
      const std::string cert = pki + "/server.crt", key = pki + "/server.key", ca = pki + "/ca.crt";
      execl(exe.c_str(), exe.c_str(), "serve", "--device", "modbus-standard@1", "--tls", "127.0.0.1:0", "--cert",
            cert.c_str(), "--key", key.c_str(), "--ca", ca.c_str(), (char*)nullptr);
      _exit(127);
    }
    close(p[1]);
    FILE* f = fdopen(p[0], "r");
    char line[256];
    while (port == 0 && fgets(line, sizeof line, f))
      if (const char* k = std::strstr(line, "listening tls 127.0.0.1:")) port = std::atoi(k + std::strlen("listening tls 127.0.0.1:"));
    fclose(f);
    if (port == 0) {
      stop();
      throw std::runtime_error("no 'listening tls' line from " + exe);
    }
  }
  void stop() {
    if (pid > 0) {
      kill(pid, SIGTERM);
      waitpid(pid, nullptr, 0);
      pid = -1;
    }
  }
  ~TlsServe() { stop(); }
};

// The attacker: a process that opens `n` TLS connections from 127.0.0.2 one
// after another, writes "opened K SECONDS\n" to `report`, and holds them,
// idle, until SIGTERM.
pid_t attacker(const std::string& pki, int port, int n, int nice_value, int& report) {
  int p[2];
  if (pipe(p) != 0) throw std::runtime_error("pipe failed");
  pid_t pid = fork();
  if (pid == 0) {
    close(p[0]);
    if (nice_value) (void)!nice(nice_value);
    rlimit l{};
    getrlimit(RLIMIT_NOFILE, &l);
    if (l.rlim_cur < rlim_t(n) + 64 && l.rlim_max >= rlim_t(n) + 64) {
      l.rlim_cur = rlim_t(n) + 64;
      setrlimit(RLIMIT_NOFILE, &l);
    }
    SSL_CTX* ctx = client_ctx(pki);
    std::vector<Conn> held;
    auto t0 = Clock::now();
    for (int i = 0; i < n; ++i) {
      Conn c = tls_connect(ctx, port, "127.0.0.2", 5000);
      if (c.ssl) held.push_back(c);
    }
    char line[64];
    int len = std::snprintf(line, sizeof line, "opened %zu %.3f\n", held.size(), seconds(t0, Clock::now()));
    (void)!write(p[1], line, size_t(len));
    close(p[1]);
    pause();
    _exit(0);
  }
  close(p[1]);
  report = p[0];
  return pid;
}

struct Round {
  PollStats base, opening, held;
  int opened = 0;
  double open_s = 0;
};

double median(std::vector<double> v) {
  std::sort(v.begin(), v.end());
  return v.empty() ? 0 : v[v.size() / 2];
}

std::string make_pki() {
  char dir[] = "/tmp/mbc_bench_tls.XXXXXX";
  if (!mkdtemp(dir)) throw std::runtime_error("mkdtemp failed");
  const std::string script = "conformance/tests/security/make_pki.sh";
  if (!std::filesystem::exists(script)) throw std::runtime_error(script + " not found: run from the source root");
  const std::string cmd = "bash " + script + " " + std::string(dir) + "/pki >/dev/null 2>&1";
  if (std::system(cmd.c_str()) != 0) throw std::runtime_error("make_pki.sh failed");
  return std::string(dir) + "/pki";
}

void line(const char* name, const PollStats& st) {
  std::printf("  %-10s %6d %8.2f%% %9.2f %9.2f %8.0f%%\n", name, st.sent, 100 * st.share(), st.p50_ms, st.p99_ms, 100 * st.cpu);
}

}  // namespace

int main(int argc, char** argv) {
  signal(SIGPIPE, SIG_IGN);
  std::string exe = "build/bin/mbconform";
  int idle = 1024, rounds = 3, attacker_nice = 0;
  rlim_t nofile = 4096;
  for (int i = 1; i < argc; ++i) {
    std::string a = argv[i];
    auto next = [&]() -> long {
      if (i + 1 >= argc) {
        std::fprintf(stderr, "mbc_bench_tls: %s needs a value\n", a.c_str());
        std::exit(2);
      }
      return std::strtol(argv[++i], nullptr, 10);
    };
    if (a == "--idle") idle = int(std::clamp<long>(next(), 1, 100000));
    else if (a == "--rounds") rounds = int(std::clamp<long>(next(), 1, 100));
    else if (a == "--nofile") nofile = rlim_t(std::clamp<long>(next(), 64, 1 << 20));
    else if (a == "--attacker-nice") attacker_nice = int(std::clamp<long>(next(), 0, 19));
    else exe = a;
  }
  std::string pki;
  try {
    pki = make_pki();
    rlimit own{};
    getrlimit(RLIMIT_NOFILE, &own);
    SSL_CTX* ctx = client_ctx(pki);
    TlsServe serve(exe, pki, nofile);
    std::printf("mbc_bench_tls: serve --tls under RLIMIT_NOFILE %lu; good client FC03 x%d every %lld ms; attacker: %d idle TLS "
                "connections (nice %d); %d rounds\n",
                (unsigned long)nofile, kRegs, (long long)kPollPeriod.count(), idle, attacker_nice, rounds);
    std::vector<Round> all;
    for (int r = 0; r < rounds; ++r) {
      Round rd;
      rd.base = poll_for(ctx, serve.port, serve.pid, kPollFor);
      int report = -1;
      pid_t att = attacker(pki, serve.port, idle, attacker_nice, report);
      rd.opening = poll_run(ctx, serve.port, serve.pid, [report] {
        pollfd p{report, POLLIN, 0};
        return poll(&p, 1, 0) == 1;
      });
      char buf[64] = {};
      FILE* f = fdopen(report, "r");
      if (f && fgets(buf, sizeof buf, f)) std::sscanf(buf, "opened %d %lf", &rd.opened, &rd.open_s);
      if (f) fclose(f);
      rd.held = poll_for(ctx, serve.port, serve.pid, kPollFor);
      kill(att, SIGKILL);
      waitpid(att, nullptr, 0);
      std::this_thread::sleep_for(std::chrono::seconds(1));  // serve sees them go
      std::printf("round %d: %d of %d connections opened in %.1f s\n", r + 1, rd.opened, idle, rd.open_s);
      std::printf("  %-10s %6s %9s %9s %9s %9s\n", "phase", "sent", "answered", "p50 ms", "p99 ms", "serve CPU");
      line("baseline", rd.base);
      line("opening", rd.opening);
      line("held", rd.held);
      std::fflush(stdout);
      all.push_back(rd);
    }
    auto med = [&](auto get) {
      std::vector<double> v;
      for (const auto& rd : all) v.push_back(get(rd));
      return median(v);
    };
    const double base99 = med([](const Round& r) { return r.base.p99_ms; });
    const double open99 = med([](const Round& r) { return r.opening.p99_ms; });
    const double held99 = med([](const Round& r) { return r.held.p99_ms; });
    const double open_share = med([](const Round& r) { return r.opening.share(); });
    const double held_share = med([](const Round& r) { return r.held.share(); });
    std::printf("medians of %d rounds: p50 baseline %.2f, opening %.2f, held %.2f ms; p99 baseline %.2f, opening %.2f, held %.2f ms\n",
                rounds, med([](const Round& r) { return r.base.p50_ms; }), med([](const Round& r) { return r.opening.p50_ms; }),
                med([](const Round& r) { return r.held.p50_ms; }), base99, open99, held99);
    std::printf("p99 / baseline p99 (each round's own baseline, median): opening %.2f, held %.2f\n",
                med([](const Round& r) { return r.opening.p99_ms / std::max(1e-6, r.base.p99_ms); }),
                med([](const Round& r) { return r.held.p99_ms / std::max(1e-6, r.base.p99_ms); }));
    std::filesystem::remove_all(std::filesystem::path(pki).parent_path());
    if (base99 > 10) {
      std::printf("INVALID: the baseline p99 is %.2f ms, above the 10 ms target: the machine was too busy to measure\n", base99);
      return 3;
    }
    const bool met = open_share >= 0.99 && held_share >= 0.99 && open99 <= 10 && held99 <= 10;
    std::printf("targets: answered >= 99%% %s, p99 <= 10 ms while opening %s, while held %s\n",
                open_share >= 0.99 && held_share >= 0.99 ? "met" : "NOT met", open99 <= 10 ? "met" : "NOT met",
                held99 <= 10 ? "met" : "NOT met");
    return met ? 0 : 1;
  } catch (const std::exception& e) {
    if (!pki.empty()) std::filesystem::remove_all(std::filesystem::path(pki).parent_path());
    std::fprintf(stderr, "mbc_bench_tls: %s\n", e.what());
    return 2;
  }
}
