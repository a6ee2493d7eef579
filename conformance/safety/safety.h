// Safety with live drives: a drive moves a machine. Before a run writes
// anything it snapshots every readable, writable register; afterwards (and on
// error or SIGINT) it writes them back and verifies. Command and motion
// registers are never written without --allow-motion; persistent registers
// are not written without --allow-eeprom-writes unless the spec names a
// "do not persist" switch (57HS-R 0x0016) that the run turns on first.
#pragma once

#include <cstdint>
#include <optional>
#include <string>
#include <vector>

#include "spec.h"
#include "targets/target.h"

namespace mbc::conf {

struct WritePolicy {
  bool allow_motion = false;
  bool allow_eeprom_writes = false;
};

struct WriteDecision {
  bool allowed = true;
  std::string reason;  // why not ("command register: needs --allow-motion")
};

// Whether a case may write `r` on `target`. Reference targets (not live)
// allow everything: they are simulations and power-cycle on demand. On a live
// target: command registers need allow_motion (and allow_eeprom_writes when
// the command stores to EEPROM); registers stored on write need
// allow_eeprom_writes unless the spec names a "do not persist" switch, which
// Snapshot::take turns on before the run writes anything.
WriteDecision may_write(const spec::Spec&, const spec::Register& r, const TargetInfo& target, const WritePolicy&);

// The registers' values before the run, and putting them back.
class Snapshot {
 public:
  // Reads every readable, writable (rw) holding register of the spec that the
  // policy lets the run write (FC 03, in chunks within the profile's
  // max_quantity). Registers it cannot read are listed in failures(). When
  // the spec names a "do not persist" switch (Persistence.unless_register,
  // 57HS-R 0x0016) it is read, kept, and turned on, so the run's writes stay
  // out of EEPROM; turning it on and back off costs one stored write each.
  // `spec` must outlive the snapshot.
  static Snapshot take(Target&, const spec::Spec&, const WritePolicy&);
  // Writes every changed register back (FC 06, or FC 16 for 2-word registers
  // and where FC 06 is not in the profile), reads back to verify, and puts
  // the switch back last; returns the registers it could not restore, as
  // messages. Idempotent: it may run again after an interrupted restore.
  std::vector<std::string> restore(Target&) const;
  const std::vector<std::string>& failures() const { return failures_; }
  size_t size() const { return kept_.size(); }
  // The switch turned on by take(): address and the value it had before.
  std::optional<std::pair<uint16_t, uint16_t>> persist_switch() const { return switch_; }

  struct Kept {
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
