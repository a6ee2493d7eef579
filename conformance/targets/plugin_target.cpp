// plugin:PATH.so?device=ID&unit=N&config=...&timeout=MS: a vendor's slave
// stack through the C ABI of conformance/plugin/mbconform_plugin.h, run in a
// child process (mbconform-plugin-host, conformance/plugin/host/) so that its
// faults are findings, not mbconform's: a crash or an abort (the signal
// named), a hang past the per-request watchdog (timeout=, 3000 ms by
// default), or a broken contract (a reply longer than the capacity, a write
// past it, a failure without an error message) fails the request with a
// message saying which (RecoveredFault: it fails that exchange and never
// counts toward a lost target); a new session is forked and the run goes on.
// The host is a fork server (host_protocol.h): it loads the plugin once and
// forks one session per instance, so a crash costs a fork (about a
// millisecond, bench/bench_plugin_restart.cpp), not a process start and a
// load. A plugin that signals its parent (kill(getppid(), SIGKILL)) ends the
// host, which is then started again. The host, its sessions and everything
// they fork share one process group, and the host is the subreaper of what
// leaves it: all of it ends with the target. Each session runs under a memory
// limit (mem=MIB, default $MBCONFORM_PLUGIN_MEM_MB or 1024) and a CPU-time
// limit (kCpuSeconds).
// What the target can do follows the hooks the plugin fills in: handle_rtu
// gives raw frames, power_cycle a power cycle, advance_time_us a virtual clock.
#include <cstdlib>
#include <fcntl.h>
#include <fmt/core.h>
#include <poll.h>
#include <signal.h>
#include <sys/prctl.h>
#include <sys/resource.h>
#include <sys/socket.h>
#include <sys/wait.h>
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <cstring>
#include <filesystem>
#include <optional>
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

// The fork server (host_protocol.h): the plugin loaded once in a host
// process, and one session (a fork of it) at a time. A crashed session is
// replaced by a fork, in about a millisecond; the host itself is started
// again only when it is gone (a plugin that killed its parent).
class HostProcess {
 public:
  HostProcess(const std::string& library, const std::string& config, int mem_mib) {
    int ctl[2];
    if (socketpair(AF_UNIX, SOCK_SEQPACKET | SOCK_CLOEXEC, 0, ctl) != 0)
      throw std::runtime_error(fmt::format("socketpair: {}", std::strerror(errno)));
    std::string exe = host_path();
    std::string mem = std::to_string(mem_mib), cpu = std::to_string(kCpuSeconds);
    // A session that died between two requests closes its pipe: the next
    // write must fail with EPIPE (a fault, named) rather than end mbconform by SIGPIPE.
    ::signal(SIGPIPE, SIG_IGN);
    pid_t parent = getpid();
    pid_ = fork();
    if (pid_ < 0) throw std::runtime_error(fmt::format("fork: {}", std::strerror(errno)));
    if (pid_ == 0) {
      // Its own process group (a terminal's Ctrl-C is mbconform's to handle,
      // and the group is killed at the end); it ends with mbconform, killing
      // what the plugin started first (SIGTERM: the host cleans up).
      setpgid(0, 0);
      prctl(PR_SET_PDEATHSIG, SIGTERM);
      rlimit no_core{0, 0};  // a crashing vendor stack is a finding, not a core file
      setrlimit(RLIMIT_CORE, &no_core);
      if (getppid() != parent) _exit(127);
#if MBC_ASAN
      // AddressSanitizer reserves terabytes of shadow address space, which
      // RLIMIT_AS forbids: the sanitizer's own RSS limit stops the host instead.
      std::string asan = getenv("ASAN_OPTIONS") ? getenv("ASAN_OPTIONS") : "";
      asan += fmt::format("{}hard_rss_limit_mb={}", asan.empty() ? "" : ":", mem_mib);
      setenv("ASAN_OPTIONS", asan.c_str(), 1);
#endif
      // dup2 onto the descriptor the socket already is keeps its O_CLOEXEC:
      // move it clear of kControlFd first.
      int c = fcntl(ctl[1], F_DUPFD, 10);
      dup2(c, host::kControlFd);
      ::close(c);
      execl(exe.c_str(), exe.c_str(), library.c_str(), config.c_str(), mem.c_str(), cpu.c_str(), static_cast<char*>(nullptr));
      _exit(127);
    }
    setpgid(pid_, pid_);  // (both sides: whichever runs first)
    ::close(ctl[1]);
    ctl_ = ctl[0];
  }

  ~HostProcess() {
    end_session(std::chrono::milliseconds(1000));
    ::close(ctl_);  // the host kills what the plugin left and exits
    wait_host(std::chrono::milliseconds(2000));
    kill(-pid_, SIGKILL);  // whatever of its process group is left (the host was killed)
  }
  HostProcess(const HostProcess&) = delete;
  HostProcess& operator=(const HostProcess&) = delete;

  // The host's kLoaded: empty when the plugin loaded, else why not.
  std::string loaded(int timeout_ms) {
    host::Control c;
    auto deadline = live::Clock::now() + std::chrono::milliseconds(timeout_ms);
    if (!next_control(c, deadline) || c.op != host::kLoaded) {
      if (!alive_) return host_end();
      return fmt::format("the plugin host did not load the plugin within {} ms", timeout_ms);
    }
    if (c.status != 0) return std::string(c.text, strnlen(c.text, sizeof c.text));
    return "";
  }

  bool alive() const { return alive_; }
  bool in_session() const { return session_ > 0; }

  // The response, or an error saying why none came (the session is then gone).
  struct Answer {
    host::Response head;
    Bytes payload;
    std::string fault;  // set when the session crashed, hung or exited, or the host is gone
  };

  // Forks a session and reads its create() answer.
  Answer spawn(int timeout_ms) {
    Answer a;
    int req[2], resp[2];
    if (pipe2(req, O_CLOEXEC) != 0) throw std::runtime_error(fmt::format("pipe: {}", std::strerror(errno)));
    if (pipe2(resp, O_CLOEXEC) != 0) {
      ::close(req[0]), ::close(req[1]);
      throw std::runtime_error(fmt::format("pipe: {}", std::strerror(errno)));
    }
    host::Control c;
    c.op = host::kSpawn;
    int pass[2] = {req[0], resp[1]};
    char cbuf[CMSG_SPACE(sizeof pass)] = {};
    iovec iov{&c, sizeof c};
    msghdr m{};
    m.msg_iov = &iov;
    m.msg_iovlen = 1;
    m.msg_control = cbuf;
    m.msg_controllen = sizeof cbuf;
    cmsghdr* h = CMSG_FIRSTHDR(&m);
    h->cmsg_level = SOL_SOCKET;
    h->cmsg_type = SCM_RIGHTS;
    h->cmsg_len = CMSG_LEN(sizeof pass);
    std::memcpy(CMSG_DATA(h), pass, sizeof pass);
    ssize_t sent;
    do sent = sendmsg(ctl_, &m, MSG_NOSIGNAL);
    while (sent < 0 && errno == EINTR);
    ::close(req[0]);
    ::close(resp[1]);
    to_ = req[1];
    from_ = resp[0];
    auto deadline = live::Clock::now() + std::chrono::milliseconds(timeout_ms);
    host::Control r;
    if (sent != ssize_t(sizeof c) || !next_control(r, deadline) || r.op != host::kSpawned || r.pid <= 0) {
      close_pipes();
      a.fault = alive_ ? fmt::format("the plugin host could not start a session: {}", r.status < 0 ? std::strerror(-r.status) : "no answer")
                       : host_end();
      return a;
    }
    session_ = r.pid;
    exited_.reset();
    if (!read_all(&a.head, sizeof a.head, deadline, a.fault, "create", timeout_ms)) return a;
    a.payload.resize(a.head.length);
    read_all(a.payload.data(), a.payload.size(), deadline, a.fault, "create", timeout_ms);
    return a;
  }

  Answer call(const host::Request& q, std::span<const uint8_t> payload, int timeout_ms, const char* what) {
    Answer a;
    auto deadline = live::Clock::now() + std::chrono::milliseconds(timeout_ms);
    if (!write_all(&q, sizeof q) || !write_all(payload.data(), payload.size())) {
      a.fault = ended(what, deadline + kExitWait);
      return a;
    }
    if (!read_all(&a.head, sizeof a.head, deadline, a.fault, what, timeout_ms)) return a;
    a.payload.resize(a.head.length);
    read_all(a.payload.data(), a.payload.size(), deadline, a.fault, what, timeout_ms);
    return a;
  }

  // Ends the session: end of input (destroy() runs), then SIGKILL after `grace`.
  void end_session(std::chrono::milliseconds grace) {
    if (session_ <= 0) {
      close_pipes();
      return;
    }
    ::close(to_);
    to_ = -1;
    if (!wait_exit(live::Clock::now() + grace)) {
      kill_session();
      wait_exit(live::Clock::now() + kExitWait);
    }
    close_pipes();
    session_ = -1;
  }

 private:
  // How long a killed or crashed session's wait status may take to come.
  static constexpr std::chrono::milliseconds kExitWait{2000};

  void close_pipes() {
    if (to_ >= 0) ::close(to_);
    if (from_ >= 0) ::close(from_);
    to_ = from_ = -1;
  }

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

  // One control message by `deadline`; false at the deadline or when the
  // host is gone (alive_ then false). A kExited of the session is kept.
  bool next_control(host::Control& c, live::Clock::time_point deadline) {
    while (alive_) {
      auto left = std::chrono::duration_cast<std::chrono::milliseconds>(deadline - live::Clock::now()).count();
      pollfd pf{ctl_, POLLIN, 0};
      int rc = ::poll(&pf, 1, int(std::max<int64_t>(0, left)));
      if (rc < 0 && errno == EINTR) continue;
      if (rc <= 0) return false;
      if (!take_control(c)) return false;
      if (c.op == host::kExited && c.pid != session_) continue;  // an earlier session's
      return true;
    }
    return false;
  }

  // Reads the control message that is there; false when the host is gone.
  bool take_control(host::Control& c) {
    ssize_t n;
    do n = ::recv(ctl_, &c, sizeof c, 0);
    while (n < 0 && errno == EINTR);
    if (n != ssize_t(sizeof c)) {
      alive_ = false;
      return false;
    }
    if (c.op == host::kExited && c.pid == session_) exited_ = c.status;
    return true;
  }

  // Until the session's wait status has come (true) or the deadline.
  bool wait_exit(live::Clock::time_point deadline) {
    host::Control c;
    while (!exited_ && alive_)
      if (!next_control(c, deadline)) break;
    return exited_.has_value() || !alive_;
  }

  void kill_session() {
    if (session_ <= 0 || !alive_) return;
    host::Control c;
    c.op = host::kKill;
    c.pid = session_;
    ::send(ctl_, &c, sizeof c, MSG_NOSIGNAL);
  }

  // The host's end, in words (after its control socket closed).
  std::string host_end() {
    int st = wait_host(kExitWait);
    if (st < 0) return "the plugin host vanished";
    if (WIFEXITED(st) && WEXITSTATUS(st) == 127) return "the plugin host could not start (" + host_path() + ")";
    if (WIFSIGNALED(st)) return fmt::format("the plugin host was killed: {}", signal_text(WTERMSIG(st)));
    return fmt::format("the plugin host exited (status {})", WIFEXITED(st) ? WEXITSTATUS(st) : -1);
  }

  // Reaps the host (its wait status), killing its group after `grace`; -1
  // when it was reaped before.
  int wait_host(std::chrono::milliseconds grace) {
    if (host_status_) return *host_status_;
    if (reaped_) return -1;
    auto deadline = live::Clock::now() + grace;
    int st = 0;
    for (;;) {
      pid_t r = waitpid(pid_, &st, WNOHANG);
      if (r == pid_) break;
      if (r < 0 && errno != EINTR) {  // ECHILD: not ours to wait for any more
        reaped_ = true;
        return -1;
      }
      if (live::Clock::now() >= deadline) {
        kill(-pid_, SIGKILL);
        while (waitpid(pid_, &st, 0) < 0 && errno == EINTR) {
        }
        break;
      }
      usleep(1000);
    }
    reaped_ = true;
    alive_ = false;
    host_status_ = st;
    kill(-pid_, SIGKILL);
    return st;
  }

  // Why the session gave no answer to `what`, once its wait status came.
  std::string ended(const char* what, live::Clock::time_point deadline) {
    wait_exit(deadline);
    pid_t was = session_;
    session_ = -1;
    close_pipes();
    if (!alive_) return fmt::format("{} during {}", host_end(), what);
    if (!exited_) return fmt::format("the plugin session {} did not end after closing its pipe during {}", was, what);
    int st = *exited_;
    if (WIFSIGNALED(st)) return fmt::format("the plugin crashed: {} during {}", signal_text(WTERMSIG(st)), what);
    return fmt::format("the plugin exited (status {}) during {}", WIFEXITED(st) ? WEXITSTATUS(st) : -1, what);
  }

  bool read_all(void* p, size_t n, live::Clock::time_point deadline, std::string& fault, const char* what,
                int timeout_ms) {
    auto* b = static_cast<uint8_t*>(p);
    while (n) {
      auto left = std::chrono::duration_cast<std::chrono::milliseconds>(deadline - live::Clock::now()).count();
      // The session's end comes on the control socket even when a process the
      // plugin forked holds the response pipe open.
      pollfd pf[2] = {{from_, POLLIN, 0}, {exited_ || !alive_ ? -1 : ctl_, POLLIN, 0}};
      // Once the session ended, what it wrote before is read without waiting.
      bool ended_already = exited_ || !alive_;
      int rc = left > 0 || ended_already ? ::poll(pf, 2, ended_already ? 0 : int(left)) : 0;
      if (rc < 0 && errno == EINTR) continue;
      if (rc == 0) {
        if (exited_ || !alive_) {
          fault = ended(what, deadline);
          return false;
        }
        kill_session();
        fault = ended(what, live::Clock::now() + kExitWait);
        if (fault.find("crashed: SIGKILL") != std::string::npos || fault.find("did not end") != std::string::npos)
          fault = fmt::format("the plugin hung: no answer to {} within {} ms (watchdog: timeout= in the URI); killed",
                              what, timeout_ms);
        return false;
      }
      if (pf[1].revents && !(pf[0].revents)) {
        host::Control c;
        take_control(c);
        continue;
      }
      if (!pf[0].revents) continue;
      ssize_t got = ::read(from_, b, n);
      if (got < 0 && errno == EINTR) continue;
      if (got <= 0) {
        fault = ended(what, live::Clock::now() + kExitWait);
        return false;
      }
      b += got;
      n -= size_t(got);
    }
    return true;
  }

  pid_t pid_ = -1;      // the host (its process group too)
  int ctl_ = -1;        // the control socket
  bool alive_ = true;   // its control socket is open
  bool reaped_ = false;
  std::optional<int> host_status_;
  pid_t session_ = -1;  // the session's pid, -1 when none
  int to_ = -1, from_ = -1;
  std::optional<int> exited_;  // the session's wait status, once the host reported it
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

    info_.kind = TargetKind::plugin;
    info_.framing = framing_of(info_.kind);
    info_.live = is_live(info_.kind);
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
  // Starts a session (and the host first when there is none) and returns
  // its create() answer; throws when there is none.
  std::string start() {
    if (process_ && !process_->alive()) process_.reset();
    if (!process_) {
      process_ = std::make_unique<HostProcess>(library_, config_, mem_mib_);
      if (std::string why = process_->loaded(timeout_ms_); !why.empty()) {
        process_.reset();
        throw std::runtime_error(fmt::format("target '{}': {}", base_, why));
      }
    }
    auto a = process_->spawn(timeout_ms_);
    std::string text(a.payload.begin(), a.payload.end());
    if (!a.fault.empty() || a.head.status != 0) {
      process_->end_session(std::chrono::milliseconds(1000));
      if (!process_->alive()) process_.reset();
      throw std::runtime_error(fmt::format("target '{}': {}", base_, a.fault.empty() ? text : a.fault));
    }
    return text;
  }

  // One request; the reply payload. A fault of the plugin throws, naming the
  // signal, the hang or the contract broken, after restarting the host.
  Bytes call(const host::Request& q, std::span<const uint8_t> payload, const char* what) {
    if (!process_ || !process_->in_session()) start();
    auto a = process_->call(q, payload, timeout_ms_, what);
    if (!a.fault.empty()) {
      try {
        start();
      } catch (const std::exception& e) {
        throw std::runtime_error(fmt::format("{}: {}; restart failed: {}", info_.uri, a.fault, e.what()));
      }
      // The host answers again: this exchange failed, the target did not go.
      throw RecoveredFault(fmt::format("{}: {}; a new session was forked", info_.uri, a.fault));
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
