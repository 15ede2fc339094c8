// Connected constraint clusters: S = G M⁻¹ Gᵀ is block-diagonal over them.
#include "integrators/clusters.hpp"

#include <algorithm>
#include <utility>

#include "core/disjoint_sets.hpp"

namespace stiffmd {

std::vector<ConstraintCluster> find_clusters(const std::vector<StiffBond>& bonds, const Eigen::VectorXd& inv_mass) {
  // Two bonds are coupled iff they share a mobile particle (a pinned one, m⁻¹ = 0, transmits no
  // constraint force): the particles' components with only mobile ones joining, a bond's cluster
  // the component of its mobile ends (one with none, both ends pinned, is a cluster of its own).
  const int n = static_cast<int>(inv_mass.size()), m = static_cast<int>(bonds.size());
  std::vector<std::pair<int, int>> ends(static_cast<size_t>(m));
  std::vector<char> mobile(static_cast<size_t>(n));
  for (int b = 0; b < m; ++b) ends[b] = {bonds[b].i, bonds[b].j};
  for (int p = 0; p < n; ++p) mobile[p] = inv_mass[p] != 0.0;
  const std::vector<int> component = connected_components(n, ends, &mobile);
  std::vector<int> cluster_of_component(static_cast<size_t>(n), -1);
  std::vector<ConstraintCluster> clusters;
  for (int b = 0; b < m; ++b) {
    const int p = mobile[bonds[b].i] ? bonds[b].i : bonds[b].j;  // a mobile end, if it has one
    int k = static_cast<int>(clusters.size());                   // a new cluster, unless p's component has one
    if (mobile[p]) {
      int& known = cluster_of_component[component[p]];
      if (known < 0)
        known = k;
      else
        k = known;
    }
    if (k == static_cast<int>(clusters.size())) clusters.emplace_back();
    ConstraintCluster& c = clusters[k];
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
