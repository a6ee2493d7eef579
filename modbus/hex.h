// Frames as the manuals print them: "01 03 00 23 00 01 75 C0".
#pragma once

#include <cstdint>
#include <optional>
#include <span>
#include <string>
#include <string_view>

#include "modbus/bytes.h"

namespace mbc {

// Strict: uppercase pairs separated by single spaces (the spec's format).
std::optional<Bytes> parse_hex_strict(std::string_view s);
// Lenient: any whitespace, either case, pairs may run together ("0B 580B").
std::optional<Bytes> parse_hex(std::string_view s);
// Uppercase pairs separated by single spaces.
std::string to_hex(std::span<const uint8_t> bytes);

}  // namespace mbc
