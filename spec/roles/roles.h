// The roles a register can play that decide whether a live drive may be
// written: one lexicon, in Chinese and English, for every place that has
// only a register's name to go by (the CSV and wb-mqtt-serial importers,
// and the frame policy for maps no manual states). roles.cpp holds the
// words; spec/README.md ("Roles") lists them for a vendor.
//
// What each role means on a live drive (conformance/policy/):
//   slave_address, baud, parity, frame_format: never written (the drive
//     would leave the line, and the restore could not reach it);
//   motion: run, start, stop, jog, direction, control word, command:
//     --allow-motion;
//   save: save, store, EEPROM: the EEPROM opt-in;
//   factory_reset: restore factory defaults, initialise: the EEPROM opt-in.
#pragma once

#include <optional>
#include <string>
#include <string_view>
#include <vector>

namespace mbc::spec {

enum class Role { none, slave_address, baud, parity, frame_format, motion, save, factory_reset };

const char* to_string(Role);  // "slave-address", "baud", ..., "none"
// The role named by `text` as a `role` column or key would name it
// ("slave-address", "baud", "motion", "none", ...; case, '_' and ' ' for
// '-' do not matter); nullopt if it names none.
std::optional<Role> role_from_string(std::string_view text);

struct RoleMatch {
  Role role = Role::none;
  std::string word;  // the lexicon's word that matched ("波特率", "baud"), empty for none
};
// The role a register's name gives it, from the lexicon (case-insensitive for
// English; either name may be empty). The first match in the lexicon's order
// wins: a line setting before a command ("通讯地址" is an address, not a
// command), factory reset before save.
RoleMatch role_of_name(std::string_view en, std::string_view zh = {});

// The lexicon, in match order (spec/README.md "Roles" lists every word; a
// test holds the two together).
struct RoleWord {
  Role role;
  std::string_view word;
};
std::vector<RoleWord> role_lexicon();

// Whether writing a register of this role can cut the drive off the line.
inline bool is_line_setting(Role r) {
  return r == Role::slave_address || r == Role::baud || r == Role::parity || r == Role::frame_format;
}

}  // namespace mbc::spec
