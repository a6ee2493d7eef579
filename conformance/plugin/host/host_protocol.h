// The pipe protocol between mbconform (conformance/targets/plugin_target.cpp)
// and mbconform-plugin-host (plugin_host.cpp), the small process a vendor
// plugin runs in so that its crash, abort, hang or broken contract is a
// finding about one request, not the end of the run. Internal: both ends are
// built from this header; it is not part of the plugin ABI.
//
// The host reads requests on descriptor kRequestFd and writes responses on
// kResponseFd (stdout and stderr stay the plugin's own). First it writes one
// response for create(): status 0 and "<hook flags> <name>", or status
// kPluginFailed and the plugin's message. Then, per request, one response.
#pragma once

#include <cstdint>

namespace mbc::conf::plugin_host {

inline constexpr int kRequestFd = 3;
inline constexpr int kResponseFd = 4;

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

// Hook flags in the create() response.
constexpr unsigned kHasRtu = 1, kHasPdu = 2, kHasReset = 4, kHasPowerCycle = 8, kHasAdvance = 16;

}  // namespace mbc::conf::plugin_host
