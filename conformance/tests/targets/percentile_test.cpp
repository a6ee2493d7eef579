// The one percentile (targets/percentile.h) against the nearest-rank
// definition: the P-th percentile of n values is the smallest value x with at
// least P % of the values at or below x. The oracle below counts, for every
// candidate, how many values are at or below it; it shares no arithmetic with
// the rank formula under test.
#include <gtest/gtest.h>

#include <algorithm>
#include <cstdint>
#include <random>
#include <vector>

#include "targets/percentile.h"

using mbc::conf::percentile;

namespace {

int64_t by_definition(const std::vector<int64_t>& values, unsigned percent) {
  std::vector<int64_t> sorted = values;
  std::sort(sorted.begin(), sorted.end());
  for (int64_t x : sorted) {
    size_t at_or_below = size_t(std::count_if(values.begin(), values.end(), [&](int64_t v) { return v <= x; }));
    if (at_or_below * 100 >= size_t(percent) * values.size()) return x;  // at least P % at or below x
  }
  return sorted.back();
}

int64_t p(std::vector<int64_t> v, unsigned percent) { return percentile(std::span(v), percent); }

}  // namespace

TEST(Percentile, HundredValuesP99IsThe99thNotTheMaximum) {
  std::vector<int64_t> v;
  for (int64_t i = 100; i >= 1; --i) v.push_back(i);
  EXPECT_EQ(p(v, 99), 99);
  EXPECT_EQ(p(v, 50), 50);
  EXPECT_EQ(p(v, 100), 100);
  EXPECT_EQ(p(v, 1), 1);
}

TEST(Percentile, FewerThanHundredValuesP99IsTheirMaximum) {
  std::vector<int64_t> v = {7, 3, 9, 1, 5};
  EXPECT_EQ(p(v, 99), 9);
  EXPECT_EQ(p(v, 50), 5);  // ceil(2.5) = the 3rd smallest
  EXPECT_EQ(p({42}, 99), 42);
  EXPECT_EQ(p({42}, 1), 42);
}

TEST(Percentile, TwoHundredValuesP99IsThe198th) {
  std::vector<int64_t> v;
  for (int64_t i = 1; i <= 200; ++i) v.push_back(i * 10);
  EXPECT_EQ(p(v, 99), 1980);  // 198 of 200 values (99 %) are at or below it; 197 are not enough
}

TEST(Percentile, AgreesWithTheDefinitionOnShuffledValuesWithRepeats) {
  std::mt19937 rng(35);
  for (int round = 0; round < 300; ++round) {
    size_t n = 1 + rng() % 250;
    std::vector<int64_t> v(n);
    for (auto& x : v) x = int64_t(rng() % 40);  // many repeats
    for (unsigned percent : {1u, 10u, 50u, 90u, 99u, 100u})
      ASSERT_EQ(p(v, percent), by_definition(v, percent)) << "n=" << n << " p" << percent;
  }
}
