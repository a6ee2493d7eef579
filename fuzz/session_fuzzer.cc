// A session with one reference device: frames (valid, corrupted, for other
// slave ids), virtual time advancing between them (Device::advance moves the
// axis and runs timed behaviour) and power cycles. Every exchange keeps the
// invariants of check_exchange; the clock only moves forward; a power cycle
// brings volatile registers back to the spec's defaults.
#include <cstddef>
#include <cstdint>

#include "fuzz_support.h"
#include "input_format.h"
#include "modbus/crc16.h"

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  using namespace mbc;
  constexpr const char* kHarness = "session_fuzzer";
  if (size < 2) return 0;
  const auto& all = fuzz::specs();
  size_t index = data[0] % all.size();
  const spec::Spec& s = all[index];
  uint8_t slave = data[1] ? data[1] : fuzz::default_slave(s);
  ref::Device& d = fuzz::fresh_device(index, slave);
  size_t at = 2;
  int steps = 0;
  while (at < size && steps++ < 256) {
    uint8_t op = data[at++] % 4;
    switch (op) {
      case fuzz::kFrameFixCrc:
      case fuzz::kFrameRaw: {
        if (at >= size) return 0;
        size_t len = data[at++];
        size_t n = std::min<size_t>(len, size - at);
        Bytes adu(data + at, data + at + n);
        at += n;
        if (op == fuzz::kFrameFixCrc) {
          append_crc(adu);
        }
        auto before = fuzz::holding_image(d);
        auto reply = d.handle_rtu(adu);
        fuzz::check_exchange(kHarness, d, adu, reply, before, fuzz::holding_image(d));
        break;
      }
      case fuzz::kAdvanceMs: {
        if (at + 2 > size) return 0;
        uint64_t ms = uint64_t(data[at]) << 8 | data[at + 1];
        at += 2;
        uint64_t t0 = d.now_us();
        d.advance(ms * 1000);
        MBC_FUZZ_CHECK(d.now_us() == t0 + ms * 1000, kHarness, "virtual clock did not advance by the amount asked");
        break;
      }
      case fuzz::kPowerCycle: {
        d.power_cycle();
        // Volatile holding registers come back to the spec's default after a
        // power cycle (the spec's persistence: store none). Registers a
        // behaviour computes on power-up (status, position) are read-only.
        for (const auto& r : s.registers) {
          if (r.table != spec::Table::holding || r.persistence.store != spec::Store::none || !r.default_value ||
              r.access == spec::Access::ro || r.access == spec::Access::command || r.type == spec::DataType::f32)
            continue;
          int64_t want = int64_t(*r.default_value);
          MBC_FUZZ_CHECK(d.value(r) == want, kHarness,
                         s.device.id + ": after a power cycle volatile register " + r.key + " holds " +
                             std::to_string(d.value(r)) + ", its default is " + std::to_string(want));
        }
        break;
      }
    }
  }
  return 0;
}
