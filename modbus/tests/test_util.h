// Test helper: bytes from hex as the standards print them.
#pragma once

#include <gtest/gtest.h>

#include <string_view>

#include "modbus/hex.h"

namespace mbc::test {

inline Bytes hex(std::string_view s) {
  auto b = parse_hex(s);
  if (!b) ADD_FAILURE() << "bad hex in test: " << s;
  return b ? *b : Bytes{};
}

}  // namespace mbc::test
