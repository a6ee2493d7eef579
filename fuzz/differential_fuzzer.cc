// Differential: the reference engine running the modbus-standard spec against
// libmodbus's modbus_reply() on an equivalent mapping (fuzz/libmodbus_server.h),
// fed the same RTU request. Any difference in the reply bytes, or in the
// coils and holding registers afterwards, is a finding, except the documented
// differences in kKnownDifferences (fuzz/README.md says which side MBAP
// v1.1b3 backs and why). Everything else that differs is new.
#include <cstddef>
#include <cstdint>
#include <string_view>

#include "fuzz_support.h"
#include "input_format.h"
#include "libmodbus_server.h"
#include "modbus/bytes.h"
#include "modbus/crc16.h"
#include "modbus/judge.h"
#include "modbus/limits.h"
#include "modbus/pdu.h"
#include "modbus/rtu.h"

namespace {
using namespace mbc;
using fuzz::LibmodbusServer;
constexpr const char* kHarness = "differential_fuzzer";
constexpr uint8_t kSlave = 1;


// A documented difference: its name (a heading in fuzz/README.md) and when it applies.
struct KnownDifference {
  std::string_view name;
  bool (*applies)(std::span<const uint8_t> pdu, const std::optional<Bytes>& engine, const std::optional<Bytes>& libmodbus);
};

bool holding_range_touches_extra(std::span<const uint8_t> pdu) {
  // The spec maps holding 0x0200..0x0212 beyond the 256-register block the
  // libmodbus mapping mirrors (a contiguous modbus_mapping_t cannot leave the
  // spec's gap 0x0100..0x01FF unmapped).
  auto touches = [](uint32_t start, uint32_t count) { return start + count > 0x0200 && start <= 0x0212; };
  uint8_t fc = pdu[0];
  if (pdu.size() < 5) return false;
  uint16_t a = be16(pdu, 1), q = be16(pdu, 3);
  switch (fc) {
    case 3: case 16: return touches(a, q ? q : 1);
    case 6: case 22: return touches(a, 1);
    case 23: return touches(a, q ? q : 1) || (pdu.size() >= 9 && touches(be16(pdu, 5), be16(pdu, 7) ? be16(pdu, 7) : 1));
    default: return false;
  }
}

const KnownDifference kKnownDifferences[] = {
    // MBAP §6.7, §6.8, §6.13, §6.21: contents are device specific (FC 07 status
    // byte, FC 08 serial-line diagnostics, FC 17 server id, FC 43/14 identification
    // objects); libmodbus 3.1.6 implements some differently and some not at all.
    {"device-specific-functions",
     [](auto pdu, auto&, auto&) { return pdu[0] == 7 || pdu[0] == 8 || pdu[0] == 17 || pdu[0] == 43; }},
    {"extra-holding-registers", [](auto pdu, auto&, auto&) { return holding_range_touches_extra(pdu); }},
    // MBAP §4.1: codes 128-255 are reserved for exception responses, and an
    // exception reply's function code is the request's + 0x80 (§7).
    // libmodbus 3.1.6 adds 0x80 in a uint8_t: a request with FC 0xF6 gets
    // "76 01" (a normal-looking reply for FC 0x76); the engine answers "F6 01".
    {"exception-fc-overflow", [](auto pdu, auto&, auto&) { return pdu[0] >= 0x80; }},
    // MBAP §6.5 Figure 15 checks the output value (0x0000 or 0xFF00, else 03)
    // before the address (else 02); libmodbus 3.1.6 checks the address first,
    // so FC 05 with a bad value outside its map gets 02 there, 03 from the engine.
    {"fc05-check-order",
     [](auto pdu, auto&, auto&) { return pdu[0] == 5 && pdu.size() >= 5 && be16(pdu, 3) != 0 && be16(pdu, 3) != 0xFF00; }},
    // MBAP §6.11 Figure 21: "Byte Count == N" (N = quantity / 8, rounded up) is
    // a condition for executing FC 15; libmodbus 3.1.6 writes the coils whatever
    // the byte count says (the engine answers 03 and writes nothing).
    {"fc15-byte-count-unchecked",
     [](auto pdu, auto&, auto&) { return pdu[0] == 15 && pdu.size() >= 6 && pdu[5] != (be16(pdu, 3) + 7) / 8; }},
};

struct Pair {
  size_t engine_index = 0;
  LibmodbusServer libmodbus{kSlave};
  Pair() {
    const auto& all = fuzz::specs();
    while (all[engine_index].device.id != "modbus-standard") ++engine_index;
  }
};
}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  static Pair pair;
  if (size < 2) return 0;
  const bool broadcast = data[0] & fuzz::kBroadcast;
  // Built by reserve + push_back: gcc 12 takes insert into a one-element
  // vector for a write past its end (-Warray-bounds, a false positive).
  Bytes adu;
  adu.reserve(size + kRtuCrc);
  adu.push_back(broadcast ? uint8_t(0) : kSlave);
  adu.insert(adu.end(), data + 1, data + size);
  // Frame it as a receiver would deliver it: the length the function code
  // implies (MBAP §6; libmodbus's receive does the same), else as given.
  // A truncated head is padded with zeros until its length is decided.
  Bytes probe = adu;
  if (probe.size() < 12) probe.resize(12, 0);
  if (auto n = rtu_adu_length(probe, Direction::request)) {
    if (*n > kMaxRtuAdu) return 0;  // not an RTU frame (MB-SL §2.5.1.1)
    adu.resize(*n - 2, 0);
  }
  if (adu.size() > kMaxRtuAdu - kRtuCrc) return 0;
  append_crc(adu);
  std::span<const uint8_t> pdu(adu.data() + 1, adu.size() - 3);

  ref::Device& d = fuzz::fresh_device(pair.engine_index, kSlave);
  modbus_mapping_t& m = pair.libmodbus.map();
  for (int a = 0; a < LibmodbusServer::kItems; ++a) {
    m.tab_bits[a] = d.coil(uint16_t(a));
    m.tab_input_bits[a] = d.discrete_input(uint16_t(a));
    m.tab_input_registers[a] = d.input_word(uint16_t(a));
    m.tab_registers[a] = d.word(uint16_t(a));
  }
  auto engine = d.handle_rtu(adu);
  auto libmodbus = pair.libmodbus.reply(adu);

  for (const auto& k : kKnownDifferences)
    if (k.applies(pdu, engine, libmodbus)) return 0;

  auto ctx = [&](const std::string& what) {
    return what + "\n  request:   " + to_hex(adu) + "  (" + describe_pdu(pdu, true) + ")\n  engine:    " +
           fuzz::hex_or_silence(engine) + "\n  libmodbus: " + fuzz::hex_or_silence(libmodbus);
  };
  MBC_FUZZ_CHECK(engine == libmodbus, kHarness, ctx("replies differ"));
  for (int a = 0; a < LibmodbusServer::kItems; ++a) {
    MBC_FUZZ_CHECK(bool(m.tab_bits[a]) == d.coil(uint16_t(a)), kHarness, ctx("coil " + std::to_string(a) + " differs afterwards"));
    MBC_FUZZ_CHECK(m.tab_registers[a] == d.word(uint16_t(a)), kHarness,
                   ctx("holding register " + std::to_string(a) + " differs afterwards"));
  }
  return 0;
}
