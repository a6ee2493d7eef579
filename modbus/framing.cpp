#include "modbus/framing.h"

#include "modbus/mbap.h"
#include "modbus/rtu.h"

namespace mbc {

const Framing kRtu{"rtu", kRtuAddress, kRtuCrc, kMaxRtuAdu,
                   [](uint8_t unit, std::span<const uint8_t> pdu, uint16_t) { return rtu_frame(unit, pdu); },
                   rtu_unframe};
const Framing kTcp{"tcp", kMbapHeader, 0, kMaxTcpAdu,
                   [](uint8_t unit, std::span<const uint8_t> pdu, uint16_t transaction) {
                     return mbap_frame(transaction, unit, pdu);
                   },
                   mbap_unframe};

const char* to_string(Transport t) {
  switch (t) {
    case Transport::tcp: return "tcp";
    case Transport::rtu_tcp: return "rtu-tcp";
    case Transport::pty: return "pty";
    case Transport::tls: return "tls";
  }
  return "?";
}

const Framing& framing_of(Transport t) { return t == Transport::tcp || t == Transport::tls ? kTcp : kRtu; }

}  // namespace mbc
