// A molecule's anchor: the point that says which domain owns it (docs/parallel.md, "The design").
// Its centre of mass Σ m x / Σ m over its particles, unwrapped, summed by increasing global index,
// where a fixed particle (inverse mass 0) counts with mass 1. Every reader that assigns molecules
// to domains — the decomposition at the start and at each migration, a builder that grows only
// some molecules — forms it with these operations, so all of them agree to the last bit.
#pragma once

#include <Eigen/Core>

namespace stiffmd {

// A particle's mass in its molecule's anchor.
inline double anchor_mass(double inv_mass) {
  return inv_mass > 0.0 ? 1.0 / inv_mass : 1.0;
}

// Σ m x and Σ m, added particle by particle in the order given.
class MoleculeAnchor {
 public:
  template <class Position>
  void add(double mass, const Position& x) {
    sum_ += mass * x;
    total_ += mass;
  }
  Eigen::Vector3d value() const { return sum_ / total_; }

 private:
  Eigen::Vector3d sum_ = Eigen::Vector3d::Zero();
  double total_ = 0.0;
};

}  // namespace stiffmd
