// Registers the interoperability tests exercise, chosen from the spec (never
// from the engine), so every device is tested by what its manual says.
#pragma once

#include <optional>
#include <string>

#include "spec.h"

namespace mbc::serve_test {

// A plain rw holding word with a range: one word, u16/s16 (or a ranged enum
// when `allow_enum`), no command, takes effect at once, not a serial setting
// (writing the slave id or baud rate would cut the line).
bool plain_rw(const spec::Spec& s, const spec::Register& r, bool allow_enum = false);

// The middle of a register's range as the raw word a master writes.
uint16_t middle_word(const spec::Register& r);

// The first plain rw register.
const spec::Register* pick_rw(const spec::Spec& s);

// The first rw holding word the spec gives no range (not a command, not a serial setting).
const spec::Register* pick_rw_word(const spec::Spec& s);

// A word whose default the spec states (holding or input table): a
// read-only one if there is one, else a read-write one.
const spec::Register* pick_default_word(const spec::Spec& s);

// A plain rw register kept in EEPROM/flash on write whose range holds a
// value other than its default.
const spec::Register* pick_persistent_on_write(const spec::Spec& s);

// A plain rw register with a default that a power cycle resets when nothing
// saved it: volatile, or persisted only by a save command.
const spec::Register* pick_lost_at_power_off(const spec::Spec& s);

// A value in range that differs from the default.
uint16_t word_other_than_default(const spec::Register& r);

}  // namespace mbc::serve_test
