// A stable counting sort on the threads, for the neighbour list's cells and rows (Cormen et al.,
// "Introduction to Algorithms", §8.2, with per-part counts as in a parallel radix sort).
//
// The items come in `parts` sequences (part u: a block of particles, or the pairs one thread
// found), each with a key in [0, keys). Sorted, they are ordered by key, then by part, then by
// their place within the part: the order a single pass over the parts in turn would give, so the
// result does not depend on how many parts there are, only on the items' concatenated order.
// Each part counts its own keys (count[u][k]); the starts follow from the counts in two passes
// over blocks of keys with one short serial prefix over the blocks (integers: any split gives the
// same starts); each part then places its items through its own cursors,
//     start[k] + Σ_{u' < u} count[u'][k] + (the part's earlier items of key k).
// The buffers are members, reused from one sort to the next: once sized, nothing is allocated.
#pragma once

#include <array>
#include <cstdint>
#include <vector>

#include "core/parallel.hpp"

namespace stiffmd {

template <class Offset>
class CountingSort {
 public:
  // Starts a sort of items in `parts` (≤ kMaxParts) sequences by keys in [0, keys); then each
  // part clears its counts (clear) from its own thread.
  void begin(int parts, int keys) {
    parts_ = parts;
    keys_ = keys;
    if (static_cast<int>(count_.size()) < parts) count_.resize(parts);
  }

  // Part u's counts by key, set to 0: ++counts[k] once per item of key k, from part u only.
  int* clear(int u) {
    count_[u].assign(static_cast<std::size_t>(keys_), 0);
    return count_[u].data();
  }

  // Fills start[0 … keys]: start[k] the first slot of key k, start[keys] the number of items. On
  // the threads; afterwards each part's counts are its cursors (cursor).
  void starts(Offset* start) {
    const int keys = keys_, parts = parts_;
    const int blocks = threads_for(keys);
    std::array<Offset, kMaxParts + 1> block_start{};
    // The items of each block of keys, then their starts: an exclusive prefix over the blocks.
    parallel_numbered_blocks(keys, blocks, [&](int v, std::int64_t b, std::int64_t e) {
      Offset sum = 0;
      for (int u = 0; u < parts; ++u) {
        const int* c = count_[u].data();
        for (std::int64_t k = b; k < e; ++k) sum += c[k];
      }
      block_start[v + 1] = sum;
    });
    for (int v = 0; v < blocks; ++v) block_start[v + 1] += block_start[v];
    // In place of the counts, Σ_{u' < u} count[u'][k] (part u's first slot of key k past start[k]),
    // part by part over the block's keys (a loop along k: contiguous, so it runs in vector lanes),
    // before[k] ending as the items of key k; then start[k] by a prefix over the block.
    if (static_cast<int>(before_.size()) < keys) before_.resize(static_cast<std::size_t>(keys));
    parallel_numbered_blocks(keys, blocks, [&](int v, std::int64_t b, std::int64_t e) {
      int* before = before_.data();
      for (std::int64_t k = b; k < e; ++k) before[k] = 0;
      for (int u = 0; u < parts; ++u) shift_counts(count_[u].data() + b, before + b, e - b);
      Offset run = block_start[v];
      for (std::int64_t k = b; k < e; ++k) {
        start[k] = run;
        run += before[k];
      }
    });
    start[keys] = block_start[blocks];
    start_ = start;
  }

  // Part u's slots after starts(): slot(k) is the place of its next item of key k (its items in
  // their order, from part u only).
  struct Cursor {
    const Offset* start;
    int* next;
    Offset slot(int key) { return start[key] + next[key]++; }
  };
  Cursor cursor(int u) { return {start_, count_[u].data()}; }

 private:
  // count[k] becomes before[k], and before[k] grows by the old count[k], for k < len.
  static void shift_counts(int* __restrict count, int* __restrict before, std::int64_t len) {
    for (std::int64_t k = 0; k < len; ++k) {
      const int here = count[k];
      count[k] = before[k];
      before[k] += here;
    }
  }

  int parts_ = 0, keys_ = 0;
  std::vector<std::vector<int>> count_;  // per part, per key
  std::vector<int> before_;              // starts' scratch: per key, the items of the parts so far
  const Offset* start_ = nullptr;
};

}  // namespace stiffmd
