// Register maps in and out of the spec language (`mbconform spec import` and
// `spec export`): a CSV register map in, a spec skeleton out; a spec's map out
// as CSV, Home Assistant `modbus:` YAML or an EdgeX v3 device-modbus profile.
// The formats are described in spec/README.md ("Register maps in CSV") and
// in each function below.
#pragma once

#include <optional>
#include <string>
#include <vector>

#include "roles/roles.h"
#include "spec.h"

namespace mbc::exchange {

// What an import made of one register's role (spec/roles/roles.h): from
// its name through the lexicon, or from the sheet's `role` column.
struct Classified {
  spec::Table table = spec::Table::holding;
  uint32_t address = 0;
  std::string name;
  spec::Role role = spec::Role::none;
  std::string word;  // the lexicon's word that matched, "role column", or empty
  spec::Access access = spec::Access::ro;  // as written into the spec
};

struct ImportResult {
  std::string yaml;                 // the spec skeleton, when errors is empty
  std::vector<std::string> errors;  // "file:line: error: what", in file order; at most 20, then "N more errors"
  size_t registers = 0;
  // "file:line: warning: what" (a column that is ignored, a GBK file
  // converted); at most 20, then "N more warnings not shown (M in all)".
  std::vector<std::string> warnings;
  size_t error_count = 0;  // every error, shown or not
  std::vector<Classified> classified;  // every register, in the spec's order
};

// At most this many errors or warnings are kept in an ImportResult; the
// rest are counted in one line (a bad file of 100,000 rows must not print
// 100,000 lines).
inline constexpr size_t kShownLines = 20;
// The largest sheet or template an import reads (a register map of every
// address of the four tables is a few MiB; the spec it makes must stay under
// the loader's 4 MiB).
inline constexpr size_t kMaxImportBytes = 4u << 20;

// The table of what an import classified: every register with a role, or a
// role column's word, one line each (register, name, role, the word that
// matched or "role column"), then how many have no role.
std::string classification_table(const ImportResult& r);

// Turns CSV text (the register map of one device) into the YAML of a spec
// with id `id`. `file` names the CSV in errors and in every register's
// `section:` ("<file name>:<line>"): each imported fact cites the row that
// states it. The skeleton passes `spec check` when errors is empty.
// Text that is not UTF-8 is taken as GB18030 (GBK, the default of Chinese
// Excel) and converted with iconv, with a warning; text that is neither is
// one error naming the file and the first bad byte's line.
ImportResult import_csv(const std::string& text, const std::string& file, const std::string& id);

// `text` as UTF-8: itself when valid, else converted from GB18030; nullopt
// when it is neither. `line` gets the line of the first byte that is not UTF-8.
std::optional<std::string> to_utf8(const std::string& text, int& line);

// Turns a wb-mqtt-serial device template (JSON, Wiren Board's public
// register maps) into the YAML of a spec with id `id` (import_wb.cpp says
// what maps to what). Errors and warnings as import_csv's, with the
// template entry ("channels[3] 'Drive Start'") in place of a line.
ImportResult import_wb_template(const std::string& text, const std::string& file, const std::string& id);
// The template's own device id as a spec id (danfoss-fc-51, mst24-v1), or empty.
std::string wb_template_id(const std::string& text);
// A spec's register map as a wb-mqtt-serial device template: a channel per
// register (bitfields also as a bit channel per field, A:BIT:WIDTH), the
// spec's operations.setup as `setup`, its timing as the device's timeouts.
std::string export_wb_template(const spec::Spec& s);

// A table as the CSV names it: "coil", "discrete input", "input register",
// "holding register".
const char* csv_table_name(spec::Table t);

// The CSV columns, in the order export_csv writes them.
extern const std::vector<std::string> kCsvColumns;

// The register map as CSV (kCsvColumns; addresses in hex, 0x0044). Enum and
// bitfield registers are written as the integer type that carries them
// (u16, or u32 for two words): the CSV has no column for their values.
std::string export_csv(const spec::Spec& s);

// Home Assistant `modbus:` YAML (one serial hub): sensors for registers,
// binary_sensors for discrete inputs and read-only coils, switches for
// writable coils. Keys follow the modbus integration's schema (see
// export.cpp for the version); writes to holding registers go through the
// `modbus.write_register` action, documented in the file's comments.
//
// Each entity gets a `scan_interval` (seconds): `fast_scan` for what the
// drive changes by itself (read-only registers: status, measurements),
// `slow_scan` for settings that change only when written. Numeric read-only
// sensors get `state_class: measurement` (`total_increasing` where the name
// says it counts up: total, count, hours, energy), so Home Assistant keeps
// their statistics; settings and coded values (enums, bit fields) get none.
// `only` keeps the registers that match one of its patterns: an address
// (0x0044, 68), an address range (0x0040-0x004F), or a glob on the key or
// the English name (speed*, *current*); empty keeps every register.
struct HomeAssistantOptions {
  int fast_scan = 5, slow_scan = 60;
  std::vector<std::string> only;
};
std::string export_home_assistant(const spec::Spec& s, const HomeAssistantOptions& o = {});

// Whether register `r` matches one of `patterns` (as HomeAssistantOptions::only).
bool register_matches(const spec::Register& r, const std::vector<std::string>& patterns);

// An EdgeX v3 device-modbus device profile (YAML): one deviceResource per
// register, with primaryTable, startingAddress, rawType and isWordSwap.
std::string export_edgex(const spec::Spec& s);

}  // namespace mbc::exchange
