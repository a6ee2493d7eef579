// LD_PRELOAD shim: the process it is loaded into sees the timers of a host
// without high-resolution timers (a kernel or virtual machine whose timers
// fire on the scheduler tick, 4 ms at HZ=250): clock_getres says 4 ms, and a
// wait with a timeout (epoll_pwait2, epoll_wait, ppoll, poll) ends at the
// first tick after its deadline, not at it. With COARSE_TIMERS_LATE_US=N
// instead, clock_getres tells the truth and every such wait ends N us after
// its deadline (a large timer slack, a busy hypervisor). The served line's
// tests start `serve` under it to show its characters still come at their
// line time.
#define _GNU_SOURCE
#include <dlfcn.h>
#include <poll.h>
#include <signal.h>
#include <stdint.h>
#include <stdlib.h>
#include <sys/epoll.h>
#include <time.h>

static const int64_t kTickNs = 4000000;

static int64_t now_ns(void) {
  struct timespec t;
  clock_gettime(CLOCK_MONOTONIC, &t);
  return (int64_t)t.tv_sec * 1000000000 + t.tv_nsec;
}

// COARSE_TIMERS_LATE_US in ns, -1 when unset.
static int64_t late_ns(void) {
  static int64_t late = -2;
  if (late == -2) {
    const char* v = getenv("COARSE_TIMERS_LATE_US");
    late = v ? atoll(v) * 1000 : -1;
  }
  return late;
}

// The timeout that ends at the first tick at or after `timeout` from now
// (or COARSE_TIMERS_LATE_US after it).
static struct timespec on_tick(const struct timespec* timeout) {
  int64_t now = now_ns();
  int64_t due = now + (int64_t)timeout->tv_sec * 1000000000 + timeout->tv_nsec;
  int64_t tick = late_ns() >= 0 ? due + late_ns() : (due + kTickNs - 1) / kTickNs * kTickNs;
  int64_t wait = tick - now;
  struct timespec out = {(time_t)(wait / 1000000000), (long)(wait % 1000000000)};
  return out;
}

int clock_getres(clockid_t id, struct timespec* res) {
  if (late_ns() >= 0) {
    static int (*real)(clockid_t, struct timespec*);
    if (!real) real = (int (*)(clockid_t, struct timespec*))dlsym(RTLD_NEXT, "clock_getres");
    return real(id, res);
  }
  if (res) res->tv_sec = 0, res->tv_nsec = kTickNs;
  return 0;
}

int epoll_pwait2(int epfd, struct epoll_event* events, int maxevents, const struct timespec* timeout, const sigset_t* sigmask) {
  static int (*real)(int, struct epoll_event*, int, const struct timespec*, const sigset_t*);
  if (!real) real = (int (*)(int, struct epoll_event*, int, const struct timespec*, const sigset_t*))dlsym(RTLD_NEXT, "epoll_pwait2");
  if (!timeout || (timeout->tv_sec == 0 && timeout->tv_nsec == 0)) return real(epfd, events, maxevents, timeout, sigmask);
  struct timespec t = on_tick(timeout);
  return real(epfd, events, maxevents, &t, sigmask);
}

int ppoll(struct pollfd* fds, nfds_t n, const struct timespec* timeout, const sigset_t* sigmask) {
  static int (*real)(struct pollfd*, nfds_t, const struct timespec*, const sigset_t*);
  if (!real) real = (int (*)(struct pollfd*, nfds_t, const struct timespec*, const sigset_t*))dlsym(RTLD_NEXT, "ppoll");
  if (!timeout || (timeout->tv_sec == 0 && timeout->tv_nsec == 0)) return real(fds, n, timeout, sigmask);
  struct timespec t = on_tick(timeout);
  return real(fds, n, &t, sigmask);
}

static struct timespec of_ms(int ms) {
  struct timespec t = {ms / 1000, (long)(ms % 1000) * 1000000L};
  return t;
}

int epoll_wait(int epfd, struct epoll_event* events, int maxevents, int ms) {
  if (ms <= 0) {
    static int (*real)(int, struct epoll_event*, int, int);
    if (!real) real = (int (*)(int, struct epoll_event*, int, int))dlsym(RTLD_NEXT, "epoll_wait");
    return real(epfd, events, maxevents, ms);
  }
  struct timespec t = of_ms(ms);
  return epoll_pwait2(epfd, events, maxevents, &t, 0);
}

int poll(struct pollfd* fds, nfds_t n, int ms) {
  if (ms <= 0) {
    static int (*real)(struct pollfd*, nfds_t, int);
    if (!real) real = (int (*)(struct pollfd*, nfds_t, int))dlsym(RTLD_NEXT, "poll");
    return real(fds, n, ms);
  }
  struct timespec t = of_ms(ms);
  return ppoll(fds, n, &t, 0);
}
