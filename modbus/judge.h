// The master's judgement of a reply (MBAP v1.1b3 §6 for every function code,
// §7 for exceptions), from the standard alone: the runner, the property tests
// and the black-box fuzzer all judge replies here.
#pragma once

#include <cstdint>
#include <span>
#include <string>
#include <vector>

namespace mbc {

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

// A PDU decoded for people: "FC03 read holding registers: 2 bytes: 0x1234".
std::string describe_pdu(std::span<const uint8_t> pdu, bool is_request);

}  // namespace mbc
