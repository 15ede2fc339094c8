// The dynamical state: contiguous 3×N storage, one column per particle (style.md §7).
#pragma once

#include <Eigen/Core>
#include <cstdint>

namespace stiffmd {

struct State {
  Eigen::Matrix3Xd x;        // positions
  Eigen::Matrix3Xd v;        // velocities (p = M v)
  Eigen::VectorXd inv_mass;  // 1/m_i; 0 marks a fixed particle (e.g. the pendulum's pivot)
  double t = 0.0;            // time
  std::int64_t step = 0;     // macro steps taken

  int size() const { return static_cast<int>(x.cols()); }

  // ½ vᵀ M v, skipping fixed particles (their velocity is zero by construction).
  double kinetic_energy() const {
    double e = 0.0;
    for (int i = 0; i < size(); ++i)
      if (inv_mass[i] > 0.0) e += 0.5 * v.col(i).squaredNorm() / inv_mass[i];
    return e;
  }
};

}  // namespace stiffmd
