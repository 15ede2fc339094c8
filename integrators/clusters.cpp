// Connected constraint clusters (design.md §2): S = G M⁻¹ Gᵀ is block-diagonal over them.
#include <algorithm>
#include <numeric>

#include "integrators/constraints.hpp"

namespace stiffmd {

std::vector<ConstraintCluster> find_clusters(const std::vector<StiffBond>& bonds, const Eigen::VectorXd& inv_mass) {
  // Union–find over bonds: two bonds are coupled iff they share a mobile particle.
  const int m = static_cast<int>(bonds.size());
  std::vector<int> parent(m);
  std::iota(parent.begin(), parent.end(), 0);
  auto root = [&](int b) {
    while (parent[b] != b) b = parent[b] = parent[parent[b]];
    return b;
  };
  std::vector<int> last_bond_at(static_cast<size_t>(inv_mass.size()), -1);
  for (int b = 0; b < m; ++b) {
    for (int p : {bonds[b].i, bonds[b].j}) {
      if (inv_mass[p] == 0.0) continue;  // a fixed particle transmits no constraint force
      if (last_bond_at[p] >= 0) parent[root(b)] = root(last_bond_at[p]);
      last_bond_at[p] = b;
    }
  }
  std::vector<int> cluster_of_root(m, -1);
  std::vector<ConstraintCluster> clusters;
  for (int b = 0; b < m; ++b) {
    int r = root(b);
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

}  // namespace stiffmd
