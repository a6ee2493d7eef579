// A vendor's slave stack behind the plugin C ABI
// (conformance/plugin/mbconform_plugin.h), fuzzed in process with coverage:
//   MBCONFORM_PLUGIN=./libmystack.so [MBCONFORM_PLUGIN_CONFIG=...] [MBCONFORM_PLUGIN_UNIT=1]
//     plugin_fuzzer -dict=fuzz/device_fuzzer.dict corpus-dir corpus/plugin
// Build the stack with -fsanitize=fuzzer-no-link,address to get its edges
// and its memory errors. Input (fuzz/input_format.h): records [flags][n][n bytes],
// flags bit 0 = append the right CRC; each record is one frame on the line.
// The instance is reset() between inputs (or created anew when the plugin has
// no reset). Invariants, from the ABI's rules and MB-SL v1.02 / MBAP v1.1b3:
// the call returns 0..response_capacity (a negative return is the plugin
// failing), a reply is an RTU frame of 4..256 bytes with a right CRC from
// the plugin's unit, the master judge accepts it for a valid request, and
// frames for another slave id or broadcast get no reply.
#include <dlfcn.h>

#include <cstdio>
#include <cstdlib>
#include <string>
#include <vector>

#include "fuzz_support.h"
#include "input_format.h"
#include "mbconform_plugin.h"
#include "modbus/crc16.h"
#include "modbus/judge.h"

namespace {
using namespace mbc;
constexpr const char* kHarness = "plugin_fuzzer";

const mbconform_plugin_api_v1* api = nullptr;
void* instance = nullptr;
std::string config;
uint8_t unit = 1;

[[noreturn]] void cannot_run(const std::string& why) {
  std::fprintf(stderr, "plugin_fuzzer: %s\n", why.c_str());
  std::exit(2);
}

void* create() {
  char error[256] = {};
  void* in = api->create(config.c_str(), error, sizeof error);
  if (!in) cannot_run(std::string("create(\"") + config + "\") failed: " + error);
  return in;
}

std::string last_error() {
  const char* e = api->last_error ? api->last_error(instance) : nullptr;
  return e ? e : "(no last_error)";
}
}  // namespace

extern "C" int LLVMFuzzerInitialize(int*, char***) {
  const char* path = std::getenv("MBCONFORM_PLUGIN");
  if (!path || !*path) cannot_run("set MBCONFORM_PLUGIN to the plugin's .so");
  if (const char* c = std::getenv("MBCONFORM_PLUGIN_CONFIG")) config = c;
  if (const char* u = std::getenv("MBCONFORM_PLUGIN_UNIT")) unit = uint8_t(std::atoi(u));
  void* lib = dlopen(path, RTLD_NOW | RTLD_LOCAL);
  if (!lib) cannot_run(std::string("dlopen: ") + dlerror());
  auto entry = reinterpret_cast<mbconform_plugin_entry_fn>(dlsym(lib, MBCONFORM_PLUGIN_ENTRY));
  if (!entry) cannot_run(std::string(path) + " exports no " + MBCONFORM_PLUGIN_ENTRY);
  api = entry();
  if (!api || api->abi_version < 1 || api->struct_size < sizeof(mbconform_plugin_api_v1) || !api->create ||
      !api->destroy || (!api->handle_rtu && !api->handle_pdu))
    cannot_run(std::string(path) + ": not a version-1 plugin table with create, destroy and a handler");
  instance = create();
  return 0;
}

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  if (!api) LLVMFuzzerInitialize(nullptr, nullptr);
  if (api->reset) {
    MBC_FUZZ_CHECK(api->reset(instance) == 0, kHarness, "reset() failed: " + last_error());
  } else {
    api->destroy(instance);
    instance = create();
  }
  size_t at = 0;
  for (int frames = 0; at + 2 <= size && frames < 32; ++frames) {
    uint8_t flags = data[at];
    size_t n = std::min<size_t>(data[at + 1], size - at - 2);
    Bytes adu(data + at + 2, data + at + 2 + n);
    at += 2 + n;
    if (flags & fuzz::kFixCrc) {
      append_crc(adu);
    }
    // Exact-size heap buffers, so ASan sees a read or write past either end.
    std::vector<uint8_t> request(adu), response(MBCONFORM_RESPONSE_CAPACITY);
    int got = 0;
    const bool valid = adu.size() >= 4 && adu.size() <= MBCONFORM_MAX_RTU_ADU && crc_ok(adu);
    if (api->handle_rtu) {
      got = api->handle_rtu(instance, request.data(), request.size(), response.data(), response.size());
    } else {
      if (!valid) continue;  // a PDU-only stack never sees a broken frame
      std::vector<uint8_t> pdu(adu.begin() + 1, adu.end() - 2);
      got = api->handle_pdu(instance, adu[0], pdu.data(), pdu.size(), response.data() + 1, response.size() - 3);
      if (got > 0) {  // frame the PDU as the host does
        response[0] = adu[0];
        uint16_t c = crc16(std::span<const uint8_t>(response.data(), size_t(got) + 1));
        response[size_t(got) + 1] = uint8_t(c & 0xFF);
        response[size_t(got) + 2] = uint8_t(c >> 8);
        got += 3;
      }
    }
    auto ctx = [&](const std::string& what) {
      return what + "\n  sent:  " + to_hex(adu) + "\n  reply: " +
             (got > 0 ? to_hex(std::span<const uint8_t>(response.data(), size_t(std::min<int>(got, 512)))) : "(none)");
    };
    MBC_FUZZ_CHECK(got >= 0, kHarness, ctx("the plugin failed: " + last_error()));
    MBC_FUZZ_CHECK(size_t(got) <= response.size(), kHarness, ctx("returned more bytes than response_capacity"));
    if (got == 0) continue;
    std::span<const uint8_t> reply(response.data(), size_t(got));
    MBC_FUZZ_CHECK(reply.size() >= 4 && reply.size() <= MBCONFORM_MAX_RTU_ADU && crc_ok(reply), kHarness,
                   ctx("reply is not an RTU frame of 4..256 bytes with a right CRC (MB-SL v1.02 §2.5.1)"));
    MBC_FUZZ_CHECK(!adu.empty() && adu[0] == unit && reply[0] == unit, kHarness,
                   ctx("a reply to a frame for another slave id or broadcast, or from another id (MB-SL v1.02 §2.1)"));
    if (valid) {
      Judged j = judge_reply(std::span<const uint8_t>(adu).subspan(1, adu.size() - 3), reply.subspan(1, reply.size() - 3));
      std::string problems;
      for (const auto& p : j.problems) problems += "\n  judge: " + p;
      MBC_FUZZ_CHECK(j.ok(), kHarness, ctx("malformed reply" + problems));
    }
  }
  return 0;
}
