// The one restore: puts a live drive back from its journal (session/README.md).
// The session runs it when a command ends (also after SIGINT, a lost target
// or a full disk, then from what the journal kept in memory), and
// `mbconform restore JOURNAL` runs it from the file alone after a SIGKILL.
//
//   - The journal's header (device, unit, spec file fingerprint, the identity
//     the drive gave) is checked against the target before anything is
//     written (journal_mismatch; `restore --force-identity` overrides).
//   - A damaged record is named and skipped; the rest still restores.
//   - Every write goes through the frame policy (restore_refusal, the one
//     place): never a slave-id, baud or frame-format register, never a
//     command; a command register written is undone by the spec's stop
//     operation (control.motion.stop), not by a write of an old value.
//   - Read-only registers are not put back (they change by side effect).
//   - An address an earlier restore put back and that changed since is left
//     alone (the user changed it).
#pragma once

#include <optional>
#include <span>
#include <string>
#include <vector>

#include "session/journal.h"
#include "session/link.h"
#include "spec.h"
#include "targets/target.h"

namespace mbc::conf {

struct RestoreReport {
  size_t kept = 0;       // addresses journaled
  size_t restored = 0;   // written back (they had changed)
  size_t verified = 0;   // read back equal to their original at the end
  std::vector<std::string> not_restored;  // one line each
  // Addresses written although the drive would not read them first (an
  // unmapped address the write was meant to be refused at): nothing to put back.
  std::vector<std::string> unread;
  // What needs no action but is worth saying: a record cut off at the end of
  // the file, a read-only register, an address left alone because it changed
  // since an earlier restore, a command register stopped, and what the
  // journal could not record.
  std::vector<std::string> notes;
  bool gave_up = false;  // the target did not answer: the rest is listed in not_restored
  std::string journal;   // its path
};

// Puts back every original of `contents` on `target` (spec: how to write
// each table), appending what it did to `record` (a record the journal cannot
// take is named in the report's notes).
RestoreReport restore_journal(Target& target, const spec::Spec& spec, const JournalContents& contents, Journal& record);

// Why `pdu` to `unit` may not go out as part of a restore, or nullopt: the
// one place a restore asks the frame policy. `stop_operation`: the spec's
// own stop (control.motion.stop), the only command a restore sends.
std::optional<Refusal> restore_refusal(const spec::Spec& spec, const TargetInfo& info, uint8_t unit,
                                       std::span<const uint8_t> pdu, bool stop_operation);

// What the drive says it is, for the journal's header: its FC 43/14 objects
// where the spec says it answers them, else which of up to 8 registers spread
// over the spec's readable map it answers (not their values, which change).
std::string journal_identity(Target& target, const spec::Spec& spec);
// The spec file's CRC-32 ("1A2B3C4D"), empty when it cannot be read.
std::string spec_fingerprint(const spec::Spec& spec);

// Why `contents` may not be restored onto `target` with `spec` (its header
// names another device, unit, spec file or identity), or empty. One line.
std::string journal_mismatch(Target& target, const spec::Spec& spec, const JournalContents& contents);

// ---- the drive's control (spec control:) ----

// The state the drive's status names now, with the words read, as the
// journal's record: "control operation_enabled statusword=0237"; empty when
// the spec has no control or the status cannot be read.
std::string control_record(Target& target, const spec::Spec& spec);
// Whether `address` is a register a control command is written to.
bool is_control_command_register(const spec::Spec& spec, spec::Table table, uint16_t address);
// Takes the drive to the control's safe state (spec control.safe) by the
// commands along transitions that start no motion, reading the status after
// each (re-planned from the state read). Appends what it sent to `did`;
// "" when the status names the safe state at the end, else why not.
std::string control_to_safe(Target& target, const spec::Spec& spec, std::vector<std::string>& did);

// ---- shared by the session's journaling and the restore ----

// "holding 0x0010 pulse/direction signal polarity" (the spec's name when it has one).
std::string journal_label(const spec::Spec* s, spec::Table table, uint16_t address);
// The most items one read of `table` may ask for (the profile's, else the standard's).
int journal_read_limit(const spec::Spec* s, spec::Table table);
bool no_reply(const std::string& why);
// Each entry's value as the target reads it now (entries of one table at
// consecutive addresses in one request, up to the read limit); nullopt with
// `whys[k]` where it could not be read.
std::vector<std::optional<std::vector<uint16_t>>> read_entries(Target& t, const spec::Spec* s,
                                                               const std::vector<const JournalEntry*>& es,
                                                               std::vector<std::string>& whys);

}  // namespace mbc::conf
