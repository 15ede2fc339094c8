// Linear chains built molecule by molecule: molecule m's beads depend only on (seed, m), the chain
// spec and the box, so a rank can build just the molecules it owns, in memory and time of its own
// molecules, and the pieces of any partition put together are the whole build bit for bit
// (docs/parallel.md, "The set-up by parts"; the deck's [[build]] growth = "by-molecule",
// docs/decks.md).
//
// Each molecule draws from its own random stream, std::mt19937_64 seeded with a key mixed from
// (seed, m) (splitmix64's finaliser), through the same portable uniforms and unit vectors as the
// other builders (core/portable_random.hpp: no std::*_distribution, no libm log/exp; the same bits
// on every IEEE-754 machine). From it the molecule takes its first bead, uniform in the start
// region (builders.hpp), and then its walk: each bead at bond_length from the previous one, the
// first of up to kTrials uniform directions that keeps it min_distance (minimum image) from every
// bead of its own chain but its bonded parent — a self-avoiding walk, backing off and restarting
// when stuck as the other builders do.
//
// Across molecules nothing is tested: a rank cannot test a bead against beads it does not build,
// and any rejection between molecules that every rank could repeat alike would need the final
// walks of the molecules tested against, which need theirs in turn, back to the whole system. The
// walks therefore overlap one another at melt densities, as LAMMPS's chain tool's do; the run's
// soft start removes the overlaps ([minimize] with max_force, which the overlap check at the start
// asks for: docs/decks.md "Validation"). The closest non-bonded distances left on a 32 000-bead
// melt are in docs/parallel.md.
#pragma once

#include <Eigen/Core>
#include <array>
#include <cstdint>
#include <functional>
#include <utility>
#include <vector>

#include "core/box.hpp"
#include "engine/scene/builders.hpp"

namespace stiffmd {

// The built molecules, each with its beads in chain order (bead k of molecule m has global index
// m·beads + k), molecules by increasing index: so the beads' global indices increase, and the
// items are the whole build's items of these molecules, in the whole build's order.
struct BuiltMolecules {
  std::vector<int> molecules;                 // the molecules built, increasing
  Eigen::Matrix3Xd x;                         // positions, unwrapped (each molecule whole)
  std::vector<int> global;                    // per bead: its index in the whole build
  std::vector<int> molecule;                  // per bead: its molecule's index in the whole build
  Eigen::Matrix3Xd anchors;                   // per molecule built: its centre of mass (below)
  std::vector<std::pair<int, int>> bonds;     // by global index: (i, i+1) along each chain
  std::vector<std::array<int, 3>> angles;     // (i−1, i, i+1): the whole build's order (builders.hpp)
  std::vector<std::array<int, 4>> dihedrals;  // (i−1, i, i+1, i+2)
};

// The random stream's key of molecule m: splitmix64's finaliser of the seed's, plus m.
std::uint64_t molecule_stream_key(std::uint64_t seed, int molecule);

// The molecules m with wanted(m) (all of 0 … chains − 1 are asked, in order; each grows only if
// wanted). `inv_mass` is the beads' inverse mass, for the anchors: Σ_i m_i x_i / Σ_i m_i over the
// molecule's beads by increasing global index with m_i = 1/inv_mass (1 for inv_mass = 0), the
// expression Decomposition::distribute evaluates (engine/domain/decomposition.cpp), so a rank
// can tell which of the molecules it built are its own. The anchor needs the whole walk: a rank
// that must find its molecules without knowing them in advance grows every walk once
// (chain_anchors_by_molecule), O(N) time, O(chains) memory.
//
// Validation as the other builders (builders.hpp; std::invalid_argument), and a molecule that
// cannot be grown within the bounded tries throws std::runtime_error naming it.
BuiltMolecules build_linear_chains_by_molecule(const ChainSpec& spec, const Box& box,
                                               const std::function<bool(int)>& wanted, double inv_mass = 1.0);

// The molecules [first, end).
BuiltMolecules build_linear_chains_by_molecule(const ChainSpec& spec, const Box& box, int first, int end,
                                               double inv_mass = 1.0);

// Every molecule's anchor (as above), keeping one walk at a time: 3·chains doubles.
Eigen::Matrix3Xd chain_anchors_by_molecule(const ChainSpec& spec, const Box& box, double inv_mass = 1.0);

// The whole build (every molecule) as the other builders return it: local = global indices.
Polymer build_linear_chains_by_molecule(const ChainSpec& spec, const Box& box);

}  // namespace stiffmd
