// Safety with live drives: a drive moves a machine. Before a run writes
// anything it snapshots every readable, writable register of every table the
// run may write (holding registers and coils); afterwards (and on
// error or SIGINT) it writes them back and verifies. Command and motion
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

// The registers' values before the run, and putting them back.
class Snapshot {
 public:
  // Reads every writable (rw) register of the spec, in every table, that the
  // policy lets the run write (FC 03 for holding registers, FC 01 for coils,
  // in chunks within the profile's max_quantity). Registers it cannot read
  // are listed in failures() as one line with address ranges. When
  // the spec names a "do not persist" switch (Persistence.unless_register,
  // 57HS-R 0x0016) it is read, kept, and turned on, so the run's writes stay
  // out of EEPROM; turning it on and back off costs one stored write each.
  // `spec` must outlive the snapshot.
  static Snapshot take(Target&, const spec::Spec&, const WritePolicy&);
  // Writes every changed register back (FC 06/05, or FC 16/15 for 2-word
  // registers and where the single write is not in the profile), reads each
  // back, then verifies the whole snapshot once more, and puts the switch
  // back last; returns the registers it could not restore, as
  // messages. Idempotent: it may run again after an interrupted restore.
  std::vector<std::string> restore(Target&) const;
  const std::vector<std::string>& failures() const { return failures_; }
  size_t size() const { return kept_.size(); }
  // The switch turned on by take(): address and the value it had before.
  std::optional<std::pair<uint16_t, uint16_t>> persist_switch() const { return switch_; }

  struct Kept {
    spec::Table table = spec::Table::holding;
    uint16_t address = 0;
    int words = 1;
    uint16_t value[2] = {0, 0};  // in wire order (lower address first)
    std::string name;
  };
  const std::vector<Kept>& kept() const { return kept_; }

 private:
  const spec::Spec* spec_ = nullptr;
  std::vector<Kept> kept_;
  std::optional<std::pair<uint16_t, uint16_t>> switch_;
  std::vector<std::string> failures_;
};

}  // namespace mbc::conf
