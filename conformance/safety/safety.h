// Safety with live drives: a drive moves a machine. What a run writes is
// journaled and put back by the session (session/journal.h,
// session/restore.h); the reads and writes it does that with are here. Command and motion
// registers are never written without --allow-motion; persistent registers
// are not written without --allow-eeprom-writes unless the spec names a
// "do not persist" switch (57HS-R 0x0016) that the run turns on first.
// What may be written is the frame policy's to say (policy/policy.h).
#pragma once

#include <cstdint>
#include <optional>
#include <span>
#include <string>
#include <vector>

#include "policy/policy.h"
#include "spec.h"
#include "targets/target.h"

namespace mbc::conf {

// Modbus TCP addresses a server by its IP address; the unit identifier
// reaches a device behind a gateway. A server reached directly takes 0xFF,
// and 0 as well (Modbus Messaging on TCP/IP Implementation Guide V1.0b
// §4.4.1.2; spec/devices/modbus-standard.yaml, serial.broadcast): on an MBAP
// target unit 0 is not a broadcast the target can be judged on. The reason a
// broadcast case does not apply there, or empty on an RTU target.
std::string broadcast_not_applicable(const TargetInfo& target);

// `count` items of `table` (holding: FC 03, coils: FC 01; bits as 0/1) at
// `address`; nullopt with `why` (no reply, an exception, a malformed reply).
std::optional<std::vector<uint16_t>> read_table(Target&, spec::Table table, uint16_t address, int count, std::string& why);
// Writes `values` (FC 06/05, or FC 16/15 for 2 words or where the single
// write is not in the profile) and reads them back; the failure, or empty.
std::string write_table_verified(Target&, const spec::Spec&, spec::Table table, uint16_t address,
                                 std::span<const uint16_t> values, const std::string& what);
// The "do not persist" switch the spec names (57HS-R 0x0016) and its "on" value.
std::optional<std::pair<uint16_t, int64_t>> persist_switch(const spec::Spec&);
// "holding 0x0010 pulse/direction signal polarity".
std::string register_label(const spec::Register&);

}  // namespace mbc::conf
