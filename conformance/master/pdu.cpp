#include "master/pdu.h"

#include <fmt/core.h>

#include "codec/crc16.h"

namespace mbc::conf {
namespace {

void put16(Bytes& b, uint16_t v) {
  b.push_back(uint8_t(v >> 8));
  b.push_back(uint8_t(v & 0xFF));
}
uint16_t be16(std::span<const uint8_t> p, size_t at) { return uint16_t(p[at] << 8 | p[at + 1]); }

constexpr size_t kMaxPdu = 253;  // MBAP v1.1b3 §4.1

const char* fc_name(uint8_t fc) {
  switch (fc & 0x7F) {
    case 1: return "read coils";
    case 2: return "read discrete inputs";
    case 3: return "read holding registers";
    case 4: return "read input registers";
    case 5: return "write single coil";
    case 6: return "write single register";
    case 7: return "read exception status";
    case 8: return "diagnostics";
    case 11: return "get comm event counter";
    case 12: return "get comm event log";
    case 15: return "write multiple coils";
    case 16: return "write multiple registers";
    case 17: return "report server id";
    case 22: return "mask write register";
    case 23: return "read/write multiple registers";
    case 43: return "encapsulated interface";
    default: return "unknown function";
  }
}

}  // namespace

Bytes read_request(uint8_t fc, uint16_t address, uint16_t quantity) {
  Bytes b{fc};
  put16(b, address);
  put16(b, quantity);
  return b;
}

Bytes write_single_register(uint16_t address, uint16_t value) {
  Bytes b{6};
  put16(b, address);
  put16(b, value);
  return b;
}

Bytes write_single_coil(uint16_t address, bool on) {
  Bytes b{5};
  put16(b, address);
  put16(b, on ? 0xFF00 : 0x0000);
  return b;
}

Bytes write_multiple_registers(uint16_t address, std::span<const uint16_t> values) {
  Bytes b{16};
  put16(b, address);
  put16(b, uint16_t(values.size()));
  b.push_back(uint8_t(values.size() * 2));
  for (uint16_t v : values) put16(b, v);
  return b;
}

Bytes write_multiple_coils(uint16_t address, std::span<const bool> values) {
  Bytes b{15};
  put16(b, address);
  put16(b, uint16_t(values.size()));
  size_t n = (values.size() + 7) / 8;
  b.push_back(uint8_t(n));
  size_t at = b.size();
  b.resize(at + n, 0);
  for (size_t i = 0; i < values.size(); ++i)
    if (values[i]) b[at + i / 8] |= uint8_t(1u << (i % 8));
  return b;
}

Bytes mask_write_register(uint16_t address, uint16_t and_mask, uint16_t or_mask) {
  Bytes b{22};
  put16(b, address);
  put16(b, and_mask);
  put16(b, or_mask);
  return b;
}

Bytes read_write_registers(uint16_t read_address, uint16_t read_quantity, uint16_t write_address,
                           std::span<const uint16_t> values) {
  Bytes b{23};
  put16(b, read_address);
  put16(b, read_quantity);
  put16(b, write_address);
  put16(b, uint16_t(values.size()));
  b.push_back(uint8_t(values.size() * 2));
  for (uint16_t v : values) put16(b, v);
  return b;
}

Bytes rtu_frame(uint8_t slave, std::span<const uint8_t> pdu) {
  Bytes b{slave};
  b.insert(b.end(), pdu.begin(), pdu.end());
  uint16_t crc = crc16(b);
  b.push_back(uint8_t(crc & 0xFF));
  b.push_back(uint8_t(crc >> 8));
  return b;
}

Judged judge_reply(std::span<const uint8_t> req, std::span<const uint8_t> rep) {
  Judged j;
  auto problem = [&](std::string s) { j.problems.push_back(std::move(s)); };
  if (rep.empty()) {
    problem("empty reply PDU");
    return j;
  }
  if (rep.size() > kMaxPdu) problem(fmt::format("reply PDU is {} bytes, over the 253 of MBAP v1.1b3 §4.1", rep.size()));
  uint8_t fc = req.empty() ? 0 : req[0];
  if (rep[0] == uint8_t(fc | 0x80)) {
    j.kind = Judged::Kind::exception;
    if (rep.size() != 2) {
      problem(fmt::format("exception reply is {} bytes, MBAP v1.1b3 §7 says 2", rep.size()));
      if (rep.size() < 2) { j.kind = Judged::Kind::malformed; return j; }
    }
    j.exception_code = rep[1];
    return j;
  }
  if (rep[0] != fc) {
    problem(fmt::format("reply function code 0x{:02X}, request was 0x{:02X}", rep[0], fc));
    return j;
  }
  auto want_size = [&](size_t n) {
    if (rep.size() != n) {
      problem(fmt::format("reply is {} bytes, expected {}", rep.size(), n));
      return false;
    }
    return true;
  };
  auto echo = [&](size_t n) {
    if (!want_size(n)) return;
    if (req.size() < n || !std::equal(rep.begin(), rep.begin() + n, req.begin()))
      problem("reply does not echo the request (MBAP v1.1b3 §6)");
  };
  switch (fc) {
    case 1:
    case 2: {
      if (req.size() < 5 || rep.size() < 2) { problem("reply too short"); break; }
      uint16_t q = be16(req, 3);
      size_t n = (q + 7) / 8;
      if (rep[1] != n) problem(fmt::format("byte count {} for {} bits, expected {}", rep[1], q, n));
      if (!want_size(2 + size_t(rep[1]))) break;
      for (size_t i = 0; i < q && i / 8 < rep[1]; ++i) j.bits.push_back(rep[2 + i / 8] >> (i % 8) & 1);
      if (rep[1] == n && q % 8 && (rep[1 + n] >> (q % 8)))
        problem("padding bits of the last byte are not zero (MBAP v1.1b3 §6.1)");
      break;
    }
    case 3:
    case 4:
    case 23: {
      if (req.size() < 5 || rep.size() < 2) { problem("reply too short"); break; }
      uint16_t q = be16(req, 3);
      if (rep[1] != 2 * q) problem(fmt::format("byte count {} for {} registers, expected {}", rep[1], q, 2 * q));
      if (!want_size(2 + size_t(rep[1]))) break;
      for (size_t i = 0; i + 1 < rep[1]; i += 2) j.registers.push_back(be16(rep, 2 + i));
      break;
    }
    case 5:
    case 6: echo(5); break;
    case 15:
    case 16: echo(5); break;
    case 22: echo(7); break;
    case 8:
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
  if (!is_request && (fc & 0x80)) {
    return fmt::format("FC{:02} {} exception {}", fc & 0x7F, fc_name(fc),
                       pdu.size() > 1 ? fmt::format("{:02X}", pdu[1]) : std::string("(missing code)"));
  }
  std::string s = fmt::format("FC{:02} {}", fc, fc_name(fc));
  if (is_request && pdu.size() >= 5 && (fc <= 6 || fc == 15 || fc == 16 || fc == 22 || fc == 23)) {
    bool single = fc == 5 || fc == 6;
    s += fmt::format(" address {} (0x{:04X}) {} {}", be16(pdu, 1), be16(pdu, 1), single ? "value" : "quantity",
                     be16(pdu, 3));
  } else if (!is_request && pdu.size() >= 2 && (fc <= 4 || fc == 23)) {
    s += fmt::format(": {} bytes", pdu[1]);
    if (fc >= 3) {
      for (size_t i = 2; i + 1 < pdu.size(); i += 2) s += fmt::format(" {:04X}", be16(pdu, i));
    }
  } else if (!is_request && pdu.size() >= 5) {
    s += fmt::format(" address {} (0x{:04X}) {:04X}", be16(pdu, 1), be16(pdu, 1), be16(pdu, 3));
  }
  return s;
}

}  // namespace mbc::conf
