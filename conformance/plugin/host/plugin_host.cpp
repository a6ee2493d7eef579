// mbconform-plugin-host PATH CONFIG: loads one vendor plugin (the C ABI of
// mbconform_plugin.h), creates one instance and serves requests from
// mbconform over a pipe (host_protocol.h). It checks the contract the ABI
// states around every call: a reply length over the capacity, a write past
// the capacity (guard bytes), a negative length without an error message.
// A crash or a hang here costs mbconform one request: it restarts the host.
#include <dlfcn.h>
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <cstddef>
#include <cstdio>
#include <cstring>
#include <string>
#include <vector>

#include "host_protocol.h"
#include "mbconform_plugin.h"

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

bool respond(int32_t status, const void* payload, size_t n) {
  Response r{status, uint32_t(n)};
  return write_all(kResponseFd, &r, sizeof r) && write_all(kResponseFd, payload, n);
}
bool respond(int32_t status, const std::string& text) { return respond(status, text.data(), text.size()); }

constexpr size_t kGuard = 64;

}  // namespace

// Under AddressSanitizer (the CI's sanitizer build) a plugin's SIGSEGV must
// still end this process by that signal, so that mbconform can name it.
extern "C" __attribute__((used, visibility("default"))) const char* __asan_default_options() {
  return "handle_segv=0:handle_sigbus=0:handle_sigfpe=0:handle_sigill=0";
}

namespace {

constexpr uint8_t kGuardByte = 0xA5;

}  // namespace

int main(int argc, char** argv) {
  if (argc != 3) {
    std::fprintf(stderr, "usage: mbconform-plugin-host PLUGIN.so CONFIG (started by mbconform, not by hand)\n");
    return 2;
  }
  void* handle = dlopen(argv[1], RTLD_NOW | RTLD_LOCAL);
  if (!handle) {
    respond(kPluginFailed, std::string("cannot load: ") + dlerror());
    return 1;
  }
  auto entry = reinterpret_cast<mbconform_plugin_entry_fn>(dlsym(handle, MBCONFORM_PLUGIN_ENTRY));
  if (!entry) {
    respond(kPluginFailed, std::string("no ") + MBCONFORM_PLUGIN_ENTRY + " symbol: not an mbconform plugin");
    return 1;
  }
  const mbconform_plugin_api_v1* api = entry();
  const size_t v1_size = offsetof(mbconform_plugin_api_v1, last_error) + sizeof(void*);
  if (!api || api->abi_version != MBCONFORM_PLUGIN_ABI_VERSION || api->struct_size < v1_size) {
    respond(kPluginFailed, "plugin ABI version " + std::to_string(api ? api->abi_version : 0) + " (size " +
                               std::to_string(api ? api->struct_size : 0) + "), this host speaks version " +
                               std::to_string(MBCONFORM_PLUGIN_ABI_VERSION));
    return 1;
  }
  if (!api->create || !api->destroy || (!api->handle_rtu && !api->handle_pdu)) {
    respond(kPluginFailed, "the plugin lacks create, destroy or both handle hooks");
    return 1;
  }
  char error[256] = "";
  void* instance = api->create(argv[2], error, sizeof error);
  if (!instance) {
    error[sizeof error - 1] = 0;
    respond(kPluginFailed, std::string("the plugin refused config '") + argv[2] + "': " + error);
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
  std::vector<uint8_t> out(MBCONFORM_RESPONSE_CAPACITY + kGuard);
  for (;;) {
    Request q;
    if (!read_all(kRequestFd, &q, sizeof q)) break;  // mbconform closed the pipe: done
    payload.resize(q.length);
    if (q.length && !read_all(kRequestFd, payload.data(), q.length)) break;
    bool ok = true;
    if (q.op == kRtu || q.op == kPdu) {
      const char* hook = q.op == kRtu ? "handle_rtu" : "handle_pdu";
      std::fill(out.begin(), out.end(), kGuardByte);
      int n = q.op == kRtu ? (api->handle_rtu ? api->handle_rtu(instance, payload.data(), payload.size(), out.data(),
                                                                MBCONFORM_RESPONSE_CAPACITY)
                                              : -1)
                           : (api->handle_pdu ? api->handle_pdu(instance, q.unit, payload.data(), payload.size(),
                                                                out.data(), MBCONFORM_RESPONSE_CAPACITY)
                                              : -1);
      bool guard_intact = true;
      for (size_t i = MBCONFORM_RESPONSE_CAPACITY; i < out.size(); ++i) guard_intact &= out[i] == kGuardByte;
      if (n > int(MBCONFORM_RESPONSE_CAPACITY))
        ok = respond(kContract, std::string(hook) + " returned " + std::to_string(n) + " bytes, over the " +
                                    std::to_string(MBCONFORM_RESPONSE_CAPACITY) + "-byte response capacity");
      else if (!guard_intact)
        ok = respond(kContract, std::string(hook) + " wrote past the " + std::to_string(MBCONFORM_RESPONSE_CAPACITY) +
                                    "-byte response capacity");
      else if (n < 0)
        ok = failure(n, hook);
      else
        ok = respond(n, out.data(), size_t(n));
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
  dlclose(handle);
  return 0;
}
