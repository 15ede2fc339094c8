// OpenMP in one place (docs/design.md §9). Every parallel loop in the engine
// splits its work into a fixed partition per thread count and combines per-thread results in
// thread order, so a run is bit-for-bit reproducible for a given OMP_NUM_THREADS (no atomics,
// no OpenMP reductions, whose combination order is unspecified). Loops over fewer than
// kParallelMin items stay serial: a fork/join costs microseconds, a two-bond pendulum step less.
#pragma once

#include <algorithm>
#include <array>
#include <chrono>
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
// The wall time spent inside the outermost run_parts calls of this thread, whatever their part
// count: the work that runs in parallel with more threads. The rest of a step loop is its serial
// share (Amdahl's law: with p threads at best 1/(s + (1 − s)/p) faster), which one thread can
// measure. Timed only while `on` (a run of at least kParallelMin particles: below it every loop
// stays serial, and two steady_clock reads per call would be felt by a two-bond pendulum's step);
// nested calls (a part that splits again) are inside their parent's time.
struct ParallelTime {
  double seconds = 0.0;
  int depth = 0;
  bool on = false;
};
inline ParallelTime& parallel_time() {
  thread_local ParallelTime t;
  return t;
}
inline double parallel_seconds() {
  return parallel_time().seconds;
}
inline void reset_parallel_seconds() {
  parallel_time().seconds = 0.0;
}
inline void time_parallel_loops(bool on) {
  parallel_time().on = on;
}

namespace parallel_detail {
// Times an outermost run_parts call into parallel_time().
class Timed {
 public:
  Timed() : t_(parallel_time()), counted_(t_.on), outermost_(counted_ && t_.depth++ == 0) {
    if (outermost_) start_ = std::chrono::steady_clock::now();
  }
  ~Timed() {
    if (!counted_) return;
    --t_.depth;
    if (outermost_) t_.seconds += std::chrono::duration<double>(std::chrono::steady_clock::now() - start_).count();
  }
  Timed(const Timed&) = delete;
  Timed& operator=(const Timed&) = delete;

 private:
  ParallelTime& t_;
  bool counted_, outermost_;
  std::chrono::steady_clock::time_point start_;
};
}  // namespace parallel_detail

template <class Part>
void run_parts(int parts, Part&& part) {
  const parallel_detail::Timed timed;
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
    const parallel_detail::Timed timed;
    if (parts == 1) body(std::int64_t{0}, n);
    return;
  }
  run_parts(parts, [&](int u) { body(block_begin(n, parts, u), block_begin(n, parts, u + 1)); });
}

}  // namespace stiffmd
