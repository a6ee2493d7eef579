// The gate: every frame a command sends to a live target is checked here
// before it goes out (README.md, "Live drives"). The safety opt-ins apply to
// every command alike:
//   - a valid write never goes to a unit other than the target's (there is
//     no opt-in: another drive on the line cannot be restored);
//   - a write to unit 0 (broadcast) needs --allow-broadcast;
//   - command and motion registers need --allow-motion;
//   - writes stored to EEPROM/flash need --allow-eeprom-writes (unless the
//     spec's "do not persist" switch is held on by the session);
//   - writes where the access is not stated (a probed or given map without
//     access) need --allow-writes;
//   - registers that set the slave id, baud rate or frame format, and the
//     "do not persist" switch itself, are never written by a check.
// Raw bytes are judged by what a receiver could take from them: every prefix
// with a valid CRC (a receiver that frames by length) and each part of a
// split frame.
#pragma once

#include <cstdint>
#include <optional>
#include <span>
#include <string>
#include <utility>
#include <vector>

#include "modbus/hex.h"
#include "safety/safety.h"
#include "session/link.h"
#include "spec.h"

namespace mbc::conf {

// The items a request PDU writes (FC 05, 06, 15, 16, 22, 23); nullopt for a
// request that writes nothing the standard defines.
struct WriteRange {
  spec::Table table = spec::Table::holding;
  uint16_t address = 0;
  int count = 1;
};
std::optional<WriteRange> writes_of(std::span<const uint8_t> pdu);

// The (unit, PDU) frames a receiver could take from raw bytes in `framing`.
std::vector<std::pair<uint8_t, Bytes>> frames_in(Framing framing, std::span<const uint8_t> bytes, std::optional<size_t> gap_after);

struct GateRules {
  WritePolicy policy;
  bool access_unstated = false;  // the map in use states no access (--map auto, a map without access)
  bool allow_writes = false;     // --allow-writes
};

class Gate {
 public:
  // `spec` may be null (spec discover: nothing is known, so nothing may be written).
  Gate(const spec::Spec* spec, const TargetInfo& info, GateRules rules) : spec_(spec), info_(info), rules_(rules) {}
  // Why the frame may not go out, or nullopt. Targets that are not live
  // (ref:, plugin:) pass everything: they are simulations.
  std::optional<Refusal> check(uint8_t unit, std::span<const uint8_t> pdu) const;
  const GateRules& rules() const { return rules_; }

 private:
  const spec::Spec* spec_;
  TargetInfo info_;
  GateRules rules_;
};

}  // namespace mbc::conf
