// The master side of the protocol: building request PDUs and judging the
// replies a target sends back (MBAP v1.1b3 §6 for every function code). The
// runner, the property tests and the black-box fuzzer all judge replies here,
// from the standard alone; nothing in this file knows the reference devices.
#pragma once

#include <cstdint>
#include <optional>
#include <span>
#include <string>
#include <vector>

#include "codec/hex.h"

namespace mbc::conf {

// Request builders (no slave id, no CRC: a PDU).
Bytes read_request(uint8_t fc, uint16_t address, uint16_t quantity);  // FC 01-04
Bytes write_single_register(uint16_t address, uint16_t value);         // FC 06
Bytes write_single_coil(uint16_t address, bool on);                    // FC 05
Bytes write_multiple_registers(uint16_t address, std::span<const uint16_t> values);  // FC 16
Bytes write_multiple_coils(uint16_t address, std::span<const bool> values);          // FC 15
Bytes mask_write_register(uint16_t address, uint16_t and_mask, uint16_t or_mask);    // FC 22
Bytes read_write_registers(uint16_t read_address, uint16_t read_quantity, uint16_t write_address,
                           std::span<const uint16_t> values);                        // FC 23

// RTU ADU around a PDU: slave, PDU, CRC low byte first (MB-SL v1.02 §2.5.1).
Bytes rtu_frame(uint8_t slave, std::span<const uint8_t> pdu);

// What a reply PDU says, judged against the request that provoked it.
struct Judged {
  enum class Kind { normal, exception, malformed } kind = Kind::malformed;
  uint8_t exception_code = 0;
  std::vector<uint16_t> registers;  // FC 03, 04, 23
  std::vector<bool> bits;           // FC 01, 02 (exactly quantity bits)
  // Every way the reply departs from MBAP v1.1b3 for this request: wrong
  // function code, byte count != 2 x quantity, echo of FC 05/06/15/16 not
  // matching the request, padding bits set, over 253 bytes. Empty when well formed.
  std::vector<std::string> problems;
  bool ok() const { return problems.empty() && kind != Kind::malformed; }
};
Judged judge_reply(std::span<const uint8_t> request_pdu, std::span<const uint8_t> reply_pdu);

// A reply frame decoded for people: "FC03 read holding registers: 2 bytes: 0x1234".
std::string describe_pdu(std::span<const uint8_t> pdu, bool is_request);

}  // namespace mbc::conf
