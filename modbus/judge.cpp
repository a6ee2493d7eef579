#include "modbus/judge.h"

#include <algorithm>

#include "modbus/bytes.h"
#include "modbus/function_codes.h"
#include "modbus/limits.h"
#include "modbus/text.h"

namespace mbc {

Judged judge_reply(std::span<const uint8_t> req, std::span<const uint8_t> rep) {
  Judged j;
  auto problem = [&](std::string s) { j.problems.push_back(std::move(s)); };
  if (rep.empty()) {
    problem("empty reply PDU");
    return j;
  }
  if (rep.size() > kMaxPdu) problem(strf("reply PDU is %zu bytes, over the 253 of MBAP v1.1b3 §4.1", rep.size()));
  uint8_t fc = req.empty() ? 0 : req[0];
  if (rep[0] == uint8_t(fc | kExceptionBit)) {
    j.kind = Judged::Kind::exception;
    if (rep.size() != 2) {
      problem(strf("exception reply is %zu bytes, MBAP v1.1b3 §7 says 2", rep.size()));
      if (rep.size() < 2) { j.kind = Judged::Kind::malformed; return j; }
    }
    j.exception_code = rep[1];
    return j;
  }
  if (rep[0] != fc) {
    problem(strf("reply function code 0x%02X, request was 0x%02X", rep[0], fc));
    return j;
  }
  auto want_size = [&](size_t n) {
    if (rep.size() != n) {
      problem(strf("reply is %zu bytes, expected %zu", rep.size(), n));
      return false;
    }
    return true;
  };
  auto echo = [&](size_t n) {
    if (!want_size(n)) return;
    if (req.size() < n || !std::equal(rep.begin(), rep.begin() + ptrdiff_t(n), req.begin()))
      problem("reply does not echo the request (MBAP v1.1b3 §6)");
  };
  switch (fc) {
    case fc::read_coils:
    case fc::read_discrete_inputs: {
      if (req.size() < 5 || rep.size() < 2) { problem("reply too short"); break; }
      uint16_t q = be16(req, 3);
      size_t n = (q + 7) / 8;
      if (rep[1] != n) problem(strf("byte count %u for %u bits, expected %zu", rep[1], q, n));
      if (!want_size(2 + size_t(rep[1]))) break;
      for (size_t i = 0; i < q && i / 8 < rep[1]; ++i) j.bits.push_back(rep[2 + i / 8] >> (i % 8) & 1);
      if (rep[1] == n && q % 8 && (rep[1 + n] >> (q % 8)))
        problem("padding bits of the last byte are not zero (MBAP v1.1b3 §6.1)");
      break;
    }
    case fc::read_holding_registers:
    case fc::read_input_registers:
    case fc::read_write_multiple_registers: {
      if (req.size() < 5 || rep.size() < 2) { problem("reply too short"); break; }
      uint16_t q = be16(req, 3);
      if (rep[1] != 2 * q) problem(strf("byte count %u for %u registers, expected %d", rep[1], q, 2 * q));
      if (!want_size(2 + size_t(rep[1]))) break;
      for (size_t i = 0; i + 1 < rep[1]; i += 2) j.registers.push_back(be16(rep, 2 + i));
      break;
    }
    case fc::write_single_coil:
    case fc::write_single_register:
    case fc::write_multiple_coils:
    case fc::write_multiple_registers: echo(5); break;
    case fc::mask_write_register: echo(7); break;
    case fc::diagnostics:
      if (rep.size() < 3) problem("diagnostics reply too short");
      break;
    default: break;  // FC 7, 11, 12, 17, 43: variable replies, shape not judged here
  }
  j.kind = j.problems.empty() ? Judged::Kind::normal : Judged::Kind::malformed;
  return j;
}

std::string describe_pdu(std::span<const uint8_t> pdu, bool is_request) {
  if (pdu.empty()) return "(empty)";
  uint8_t fc = pdu[0];
  const char* name = function_name(uint8_t(fc & ~kExceptionBit));
  if (!is_request && (fc & kExceptionBit)) {
    return strf("FC%02d %s exception %s", fc & 0x7F, name,
                pdu.size() > 1 ? strf("%02X", pdu[1]).c_str() : "(missing code)");
  }
  std::string s = strf("FC%02u %s", fc, name);
  if (is_request && pdu.size() >= 5 && (fc <= 6 || fc == 15 || fc == 16 || fc == 22 || fc == 23)) {
    bool single = fc == 5 || fc == 6;
    s += strf(" address %u (0x%04X) %s %u", be16(pdu, 1), be16(pdu, 1), single ? "value" : "quantity", be16(pdu, 3));
  } else if (!is_request && pdu.size() >= 2 && (fc <= 4 || fc == 23)) {
    s += strf(": %u bytes", pdu[1]);
    if (fc >= 3) {
      for (size_t i = 2; i + 1 < pdu.size(); i += 2) s += strf(" %04X", be16(pdu, i));
    }
  } else if (!is_request && pdu.size() >= 5) {
    s += strf(" address %u (0x%04X) %04X", be16(pdu, 1), be16(pdu, 1), be16(pdu, 3));
  }
  return s;
}

}  // namespace mbc
