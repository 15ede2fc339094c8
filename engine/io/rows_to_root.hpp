// Rows keyed by a global number (a particle's index, a bonded item's place in the system's list)
// held by the ranks of a decomposed run, streamed to rank 0 in the order of that number, one block
// of consecutive numbers at a time: what a file laid out in global order and written by rank 0
// alone (the XYZ frame, the trajectories' topology.data, the H5MD file's time-independent
// datasets: docs/parallel.md, "Outputs") is written from, with rank 0 holding one block of rows
// and each rank its own, never O(N).
#pragma once

#include <cstddef>
#include <cstdint>
#include <functional>

#include "core/communicator.hpp"

namespace stiffmd {

struct RowStream {
  std::int64_t rows = 0;  // the whole's: numbers 0 … rows − 1, each on exactly one rank
  int width = 1;          // values per row (doubles: an integer below 2⁵³ or the double itself is exact)
  std::int64_t block = 4096;
};

// This rank's `mine` rows, k = 0 … mine − 1 with increasing numbers key(k); fill(k, out) writes
// row k's `width` values. Rank 0's take(first, count, values) gets the rows [first, first + count)
// of the whole, row-major (count × width values), block after block in order; the other ranks'
// take is never called. One gather per block: ⌈rows / block⌉ in all. Collective. Throws
// std::logic_error (rank 0; another rank when its numbers do not increase) for a row on two ranks,
// on none, or out of range.
void stream_rows_to_root(const Communicator& ranks, const RowStream& stream, std::size_t mine,
                         const std::function<std::int64_t(std::size_t)>& key,
                         const std::function<void(std::size_t, double*)>& fill,
                         const std::function<void(std::int64_t, std::int64_t, const double*)>& take);

}  // namespace stiffmd
