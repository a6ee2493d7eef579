#include "serve/mbap.h"

#include <algorithm>
#include <iterator>

namespace mbc::serve {

std::optional<Mbap> parse_mbap(std::span<const uint8_t> b) {
  if (b.size() < kMbapHeader) return std::nullopt;
  return Mbap{uint16_t(b[0] << 8 | b[1]), uint16_t(b[2] << 8 | b[3]), uint16_t(b[4] << 8 | b[5]), b[6]};
}

Bytes mbap_reply(const Mbap& req, std::span<const uint8_t> pdu) {
  uint16_t length = uint16_t(1 + pdu.size());
  Bytes out(kMbapHeader + pdu.size());
  const uint8_t header[kMbapHeader] = {uint8_t(req.transaction >> 8), uint8_t(req.transaction), uint8_t(req.protocol >> 8),
                                       uint8_t(req.protocol),         uint8_t(length >> 8),     uint8_t(length),
                                       req.unit};
  std::copy(std::begin(header), std::end(header), out.begin());
  std::copy(pdu.begin(), pdu.end(), out.begin() + kMbapHeader);
  return out;
}

}  // namespace mbc::serve
