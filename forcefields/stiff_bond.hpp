// A stiff, constraint-defining bond b = (i, j) (docs/design.md §1):
//   V_b = ½ α_b² g_b(x)²,   g_b(x) = |x_i − x_j| − ℓ_b,   energy ε⁻² V_b.
// The set of these bonds defines the constraint manifold g(x) = 0 used by the
// constraint toolbox (integrators/constraints.hpp).
//
// The rules a set of stiff bonds obeys are checked once, here (find_stiff_bond_problem), for the
// stiff-harmonic force term, the constraint toolbox and the stiff modes alike; g_b and max |g|
// are defined once, here, on the one bond vector (core/state.hpp).
#pragma once

#include <Eigen/Core>
#include <algorithm>
#include <array>
#include <cmath>
#include <optional>
#include <string>
#include <vector>

#include "core/parallel.hpp"

#include "core/state.hpp"

namespace stiffmd {

struct StiffBond {
  int i = 0;  // particle indices
  int j = 0;
  double length = 1.0;  // ℓ_b, rest length
  double alpha = 1.0;   // α_b, stiffness in units of 1/ε
};

// All constraint-defining bonds of a scene and their common ε.
struct StiffBonds {
  std::vector<StiffBond> bonds;
  double epsilon = 1.0;
  // The rigid methods' SHAKE stops, as LAMMPS's fix shake/rattle with this tolerance, at the first
  // iterate whose update changed no multiplier λ_b / |d_b(x_ref)| by more than it (a mass; the
  // toolbox's multiplier_tol, integrators/constraints.hpp); 0: it iterates to max |g| ≤ 1e-12.
  double shake_tolerance = 0.0;
};

// "bond b (particles i–j)", for messages.
inline std::string describe_bond(int b, const StiffBond& bond) {
  return "bond " + std::to_string(b) + " (particles " + std::to_string(bond.i) + "–" + std::to_string(bond.j) + ")";
}

// g_b(x) = |x_i − x_j| − ℓ_b.
inline double constraint_value(const StiffBond& b, const Eigen::Matrix3Xd& x) {
  return bond_vector(x, b.i, b.j).norm() - b.length;
}

// max_b |g_b(x)| (0 without bonds): the constraint violation reported everywhere.
inline double max_violation(const std::vector<StiffBond>& bonds, const Eigen::Matrix3Xd& x) {
  // In blocks of bonds on the threads: a maximum is the same in any grouping.
  const std::int64_t n = static_cast<std::int64_t>(bonds.size());
  const int parts = threads_for(n);
  std::array<double, kMaxParts> worst{};
  parallel_numbered_blocks(n, parts, [&](int u, std::int64_t first, std::int64_t last) {
    double w = 0.0;
    for (std::int64_t k = first; k < last; ++k) w = std::max(w, std::abs(constraint_value(bonds[k], x)));
    worst[u] = w;
  });
  double w = 0.0;
  for (int u = 0; u < parts; ++u) w = std::max(w, worst[u]);
  return w;
}

// The first broken rule, if any: `bond` is the index of the offending bond (−1 for a particle's
// inverse mass), `what` a sentence naming the bond by its particles.
struct StiffBondProblem {
  int bond = -1;
  std::string what;
};

// Rules: particle indices ≥ 0 (and < inv_mass->size()), two distinct particles, ℓ_b finite and
// > 0, α_b finite and > 0, at most one stiff bond per particle pair; with the inverse masses
// (inv_mass not null): each finite and ≥ 0, and no bond joining two fixed particles (S_bb = 0:
// it constrains nothing and has no vibrational mode). Lengths must be realisable: around every
// cycle of the bond graph each length is shorter than the sum of the others (the polygon
// inequality, i.e. ℓ_e < the shortest path between e's ends avoiding e); equality leaves only
// collinear configurations, where G is rank deficient and S singular, so it is refused too.
std::optional<StiffBondProblem> find_stiff_bond_problem(const std::vector<StiffBond>& bonds,
                                                        const Eigen::VectorXd* inv_mass);

}  // namespace stiffmd
