// Whether n values are all finite, in one pass without a branch per value (the run's check after
// every step on one process, engine/run/run.cpp, and on ranks, engine/domain/decomposition.cpp).
#pragma once

#include <cstdint>

namespace stiffmd {

// x·0 is ±0 for a finite x and NaN for ±∞ and NaN, and a NaN stays one through a sum: Σ p_i·0 is 0
// exactly when every p_i is finite. Four independent sums, which the compiler vectorises.
inline bool all_finite(const double* p, std::int64_t n) {
  double sum[4] = {0.0, 0.0, 0.0, 0.0};
  std::int64_t i = 0;
  for (; i + 4 <= n; i += 4)
    for (int l = 0; l < 4; ++l) sum[l] += p[i + l] * 0.0;
  for (; i < n; ++i) sum[0] += p[i] * 0.0;
  return (sum[0] + sum[1]) + (sum[2] + sum[3]) == 0.0;
}

}  // namespace stiffmd
