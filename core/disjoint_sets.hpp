// Disjoint sets of 0 .. n − 1 (union–find): the one connected-components primitive of the engine,
// for the two notions built on it, which differ in what joins two items:
//   molecules            particles joined by every bonded term, pinned particles included (a term
//                        acts on all its particles: engine/domain/decomposition.*, imports without
//                        molecule ids, engine/scene/scene_sources.cpp);
//   constraint clusters  stiff bonds joined by a shared mobile particle only (S = G M⁻¹ Gᵀ couples
//                        two bonds through m⁻¹ of the particle they share, 0 at a pinned one:
//                        find_clusters, integrators/clusters.hpp).
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

}  // namespace stiffmd
