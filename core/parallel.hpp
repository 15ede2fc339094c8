// OpenMP in one place (style.md: "OpenMP where the work is"). Every parallel loop in the engine
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

namespace detail {
template <class Part>
void run_parts_on_threads(int parts, Part& part) {
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
}  // namespace detail

// The time spent inside parallel loops, for the share of a run that stays serial (Amdahl's law:
// a serial share s caps the speed-up at p threads at 1/(s + (1 − s)/p)). Opt-in and per thread:
// reset_parallel_seconds() starts counting on the calling thread; from then on every outermost
// run_parts call that thread makes (parts = 1 included: at one thread the question is which work
// could run in parallel), and every parallel_blocks call over at least kParallelMin items (below
// that it is serial at any thread count), adds its wall time — two steady_clock reads per call.
// Calls nested in a timed one are not counted again.
namespace detail {
struct ParallelClock {
  bool counting = false;
  int depth = 0;  // timed calls open on this thread
  std::chrono::steady_clock::duration inside{};
};
inline thread_local ParallelClock parallel_clock;

// Runs f(), adding its wall time to the thread's clock when it is the outermost timed call.
template <class F>
void timed_parallel(F&& f) {
  ParallelClock& c = parallel_clock;
  if (!c.counting || c.depth > 0) {
    f();
    return;
  }
  struct Close {  // also when f throws
    ParallelClock& c;
    std::chrono::steady_clock::time_point start;
    ~Close() {
      c.inside += std::chrono::steady_clock::now() - start;
      --c.depth;
    }
  } close{c, std::chrono::steady_clock::now()};
  ++c.depth;
  f();
}
}  // namespace detail

// Seconds this thread spent inside parallel loops since its last reset_parallel_seconds() (0 if
// it never called it).
inline double parallel_seconds() {
  return std::chrono::duration<double>(detail::parallel_clock.inside).count();
}

// Sets this thread's count to 0 and starts counting (see above).
inline void reset_parallel_seconds() {
  detail::parallel_clock.counting = true;
  detail::parallel_clock.inside = {};
}

// Stops counting on this thread (parallel_seconds keeps its value): a run counts only while it
// steps, and a small system not at all.
inline void stop_parallel_seconds() {
  detail::parallel_clock.counting = false;
}

// Runs f() where a loop over `items` items runs as one part (one thread, or a caller's own serial
// path): counted by parallel_seconds from kParallelMin items on, as run_parts(1, …) is — with more
// threads it would be split — and called plainly below that, where it is serial at any thread count.
template <class F>
void run_as_one_part(std::int64_t items, F&& f) {
  if (items < kParallelMin)
    f();
  else
    detail::timed_parallel(f);
}

// The most parts any parallel loop started by this thread ran on since its last
// reset_widest_team(): the threads a run's step loop actually used. A loop below kParallelMin items
// runs as one part whatever OMP_NUM_THREADS says, and a small system's loops all do — but a pair
// loop splits by pairs, so a system of fewer particles may still use every thread there.
namespace detail {
inline thread_local int widest_team = 1;
}
inline int widest_team() {
  return detail::widest_team;
}
inline void reset_widest_team() {
  detail::widest_team = 1;
}

// Runs part(u) for u = 0 … parts − 1, in parallel when parts > 1. Each part writes only its own
// data, so the result does not depend on which thread ran which part, nor on the team OpenMP
// actually gives. An exception thrown in a part is caught there (it must not leave a parallel
// region) and the first one, in part order, is rethrown after every part has ended.
// A loop that is serial at every thread count calls its body directly or through run_as_one_part
// with no items, not through run_parts with one part: that would count as parallel work.
template <class Part>
void run_parts(int parts, Part&& part) {
  if (parts <= 1) {
    if (parts == 1) detail::timed_parallel([&] { part(0); });
    return;
  }
  if (team_size() == 1) detail::widest_team = std::max(detail::widest_team, parts);  // not a nested loop
  detail::timed_parallel([&] { detail::run_parts_on_threads(parts, part); });
}

// Runs body(u, begin, end) on `parts` contiguous blocks of [0, n): block u is
// [block_begin(n, parts, u), block_begin(n, parts, u + 1)).
template <class Body>
void parallel_numbered_blocks(std::int64_t n, int parts, Body&& body) {
  if (parts <= 1) {  // small systems: no lambda, no 64-bit divisions (≈ 20 cycles each) per call
    if (parts == 1) run_as_one_part(n, [&] { body(0, std::int64_t{0}, n); });
    return;
  }
  run_parts(parts, [&](int u) { body(u, block_begin(n, parts, u), block_begin(n, parts, u + 1)); });
}

// Runs body(begin, end) on `parts` contiguous blocks of [0, n).
template <class Body>
void parallel_blocks(std::int64_t n, int parts, Body&& body) {
  parallel_numbered_blocks(n, parts, [&](int, std::int64_t begin, std::int64_t end) { body(begin, end); });
}

// Σ of body(begin, end) over `parts` contiguous blocks of [0, n), the blocks' sums added in block
// order: the same bits for a given number of parts, and with one part the sum body(0, n) itself.
template <class Body>
double parallel_sum(std::int64_t n, int parts, Body&& body) {
  std::array<double, kMaxParts> sums{};
  parallel_numbered_blocks(n, parts, [&](int u, std::int64_t begin, std::int64_t end) { sums[u] = body(begin, end); });
  double total = sums[0];
  for (int u = 1; u < parts; ++u) total += sums[u];
  return total;
}

}  // namespace stiffmd
