#include "modbus/mbap.h"

#include "modbus/text.h"

namespace mbc {

std::optional<Mbap> parse_mbap(std::span<const uint8_t> b) {
  if (b.size() < kMbapHeader) return std::nullopt;
  return Mbap{be16(b, 0), be16(b, 2), be16(b, 4), b[6]};
}

void append_mbap_reply(Bytes& out, const Mbap& req, std::span<const uint8_t> pdu) {
  const uint16_t length = uint16_t(1 + pdu.size());
  const uint8_t header[kMbapHeader] = {uint8_t(req.transaction >> 8), uint8_t(req.transaction),
                                       uint8_t(req.protocol >> 8),    uint8_t(req.protocol),
                                       uint8_t(length >> 8),          uint8_t(length),
                                       req.unit};
  out.insert(out.end(), header, header + kMbapHeader);
  out.insert(out.end(), pdu.begin(), pdu.end());
}

Bytes mbap_reply(const Mbap& req, std::span<const uint8_t> pdu) {
  Bytes out;
  out.reserve(kMbapHeader + pdu.size());
  append_mbap_reply(out, req, pdu);
  return out;
}

Bytes mbap_frame(uint16_t transaction, uint8_t unit, std::span<const uint8_t> pdu) {
  return mbap_reply(Mbap{transaction, 0, 0, unit}, pdu);
}

Unframed mbap_unframe(std::span<const uint8_t> adu) {
  Unframed u;
  auto h = parse_mbap(adu);
  if (!h) {
    u.error = strf("%zu bytes: shorter than the 7-byte MBAP header", adu.size());
    return u;
  }
  u.unit = h->unit;
  u.transaction = h->transaction;
  u.pdu.assign(adu.begin() + kMbapHeader, adu.end());
  if (h->protocol != 0) u.error = strf("MBAP protocol id %u, not 0 (Modbus)", h->protocol);
  else if (h->adu_size() != adu.size())
    u.error = strf("MBAP length %u (unit id + %u PDU bytes) but %zu bytes follow the length field", h->length,
                   h->length ? h->length - 1u : 0u, adu.size() - 6);
  else if (!h->length_ok())
    u.error = strf("MBAP length %u: a PDU of 1..%zu bytes needs 2..%zu (MBAP v1.1b3 §4.1)", h->length, kMaxPdu, kMaxPdu + 1);
  return u;
}

}  // namespace mbc
