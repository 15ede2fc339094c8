// Connected components (union–find): the one connected-components function of the engine, for
// the two notions built on it, which differ in what joins two particles:
//   molecules            every bonded term joins its particles, pinned ones included (a term acts
//                        on all its particles): bonded_molecules (core/topology.hpp; a decomposed
//                        run's ownership, the barostat's rigid units), imports without molecule
//                        ids (bonds only, engine/scene/scene_sources.cpp);
//   constraint clusters  stiff bonds join their two ends only when both are mobile (S = G M⁻¹ Gᵀ
//                        couples two bonds through m⁻¹ of the particle they share, 0 at a pinned
//                        one): find_clusters, integrators/clusters.hpp, a bond's cluster being
//                        the component of its mobile ends.
// Each set's root is its least element, so numbering the sets by their roots in increasing order
// numbers them by their first element, whatever the order of the joins.
#pragma once

#include <numeric>
#include <utility>
#include <vector>

namespace stiffmd {

class DisjointSets {
 public:
  explicit DisjointSets(int n) : parent_(static_cast<size_t>(n)) { std::iota(parent_.begin(), parent_.end(), 0); }

  // The least element of a's set (path halving on the way).
  int root(int a) {
    while (parent_[a] != a) a = parent_[a] = parent_[parent_[a]];
    return a;
  }
  void join(int a, int b) {
    a = root(a), b = root(b);
    if (a == b) return;
    if (b < a) std::swap(a, b);
    parent_[b] = a;
  }
  int size() const { return static_cast<int>(parent_.size()); }

 private:
  std::vector<int> parent_;
};

// The connected components of vertices 0 … n − 1 joined by `edges`: a label per vertex, the
// components numbered 0, 1, … in the order of their first (least) vertex; a lone vertex is its
// own. With `couples` (per vertex), an edge joins its two ends only when both couple: a vertex
// that does not couple is a component of its own, and the edges that meet there join nothing
// through it.
inline std::vector<int> connected_components(int n, const std::vector<std::pair<int, int>>& edges,
                                             const std::vector<char>* couples = nullptr) {
  DisjointSets sets(n);
  for (const auto& [a, b] : edges)
    if (!couples || ((*couples)[a] && (*couples)[b])) sets.join(a, b);
  std::vector<int> label(static_cast<size_t>(n));
  int components = 0;
  for (int v = 0; v < n; ++v) {
    const int root = sets.root(v);  // ≤ v: its label is given
    label[v] = root == v ? components++ : label[root];
  }
  return label;
}

}  // namespace stiffmd
