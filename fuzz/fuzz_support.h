// What every harness shares: the specs compiled in (so a harness runs where
// there is no source tree, e.g. on OSS-Fuzz), one reusable reference device
// per spec, and the invariants a device exchange must keep. A broken
// invariant is a finding: it prints what was sent and what came back, as hex,
// and aborts so libFuzzer (or the replay main) saves and reports the input.
#pragma once

#include <cstdint>
#include <map>
#include <optional>
#include <span>
#include <string>
#include <string_view>
#include <vector>

#include "engine/device.h"
#include "modbus/hex.h"
#include "spec.h"

namespace mbc::fuzz {

struct EmbeddedSpec {
  std::string_view id;
  std::string_view yaml;
};
// spec/devices/*.yaml at build time, sorted by id (generated: embed_specs.cmake).
const std::vector<EmbeddedSpec>& embedded_specs();

// The embedded specs, loaded once; a spec that does not load is a build error
// of the project (its own tests fail too), so this aborts with the diagnostics.
const std::vector<spec::Spec>& specs();
const spec::Spec& spec_by_id(std::string_view id);

// Reports a broken invariant and aborts.
[[noreturn]] void finding(const char* harness, const std::string& what);

#define MBC_FUZZ_CHECK(cond, harness, what)               \
  do {                                                     \
    if (!(cond)) ::mbc::fuzz::finding(harness, (what));   \
  } while (0)

// The slave id a device is configured with when the input says 0: the spec's
// default, else 1 (a drive whose id comes from DIP switches has no default).
uint8_t default_slave(const spec::Spec&);

// One reference device per spec, reused across inputs (building one clears
// 400 KB of tables). fresh_device() returns it in its factory state.
ref::Device& fresh_device(size_t spec_index, uint8_t slave_id);

// The holding-register image (the words of every holding register the spec
// maps, in address order): ref::Device::holding_image() as a flat vector, so
// harnesses can take it before and after every frame cheaply.
using Image = std::vector<uint16_t>;
Image holding_image(const ref::Device&);

// The invariants of one RTU exchange with a reference device, from the
// standard and the device's spec (never from the engine's code):
//  * a reply is a well-formed RTU frame (4..256 bytes, CRC right) from the
//    device's own slave id, and the master-side judge accepts it for the request
//    (byte count = 2 x quantity, echoes, exception codes the spec or MBAP §7 know);
//  * nothing is answered to another slave id or to broadcast (MB-SL v1.02 §2.1);
//  * a frame that is not valid for this device (bad length or CRC, another
//    slave id) changes no holding register, and neither does an exception
//    reply ("rejection changes nothing", MBAP v1.1b3 §7);
//  * a CRC error is answered only as the spec's crc_error policy says.
void check_exchange(const char* harness, const ref::Device& device, std::span<const uint8_t> adu,
                    const std::optional<Bytes>& reply, const Image& before, const Image& after);

// "01 03 00 00 00 01 84 0A" or "(silence)".
std::string hex_or_silence(const std::optional<Bytes>& b);

}  // namespace mbc::fuzz
