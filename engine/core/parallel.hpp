// OpenMP in one place (docs/design.md §9). Every parallel loop in the engine
// splits its work into a fixed partition per thread count and combines per-thread results in
// thread order, so a run is bit-for-bit reproducible for a given OMP_NUM_THREADS (no atomics,
// no OpenMP reductions, whose combination order is unspecified). Loops over fewer than
// kParallelMin items stay serial: a fork/join costs microseconds, a two-bond pendulum step less.
#pragma once

#include <algorithm>
#include <array>
#include <cstdint>
#include <exception>

#ifdef _OPENMP
#include <omp.h>
#endif

namespace stiffmd {

inline constexpr std::int64_t kParallelMin = 4096;
inline constexpr int kMaxParts = 256;  // the most parts a parallel loop is split into

inline int max_threads() {
#ifdef _OPENMP
  return omp_get_max_threads();
#else
  return 1;
#endif
}

// Sets the thread count of later parallel loops (as OMP_NUM_THREADS does at start-up).
inline void set_max_threads([[maybe_unused]] int n) {
#ifdef _OPENMP
  omp_set_num_threads(n);
#endif
}

// Threads in the current team (1 outside a parallel region).
inline int team_size() {
#ifdef _OPENMP
  return omp_get_num_threads();
#else
  return 1;
#endif
}

inline int thread_id() {
#ifdef _OPENMP
  return omp_get_thread_num();
#else
  return 0;
#endif
}

// Parts to split n items into: one per thread, 1 below kParallelMin.
inline int threads_for(std::int64_t n) {
  return n < kParallelMin ? 1 : std::min(max_threads(), kMaxParts);
}

// Block t of n items split into `parts` nearly equal contiguous blocks: [begin, end).
inline std::int64_t block_begin(std::int64_t n, int parts, int t) {
  return n * t / parts;
}

// Runs part(u) for u = 0 … parts − 1, in parallel when parts > 1. Each part writes only its own
// data, so the result does not depend on which thread ran which part, nor on the team OpenMP
// actually gives. An exception thrown in a part is caught there (it must not leave a parallel
// region) and the first one, in part order, is rethrown after every part has ended.
template <class Part>
void run_parts(int parts, Part&& part) {
  if (parts <= 1) {
    if (parts == 1) part(0);
    return;
  }
  std::array<std::exception_ptr, kMaxParts> error;
#pragma omp parallel for schedule(static, 1) num_threads(parts)
  for (int u = 0; u < parts; ++u) {
    try {
      part(u);
    } catch (...) {
      error[u] = std::current_exception();
    }
  }
  for (int u = 0; u < parts; ++u)
    if (error[u]) std::rethrow_exception(error[u]);
}

// Runs body(begin, end) on `parts` contiguous blocks of [0, n).
template <class Body>
void parallel_blocks(std::int64_t n, int parts, Body&& body) {
  if (parts <= 1) {  // small systems: no lambda, no 64-bit divisions (≈ 20 cycles each) per call
    if (parts == 1) body(std::int64_t{0}, n);
    return;
  }
  run_parts(parts, [&](int u) { body(block_begin(n, parts, u), block_begin(n, parts, u + 1)); });
}

}  // namespace stiffmd
