// Every spec'd reference device handling one RTU frame. The first input byte
// picks the device (fuzz/input_format.h), so one binary covers all of them
// and a new spec is fuzzed without a new harness.
#include <cstddef>
#include <cstdint>

#include "fuzz_support.h"
#include "input_format.h"
#include "modbus/crc16.h"

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  using namespace mbc;
  if (size < 3) return 0;
  const auto& all = fuzz::specs();
  size_t index = data[0] % all.size();
  uint8_t slave = data[1] ? data[1] : fuzz::default_slave(all[index]);
  Bytes adu(data + 3, data + size);
  if (data[2] & fuzz::kFixCrc) {
    append_crc(adu);
  }
  ref::Device& d = fuzz::fresh_device(index, slave);
  auto before = fuzz::holding_image(d);
  auto reply = d.handle_rtu(adu);
  fuzz::check_exchange("device_fuzzer", d, adu, reply, before, fuzz::holding_image(d));
  return 0;
}
