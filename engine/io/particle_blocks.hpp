// A system's particles cut into blocks of consecutive global indices, one per process: process r
// of P holds [⌊N r / P⌋, ⌊N (r + 1) / P⌋), N/P of them. What a file laid out by global index
// (the shared H5MD file's rows, a checkpoint's arrays: docs/parallel.md, "Outputs") is written
// by: each process writes its block as one contiguous piece, whichever process owns the
// particles, after one exchange that brings every owned row to its block.
#pragma once

#include <cstdint>
#include <vector>

#include "core/communicator.hpp"

namespace stiffmd {

struct ParticleBlock {
  std::int64_t first = 0, count = 0;  // the global indices [first, first + count)
};

// Process `rank`'s block of n particles over `ranks` processes.
ParticleBlock block_of(std::int64_t n, int ranks, int rank);
// The process whose block holds global index g: the largest r with ⌊n r / P⌋ ≤ g, i.e.
// n r / P < g + 1, r = ⌊((g + 1) P − 1) / n⌋.
int block_owner(std::int64_t g, std::int64_t n, int ranks);

// One per-particle array of an exchange: `rows` values per particle, column-major (an
// Eigen::Matrix3Xd's data: rows = 3; a vector's: rows = 1). `owned`: the process's particles in the
// order of its ids; `block`: where its block's count × rows values go (sized by the caller).
struct BlockArray {
  const double* owned;
  double* block;
  int rows;
};

// The exchange, with its buffers kept between calls (a trajectory exchanges every frame).
class BlockExchange {
 public:
  // Each process's rows (global indices `ids`, any set, each on exactly one process) go to the
  // process whose block of n holds them, in one exchange; every block's rows arrive. Collective.
  // Throws std::invalid_argument when an index is out of range, on two processes or on none.
  void run(const Communicator& comm, std::int64_t n, const std::vector<int>& ids,
           const std::vector<BlockArray>& arrays);
  // The same for the rows [from, to) of every block alone (row j of a block: its global index
  // first + j; the same from, to on every process): each array's `block` receives the block's rows
  // from … to − 1, row j at j − from. A file written by blocks in rounds of rows (the checkpoint)
  // holds one round's rows at a time, not the block's. Collective.
  void run(const Communicator& comm, std::int64_t n, const std::vector<int>& ids, const std::vector<BlockArray>& arrays,
           std::int64_t from, std::int64_t to);

 private:
  std::vector<std::vector<double>> send_, received_;
  std::vector<std::size_t> sending_;  // per process, the rows it is sent
  std::vector<char> filled_;
};

}  // namespace stiffmd
