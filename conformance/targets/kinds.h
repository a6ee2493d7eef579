// One factory per target kind (one file each in conformance/targets/);
// open_target() in target.cpp picks one by the URI's scheme.
#pragma once

#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "targets/target.h"

namespace mbc::conf {

std::unique_ptr<Target> make_ref_target(const Uri& uri);       // ref_target.cpp
std::unique_ptr<Target> make_modbus_target(const Uri& uri);    // live_target.cpp: tcp, rtu-tcp, rtu (libmodbus)
std::unique_ptr<Target> make_plugin_target(const Uri& uri);    // plugin_target.cpp
std::unique_ptr<Target> make_tls_target(const Uri& uri);       // tls_target.cpp: mbtls (Modbus/TCP Security)

// Fills reply.pdu or reply.framing_error from reply.frame, an RTU ADU that
// should come from `slave` (MB-SL v1.02 §2.5.1: address, PDU, CRC low first).
void decode_rtu_reply(Reply& reply, uint8_t slave);

// What a USB serial adapter's latency timer means for timing (rtu_target.cpp):
// one note for `device` (a path or a symlink to /dev/ttyUSBn) when
// `sysfs`/bus/usb-serial/devices/<name>/latency_timer exists, else none.
std::vector<std::string> usb_latency_notes(const std::string& device, const std::string& sysfs = "/sys");
// The latency timer alone, in ms; nullopt when not a readable USB adapter.
std::optional<int> usb_latency_ms(const std::string& device, const std::string& sysfs = "/sys");

}  // namespace mbc::conf
