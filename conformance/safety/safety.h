// Safety with live drives: a drive moves a machine. Before a run writes
// anything it snapshots every readable, writable register; afterwards (and on
// error or SIGINT) it writes them back and verifies. Command and motion
// registers are never written without --allow-motion; persistent registers
// are not written without --allow-eeprom-writes unless the spec names a
// "do not persist" switch (57HS-R 0x0016) that the run turns on first.
#pragma once

#include <cstdint>
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
// allow everything: they are simulations and power-cycle on demand.
WriteDecision may_write(const spec::Spec&, const spec::Register& r, const TargetInfo& target, const WritePolicy&);

// The registers' values before the run, and putting them back.
class Snapshot {
 public:
  // Reads every readable, writable (rw) holding register of the spec that the
  // policy lets the run write. Registers it cannot read are listed in failures().
  static Snapshot take(Target&, const spec::Spec&, const WritePolicy&);
  // Writes every changed register back (FC 06/16 per the spec's profile), reads
  // back to verify; returns the registers it could not restore, as messages.
  std::vector<std::string> restore(Target&) const;
  const std::vector<std::string>& failures() const { return failures_; }
  size_t size() const { return words_.size(); }

 private:
  const spec::Spec* spec_ = nullptr;
  std::vector<std::pair<uint16_t, uint16_t>> words_;  // address, value
  std::vector<std::string> failures_;
};

}  // namespace mbc::conf
