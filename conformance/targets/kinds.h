// One factory per target kind (one file each in conformance/targets/);
// open_target() in target.cpp picks one by the URI's scheme.
#pragma once

#include <memory>

#include "targets/target.h"

namespace mbc::conf {

std::unique_ptr<Target> make_ref_target(const Uri& uri);       // ref_target.cpp
std::unique_ptr<Target> make_modbus_target(const Uri& uri);    // live_target.cpp: tcp, rtu-tcp, rtu (libmodbus)
std::unique_ptr<Target> make_plugin_target(const Uri& uri);    // plugin_target.cpp
std::unique_ptr<Target> make_tls_target(const Uri& uri);       // tls_target.cpp: mbtls (Modbus/TCP Security)

// Fills reply.pdu or reply.framing_error from reply.frame, an RTU ADU that
// should come from `slave` (MB-SL v1.02 §2.5.1: address, PDU, CRC low first).
void decode_rtu_reply(Reply& reply, uint8_t slave);

}  // namespace mbc::conf
