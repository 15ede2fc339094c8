// Initial configurations for polymer scenes: linear chains, rings and stars grown as
// self-avoiding random walks with exact bond lengths, and a cubic box for a number density
// (Maxwell–Boltzmann velocities: maxwell_boltzmann in core/portable_random.hpp).
//
// Reproducibility: every random number comes from std::mt19937_64 (whose output the standard
// fixes) through our own uniform-from-bits, Marsaglia-polar normals and a logarithm/exponential
// written with + − × ÷ only — never std::*_distribution or libm's log/exp, whose results are
// implementation-defined. The same seed therefore gives the same output on any machine with
// IEEE-754 doubles (as long as the compiler does not contract a*b+c into fused multiply-adds,
// which could move the last bit and, rarely, flip one accept/reject decision).
#pragma once

#include <Eigen/Core>
#include <array>
#include <cstdint>
#include <utility>
#include <vector>

#include "core/box.hpp"
#include "core/portable_random.hpp"  // maxwell_boltzmann, for the builders' users

namespace stiffmd {

// What a builder returns. Beads are numbered molecule by molecule: a linear chain or ring from
// one end (ring: bead 0 is bonded to bead n−1); a star as its core, then arm 0 from the core
// outwards, arm 1, …
struct Polymer {
  Eigen::Matrix3Xd x;                         // positions, unwrapped: bonded beads are exactly
                                              // bond_length apart without any minimum image
  std::vector<std::pair<int, int>> bonds;     // in growth order: (i, i+1); a ring's closing bond is (last, first)
  std::vector<std::array<int, 3>> angles;     // every (i, j, k) with i–j and j–k bonded, i ≠ k, each once:
                                              // consecutive triplets along each backbone, and at a star's
                                              // core one triplet per pair of arms
  std::vector<std::array<int, 4>> dihedrals;  // every (i, j, k, l) with i–j, j–k, k–l bonded and
                                              // i ≠ l, by central bond j–k in bond order (LAMMPS's
                                              // definition of the proper dihedrals of a bond graph)
  std::vector<int> molecule;                  // 0-based molecule index per bead
};

struct ChainSpec {
  int chains = 1, beads = 10;  // molecules; beads per chain or ring (per arm for stars, not counting the core)
  double bond_length = 0.97;
  double min_distance = 0.8;  // no two non-bonded beads closer than this (minimum image); 0 = no check
  std::uint64_t seed = 1;
};

// Where the molecules start (the first bead of a chain or ring, a star's core), per axis:
//   periodic axis: uniform in [origin, origin + length) — the periodic cell;
//   open axis:     uniform in [origin − length/2, origin + length/2) — a region centred on the
//                  origin; a zero length puts every start on the origin (fine for one molecule).
// The molecules then grow freely from there (on open axes they may leave the region).
// Periodic axes must be longer than 2·bond_length, so that the minimum image of every bond is
// the bond itself. A start region that is a single point is refused for more than one molecule.
//
// Validation (std::invalid_argument): chains ≥ 1; beads ≥ 2 (rings ≥ 3, star arms ≥ 1);
// 1 ≤ arms ≤ kMaxStarArms (a core has arms·(arms − 1)/2 angles), and no more arms than fit
// around the core at min_distance; bond_length > 0; 0 ≤ min_distance < 2·bond_length (beads two
// bonds apart can be at most 2·bond_length apart); finite box. A configuration that cannot be
// grown within the bounded number of tries throws std::runtime_error naming the molecule.
//
// Algorithm: all molecules grow together, one bead each per round (so the box fills evenly and
// no late molecule must thread through an already-full box). For each bead, random positions at
// bond_length from its bonded parent are drawn; a position is admissible if no placed
// non-bonded bead (found through a cell list) is closer than min_distance, and of up to 32
// admissible ones the bead takes the one in closest contact with its surroundings (other
// molecules, and own beads at least 5 bonds away along the chain) — packing snugly keeps the
// free volume in one piece, which is what lets dense melts finish (details and the price in
// conformations in builders.cpp). When no direction works the molecule backs off one bead,
// then more while it stays stuck; after too many failures it starts again elsewhere, and the
// builder gives up after a bounded number of failures in all.
//
// Reach, 100 molecules at density 0.85, bond_length 0.97, one core (measured, 20 seeds each):
// linear chains of 100 build every time up to min_distance 0.94 (≤ 0.8 s; 0.9 in ~0.35 s;
// 17 of 20 at 0.95), rings of 100 up to 0.85 (≤ 1 s; 0.88: 10 of 10 in ≤ 2.3 s; 0.9: 3 of 10),
// stars of 4 arms × 25 up to 0.9 (≤ 0.9 s; 0.92: 10 of 10 in ≤ 2.2 s). A single chain of 10⁵
// beads fills a 0.85 box at min_distance 0.9 in ~3 s.
Polymer build_linear_chains(const ChainSpec& spec, const Box& box);

// Closed rings (bead n−1 bonded to bead 0): two tips grow from bead 0 in turn (beads 1, n−1,
// 2, n−2, …), each step drawn from a Gaussian-bridge bias exp(κ u·d̂) towards the other tip
// (κ = 3|d|/(m·ℓ) with m bonds still to place between them, as for a freely jointed chain)
// and restricted to the directions from which the gap can still close; the last bead lies on
// the circle at bond_length from both tips. All bonds, the closing ones included, are
// bond_length to rounding.
Polymer build_rings(const ChainSpec& spec, const Box& box);

// `chains` stars, each a core bead with `arms` arms of `spec.beads` beads (1 + arms·beads beads
// per star); the arms grow in turn, one bead each, so that no arm walls in the core.
constexpr int kMaxStarArms = 1000;
Polymer build_stars(const ChainSpec& spec, int arms, const Box& box);

// The checks above, shared by every builder (engine/scene/chains_by_molecule.hpp too): the spec,
// the box and a total of at most INT_MAX beads; std::invalid_argument starting with `who`.
void validate_chain_spec(const char* who, const ChainSpec& spec, int min_beads, const Box& box, long long total_beads);

// A cube of side (total_beads / density)^(1/3) with its corner at the origin, periodic on all
// axes. total_beads ≥ 1 and density > 0 (finite), else std::invalid_argument.
Box box_for_density(int total_beads, double density);

}  // namespace stiffmd
