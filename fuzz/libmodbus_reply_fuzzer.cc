// The baseline of the benchmark (bench/fuzz_exec_bench.cpp) and a robustness
// harness for libmodbus itself: modbus_reply() on the mapping the
// differential harness uses, fed the same input format (fuzz/input_format.h:
// [flags][pdu]) framed the same way. Invariant: a reply, when one comes, is a
// well-formed RTU frame from slave 1 (MB-SL v1.02 §2.5.1).
#include <cstddef>
#include <cstdint>

#include "fuzz_support.h"
#include "input_format.h"
#include "libmodbus_server.h"
#include "modbus/crc16.h"
#include "modbus/limits.h"
#include "modbus/rtu.h"

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  using namespace mbc;
  static fuzz::LibmodbusServer server(1);
  if (size < 2) return 0;
  Bytes adu;  // reserve + push_back: see differential_fuzzer.cc (gcc 12 -Warray-bounds)
  adu.reserve(size + kRtuCrc);
  adu.push_back((data[0] & fuzz::kBroadcast) ? uint8_t(0) : uint8_t(1));
  adu.insert(adu.end(), data + 1, data + size);
  Bytes probe = adu;
  if (probe.size() < 12) probe.resize(12, 0);
  if (auto n = rtu_adu_length(probe, Direction::request)) {
    if (*n > kMaxRtuAdu) return 0;
    adu.resize(*n - 2, 0);
  }
  if (adu.size() > kMaxRtuAdu - kRtuCrc) return 0;
  append_crc(adu);
  auto reply = server.reply(adu);
  if (reply)
    MBC_FUZZ_CHECK(reply->size() >= 4 && reply->size() <= kMaxRtuAdu && crc_ok(*reply) && (*reply)[0] == 1, "libmodbus_reply_fuzzer",
                   "libmodbus reply is not a well-formed RTU frame\n  request: " + to_hex(adu) + "\n  reply:   " + to_hex(*reply));
  return 0;
}
