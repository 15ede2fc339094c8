// Particles cut into blocks of whole molecules, for the passes that take one block at a time
// while it stays in cache (the micro steps: forcefields/bond_loop.hpp, MicroStepPlan; the
// constrained step: integrators/constraint_blocks.cpp). A molecule is a range of particle
// indices: the union of the overlapping index intervals [p, reach[p]] of its bonds (or clusters),
// reach[p] ≥ p the highest index a bond from p reaches (p itself when none does). A block closes at
// the first end of such a union at least min_particles past its start (or at the last particle).
#pragma once

#include <algorithm>
#include <cstdint>
#include <vector>

namespace stiffmd {

// Calls close(first, last) for each block, particles first … last − 1, in order, and returns each
// particle's block index.
template <class Close>
std::vector<std::int64_t> molecule_blocks(const std::vector<std::int64_t>& reach, std::int64_t min_particles,
                                          Close&& close) {
  const auto n = static_cast<std::int64_t>(reach.size());
  std::vector<std::int64_t> block_of(reach.size());
  std::int64_t first = 0, end = -1, blocks = 0;  // the block being formed, and the molecule's reach
  for (std::int64_t p = 0; p < n; ++p) {
    end = std::max(end, reach[p]);
    block_of[p] = blocks;
    if (p == end && (p + 1 - first >= min_particles || p + 1 == n)) {  // a molecule ends here
      close(first, p + 1);
      ++blocks;
      first = p + 1;
    }
  }
  return block_of;
}

}  // namespace stiffmd
