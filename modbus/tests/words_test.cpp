// 32-bit values in two registers, both word orders.
#include <gtest/gtest.h>

#include "modbus/words.h"

namespace mbc {
namespace {

// 0x00012345: high word 0x0001, low word 0x2345.
TEST(Words, HighFirstPutsTheHighWordAtTheLowerAddress) {
  EXPECT_EQ(split_u32(0x00012345, false), (std::array<uint16_t, 2>{0x0001, 0x2345}));
  EXPECT_EQ(join_u32(0x0001, 0x2345, false), 0x00012345u);
}

TEST(Words, LowFirstPutsTheLowWordAtTheLowerAddress) {
  EXPECT_EQ(split_u32(0x00012345, true), (std::array<uint16_t, 2>{0x2345, 0x0001}));
  EXPECT_EQ(join_u32(0x2345, 0x0001, true), 0x00012345u);
}

TEST(Words, SplitThenJoinIsTheIdentity) {
  for (uint32_t v : {0u, 1u, 0xFFFFFFFFu, 0x80000000u, 0x0000FFFFu, 0xDEADBEEFu})
    for (bool low_first : {false, true}) {
      auto w = split_u32(v, low_first);
      EXPECT_EQ(join_u32(w[0], w[1], low_first), v);
    }
}

}  // namespace
}  // namespace mbc
