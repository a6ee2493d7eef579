// Request throughput of the reference device vs libmodbus, as ratios measured
// in the same run (absolute numbers depend on the machine).
//   1. in-process: Device::handle_pdu (FC03, 10 registers, modbus-standard)
//      vs modbus_reply on a modbus_mapping_t with an unconnected TCP context
//      (its send fails with EBADF; the decode + build work is what is timed).
//   2. TCP loopback, 1 and 16 libmodbus client threads: `mbconform serve`
//      (subprocess) vs a select()-loop libmodbus server and a null
//      responder (a poll loop that answers every request with fixed bytes,
//      only the transaction id copied: the most this machine does over
//      loopback), each in a process of its own like serve. Rounds are
//      interleaved (5 rounds) and the median of each is kept.
//      Targets: 16 clients, serve >= 0.85x the null responder; 1 client,
//      serve >= 1.0x libmodbus. A null responder that does not beat both
//      servers means the machine was too busy to measure: the run is invalid.
// Usage: mbc_bench [path/to/mbconform]   (default build/bin/mbconform; run
// from the source root so the spec directory is found). Loopback only;
// every loop is bounded and the subprocess is killed at the end.
#include <modbus.h>

#include <arpa/inet.h>
#include <fcntl.h>
#include <netinet/in.h>
#include <netinet/tcp.h>
#include <poll.h>
#include <signal.h>
#include <sys/select.h>
#include <sys/socket.h>
#include <sys/wait.h>
#include <unistd.h>

#include <algorithm>
#include <atomic>
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <stdexcept>
#include <string>
#include <thread>
#include <vector>

#include "engine/device.h"
#include "loader.h"

namespace {

using Clock = std::chrono::steady_clock;
constexpr int kRegs = 10;
constexpr int kMapRegs = 256;  // the modbus-standard holding block 0x0000..0x00FF
constexpr long kInProcess = 200000;

double seconds(Clock::time_point a, Clock::time_point b) { return std::chrono::duration<double>(b - a).count(); }

// ---- 1. in-process ----
double bench_device() {
  mbc::ref::Device dev(mbc::spec::load_spec_by_id("modbus-standard"), 1);
  const uint8_t pdu[] = {0x03, 0x00, 0x00, 0x00, kRegs};
  size_t sink = 0;
  auto t0 = Clock::now();
  for (long i = 0; i < kInProcess; ++i) {
    auto r = dev.handle_pdu(pdu);
    if (!r || r->size() != 2 + 2 * kRegs) throw std::runtime_error("unexpected FC03 reply from Device");
    sink += r->size();
  }
  auto t1 = Clock::now();
  if (sink == 0) std::puts("");
  return kInProcess / seconds(t0, t1);
}

double bench_modbus_reply() {
  modbus_t* ctx = modbus_new_tcp("127.0.0.1", 1502);  // never connected
  modbus_mapping_t* map = modbus_mapping_new(0, 0, kMapRegs, 0);
  if (!ctx || !map) throw std::runtime_error("libmodbus allocation failed");
  modbus_set_slave(ctx, 1);
  // MBAP (transaction, protocol 0, length 6, unit 1) + PDU.
  const uint8_t req[] = {0x00, 0x01, 0x00, 0x00, 0x00, 0x06, 0x01, 0x03, 0x00, 0x00, 0x00, kRegs};
  auto t0 = Clock::now();
  for (long i = 0; i < kInProcess; ++i) modbus_reply(ctx, req, sizeof req, map);
  auto t1 = Clock::now();
  modbus_mapping_free(map);
  modbus_free(ctx);
  return kInProcess / seconds(t0, t1);
}

// ---- 2. TCP loopback ----
double run_clients(int port, int threads, int per_thread) {
  std::atomic<int> ready{0};
  std::atomic<bool> go{false};
  std::atomic<long> failures{0};
  std::vector<std::thread> ts;
  for (int t = 0; t < threads; ++t) {
    ts.emplace_back([&] {
      modbus_t* ctx = modbus_new_tcp("127.0.0.1", port);
      modbus_set_slave(ctx, 1);
      modbus_set_response_timeout(ctx, 2, 0);
      bool ok = modbus_connect(ctx) == 0;
      ready++;
      while (!go.load()) std::this_thread::yield();
      uint16_t regs[kRegs];
      for (int i = 0; ok && i < per_thread; ++i)
        if (modbus_read_registers(ctx, 0, kRegs, regs) != kRegs) { failures++; ok = false; }
      if (!ok) failures++;
      modbus_close(ctx);
      modbus_free(ctx);
    });
  }
  while (ready.load() < threads) std::this_thread::yield();
  auto t0 = Clock::now();
  go = true;
  for (auto& t : ts) t.join();
  auto t1 = Clock::now();
  if (failures) throw std::runtime_error("client requests failed on port " + std::to_string(port));
  return double(threads) * per_thread / seconds(t0, t1);
}

int free_port() {
  int s = socket(AF_INET, SOCK_STREAM, 0);
  sockaddr_in a{};
  a.sin_family = AF_INET;
  a.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
  socklen_t len = sizeof a;
  if (bind(s, reinterpret_cast<sockaddr*>(&a), sizeof a) != 0 || getsockname(s, reinterpret_cast<sockaddr*>(&a), &len) != 0)
    throw std::runtime_error("cannot pick a free port");
  close(s);
  return ntohs(a.sin_port);
}

// The baselines run in their own processes, as `mbconform serve` does, so
// that all three servers meet the same scheduler on a shared machine (a thread
// of this process would be favoured while the clients wait).
volatile sig_atomic_t g_child_stop = 0;
extern "C" void on_child_stop(int) { g_child_stop = 1; }

// Forks a server loop `serve(port)` on a free port; stops it with SIGTERM.
struct ChildServer {
  pid_t pid = -1;
  int port = free_port();

  template <class Loop>
  explicit ChildServer(Loop&& serve) {
    pid = fork();
    if (pid < 0) throw std::runtime_error("fork failed");
    if (pid == 0) {
      signal(SIGTERM, on_child_stop);
      serve(port);
      _exit(0);
    }
    // Ready when it accepts a connection.
    for (int i = 0; i < 500; ++i) {
      int s = socket(AF_INET, SOCK_STREAM, 0);
      sockaddr_in a{};
      a.sin_family = AF_INET;
      a.sin_port = htons(uint16_t(port));
      a.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
      bool up = connect(s, reinterpret_cast<sockaddr*>(&a), sizeof a) == 0;
      close(s);
      if (up) return;
      std::this_thread::sleep_for(std::chrono::milliseconds(10));
    }
    throw std::runtime_error("a baseline server did not start");
  }
  ~ChildServer() {
    kill(pid, SIGTERM);
    waitpid(pid, nullptr, 0);
  }
};

// libmodbus multi-client server (tests/bandwidth-server-many-up.c pattern).
void libmodbus_server(int port) {
  modbus_t* ctx = modbus_new_tcp("127.0.0.1", port);
  modbus_set_slave(ctx, 1);
  modbus_mapping_t* map = modbus_mapping_new(0, 0, kMapRegs, 0);
  int server = modbus_tcp_listen(ctx, 32);
  if (server < 0) return;
  fd_set refset;
  FD_ZERO(&refset);
  FD_SET(server, &refset);
  int fdmax = server;
  uint8_t query[MODBUS_TCP_MAX_ADU_LENGTH];
  while (!g_child_stop) {
    fd_set rdset = refset;
    timeval tv{0, 50000};
    int n = select(fdmax + 1, &rdset, nullptr, nullptr, &tv);
    if (n <= 0) continue;
    for (int fd = 0; fd <= fdmax; ++fd) {
      if (!FD_ISSET(fd, &rdset)) continue;
      if (fd == server) {
        int c = accept(server, nullptr, nullptr);
        if (c >= 0 && c < FD_SETSIZE) { FD_SET(c, &refset); if (c > fdmax) fdmax = c; }
        else if (c >= 0) close(c);
      } else {
        modbus_set_socket(ctx, fd);
        int rc = modbus_receive(ctx, query);
        if (rc > 0) modbus_reply(ctx, query, rc, map);
        else if (rc == -1) { close(fd); FD_CLR(fd, &refset); }
      }
    }
  }
}

// The null responder: every 12-byte FC 03 request (MBAP + PDU, as the
// clients send them) gets the same 29-byte reply, its transaction id copied
// from the request. No decoding, no device: the loopback ceiling.
void null_responder(int port) {
  int server = socket(AF_INET, SOCK_STREAM | SOCK_NONBLOCK, 0);
  int one = 1;
  setsockopt(server, SOL_SOCKET, SO_REUSEADDR, &one, sizeof one);
  sockaddr_in a{};
  a.sin_family = AF_INET;
  a.sin_port = htons(uint16_t(port));
  a.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
  if (bind(server, reinterpret_cast<sockaddr*>(&a), sizeof a) != 0 || listen(server, 64) != 0) return;
  uint8_t reply[9 + 2 * kRegs] = {0, 0, 0, 0, 0, 3 + 2 * kRegs, 1, 3, 2 * kRegs};
  std::vector<pollfd> fds{{server, POLLIN, 0}};
  std::vector<std::vector<uint8_t>> pending(1);
  std::vector<uint8_t> out;
  uint8_t buf[4096];
  while (!g_child_stop) {
    if (poll(fds.data(), fds.size(), 50) <= 0) continue;
    if (fds[0].revents & POLLIN) {
      for (int c; (c = accept4(server, nullptr, nullptr, SOCK_NONBLOCK)) >= 0;) {
        setsockopt(c, IPPROTO_TCP, TCP_NODELAY, &one, sizeof one);
        fds.push_back({c, POLLIN, 0});
        pending.emplace_back();
      }
    }
    for (size_t i = 1; i < fds.size(); ++i) {
      if (!(fds[i].revents & (POLLIN | POLLHUP | POLLERR))) continue;
      ssize_t n = read(fds[i].fd, buf, sizeof buf);
      if (n <= 0) { close(fds[i].fd); fds[i].fd = -1; continue; }
      auto& in = pending[i];
      in.insert(in.end(), buf, buf + n);
      out.clear();
      size_t at = 0;
      for (; in.size() - at >= 12; at += 12) {
        reply[0] = in[at];
        reply[1] = in[at + 1];
        out.insert(out.end(), reply, reply + sizeof reply);
      }
      in.erase(in.begin(), in.begin() + ptrdiff_t(at));
      if (!out.empty() && send(fds[i].fd, out.data(), out.size(), MSG_NOSIGNAL) != ssize_t(out.size())) {
        close(fds[i].fd);
        fds[i].fd = -1;
      }
    }
  }
}

// `mbconform serve` as a subprocess; the port comes from its "listening tcp" line.
struct MbconformServer {
  pid_t pid = -1;
  int port = 0;

  explicit MbconformServer(const std::string& exe) {
    int p[2];
    if (pipe(p) != 0) throw std::runtime_error("pipe failed");
    pid = fork();
    if (pid == 0) {
      dup2(p[1], 1);
      close(p[0]);
      close(p[1]);
      execl(exe.c_str(), exe.c_str(), "serve", "--device", "modbus-standard@1", "--tcp", "127.0.0.1:0", (char*)nullptr);
      _exit(127);
    }
    close(p[1]);
    FILE* f = fdopen(p[0], "r");
    char line[256];
    while (fgets(line, sizeof line, f)) {
      const char* k = std::strstr(line, "listening tcp 127.0.0.1:");
      if (k) { port = std::atoi(k + std::strlen("listening tcp 127.0.0.1:")); break; }
    }
    // Keep the pipe open until the end would need a reader; the server only
    // prints at start-up, so closing our end is fine.
    fclose(f);
    if (port == 0) { stop(); throw std::runtime_error("no 'listening tcp' line from " + exe); }
  }
  void stop() {
    if (pid > 0) { kill(pid, SIGTERM); waitpid(pid, nullptr, 0); pid = -1; }
  }
  ~MbconformServer() { stop(); }
};

void row(const char* name, double mine, double base) {
  std::printf("%-28s %14.0f %14.0f %8.2f\n", name, mine, base, mine / base);
}

double median(std::vector<double> v) {
  std::sort(v.begin(), v.end());
  return v[v.size() / 2];
}

}  // namespace

int main(int argc, char** argv) {
  signal(SIGPIPE, SIG_IGN);
  std::string exe = argc > 1 ? argv[1] : "build/bin/mbconform";
  try {
    double dev = bench_device();
    double lib = bench_modbus_reply();
    std::printf("%-28s %14s %14s %8s\n", "scenario", "mbconform/s", "libmodbus/s", "ratio");
    row("in-process FC03 x10", dev, lib);

    struct Case { const char* name; int threads; int per_thread; double target; bool vs_null; };
    const Case cases[] = {{"tcp loopback, 1 client", 1, 8000, 1.0, false},
                          {"tcp loopback, 16 clients", 16, 1000, 0.85, true}};
    constexpr int kRounds = 5;
    MbconformServer mbc(exe);
    ChildServer base(libmodbus_server);
    ChildServer null(null_responder);
    bool valid = true, met = true;
    std::printf("\n%-28s %14s %14s %14s %9s %9s\n", "loopback (median of 5)", "serve/s", "libmodbus/s", "null/s",
                "vs lib", "vs null");
    for (const auto& c : cases) {
      std::vector<double> m, b, n;
      for (int r = 0; r < kRounds; ++r) {  // interleaved: a busy moment hits all three alike
        m.push_back(run_clients(mbc.port, c.threads, c.per_thread));
        b.push_back(run_clients(base.port, c.threads, c.per_thread));
        n.push_back(run_clients(null.port, c.threads, c.per_thread));
      }
      double ms = median(m), bs = median(b), ns = median(n);
      std::printf("%-28s %14.0f %14.0f %14.0f %9.2f %9.2f\n", c.name, ms, bs, ns, ms / bs, ms / ns);
      if (ns <= ms || ns <= bs) {
        valid = false;
        std::printf("  INVALID: the null responder did not beat both servers (machine too busy to measure)\n");
      }
      double ratio = c.vs_null ? ms / ns : ms / bs;
      bool ok = ratio >= c.target;
      met &= ok;
      std::printf("  target: serve >= %.2fx %s: %.2fx %s\n", c.target, c.vs_null ? "the null responder" : "libmodbus",
                  ratio, ok ? "met" : "NOT met");
    }
    std::printf("%s\n", !valid ? "run INVALID" : met ? "all targets met" : "a target was NOT met");
    return valid ? (met ? 0 : 1) : 3;
  } catch (const std::exception& e) {
    std::fprintf(stderr, "mbc_bench: %s\n", e.what());
    return 2;
  }
}
