// plugin:PATH.so?device=ID&unit=N&config=...&timeout=MS: a vendor's slave
// stack through the C ABI of conformance/plugin/mbconform_plugin.h, run in a
// child process (mbconform-plugin-host, conformance/plugin/host/) so that its
// faults are findings, not mbconform's: a crash or an abort (the signal
// named), a hang past the per-request watchdog (timeout=, 3000 ms by
// default), or a broken contract (a reply longer than the capacity, a write
// past it, a failure without an error message) fails the request with a
// message saying which (RecoveredFault: it fails that exchange and never
// counts toward a lost target); the host is then restarted and the run goes on.
// Between mbconform and the host sits a small intermediate process, so a
// plugin that signals its parent (kill(getppid(), SIGKILL)) ends only that;
// the intermediate, the host and every child either makes share one process
// group of their own, killed as a whole when the host goes. The host runs
// under a memory limit (mem=MIB, default $MBCONFORM_PLUGIN_MEM_MB or 1024)
// and a CPU-time limit (kCpuSeconds).
// What the target can do follows the hooks the plugin fills in: handle_rtu
// gives raw frames, power_cycle a power cycle, advance_time_us a virtual clock.
#include <cstdlib>
#include <fcntl.h>
#include <fmt/core.h>
#include <poll.h>
#include <signal.h>
#include <sys/prctl.h>
#include <sys/resource.h>
#include <sys/wait.h>
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <cstring>
#include <filesystem>
#include <stdexcept>

#include "host_protocol.h"
#include "loader.h"
#include "mbconform_plugin.h"
#include "modbus/rtu.h"
#include "targets/kinds.h"
#include "targets/live_link.h"

#if defined(__SANITIZE_ADDRESS__)
#define MBC_ASAN 1
#elif defined(__has_feature)
#if __has_feature(address_sanitizer)
#define MBC_ASAN 1
#endif
#endif
#ifndef MBC_ASAN
#define MBC_ASAN 0
#endif

namespace mbc::conf {
namespace {

namespace host = plugin_host;
constexpr int kDefaultTimeoutMs = 3000;
constexpr int kDefaultMemMiB = 1024;
// A host process's CPU time: far beyond any run's requests (each is bounded
// by the watchdog), short of a plugin that spins in a thread of its own forever.
constexpr rlim_t kCpuSeconds = 3600;

int default_mem_mib() {
  if (const char* env = std::getenv("MBCONFORM_PLUGIN_MEM_MB"); env && *env) {
    int v = std::atoi(env);
    if (v >= 16) return v;
  }
  return kDefaultMemMiB;
}

// $MBCONFORM_PLUGIN_HOST, else mbconform-plugin-host beside the running executable.
std::string host_path() {
  if (const char* env = std::getenv("MBCONFORM_PLUGIN_HOST"); env && *env) return env;
  std::error_code ec;
  auto self = std::filesystem::read_symlink("/proc/self/exe", ec);
  return (self.parent_path() / "mbconform-plugin-host").string();
}

std::string signal_text(int sig) {
  const char* abbrev = sigabbrev_np(sig);
  const char* desc = sigdescr_np(sig);
  return fmt::format("SIG{} ({})", abbrev ? abbrev : std::to_string(sig).c_str(), desc ? desc : "unknown signal");
}

// One running host: its pid and the two pipe ends mbconform holds.
class HostProcess {
 public:
  HostProcess(const std::string& library, const std::string& config, int mem_mib) {
    int req[2], resp[2];
    if (pipe2(req, O_CLOEXEC) != 0 || pipe2(resp, O_CLOEXEC) != 0)
      throw std::runtime_error(fmt::format("pipe: {}", std::strerror(errno)));
    std::string exe = host_path();
    // A host that died between two requests closes the pipe: the next write
    // must fail with EPIPE (a fault, named) rather than end mbconform by SIGPIPE.
    ::signal(SIGPIPE, SIG_IGN);
    pid_t parent = getpid();
    pid_ = fork();
    if (pid_ < 0) throw std::runtime_error(fmt::format("fork: {}", std::strerror(errno)));
    if (pid_ == 0) {
      // Its own process group (a terminal's Ctrl-C is mbconform's to handle),
      // and it dies with mbconform.
      setpgid(0, 0);
      prctl(PR_SET_PDEATHSIG, SIGKILL);
      rlimit no_core{0, 0};  // a crashing vendor stack is a finding, not a core file
      setrlimit(RLIMIT_CORE, &no_core);
      if (getppid() != parent) _exit(127);
      // The intermediate: the host's parent, so a plugin that kills its
      // parent kills this and not mbconform. It passes the host's end on.
      pid_t intermediate = getpid();
      pid_t h = fork();
      if (h < 0) _exit(127);
      if (h == 0) {
        prctl(PR_SET_PDEATHSIG, SIGKILL);
        if (getppid() != intermediate) _exit(127);
#if MBC_ASAN
        // AddressSanitizer reserves terabytes of shadow address space, which
        // RLIMIT_AS forbids: the sanitizer's own RSS limit kills the host instead.
        std::string asan = getenv("ASAN_OPTIONS") ? getenv("ASAN_OPTIONS") : "";
        asan += fmt::format("{}hard_rss_limit_mb={}", asan.empty() ? "" : ":", mem_mib);
        setenv("ASAN_OPTIONS", asan.c_str(), 1);
#else
        rlimit mem{rlim_t(mem_mib) << 20, rlim_t(mem_mib) << 20};
        setrlimit(RLIMIT_AS, &mem);
#endif
        rlimit cpu{kCpuSeconds, kCpuSeconds};
        setrlimit(RLIMIT_CPU, &cpu);
        // dup2 onto the descriptor a pipe end already is keeps its O_CLOEXEC, and
        // one end may sit on the other's target: move both clear of 3 and 4 first.
        int rq = fcntl(req[0], F_DUPFD, 10), rs = fcntl(resp[1], F_DUPFD, 10);
        dup2(rq, host::kRequestFd);
        dup2(rs, host::kResponseFd);
        ::close(rq), ::close(rs);
        execl(exe.c_str(), exe.c_str(), library.c_str(), config.c_str(), static_cast<char*>(nullptr));
        _exit(127);
      }
      ::close(req[0]), ::close(req[1]), ::close(resp[0]), ::close(resp[1]);
      int st = 0;
      while (waitpid(h, &st, 0) < 0 && errno == EINTR) {
      }
      if (WIFSIGNALED(st)) {
        signal(WTERMSIG(st), SIG_DFL);
        kill(getpid(), WTERMSIG(st));
      }
      _exit(WIFEXITED(st) ? WEXITSTATUS(st) : 127);
    }
    ::close(req[0]);
    ::close(resp[1]);
    to_ = req[1];
    from_ = resp[0];
  }
  ~HostProcess() {
    ::close(to_);  // the host destroys the instance and exits on EOF
    ::close(from_);
    for (int i = 0; i < 100; ++i) {
      if (waitpid(pid_, nullptr, WNOHANG) == pid_) {
        kill(-pid_, SIGKILL);  // a child the plugin forked does not outlive the run
        return;
      }
      usleep(10000);
    }
    kill(-pid_, SIGKILL);
    waitpid(pid_, nullptr, 0);
  }
  HostProcess(const HostProcess&) = delete;
  HostProcess& operator=(const HostProcess&) = delete;

  // The response, or an error saying why none came (the process is then gone).
  struct Answer {
    host::Response head;
    Bytes payload;
    std::string fault;  // set when the host crashed, hung or exited
  };

  // The create() answer the host writes first.
  Answer call_hello(int timeout_ms) {
    Answer a;
    auto deadline = live::Clock::now() + std::chrono::milliseconds(timeout_ms);
    if (!read_all(&a.head, sizeof a.head, deadline, a.fault, "create", timeout_ms)) return a;
    a.payload.resize(a.head.length);
    read_all(a.payload.data(), a.payload.size(), deadline, a.fault, "create", timeout_ms);
    return a;
  }

  Answer call(const host::Request& q, std::span<const uint8_t> payload, int timeout_ms, const char* what) {
    Answer a;
    if (!write_all(&q, sizeof q) || !write_all(payload.data(), payload.size())) {
      a.fault = died(what);
      return a;
    }
    auto deadline = live::Clock::now() + std::chrono::milliseconds(timeout_ms);
    if (!read_all(&a.head, sizeof a.head, deadline, a.fault, what, timeout_ms)) return a;
    a.payload.resize(a.head.length);
    read_all(a.payload.data(), a.payload.size(), deadline, a.fault, what, timeout_ms);
    return a;
  }

 private:
  bool write_all(const void* p, size_t n) {
    auto* b = static_cast<const uint8_t*>(p);
    while (n) {
      ssize_t put = ::write(to_, b, n);
      if (put < 0 && errno == EINTR) continue;
      if (put <= 0) return false;
      b += put;
      n -= size_t(put);
    }
    return true;
  }

  bool read_all(void* p, size_t n, live::Clock::time_point deadline, std::string& fault, const char* what,
                int timeout_ms) {
    auto* b = static_cast<uint8_t*>(p);
    while (n) {
      auto left = std::chrono::duration_cast<std::chrono::milliseconds>(deadline - live::Clock::now()).count();
      pollfd pf{from_, POLLIN, 0};
      int rc = left > 0 ? ::poll(&pf, 1, int(left)) : 0;
      if (rc < 0 && errno == EINTR) continue;
      if (rc == 0) {
        kill(-pid_, SIGKILL);
        waitpid(pid_, nullptr, 0);
        fault = fmt::format("the plugin hung: no answer to {} within {} ms (watchdog: timeout= in the URI); killed",
                            what, timeout_ms);
        return false;
      }
      ssize_t got = ::read(from_, b, n);
      if (got < 0 && errno == EINTR) continue;
      if (got <= 0) {
        fault = died(what);
        return false;
      }
      b += got;
      n -= size_t(got);
    }
    return true;
  }

  std::string died(const char* what) {
    int st = 0;
    if (waitpid(pid_, &st, 0) != pid_) return fmt::format("the plugin host vanished during {}", what);
    kill(-pid_, SIGKILL);
    if (WIFSIGNALED(st)) return fmt::format("the plugin crashed: {} during {}", signal_text(WTERMSIG(st)), what);
    if (WIFEXITED(st) && WEXITSTATUS(st) == 127) return "the plugin host could not start (" + host_path() + ")";
    return fmt::format("the plugin exited (status {}) during {}", WIFEXITED(st) ? WEXITSTATUS(st) : -1, what);
  }

  pid_t pid_ = -1;
  int to_ = -1, from_ = -1;
};

class PluginTarget final : public Target {
 public:
  explicit PluginTarget(const Uri& u) {
    const std::string base = "plugin:" + u.path;
    live::check_params(u, base, {"device", "unit", "config", "timeout", "mem"});
    if (u.path.empty())
      throw std::invalid_argument("target 'plugin:': needs the library's path, e.g. plugin:./libmystack.so");
    int default_unit = 1;
    if (auto id = u.param("device")) {
      try {
        default_unit = spec::load_spec_by_id(*id).serial.slave_default.value_or(1);
      } catch (const std::exception& e) {
        throw std::invalid_argument(fmt::format("target '{}': device={}: {}", base, *id, e.what()));
      }
      info_.device_id = *id;
    }
    int unit = live::int_param(u, base, "unit", default_unit, 1, 247);  // MB-SL v1.02 §2.2
    timeout_ms_ = live::int_param(u, base, "timeout", kDefaultTimeoutMs, 1, 3600 * 1000);
    mem_mib_ = live::int_param(u, base, "mem", default_mem_mib(), 16, 1 << 20);
    config_ = u.param("config").value_or("");
    // A path without a slash would make dlopen search the library path.
    library_ = u.path.find('/') == std::string::npos ? "./" + u.path : u.path;
    library_ = std::filesystem::absolute(library_).string();
    base_ = base;
    std::string hello = start();
    size_t space = hello.find(' ');
    hooks_ = unsigned(std::stoul(hello.substr(0, space)));

    info_.kind = "plugin";
    info_.framing = &mbc::kRtu;
    info_.unit = uint8_t(unit);
    info_.raw = hooks_ & host::kHasRtu;
    info_.power_cycle = hooks_ & host::kHasPowerCycle;
    info_.virtual_clock = hooks_ & host::kHasAdvance;
    info_.implementation = space == std::string::npos ? "" : hello.substr(space + 1);
    info_.uri = fmt::format("{}?{}unit={}{}", base, info_.device_id.empty() ? "" : "device=" + info_.device_id + "&",
                            unit, config_.empty() ? "" : "&config=" + config_);
  }

  const TargetInfo& info() const override { return info_; }

  Reply transact(uint8_t unit, std::span<const uint8_t> pdu) override {
    if (hooks_ & host::kHasRtu) return exchange(rtu_frame(unit, pdu), unit);
    Reply r;
    r.request = rtu_frame(unit, pdu);
    host::Request q{host::kPdu, unit, {0, 0}, uint32_t(pdu.size()), 0};
    auto t0 = live::Clock::now();
    Bytes out = call(q, pdu, "handle_pdu");
    r.latency = std::chrono::duration_cast<std::chrono::microseconds>(live::Clock::now() - t0);
    if (!out.empty()) {
      r.frame = rtu_frame(unit, out);  // framed here: the stack has no framing
      r.pdu = std::move(out);
    }
    return r;
  }

  Reply send_raw(std::span<const uint8_t> bytes, std::optional<size_t> gap_after) override {
    if (!(hooks_ & host::kHasRtu))
      throw std::logic_error(info_.uri + ": the plugin has no handle_rtu: raw frames cannot be sent");
    // A gap inside a frame splits it in two for the receiver (MB-SL §2.5.1.1).
    if (gap_after && *gap_after < bytes.size()) {
      Reply first = exchange(Bytes(bytes.begin(), bytes.begin() + ptrdiff_t(*gap_after)), info_.unit);
      Reply second = exchange(Bytes(bytes.begin() + ptrdiff_t(*gap_after), bytes.end()), info_.unit);
      second.request.assign(bytes.begin(), bytes.end());
      return first.silent() ? second : first;
    }
    return exchange(Bytes(bytes.begin(), bytes.end()), bytes.empty() ? info_.unit : bytes[0]);
  }

  void advance(std::chrono::microseconds dt) override {
    if (!(hooks_ & host::kHasAdvance)) throw std::logic_error(info_.uri + ": the plugin has no advance_time_us");
    call({host::kAdvance, 0, {0, 0}, 0, uint64_t(dt.count())}, {}, "advance_time_us");
  }

  void power_cycle() override {
    if (!(hooks_ & host::kHasPowerCycle)) throw std::logic_error(info_.uri + ": the plugin has no power_cycle");
    call({host::kPowerCycle, 0, {0, 0}, 0, 0}, {}, "power_cycle");
  }

 private:
  // Starts a host and returns its create() answer; throws when there is none.
  std::string start() {
    process_ = std::make_unique<HostProcess>(library_, config_, mem_mib_);
    auto a = process_->call_hello(timeout_ms_);
    std::string text(a.payload.begin(), a.payload.end());
    if (!a.fault.empty() || a.head.status != 0) {
      process_.reset();
      throw std::runtime_error(fmt::format("target '{}': {}", base_, a.fault.empty() ? text : a.fault));
    }
    return text;
  }

  // One request; the reply payload. A fault of the plugin throws, naming the
  // signal, the hang or the contract broken, after restarting the host.
  Bytes call(const host::Request& q, std::span<const uint8_t> payload, const char* what) {
    if (!process_) start();
    auto a = process_->call(q, payload, timeout_ms_, what);
    if (!a.fault.empty()) {
      process_.reset();
      try {
        start();
      } catch (const std::exception& e) {
        throw std::runtime_error(fmt::format("{}: {}; restart failed: {}", info_.uri, a.fault, e.what()));
      }
      // The host answers again: this exchange failed, the target did not go.
      throw RecoveredFault(fmt::format("{}: {}; host restarted", info_.uri, a.fault));
    }
    std::string text(a.payload.begin(), a.payload.end());
    if (a.head.status == host::kContract)
      throw RecoveredFault(fmt::format("{}: the plugin broke its contract: {}", info_.uri, text));
    if (a.head.status < 0)
      throw RecoveredFault(fmt::format("{}: {} failed: {}", info_.uri, what, text.empty() ? "no message" : text));
    return a.payload;
  }

  Reply exchange(Bytes adu, uint8_t slave) {
    Reply r;
    host::Request q{host::kRtu, 0, {0, 0}, uint32_t(adu.size()), 0};
    auto t0 = live::Clock::now();
    Bytes out = call(q, adu, "handle_rtu");
    r.latency = std::chrono::duration_cast<std::chrono::microseconds>(live::Clock::now() - t0);
    r.request = std::move(adu);
    r.frame = std::move(out);
    decode_rtu_reply(r, slave);
    return r;
  }

  TargetInfo info_;
  std::string base_, library_, config_;
  int timeout_ms_ = kDefaultTimeoutMs;
  int mem_mib_ = kDefaultMemMiB;
  unsigned hooks_ = 0;
  std::unique_ptr<HostProcess> process_;
};

}  // namespace

std::unique_ptr<Target> make_plugin_target(const Uri& u) { return std::make_unique<PluginTarget>(u); }

}  // namespace mbc::conf
