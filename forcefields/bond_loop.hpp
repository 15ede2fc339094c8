// The loop over two-body bonds, written once and shared by every bond style (style.md §1,
// after HOOMD's EvaluatorBond*): a style supplies only a kernel
//     static void eval(double r, const Params& p, double& energy, double& dE_dr);
#pragma once

#include <Eigen/Core>
#include <vector>

#include "engine/box.hpp"

namespace stiffmd {

template <class Params>
struct BondInstance {
  int i;
  int j;
  Params params;
};

// Adds −∇E into f for every bond and returns Σ E. Minimum image on periodic axes.
template <class Kernel, class Params>
double accumulate_bond_forces(const std::vector<BondInstance<Params>>& bonds, const Eigen::Matrix3Xd& x, const Box& box,
                              Eigen::Matrix3Xd& f) {
  double energy = 0.0;
  const bool periodic = box.any_periodic();
  for (const auto& b : bonds) {
    Eigen::Vector3d d = x.col(b.i) - x.col(b.j);
    if (periodic) d = box.min_image(d);
    const double r = d.norm();
    double e = 0.0, de_dr = 0.0;
    Kernel::eval(r, b.params, e, de_dr);
    energy += e;
    const Eigen::Vector3d fi = (-de_dr / r) * d;  // −∂E/∂x_i; Newton's third law gives x_j's
    f.col(b.i) += fi;
    f.col(b.j) -= fi;
  }
  return energy;
}

// Σ_b r_ij · f_ij over the bonds (f_ij = −dE/dr · r_ij/r, so each term is −r dE/dr).
template <class Kernel, class Params>
double accumulate_bond_virial(const std::vector<BondInstance<Params>>& bonds, const Eigen::Matrix3Xd& x,
                              const Box& box) {
  double w = 0.0;
  for (const auto& b : bonds) {
    const double r = box.min_image(x.col(b.i) - x.col(b.j)).norm();
    double e = 0.0, de_dr = 0.0;
    Kernel::eval(r, b.params, e, de_dr);
    w -= r * de_dr;
  }
  return w;
}

}  // namespace stiffmd
