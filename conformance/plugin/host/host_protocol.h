// The protocol between mbconform (conformance/targets/plugin_target.cpp) and
// mbconform-plugin-host (plugin_host.cpp), the fork server a vendor plugin
// runs in so that its crash, abort, hang or broken contract is a finding
// about one request, not the end of the run. Internal: both ends are built
// from this header; it is not part of the plugin ABI.
//
// The host loads the plugin once (dlopen, the entry point, the ABI checks)
// and then forks one session per instance: a session calls create(), serves
// requests and ends with destroy(). A crash costs a fork, not an exec and a
// load (bench/bench_plugin_restart.cpp measures it).
//
// Control: a SOCK_SEQPACKET socket on descriptor kControlFd, one Control
// message per packet. The host first sends kLoaded (status 0, or
// kPluginFailed and why in `text`). mbconform sends kSpawn with the session's
// two pipe ends as SCM_RIGHTS (the request pipe's read end, the response
// pipe's write end); the host answers kSpawned with the session's pid. When a
// session ends for any reason the host reaps it and sends kExited with its
// wait status. kKill asks it to SIGKILL the session (a watchdog). When the
// control socket closes, the host kills every process the plugin left
// (it is their subreaper) and exits.
//
// Session: it reads requests on its request pipe and writes responses on its
// response pipe (stdout and stderr stay the plugin's own). First it writes
// one response for create(): status 0 and "<hook flags> <name>", or status
// kPluginFailed and the plugin's message. Then, per request, one response.
#pragma once

#include <cstdint>

namespace mbc::conf::plugin_host {

inline constexpr int kControlFd = 3;

enum Op : uint8_t { kRtu = 1, kPdu = 2, kReset = 3, kPowerCycle = 4, kAdvance = 5 };

struct Request {
  uint8_t op = 0;
  uint8_t unit = 0;  // kPdu
  uint8_t pad[2] = {0, 0};
  uint32_t length = 0;  // payload bytes that follow (kRtu: the ADU, kPdu: the PDU)
  uint64_t arg = 0;     // kAdvance: microseconds
};

// status >= 0: the hook's result (kRtu/kPdu: the reply length, the payload
// the reply); kPluginFailed: the hook returned a failure, the payload is
// last_error(); kContract: the plugin broke the ABI's contract, the payload
// says how ("returned 600 bytes, over the 512-byte capacity").
inline constexpr int32_t kPluginFailed = -1;
inline constexpr int32_t kContract = -2;

struct Response {
  int32_t status = 0;
  uint32_t length = 0;
};

enum ControlOp : uint8_t { kLoaded = 1, kSpawn = 2, kSpawned = 3, kExited = 4, kKill = 5 };

struct Control {
  uint8_t op = 0;
  uint8_t pad[3] = {0, 0, 0};
  int32_t pid = 0;     // kSpawned, kExited, kKill
  int32_t status = 0;  // kLoaded: 0 or kPluginFailed; kExited: the wait status; kSpawned: -errno when fork failed
  char text[500] = {};  // kLoaded: why the plugin cannot be used (NUL-terminated)
};

// Hook flags in the create() response.
constexpr unsigned kHasRtu = 1, kHasPdu = 2, kHasReset = 4, kHasPowerCycle = 8, kHasAdvance = 16;

}  // namespace mbc::conf::plugin_host
