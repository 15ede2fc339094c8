// The pair terms' overlap check at the start of a run on the scene's description (Scene::
// overlap_rules, engine/scene/overlap_rule.hpp): the whole load checks its scene's particles, a
// description has none of its counted chains, so the parts are checked once they are in their
// domains (docs/parallel.md, "The run on the description"). Each rank searches its pair set (home
// beads and halo, wrapped into the box): every pair within a rule's range has a home bead on some
// rank, whose pair set holds the other bead (the range is below r_c < R). A pair of two home beads
// is counted by their home, a home–halo pair by the home of the lower global index, so the count is
// the whole system's; the closest pair is the least (r, i, j) over the ranks, as the whole load
// takes it; pairs of special weight 0 are left out by the partners each bead carries.
#pragma once

#include <Eigen/Core>
#include <string>
#include <vector>

#include "core/communicator.hpp"
#include "engine/domain/decomposition.hpp"
#include "engine/scene/scene.hpp"

namespace stiffmd {

// The first rule's finding, "where: what" as load_scene's InputError says it for the same
// closest pair, or "" when no pair overlaps; the same text on every rank (collective). `pair_terms`:
// the names of the part's pair terms in the order of Decomposition::pair_data().special.
// `owned_x`: the owned positions; `description`: the scene the rules and particle sources are of.
std::string part_overlaps(const std::vector<OverlapRule>& rules, const std::vector<std::string>& pair_terms,
                          const Decomposition& domains, const Eigen::Matrix3Xd& owned_x, const Box& box,
                          const Scene& description, const Communicator& comm);

}  // namespace stiffmd
