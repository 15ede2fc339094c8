// The loop over angle triplets (i, j, k), j the vertex, written once and shared by every angle
// style (as bond_loop.hpp is for bonds): a style supplies only a kernel
//     static void eval(double theta, const Params& p, double& energy, double& dE_dtheta);
//
// Geometry. With the arms a = x_i − x_j and b = x_k − x_j (raw differences of unwrapped
// positions: molecules are whole, ARCHITECTURE.md — LAMMPS's minimum image for any molecule
// shorter than half the box) and the normal n = a × b,
//     θ = atan2(|n|, a·b),
//     ∂θ/∂x_i = −(n̂ × a)/|a|²,   ∂θ/∂x_k = (n̂ × b)/|b|²,   ∂θ/∂x_j = −∂θ/∂x_i − ∂θ/∂x_k,
// (equal to the textbook (â cos θ − b̂)/(|a| sin θ), without dividing by sin θ).
//
// Why the kernel takes θ and not cos θ: the textbook route θ = acos(c), ∂θ/∂x = −(1/sin θ) ∂c/∂x
// divides by sin θ, which vanishes at θ = 0 and π — and a straight chain (θ = π) is the common
// case. A kernel in cos θ would only move that 1/sin θ into every θ-harmonic kernel. Here the
// factor never appears: n̂ × a is a vector of length |a| for any θ in (0, π), so the force is
// dE/dθ times a bounded vector. atan2 also keeps θ accurate near 0 and π, where acos loses half
// the digits (cos(π − 10⁻⁸) rounds to −1 exactly).
//
// Exactly collinear arms (|n| = 0, θ = 0 or π): the direction n̂ is undefined and the force is
// set to 0. That is exact when dE/dθ = 0 there (θ₀ = π harmonic, or LAMMPS's angle_style cosine,
// the usual straight-chain terms); otherwise E has a cone-shaped ridge at θ = π, where no gradient
// exists and 0 is the symmetric choice (it is what a central finite difference gives).
#pragma once

#include <Eigen/Core>
#include <Eigen/Geometry>
#include <array>
#include <cmath>
#include <sstream>
#include <vector>

#include "core/box.hpp"
#include "core/errors.hpp"
#include "core/parallel.hpp"
#include "core/state.hpp"
#include "forcefields/tuple_partition.hpp"

namespace stiffmd {

template <class Params>
struct AngleInstance {
  int i;
  int j;  // the vertex
  int k;
  Params params;
};

namespace angle_detail {

struct Geometry {
  Eigen::Vector3d a, b;  // arms x_i − x_j and x_k − x_j (raw differences of whole molecules)
  double theta = 0.0;
  Eigen::Vector3d dtheta_da, dtheta_db;  // ∂θ/∂x_i and ∂θ/∂x_k
};

// The angle is undefined when an arm has length 0 (or NaN): a numerical failure, not a NaN force.
[[noreturn]] inline void throw_degenerate(int i, int j, int k, double a_len, double b_len) {
  std::ostringstream m;
  m << "angle (" << i << ", " << j << ", " << k << ") with vertex " << j << " is undefined: arm lengths |x_" << i
    << " - x_" << j << "| = " << a_len << ", |x_" << k << " - x_" << j << "| = " << b_len;
  throw NumericalError(m.str());
}

inline Geometry geometry(int i, int j, int k, const Eigen::Matrix3Xd& x) {
  Geometry g;
  g.a = bond_vector(x, i, j);
  g.b = bond_vector(x, k, j);
  const double aa = g.a.squaredNorm(), bb = g.b.squaredNorm();
  if (!(aa > 0.0) || !(bb > 0.0)) throw_degenerate(i, j, k, std::sqrt(aa), std::sqrt(bb));
  const Eigen::Vector3d n = g.a.cross(g.b);
  const double n_len = n.norm();
  g.theta = std::atan2(n_len, g.a.dot(g.b));
  if (n_len > 0.0) {
    const Eigen::Vector3d n_hat = n / n_len;
    g.dtheta_da = -n_hat.cross(g.a) / aa;
    g.dtheta_db = n_hat.cross(g.b) / bb;
  } else {  // collinear: see the header comment
    g.dtheta_da.setZero();
    g.dtheta_db.setZero();
  }
  return g;
}

}  // namespace angle_detail

// Adds −∇E into f for every angle and returns Σ E. F_i = −E'(θ) ∂θ/∂x_i, F_k likewise, and
// F_j = −F_i − F_k (θ is translation invariant, so the three forces sum to zero). On the threads by
// owner computes (tuple_partition.hpp, `partition` the term's plan): the forces are the serial
// loop's bits for any thread count, Σ E is summed per owner.
template <class Kernel, class Params>
double accumulate_angle_forces(const std::vector<AngleInstance<Params>>& angles, const Eigen::Matrix3Xd& x,
                               const Box& box, Eigen::Matrix3Xd& f, TuplePartition<3>& partition) {
  (void)box;  // bond vectors are raw differences of whole molecules
  const int parts = threads_for(static_cast<std::int64_t>(angles.size()));
  partition.prepare(angles.size(), parts, [&](std::size_t t) {
    return std::array<int, 3>{angles[t].i, angles[t].j, angles[t].k};
  });
  std::array<double, kMaxParts> energy{};
  run_parts(parts, [&](int u) {
    double e_u = 0.0;
    for (const auto* w = partition.begin(u); w < partition.end(u); ++w) {
      const auto& t = angles[w->tuple];
      const angle_detail::Geometry g = angle_detail::geometry(t.i, t.j, t.k, x);
      double e = 0.0, de_dtheta = 0.0;
      Kernel::eval(g.theta, t.params, e, de_dtheta);
      if (w->owned & 1u) e_u += e;
      const Eigen::Vector3d fi = -de_dtheta * g.dtheta_da;
      const Eigen::Vector3d fk = -de_dtheta * g.dtheta_db;
      if (w->owned & 1u) f.col(t.i) += fi;
      if (w->owned & 4u) f.col(t.k) += fk;
      if (w->owned & 2u) f.col(t.j) -= fi + fk;
    }
    energy[u] = e_u;
  });
  double sum = energy[0];
  for (int u = 1; u < parts; ++u) sum += energy[u];
  return sum;
}

// The same for a caller without a term's plan (made here, allocating).
template <class Kernel, class Params>
double accumulate_angle_forces(const std::vector<AngleInstance<Params>>& angles, const Eigen::Matrix3Xd& x,
                               const Box& box, Eigen::Matrix3Xd& f) {
  TuplePartition<3> plan;
  return accumulate_angle_forces<Kernel>(angles, x, box, f, plan);
}

// The angle virial Σ_angles Σ_{a∈{i,j,k}} r_a · F_a with positions taken relative to the vertex
// (r_j = 0, r_i = a, r_k = b), i.e. Σ (a · F_i + b · F_k) — the form that is
// independent of the periodic image, as LAMMPS's angle virial is. Since θ depends only on the
// directions of a and b, ∂θ/∂x_i ⊥ a and ∂θ/∂x_k ⊥ b, so every term vanishes analytically
// (E(λx) = E(x): Euler's theorem at degree 0); what is returned is that sum as computed, zero to
// round-off.
template <class Kernel, class Params>
double accumulate_angle_virial(const std::vector<AngleInstance<Params>>& angles, const Eigen::Matrix3Xd& x,
                               const Box& box) {
  (void)box;  // bond vectors are raw differences of whole molecules
  const std::int64_t n = static_cast<std::int64_t>(angles.size());
  return parallel_sum(n, threads_for(n), [&](std::int64_t first, std::int64_t last) {  // blocks of angles
    double w = 0.0;
    for (std::int64_t k = first; k < last; ++k) {
      const auto& t = angles[k];
      const angle_detail::Geometry g = angle_detail::geometry(t.i, t.j, t.k, x);
      double e = 0.0, de_dtheta = 0.0;
      Kernel::eval(g.theta, t.params, e, de_dtheta);
      w -= de_dtheta * (g.a.dot(g.dtheta_da) + g.b.dot(g.dtheta_db));
    }
    return w;
  });
}

}  // namespace stiffmd
