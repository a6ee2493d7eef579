// The one percentile: the latencies of a live link (the silence window), of a
// fuzz run (the p99 that bounds its silences) and of the benchmarks.
#pragma once

#include <algorithm>
#include <cstddef>
#include <span>

namespace mbc::conf {

// The nearest-rank percentile: the smallest of the values with at least
// `percent` % of them at or below it, i.e. the ceil(percent / 100 x n)-th
// smallest (the p99 of 100 values is the 99th, of fewer than 100 their
// maximum). Reorders `values`; they must not be empty; percent in 1..100.
template <class T>
T percentile(std::span<T> values, unsigned percent) {
  const size_t rank = (values.size() * percent + 99) / 100;  // ceil, in integers
  const size_t at = std::clamp<size_t>(rank, 1, values.size()) - 1;
  std::nth_element(values.begin(), values.begin() + std::ptrdiff_t(at), values.end());
  return values[at];
}

}  // namespace mbc::conf
