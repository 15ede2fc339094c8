// The named primitives every integrator is written from (style.md §5, after JAX-MD):
// kick (momentum step) and drift (position step). Fixed particles have inverse mass 0,
// so a kick leaves their velocity at zero and a drift leaves them in place.
#pragma once

#include <Eigen/Core>

namespace stiffmd {

// v ← v + dt M⁻¹ f
inline void kick(Eigen::Matrix3Xd& v, const Eigen::VectorXd& inv_mass, const Eigen::Matrix3Xd& f, double dt) {
  v.noalias() += f * (dt * inv_mass).asDiagonal();
}

// x ← x + dt v
inline void drift(Eigen::Matrix3Xd& x, const Eigen::Matrix3Xd& v, double dt) {
  x.noalias() += dt * v;
}

}  // namespace stiffmd
