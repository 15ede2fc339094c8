// Simulation box: open (no boundaries) or orthorhombic with per-axis periodicity.
#pragma once

#include <Eigen/Core>
#include <cmath>

namespace stiffmd {

// s rounded to the nearest integer (ties to even) as (s + 1.5·2⁵²) − 1.5·2⁵²: exact for |s| < 2⁵¹
// (positions stay within 2²⁰ box lengths, checked at load), NaN stays NaN. The minimum-image
// convention's one rounding: no libm call (std::nearbyint is one on baseline x86-64) and no
// conversion to an integer type, so loops over it vectorise. Needs IEEE arithmetic as written
// (no -ffast-math, which would fold the two additions away).
inline double round_nearest(double s) {
  constexpr double k = 6755399441055744.0;  // 1.5 · 2⁵²
  return (s + k) - k;
}

struct Box {
  Eigen::Vector3d origin = Eigen::Vector3d::Zero();
  Eigen::Vector3d lengths = Eigen::Vector3d::Zero();   // edge lengths; meaningful on periodic axes
  Eigen::Vector3i periodic = Eigen::Vector3i::Zero();  // 1 on periodic axes

  bool any_periodic() const { return periodic.any(); }

  // Minimum-image separation vector (identity on open axes): d − L·round(d/L) per periodic axis.
  Eigen::Vector3d min_image(Eigen::Vector3d d) const {
    for (int a = 0; a < 3; ++a)
      if (periodic[a]) d[a] -= lengths[a] * round_nearest(d[a] / lengths[a]);
    return d;
  }
};

}  // namespace stiffmd
