// Checks every force term must pass, shared by the typed suites of bond, angle and pair kernels
// (test_bond_angle_kernels.cpp, test_pairs.cpp): forces against central finite differences of
// the term's own energy, Newton's third law, and the virial against Σ r·f (docs/design.md §11.8a).
#pragma once

#include <Eigen/Core>
#include <algorithm>
#include <cmath>
#include <random>

#include "core/box.hpp"
#include "forcefields/force_term.hpp"

namespace stiffmd::test {

inline Eigen::Matrix3Xd forces_of(const ForceTerm& term, const Eigen::Matrix3Xd& x, const Box& box) {
  Eigen::Matrix3Xd f = Eigen::Matrix3Xd::Zero(3, x.cols());
  term.add_forces(x, box, f);
  return f;
}

inline double energy_of(const ForceTerm& term, const Eigen::Matrix3Xd& x, const Box& box) {
  Eigen::Matrix3Xd f = Eigen::Matrix3Xd::Zero(3, x.cols());
  return term.add_forces(x, box, f);
}

// Max over all coordinates of |f − (−∂E/∂x)| by central differences with step d, relative to
// max(1, max |f|).
inline double fd_error(const ForceTerm& term, const Eigen::Matrix3Xd& x, const Box& box, double d = 1e-6) {
  const Eigen::Matrix3Xd f = forces_of(term, x, box);
  double worst = 0.0;
  for (int i = 0; i < x.cols(); ++i)
    for (int a = 0; a < 3; ++a) {
      Eigen::Matrix3Xd xp = x, xm = x;
      xp(a, i) += d;
      xm(a, i) -= d;
      const double fd = -(energy_of(term, xp, box) - energy_of(term, xm, box)) / (2 * d);
      worst = std::max(worst, std::abs(fd - f(a, i)));
    }
  return worst / std::max(1.0, f.cwiseAbs().maxCoeff());
}

// The virial of the definition in open space: Σ_i x_i · f_i, which for internal forces equals
// Σ over interacting pairs of r_ij · f_ij (the forces sum to zero).
inline double position_virial(const ForceTerm& term, const Eigen::Matrix3Xd& x) {
  return (x.array() * forces_of(term, x, Box{}).array()).sum();
}

// The virial through the energy alone: W = −dE(λx, λL)/dλ at λ = 1, positions and box scaled
// together (Euler: every r_ij scales by λ, and −dE/dλ = −Σ r dE/dr = Σ r_ij · f_ij).
inline double dilation_virial(const ForceTerm& term, const Eigen::Matrix3Xd& x, const Box& box, double d = 1e-6) {
  auto scaled = [&](double lambda) {
    Box b = box;
    b.lengths *= lambda;
    b.origin *= lambda;
    return energy_of(term, lambda * x, b);
  };
  return -(scaled(1 + d) - scaled(1 - d)) / (2 * d);
}

inline Box periodic_box(const Eigen::Vector3d& lengths, const Eigen::Vector3d& origin) {
  Box b;
  b.periodic = Eigen::Vector3i::Ones();
  b.lengths = lengths;
  b.origin = origin;
  return b;
}

// A random walk with step lengths uniform in [lo, hi], from `start`.
inline Eigen::Matrix3Xd random_walk(int n, double lo, double hi, unsigned seed,
                                    const Eigen::Vector3d& start = Eigen::Vector3d::Zero()) {
  std::mt19937 rng(seed);
  std::uniform_real_distribution<double> len(lo, hi);
  std::normal_distribution<double> g;
  Eigen::Matrix3Xd x(3, n);
  x.col(0) = start;
  for (int i = 1; i < n; ++i) {
    const Eigen::Vector3d u(g(rng), g(rng), g(rng));
    x.col(i) = x.col(i - 1) + len(rng) * u.normalized();
  }
  return x;
}

// Positions folded into the primary cell: bonds and angles that cross a face now straddle it.
inline Eigen::Matrix3Xd wrapped(Eigen::Matrix3Xd x, const Box& box) {
  for (int i = 0; i < x.cols(); ++i)
    for (int a = 0; a < 3; ++a) x(a, i) -= box.lengths[a] * std::floor((x(a, i) - box.origin[a]) / box.lengths[a]);
  return x;
}

}  // namespace stiffmd::test
