// The one frame policy: whether a frame may go out to a target
// (README.md in this folder has the table of rules and opt-ins). Every
// maker of checks asks it while it makes them (a case that cannot go out is
// a skip naming the opt-in, and `run --plan` shows exactly what will be
// sent); the session asks it again before each frame goes out; `restore`
// asks it before each write back. Nothing else decides what may be sent.
//
// A target that is not live (ref:, plugin:) is a simulation: every frame
// passes, so the reference runs every case. On a live target the default is
// to deny: a frame goes out only when the spec states what it does, or an
// opt-in covers it.
#pragma once

#include <cstdint>
#include <optional>
#include <set>
#include <span>
#include <string>
#include <utility>
#include <vector>

#include "modbus/hex.h"
#include "roles/roles.h"
#include "spec.h"
#include "targets/target.h"

namespace mbc::conf {

// The opt-ins, the same flags with the same meaning in every command that
// sends (tools/mbconform/options.cpp).
struct WritePolicy {
  bool allow_motion = false;         // --allow-motion: command, motion, control word registers
  bool allow_eeprom_writes = false;  // --allow-eeprom-writes: save, store, factory reset, persistent registers
  bool allow_broadcast = false;      // --allow-broadcast: requests to unit 0 other than reads
  bool allow_writes = false;         // --allow-writes: registers of a map no manual states
  bool allow_disruptive = false;     // --allow-disruptive: function codes whose effect the spec does not state
};

// Why a frame may not go out.
struct Refusal {
  std::string reason;  // one line, ending with the opt-in that allows it ("...: needs --allow-motion")
  std::string opt_in;  // that flag, empty when none does (never sent on a live target)
};

// What the policy judges by: the spec (null: nothing is known, so nothing
// but a read may go out), the target (live, unit, framing) and the opt-ins.
struct PolicyFacts {
  const spec::Spec* spec = nullptr;
  TargetInfo target;
  WritePolicy opt_ins;
  // The set-point registers of the spec's control modes (addresses) the
  // caller wrote 0 and the drive acknowledged: while every set-point is here,
  // a control command that may move (`motion: true`) moves nothing.
  std::set<uint16_t> zeroed = {};
};

struct Decision {
  std::optional<Refusal> refused;  // set: the frame may not go out
  explicit operator bool() const { return !refused; }  // true: allowed
};

// Whether request `pdu` to `unit` (0 = broadcast) may go out.
Decision allowed(const PolicyFacts&, uint8_t unit, std::span<const uint8_t> pdu);
// Whether raw bytes may go out as they are (`gap_after`: an RTU pause after
// that many bytes), judged by every frame a receiver could take from them
// (frames_in): one refused frame refuses them all.
Decision allowed_raw(const PolicyFacts&, std::span<const uint8_t> bytes, std::optional<size_t> gap_after = std::nullopt);
// Whether the natural write of `r` (FC 06/16 for holding registers, FC 05/15
// for coils) to the target's unit may go out: a maker choosing a register to
// write asks this, and it is the same allowed() as above.
Decision allowed_write(const PolicyFacts&, const spec::Register& r);

// ---- what the policy reads a frame as (also the session's journal) ----

// The items a request PDU writes (FC 05, 06, 15, 16, 22, 23); nullopt for a
// request that writes nothing the standard defines.
struct WriteRange {
  spec::Table table = spec::Table::holding;
  uint16_t address = 0;
  int count = 1;
};
std::optional<WriteRange> writes_of(std::span<const uint8_t> pdu);

// The (unit, PDU) frames a receiver could take from raw bytes in `framing`.
// MBAP: every ADU by its length field, several in one write, the last one as
// far as it goes. RTU: every prefix whose CRC holds (a receiver that frames
// by length), and after each such frame the rest again (several frames in one
// write); with a gap, each part alone as well.
std::vector<std::pair<uint8_t, Bytes>> frames_in(Framing framing, std::span<const uint8_t> bytes,
                                                 std::optional<size_t> gap_after);

// The role the spec gives a register, in the spec language's own terms
// (serial.settings, access: command with motion or eeprom, operations.save,
// operations.factory_reset, control.motion); for a spec no manual states,
// the lexicon's role of its name (spec/roles/roles.h) where those say none.
spec::Role role_of(const spec::Spec&, const spec::Register&);
// Why a write moves the axis by the spec's control (`control:`), or empty:
// a word that gives a command with `motion: true` (unless every set-point is
// in `zeroed`: the command's own `setpoints:` where it states them, else every
// mode's) or a mode's start command (a start moves to any set-point,
// 0 too), or a non-zero value written to a set-point of a mode with no start
// command (it follows its set-points at once). Mode
// selection, and commands that do not move, are not motion.
std::string control_motion(const PolicyFacts&, std::span<const uint8_t> pdu);
// The set-point registers of the spec's control modes, and the commands' own
// (every word's address).
std::set<uint16_t> control_setpoints(const spec::Spec&);
// After a write (FC 06, 16) the drive took: which set-points it made 0, and
// which it made non-zero, in `zeroed` (PolicyFacts::zeroed).
void note_zeroed(const spec::Spec&, std::span<const uint8_t> request_pdu, std::set<uint16_t>& zeroed);

// Whether the spec's facts are a manual's (device.manual.source: manual);
// otherwise an importer's, a probe's or a map's: a claim.
bool from_manual(const spec::Spec&);

}  // namespace mbc::conf
