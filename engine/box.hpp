// Simulation box: open (no boundaries) or orthorhombic with per-axis periodicity.
#pragma once

#include <Eigen/Core>
#include <cmath>
#include <cstdint>

namespace stiffmd {

struct Box {
  Eigen::Vector3d origin = Eigen::Vector3d::Zero();
  Eigen::Vector3d lengths = Eigen::Vector3d::Zero();   // edge lengths; meaningful on periodic axes
  Eigen::Vector3i periodic = Eigen::Vector3i::Zero();  // 1 on periodic axes

  bool any_periodic() const { return periodic.any(); }

  // Minimum-image separation vector (identity on open axes): d − L·round(d/L) per periodic
  // axis. The rounding is a truncating conversion of d/L ± ½, which the compiler inlines (where
  // std::nearbyint is a libm call on baseline x86-64); ties |d| = L/2 may go either way.
  Eigen::Vector3d min_image(Eigen::Vector3d d) const {
    for (int a = 0; a < 3; ++a)
      if (periodic[a]) {
        const double s = d[a] / lengths[a];
        d[a] -= lengths[a] * static_cast<double>(static_cast<std::int64_t>(s + std::copysign(0.5, s)));
      }
    return d;
  }
};

}  // namespace stiffmd
