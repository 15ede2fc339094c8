// Connected constraint clusters: S = G M⁻¹ Gᵀ is block-diagonal over them.
#include "integrators/clusters.hpp"

#include <algorithm>
#include <utility>

#include "core/disjoint_sets.hpp"

namespace stiffmd {

std::vector<ConstraintCluster> find_clusters(const std::vector<StiffBond>& bonds, const Eigen::VectorXd& inv_mass) {
  // Union–find over bonds: two bonds are coupled iff they share a mobile particle.
  const int m = static_cast<int>(bonds.size());
  DisjointSets coupled(m);
  std::vector<int> last_bond_at(static_cast<size_t>(inv_mass.size()), -1);
  for (int b = 0; b < m; ++b) {
    for (int p : {bonds[b].i, bonds[b].j}) {
      if (inv_mass[p] == 0.0) continue;  // a fixed particle transmits no constraint force
      if (last_bond_at[p] >= 0) coupled.join(b, last_bond_at[p]);
      last_bond_at[p] = b;
    }
  }
  std::vector<int> cluster_of_root(m, -1);
  std::vector<ConstraintCluster> clusters;
  for (int b = 0; b < m; ++b) {
    const int r = coupled.root(b);
    if (cluster_of_root[r] < 0) {
      cluster_of_root[r] = static_cast<int>(clusters.size());
      clusters.emplace_back();
    }
    ConstraintCluster& c = clusters[cluster_of_root[r]];
    c.bonds.push_back(b);
    c.particles.push_back(bonds[b].i);
    c.particles.push_back(bonds[b].j);
  }
  for (auto& c : clusters) {
    std::sort(c.particles.begin(), c.particles.end());
    c.particles.erase(std::unique(c.particles.begin(), c.particles.end()), c.particles.end());
  }
  return clusters;
}

ClusterPath cluster_path(const ConstraintCluster& cluster, const std::vector<StiffBond>& bonds,
                         const Eigen::VectorXd& inv_mass) {
  const int n = static_cast<int>(cluster.bonds.size());
  ClusterPath path{ClusterShape::other, cluster.bonds};
  // Neighbours of each bond (by position in cluster.bonds) through its mobile ends: a mobile
  // particle in more than two bonds couples them all (a branch point), never a path.
  // Particles are numbered within the cluster (its sorted particle list), so that the work is
  // O(bonds log bonds) per cluster, not O(all particles).
  std::vector<std::vector<int>> neighbours(n);
  const std::vector<int>& particles = cluster.particles;
  std::vector<int> first_bond_at(particles.size(), -1), bonds_at(particles.size(), 0);
  for (int k = 0; k < n; ++k)
    for (int p : {bonds[cluster.bonds[k]].i, bonds[cluster.bonds[k]].j}) {
      if (inv_mass[p] == 0.0) continue;
      const auto q = static_cast<size_t>(std::lower_bound(particles.begin(), particles.end(), p) - particles.begin());
      if (++bonds_at[q] > 2) return path;
      if (first_bond_at[q] < 0) {
        first_bond_at[q] = k;
      } else {
        neighbours[k].push_back(first_bond_at[q]);
        neighbours[first_bond_at[q]].push_back(k);
      }
    }
  // A path starts at a bond with at most one neighbour; a cycle has none.
  int start = 0;
  bool ring = true;
  for (int k = 0; k < n; ++k)
    if (neighbours[k].size() <= 1) {
      start = k;
      ring = false;
      break;
    }
  std::vector<int> order;
  for (int previous = -1, current = start; current >= 0 && static_cast<int>(order.size()) < n;) {
    order.push_back(cluster.bonds[current]);
    int next = -1;
    for (int nb : neighbours[current])
      if (nb != previous && nb != start) next = nb;
    previous = current;
    current = next;
  }
  if (static_cast<int>(order.size()) != n) return path;  // not connected as a path (cannot happen for a cluster)
  path.shape = ring ? ClusterShape::ring : ClusterShape::chain;
  path.bonds = std::move(order);
  return path;
}

BondsAtParticles bonds_at_mobile_particles(const std::vector<int>& order, const std::vector<StiffBond>& bonds,
                                           const Eigen::VectorXd& inv_mass) {
  BondsAtParticles at;
  for (int r = 0; r < static_cast<int>(order.size()); ++r) {
    const StiffBond& b = bonds[order[r]];
    if (inv_mass[b.i] > 0.0) at[b.i].emplace_back(r, +1.0);
    if (inv_mass[b.j] > 0.0) at[b.j].emplace_back(r, -1.0);
  }
  return at;
}

}  // namespace stiffmd
