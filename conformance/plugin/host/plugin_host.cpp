// mbconform-plugin-host PLUGIN.so CONFIG MEM_MIB CPU_SECONDS: the fork server
// a vendor plugin (the C ABI of mbconform_plugin.h) runs in (host_protocol.h).
// It loads the plugin once, then forks a session per instance: create(), the
// requests, destroy(). A session checks the contract the ABI states around
// every call: a reply length over the capacity, a write past the capacity
// (guard bytes), a negative length without an error message. A crash or a
// hang costs mbconform one request and a fork: it asks for a new session.
//
// The host is the subreaper of everything the plugin starts: when mbconform
// closes the control socket (or dies: SIGTERM as the parent-death signal),
// it kills every descendant, daemons that left the process group included,
// and exits.
#include <dlfcn.h>
#include <poll.h>
#include <signal.h>
#include <sys/prctl.h>
#include <sys/resource.h>
#include <sys/socket.h>
#include <sys/syscall.h>
#include <sys/wait.h>
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <cstddef>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <fstream>
#include <string>
#include <vector>

#include "host_protocol.h"
#include "mbconform_plugin.h"

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

namespace {

using namespace mbc::conf::plugin_host;

bool read_all(int fd, void* p, size_t n) {
  auto* b = static_cast<uint8_t*>(p);
  while (n) {
    ssize_t got = ::read(fd, b, n);
    if (got < 0 && errno == EINTR) continue;
    if (got <= 0) return false;
    b += got;
    n -= size_t(got);
  }
  return true;
}

bool write_all(int fd, const void* p, size_t n) {
  auto* b = static_cast<const uint8_t*>(p);
  while (n) {
    ssize_t put = ::write(fd, b, n);
    if (put < 0 && errno == EINTR) continue;
    if (put <= 0) return false;
    b += put;
    n -= size_t(put);
  }
  return true;
}

constexpr size_t kGuard = 64;
constexpr uint8_t kGuardByte = 0xA5;

// ---- a session: one instance, in a child of the host ----

struct Session {
  const mbconform_plugin_api_v1* api;
  int in, out;

  bool respond(int32_t status, const void* payload, size_t n) {
    Response r{status, uint32_t(n)};
    return write_all(out, &r, sizeof r) && write_all(out, payload, n);
  }
  bool respond(int32_t status, const std::string& text) { return respond(status, text.data(), text.size()); }

  int run(const char* config) {
    char error[256] = "";
    void* instance = api->create(config, error, sizeof error);
    if (!instance) {
      error[sizeof error - 1] = 0;
      respond(kPluginFailed, std::string("the plugin refused config '") + config + "': " + error);
      return 1;
    }
    unsigned hooks = (api->handle_rtu ? kHasRtu : 0) | (api->handle_pdu ? kHasPdu : 0) | (api->reset ? kHasReset : 0) |
                     (api->power_cycle ? kHasPowerCycle : 0) | (api->advance_time_us ? kHasAdvance : 0);
    if (!respond(0, std::to_string(hooks) + " " + (api->name ? api->name : ""))) return 1;

    auto failure = [&](int rc, const char* hook) {
      const char* why = api->last_error ? api->last_error(instance) : nullptr;
      if (!why || !*why)
        return respond(kContract, std::string(hook) + " returned " + std::to_string(rc) +
                                      " (a failure) without an error message (last_error)");
      return respond(kPluginFailed, why);
    };

    std::vector<uint8_t> payload;
    std::vector<uint8_t> buf(MBCONFORM_RESPONSE_CAPACITY + kGuard);
    for (;;) {
      Request q;
      if (!read_all(in, &q, sizeof q)) break;  // mbconform closed the pipe: done
      payload.resize(q.length);
      if (q.length && !read_all(in, payload.data(), q.length)) break;
      bool ok = true;
      if (q.op == kRtu || q.op == kPdu) {
        const char* hook = q.op == kRtu ? "handle_rtu" : "handle_pdu";
        std::fill(buf.begin(), buf.end(), kGuardByte);
        int n = q.op == kRtu ? (api->handle_rtu ? api->handle_rtu(instance, payload.data(), payload.size(), buf.data(),
                                                                  MBCONFORM_RESPONSE_CAPACITY)
                                                : -1)
                             : (api->handle_pdu ? api->handle_pdu(instance, q.unit, payload.data(), payload.size(),
                                                                  buf.data(), MBCONFORM_RESPONSE_CAPACITY)
                                                : -1);
        bool guard_intact = true;
        for (size_t i = MBCONFORM_RESPONSE_CAPACITY; i < buf.size(); ++i) guard_intact &= buf[i] == kGuardByte;
        if (n > int(MBCONFORM_RESPONSE_CAPACITY))
          ok = respond(kContract, std::string(hook) + " returned " + std::to_string(n) + " bytes, over the " +
                                      std::to_string(MBCONFORM_RESPONSE_CAPACITY) + "-byte response capacity");
        else if (!guard_intact)
          ok = respond(kContract, std::string(hook) + " wrote past the " + std::to_string(MBCONFORM_RESPONSE_CAPACITY) +
                                      "-byte response capacity");
        else if (n < 0)
          ok = failure(n, hook);
        else
          ok = respond(n, buf.data(), size_t(n));
      } else if (q.op == kReset || q.op == kPowerCycle) {
        auto fn = q.op == kReset ? api->reset : api->power_cycle;
        int rc = fn ? fn(instance) : -1;
        ok = rc < 0 ? failure(rc, q.op == kReset ? "reset" : "power_cycle") : respond(0, nullptr, 0);
      } else if (q.op == kAdvance) {
        if (api->advance_time_us) api->advance_time_us(instance, q.arg);
        ok = respond(0, nullptr, 0);
      } else {
        ok = respond(kContract, "unknown request " + std::to_string(q.op));
      }
      if (!ok) break;
    }
    api->destroy(instance);
    return 0;
  }
};

// ---- the fork server ----

volatile sig_atomic_t g_stop = 0;
void on_stop(int) { g_stop = 1; }

bool send_control(const Control& c) {
  for (;;) {
    ssize_t n = ::send(kControlFd, &c, sizeof c, MSG_NOSIGNAL);
    if (n < 0 && errno == EINTR) continue;
    return n == ssize_t(sizeof c);
  }
}

bool loaded(int32_t status, const std::string& text) {
  Control c;
  c.op = kLoaded;
  c.status = status;
  std::snprintf(c.text, sizeof c.text, "%s", text.c_str());
  return send_control(c);
}

// The processes whose parent is this one (the subreaper's adopted orphans too).
std::vector<pid_t> children() {
  std::vector<pid_t> out;
  std::ifstream in("/proc/self/task/" + std::to_string(getpid()) + "/children");
  for (pid_t p; in >> p;) out.push_back(p);
  return out;
}

// Kills every descendant: each child dies, its children come to this
// subreaper, and die in the next pass.
void kill_descendants() {
  for (int pass = 0; pass < 1000; ++pass) {
    for (pid_t p : children()) kill(p, SIGKILL);
    int st = 0;
    pid_t r = waitpid(-1, &st, __WALL);
    if (r < 0 && errno == ECHILD) return;
  }
}

pid_t pidfd_open(pid_t pid) { return pid_t(syscall(SYS_pidfd_open, pid, 0)); }

}  // namespace

// Under AddressSanitizer (the CI's sanitizer build) a plugin's SIGSEGV must
// still end the session by that signal, so that mbconform can name it.
extern "C" __attribute__((used, visibility("default"))) const char* __asan_default_options() {
  return "handle_segv=0:handle_sigbus=0:handle_sigfpe=0:handle_sigill=0";
}

int main(int argc, char** argv) {
  if (argc != 5) {
    std::fprintf(stderr, "usage: mbconform-plugin-host PLUGIN.so CONFIG MEM_MIB CPU_SECONDS (started by mbconform, not by hand)\n");
    return 2;
  }
  const char* config = argv[2];
  [[maybe_unused]] const rlim_t mem_mib = rlim_t(std::strtoull(argv[3], nullptr, 10));  // unused under ASan
  const rlim_t cpu_seconds = rlim_t(std::strtoull(argv[4], nullptr, 10));
  // Orphans of the plugin's processes come here, so none outlives the run.
  prctl(PR_SET_CHILD_SUBREAPER, 1);
  struct sigaction sa{};
  sa.sa_handler = on_stop;  // no SA_RESTART: a blocked poll returns
  sigaction(SIGTERM, &sa, nullptr);
  sigaction(SIGHUP, &sa, nullptr);
  signal(SIGPIPE, SIG_IGN);

  void* handle = dlopen(argv[1], RTLD_NOW | RTLD_LOCAL);
  if (!handle) {
    loaded(kPluginFailed, std::string("cannot load: ") + dlerror());
    return 1;
  }
  auto entry = reinterpret_cast<mbconform_plugin_entry_fn>(dlsym(handle, MBCONFORM_PLUGIN_ENTRY));
  if (!entry) {
    loaded(kPluginFailed, std::string("no ") + MBCONFORM_PLUGIN_ENTRY + " symbol: not an mbconform plugin");
    return 1;
  }
  const mbconform_plugin_api_v1* api = entry();
  const size_t v1_size = offsetof(mbconform_plugin_api_v1, last_error) + sizeof(void*);
  if (!api || api->abi_version != MBCONFORM_PLUGIN_ABI_VERSION || api->struct_size < v1_size) {
    loaded(kPluginFailed, "plugin ABI version " + std::to_string(api ? api->abi_version : 0) + " (size " +
                              std::to_string(api ? api->struct_size : 0) + "), this host speaks version " +
                              std::to_string(MBCONFORM_PLUGIN_ABI_VERSION));
    return 1;
  }
  if (!api->create || !api->destroy || (!api->handle_rtu && !api->handle_pdu)) {
    loaded(kPluginFailed, "the plugin lacks create, destroy or both handle hooks");
    return 1;
  }
  if (!loaded(0, "")) return 1;

  const pid_t server = getpid();
  pid_t session = -1;
  int session_fd = -1;  // a pidfd: readable when the session ends
  auto report_exit = [&](int st) {
    Control c;
    c.op = kExited;
    c.pid = session;
    c.status = st;
    if (session_fd >= 0) ::close(session_fd);
    session = -1;
    session_fd = -1;
    return send_control(c);
  };
  // Reaps what ended: the session (reported) and orphans the plugin left.
  auto reap = [&]() {
    for (;;) {
      int st = 0;
      pid_t r = waitpid(-1, &st, WNOHANG | __WALL);
      if (r <= 0) return true;
      if (r == session && (WIFEXITED(st) || WIFSIGNALED(st)) && !report_exit(st)) return false;
    }
  };

  while (!g_stop) {
    pollfd fds[2] = {{kControlFd, POLLIN, 0}, {session_fd, POLLIN, 0}};
    // Without a pidfd (a kernel before 5.3) the session's end is polled for.
    int rc = poll(fds, 2, session > 0 && session_fd < 0 ? 2 : -1);
    if (rc < 0) {
      if (errno == EINTR) continue;
      break;
    }
    if ((rc == 0 || fds[1].revents) && !reap()) break;
    if (!fds[0].revents) continue;
    Control c;
    char cbuf[CMSG_SPACE(2 * sizeof(int))];
    iovec iov{&c, sizeof c};
    msghdr m{};
    m.msg_iov = &iov;
    m.msg_iovlen = 1;
    m.msg_control = cbuf;
    m.msg_controllen = sizeof cbuf;
    ssize_t n = recvmsg(kControlFd, &m, MSG_CMSG_CLOEXEC);
    if (n < 0 && errno == EINTR) continue;
    if (n <= 0) break;  // mbconform closed the socket (or died): the end
    int passed[2] = {-1, -1};
    if (cmsghdr* h = CMSG_FIRSTHDR(&m); h && h->cmsg_level == SOL_SOCKET && h->cmsg_type == SCM_RIGHTS &&
                                        h->cmsg_len == CMSG_LEN(2 * sizeof(int)))
      std::memcpy(passed, CMSG_DATA(h), sizeof passed);
    if (c.op == kKill) {
      if (session > 0 && c.pid == session) kill(session, SIGKILL);
    } else if (c.op == kSpawn && passed[0] >= 0 && session < 0) {
      pid_t p = fork();
      if (p == 0) {
        // The session: dies with the host; default signals; its own limits.
        prctl(PR_SET_PDEATHSIG, SIGKILL);
        if (getppid() != server) _exit(127);
        signal(SIGTERM, SIG_DFL);
        signal(SIGHUP, SIG_DFL);
        signal(SIGPIPE, SIG_DFL);
        ::close(kControlFd);
#if !MBC_ASAN
        // (AddressSanitizer's shadow memory is mapped already: RLIMIT_AS would
        // refuse every allocation; its hard_rss_limit_mb is set by mbconform.)
        rlimit mem{mem_mib << 20, mem_mib << 20};
        if (mem_mib) setrlimit(RLIMIT_AS, &mem);
#endif
        rlimit cpu{cpu_seconds, cpu_seconds};
        if (cpu_seconds) setrlimit(RLIMIT_CPU, &cpu);
        Session s{api, passed[0], passed[1]};
        // A write on a pipe mbconform closed must fail, not kill the session
        // by SIGPIPE before destroy() runs.
        signal(SIGPIPE, SIG_IGN);
        _exit(s.run(config));
      }
      Control r;
      r.op = kSpawned;
      r.pid = p > 0 ? p : 0;
      r.status = p > 0 ? 0 : -errno;
      if (p > 0) {
        session = p;
        session_fd = pidfd_open(p);
      }
      if (!send_control(r)) break;
    }
    for (int fd : passed)
      if (fd >= 0) ::close(fd);
  }
  kill_descendants();
  return 0;
}
