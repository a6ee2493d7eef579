// Crash recovery of the plugin target (conformance/plugin/host/: a fork
// server), measured in one run beside two baselines:
//   - request: one ordinary request's round trip to the plugin session;
//   - cold start: opening the target anew (a host process started, the
//     plugin loaded, a session forked and its create() answered): what each
//     crash cost before the host forked its sessions (plus the second the
//     old host spent waiting for a child it had already reaped);
//   - recovery: a request that crashes the session (SIGSEGV) until the next
//     request is answered: the crash seen, the session reaped, a new one
//     forked and created, and that next request's round trip.
// Target: recovery p50 <= 10 ms, and recovery / cold start < 1.
//
//   build/bin/mbc_bench_plugin_restart [PLUGIN.so] [--n 200]
//
// Exit 0 when the target is met, 1 when not, 2 on a usage or setup error.
#include <fmt/core.h>

#include <algorithm>
#include <chrono>
#include <cstdlib>
#include <cstring>
#include <string>
#include <vector>

#include "targets/percentile.h"
#include "targets/target.h"

namespace {

using Clock = std::chrono::steady_clock;

double ms_since(Clock::time_point t0) { return std::chrono::duration<double, std::milli>(Clock::now() - t0).count(); }

double pct(std::vector<double> v, unsigned percent) {
  return v.empty() ? 0 : mbc::conf::percentile(std::span(v), percent);
}

}  // namespace

int main(int argc, char** argv) {
  std::string plugin = BENCH_CRASH_PLUGIN;
  int n = 200;
  for (int i = 1; i < argc; ++i) {
    if (!std::strcmp(argv[i], "--n") && i + 1 < argc) n = std::max(10, std::atoi(argv[++i]));
    else if (argv[i][0] != '-') plugin = argv[i];
    else {
      fmt::print(stderr, "usage: mbc_bench_plugin_restart [PLUGIN.so] [--n N]\n");
      return 2;
    }
  }
  const std::string uri = "plugin:" + plugin + "?unit=1";
  const uint8_t read[] = {0x03, 0x00, 0x00, 0x00, 0x01};
  const uint8_t crash[] = {0x41, 0x00};
  std::vector<double> request, cold, recovery;
  try {
    for (int i = 0; i < std::max(10, n / 10); ++i) {
      auto t0 = Clock::now();
      auto t = mbc::conf::open_target(uri);
      t->transact(1, read);
      cold.push_back(ms_since(t0));
    }
    auto t = mbc::conf::open_target(uri);
    for (int i = 0; i < n; ++i) {
      auto t0 = Clock::now();
      auto r = t->transact(1, read);
      request.push_back(ms_since(t0));
      if (!r.pdu) throw std::runtime_error("no answer to FC 03");
    }
    int faults = 0;
    for (int i = 0; i < n; ++i) {
      auto t0 = Clock::now();
      try {
        t->transact(1, crash);
      } catch (const mbc::conf::RecoveredFault&) {
        ++faults;
      }
      auto r = t->transact(1, read);
      recovery.push_back(ms_since(t0));
      if (!r.pdu) throw std::runtime_error("no answer after a crash");
    }
    if (faults != n) throw std::runtime_error(fmt::format("{} of {} crashes were reported", faults, n));
  } catch (const std::exception& e) {
    fmt::print(stderr, "mbc_bench_plugin_restart: {}\n", e.what());
    return 2;
  }
  fmt::print("plugin: {}\n", plugin);
  fmt::print("{:<12} {:>6} {:>9} {:>9}\n", "", "n", "p50 ms", "p99 ms");
  fmt::print("{:<12} {:>6} {:>9.3f} {:>9.3f}\n", "request", request.size(), pct(request, 50), pct(request, 99));
  fmt::print("{:<12} {:>6} {:>9.3f} {:>9.3f}\n", "cold start", cold.size(), pct(cold, 50), pct(cold, 99));
  fmt::print("{:<12} {:>6} {:>9.3f} {:>9.3f}\n", "recovery", recovery.size(), pct(recovery, 50), pct(recovery, 99));
  double ratio = pct(recovery, 50) / pct(cold, 50);
  bool ok = pct(recovery, 50) <= 10.0 && ratio < 1.0;
  fmt::print("recovery / cold start: {:.2f}; recovery / request: {:.1f}; target recovery p50 <= 10 ms: {}\n", ratio,
             pct(recovery, 50) / pct(request, 50), ok ? "met" : "NOT met");
  return ok ? 0 : 1;
}
