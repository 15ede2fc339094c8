// Constraint clusters: the connected sets of stiff bonds over which S = G M⁻¹ Gᵀ is block-diagonal,
// and their shapes. S_bc = ±(u_b·u_c) m⁻¹_p for two bonds b, c sharing particle p, and 0 when p is
// pinned (m⁻¹ = 0): a pinned particle couples nothing, so two bonds meeting only there belong to
// two clusters, though to one molecule (core/disjoint_sets.hpp tells the two notions apart).
//
// The clusters' order is the one every consumer numbers by — the toolbox's solves, the stiff
// modes (one mode per bond, cluster after cluster), Fixman's potential, the effective dynamics'
// actions, and a decomposed run's share of those actions (engine/domain/domain_integrator.cpp):
// each cluster's bonds ascending, the clusters in the order of their first bond.
#pragma once

#include <Eigen/Core>
#include <map>
#include <utility>
#include <vector>

#include "forcefields/stiff_bond.hpp"

namespace stiffmd {

// A connected set of stiff bonds (a molecule, a chain, the double pendulum, an arm of a pinned core).
struct ConstraintCluster {
  std::vector<int> bonds;      // indices into the bond list, in ascending order
  std::vector<int> particles;  // particles touched by these bonds (pinned ones included), ascending
};

// The clusters of `bonds`: two bonds are coupled iff they share a particle with inv_mass > 0
// (S_bc = ±(u_b·u_c)/m_shared, 0 at a pinned particle). Ordered by their first bond.
std::vector<ConstraintCluster> find_clusters(const std::vector<StiffBond>& bonds, const Eigen::VectorXd& inv_mass);

// The shape of a cluster's coupling graph (bonds joined when they share a mobile particle), which
// fixes the sparsity of S on it: a path (open chain: S tridiagonal), a cycle (ring: S cyclic
// tridiagonal), or anything else (stars, branched polymers).
enum class ClusterShape { chain, ring, other };
struct ClusterPath {
  ClusterShape shape = ClusterShape::other;
  std::vector<int> bonds;  // chain, ring: the bonds in path order (consecutive ones share a
                           // mobile particle, and for a ring the last and the first); other: as given
};
ClusterPath cluster_path(const ConstraintCluster& cluster, const std::vector<StiffBond>& bonds,
                         const Eigen::VectorXd& inv_mass);

// For each mobile particle of a cluster, the (position in `order`, sign in G: +1 at i, −1 at j)
// of its bonds, particles ascending. Fixed particles are left out: m⁻¹ = 0 there, so they
// couple nothing. The couplings of S = G M⁻¹ Gᵀ are every pair of bonds at one particle.
using BondsAtParticles = std::map<int, std::vector<std::pair<int, double>>>;
BondsAtParticles bonds_at_mobile_particles(const std::vector<int>& order, const std::vector<StiffBond>& bonds,
                                           const Eigen::VectorXd& inv_mass);

}  // namespace stiffmd
