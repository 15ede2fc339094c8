// The dynamical state: contiguous 3×N storage, one column per particle (docs/design.md §11.7).
//
// What a scene guarantees about x (engine/scene/scene_sources.cpp, make_molecules_whole): positions are
// unwrapped and every molecule is whole. Every source — [[particles]] with [[bonds]], [[build]],
// [import] of LAMMPS data (with or without image flags) or XYZ + bonds — is made whole at load by a
// traversal of each molecule's bond graph that applies the minimum image per bond; what cannot be
// made whole consistently (a bond longer than half a periodic box length, a ring that closes only
// across a box length) is refused as bad input. No step ever wraps a position. Hence on every
// periodic axis each bond's raw difference x_i − x_j is its own minimum image, and it is THE bond
// vector everywhere (bond_vector below): force terms, constraint toolbox, stiff modes, observables.
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

// The bond vector of bond (i, j): the raw difference of unwrapped positions (see above). For whole
// molecules this equals the minimum image bit for bit (round_nearest(d/L) = 0, so d − 0·L = d).
inline Eigen::Vector3d bond_vector(const Eigen::Matrix3Xd& x, int i, int j) {
  return x.col(i) - x.col(j);
}

}  // namespace stiffmd
