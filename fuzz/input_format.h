// How the harnesses read their input bytes, in one place, so the corpus
// generator (corpus_gen.cc) writes seeds the harnesses decode the same way.
//
//   device_fuzzer:       [device][slave][flags][adu...]
//       device  index into the embedded specs (sorted by id), modulo their count
//       slave   the slave id the device is configured with (0 = its default)
//       flags   bit 0: append the correct CRC to adu (else adu is sent as given)
//   session_fuzzer:      [device][slave] then records, until the input ends:
//       0x00 L bytes[L]  a frame: bytes + correct CRC      0x01 L bytes[L]  a frame sent as given
//       0x02 HI LO       advance the virtual clock by HI:LO ms   0x03  power cycle
//       (the record kind is op % 4)
//   differential_fuzzer: [flags][pdu...]   flags bit 0: broadcast (slave 0) else slave 1
//   reply_parser_fuzzer: [n][request pdu: n bytes][reply pdu...]
//   plugin_fuzzer:       records [flags][n][n bytes], flags bit 0: append the correct CRC
//   rtu_frame_fuzzer, spec_loader_fuzzer: the bytes as they are.
//
// These inputs stay binary (they are what libFuzzer mutates). Frame sequences
// for people (plans, counterexamples, the black-box fuzzer's reproducers) are
// frame scripts: conformance/check/README.md.
#pragma once

#include <cstddef>
#include <cstdint>
#include <span>

#include "modbus/hex.h"

namespace mbc::fuzz {

enum DeviceFlags : uint8_t { kFixCrc = 0x01 };
enum SessionOp : uint8_t { kFrameFixCrc = 0, kFrameRaw = 1, kAdvanceMs = 2, kPowerCycle = 3 };
enum DifferentialFlags : uint8_t { kBroadcast = 0x01 };

inline Bytes device_input(uint8_t device, uint8_t slave, uint8_t flags, std::span<const uint8_t> adu) {
  Bytes b{device, slave, flags};
  b.insert(b.end(), adu.begin(), adu.end());
  return b;
}

// Appends one session record.
inline void session_frame(Bytes& in, std::span<const uint8_t> adu, bool fix_crc) {
  in.push_back(fix_crc ? kFrameFixCrc : kFrameRaw);
  in.push_back(uint8_t(adu.size()));
  in.insert(in.end(), adu.begin(), adu.begin() + (adu.size() > 255 ? 255 : adu.size()));
}
inline void session_advance(Bytes& in, uint16_t ms) {
  in.push_back(kAdvanceMs);
  in.push_back(uint8_t(ms >> 8));
  in.push_back(uint8_t(ms));
}

// Appends one plugin_fuzzer record.
inline void plugin_frame(Bytes& in, std::span<const uint8_t> adu, bool fix_crc) {
  in.push_back(fix_crc ? kFixCrc : 0);
  in.push_back(uint8_t(adu.size() > 255 ? 255 : adu.size()));
  in.insert(in.end(), adu.begin(), adu.begin() + (adu.size() > 255 ? 255 : adu.size()));
}

inline Bytes reply_parser_input(std::span<const uint8_t> request, std::span<const uint8_t> reply) {
  Bytes b{uint8_t(request.size())};
  b.insert(b.end(), request.begin(), request.end());
  b.insert(b.end(), reply.begin(), reply.end());
  return b;
}

}  // namespace mbc::fuzz
