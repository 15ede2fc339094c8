// The loop over proper dihedrals (i, j, k, l) about the bond j–k, written once and shared by every
// dihedral style (as angle_loop.hpp is for angles): a style supplies only a kernel
//     static void eval(double phi, const Params& p, double& energy, double& dE_dphi);
//
// Geometry (Blondel & Karplus, J. Comput. Chem. 17, 1132 (1996); Bekker's form, as in GROMACS).
// With r_ij = x_i − x_j, r_kj = x_k − x_j, r_kl = x_k − x_l (raw differences of unwrapped
// positions: molecules are whole, ARCHITECTURE.md — LAMMPS's minimum image for any molecule
// shorter than half the box) and the plane normals m = r_ij × r_kj, n = r_kj × r_kl,
//     φ = atan2(|r_kj| r_ij·n, m·n)                      (m × n = r_kj (r_ij·n))
// in (−π, π]: φ = ±π is trans (the IUPAC/polymer convention, LAMMPS's), φ = 0 cis. The gradients
//     ∂φ/∂x_i = +|r_kj|/|m|² m,     ∂φ/∂x_l = −|r_kj|/|n|² n,
//     ∂φ/∂x_j = (p − 1) ∂φ/∂x_i − q ∂φ/∂x_l,   ∂φ/∂x_k = (q − 1) ∂φ/∂x_l − p ∂φ/∂x_i,
// with p = r_ij·r_kj/|r_kj|², q = r_kl·r_kj/|r_kj|², never divide by sin φ (the textbook route
// through cos φ does, and φ = 0 and π, cis and trans, are where chains sit). atan2 keeps φ
// accurate there too. The gradients sum to zero (translation invariance) by construction.
//
// Degenerate geometry: a central bond of length 0 leaves the dihedral undefined
// (NumericalError). Three collinear atoms (|m| = 0 or |n| = 0) leave the plane, hence φ,
// undefined; the force is set to 0 there (the symmetric choice; the bending terms keep chains
// away from it, as in LAMMPS, which only warns).
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
struct DihedralInstance {
  int i, j, k, l;
  Params params;
};

namespace dihedral_detail {

struct Geometry {
  Eigen::Vector3d r_ij, r_kj, r_kl;
  double phi = 0.0;
  Eigen::Vector3d dphi_di, dphi_dj, dphi_dk, dphi_dl;
};

[[noreturn]] inline void throw_degenerate(int i, int j, int k, int l) {
  std::ostringstream m;
  m << "dihedral (" << i << ", " << j << ", " << k << ", " << l << ") is undefined: its central bond " << j << "-" << k
    << " has length 0";
  throw NumericalError(m.str());
}

inline Geometry geometry(int i, int j, int k, int l, const Eigen::Matrix3Xd& x) {
  Geometry g;
  g.r_ij = bond_vector(x, i, j);  // raw differences: molecules are whole (ARCHITECTURE.md)
  g.r_kj = bond_vector(x, k, j);
  g.r_kl = bond_vector(x, k, l);
  const double kj2 = g.r_kj.squaredNorm();
  if (!(kj2 > 0.0)) throw_degenerate(i, j, k, l);
  const double kj = std::sqrt(kj2);
  const Eigen::Vector3d m = g.r_ij.cross(g.r_kj), n = g.r_kj.cross(g.r_kl);
  const double m2 = m.squaredNorm(), n2 = n.squaredNorm();
  g.phi = std::atan2(kj * g.r_ij.dot(n), m.dot(n));
  if (m2 > 0.0 && n2 > 0.0) {
    g.dphi_di = (kj / m2) * m;
    g.dphi_dl = -(kj / n2) * n;
    const double p = g.r_ij.dot(g.r_kj) / kj2, q = g.r_kl.dot(g.r_kj) / kj2;
    g.dphi_dj = (p - 1.0) * g.dphi_di - q * g.dphi_dl;
    g.dphi_dk = (q - 1.0) * g.dphi_dl - p * g.dphi_di;
  } else {  // collinear: see the header comment
    g.dphi_di.setZero();
    g.dphi_dj.setZero();
    g.dphi_dk.setZero();
    g.dphi_dl.setZero();
  }
  return g;
}

}  // namespace dihedral_detail

// Adds −∇E into f for every dihedral and returns Σ E: F_a = −E'(φ) ∂φ/∂x_a. On the threads by
// owner computes, as the angle loop (tuple_partition.hpp): the forces are the serial loop's bits
// for any thread count, Σ E is summed per owner.
template <class Kernel, class Params>
double accumulate_dihedral_forces(const std::vector<DihedralInstance<Params>>& dihedrals, const Eigen::Matrix3Xd& x,
                                  const Box& box, Eigen::Matrix3Xd& f, TuplePartition<4>& partition) {
  (void)box;  // bond vectors are raw differences of whole molecules
  const int parts = threads_for(static_cast<std::int64_t>(dihedrals.size()));
  partition.prepare(dihedrals.size(), parts, [&](std::size_t t) {
    return std::array<int, 4>{dihedrals[t].i, dihedrals[t].j, dihedrals[t].k, dihedrals[t].l};
  });
  std::array<double, kMaxParts> energy{};
  run_parts(parts, [&](int u) {
    double e_u = 0.0;
    for (const auto* w = partition.begin(u); w < partition.end(u); ++w) {
      const auto& t = dihedrals[w->tuple];
      const dihedral_detail::Geometry g = dihedral_detail::geometry(t.i, t.j, t.k, t.l, x);
      double e = 0.0, de_dphi = 0.0;
      Kernel::eval(g.phi, t.params, e, de_dphi);
      if (w->owned & 1u) e_u += e;
      if (w->owned & 1u) f.col(t.i) -= de_dphi * g.dphi_di;
      if (w->owned & 2u) f.col(t.j) -= de_dphi * g.dphi_dj;
      if (w->owned & 4u) f.col(t.k) -= de_dphi * g.dphi_dk;
      if (w->owned & 8u) f.col(t.l) -= de_dphi * g.dphi_dl;
    }
    energy[u] = e_u;
  });
  double sum = energy[0];
  for (int u = 1; u < parts; ++u) sum += energy[u];
  return sum;
}

// The dihedral virial Σ r_a · F_a with positions relative to x_j (r_i = r_ij, r_k = r_kj,
// r_l = r_kj − r_kl, raw differences: independent of the periodic image, as LAMMPS's). φ is
// invariant under x → λx, so this vanishes analytically (Euler, degree 0); what is returned is
// the sum as computed, zero to round-off.
template <class Kernel, class Params>
double accumulate_dihedral_virial(const std::vector<DihedralInstance<Params>>& dihedrals, const Eigen::Matrix3Xd& x,
                                  const Box& box) {
  (void)box;  // bond vectors are raw differences of whole molecules
  const std::int64_t n = static_cast<std::int64_t>(dihedrals.size());
  return parallel_sum(n, threads_for(n), [&](std::int64_t first, std::int64_t last) {  // blocks of dihedrals
    double w = 0.0;
    for (std::int64_t k = first; k < last; ++k) {
      const auto& t = dihedrals[k];
      const dihedral_detail::Geometry g = dihedral_detail::geometry(t.i, t.j, t.k, t.l, x);
      double e = 0.0, de_dphi = 0.0;
      Kernel::eval(g.phi, t.params, e, de_dphi);
      w -= de_dphi * (g.r_ij.dot(g.dphi_di) + g.r_kj.dot(g.dphi_dk) + (g.r_kj - g.r_kl).dot(g.dphi_dl));
    }
    return w;
  });
}

}  // namespace stiffmd
