// Simulation box: open (no boundaries) or orthorhombic with per-axis periodicity.
#pragma once

#include <Eigen/Core>
#include <cmath>

namespace stiffmd {

struct Box {
  Eigen::Vector3d origin = Eigen::Vector3d::Zero();
  Eigen::Vector3d lengths = Eigen::Vector3d::Zero();   // edge lengths; meaningful on periodic axes
  Eigen::Vector3i periodic = Eigen::Vector3i::Zero();  // 1 on periodic axes

  bool any_periodic() const { return periodic.any(); }

  // Minimum-image separation vector (identity on open axes).
  Eigen::Vector3d min_image(Eigen::Vector3d d) const {
    for (int a = 0; a < 3; ++a)
      if (periodic[a]) d[a] -= lengths[a] * std::nearbyint(d[a] / lengths[a]);
    return d;
  }
};

}  // namespace stiffmd
