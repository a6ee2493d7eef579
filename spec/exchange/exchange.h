// Register maps in and out of the spec language (`mbconform spec import` and
// `spec export`): a CSV register map in, a spec skeleton out; a spec's map out
// as CSV, Home Assistant `modbus:` YAML or an EdgeX v3 device-modbus profile.
// The formats are described in spec/README.md ("Register maps in CSV") and
// in each function below.
#pragma once

#include <string>
#include <vector>

#include "spec.h"

namespace mbc::exchange {

struct ImportResult {
  std::string yaml;                 // the spec skeleton, when errors is empty
  std::vector<std::string> errors;  // "file:line: error: what", in file order
  size_t registers = 0;
};

// Turns CSV text (the register map of one device) into the YAML of a spec
// with id `id`. `file` names the CSV in errors and in every register's
// `section:` ("<file name>:<line>"): each imported fact cites the row that
// states it. The skeleton passes `spec check` when errors is empty.
ImportResult import_csv(const std::string& text, const std::string& file, const std::string& id);

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
std::string export_home_assistant(const spec::Spec& s);

// An EdgeX v3 device-modbus device profile (YAML): one deviceResource per
// register, with primaryTable, startingAddress, rawType and isWordSwap.
std::string export_edgex(const spec::Spec& s);

}  // namespace mbc::exchange
