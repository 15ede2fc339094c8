// An analytic SETTLE for a rigid 3-site triangle, apex O and two equal base masses H1, H2 (water):
// the reference the general constraint solver is measured against on water (BM_WaterConstraints,
// docs/performance.md). Benchmark-only: the engine solves every cluster with its general solver.
//
// Positions (Miyamoto & Kollman, J. Comput. Chem. 13, 952 (1992)): the unconstrained step moves
// the centre of mass freely; in the frame of the old plane (z its normal, x ⟂ the new O and z) the
// constrained triangle is the canonical one — O at (0, r_a), H1 at (−r_c, −r_b), H2 at (r_c, −r_b)
// about the centre of mass — turned by three angles φ, ψ, θ that keep each atom's z and make the
// displacements combinations of the old bond vectors, which is SHAKE's converged solution in
// closed form. Velocities: RATTLE's projection v ← v − M⁻¹Gᵀμ, S μ = G v, with the 3×3 S of the
// triangle solved by its cofactors (the velocity half of SETTLE).
#pragma once

#include <Eigen/Core>
#include <Eigen/Geometry>
#include <cmath>

namespace stiffmd::bench {

struct SettleWater {
  int o = 0, h1 = 0, h2 = 0;  // particle indices: the apex and the two base atoms
};

struct SettleGeometry {
  double m_o, m_h, d_oh, d_hh;
  double ra, rb, rc;  // the canonical triangle about its centre of mass
  SettleGeometry(double mo, double mh, double doh, double dhh) : m_o(mo), m_h(mh), d_oh(doh), d_hh(dhh) {
    rc = 0.5 * d_hh;
    const double height = std::sqrt(d_oh * d_oh - rc * rc);  // O above the H–H midpoint
    ra = 2.0 * m_h * height / (m_o + 2.0 * m_h);             // O above the centre of mass
    rb = height - ra;                                        // the H–H midpoint below it
  }
};

// x_new ← the constrained positions, from the old ones x_old (on the manifold) and the
// unconstrained step x_new.
inline void settle_positions(const SettleGeometry& g, const SettleWater& w, const Eigen::Matrix3Xd& x_old,
                             Eigen::Matrix3Xd& x_new) {
  using V = Eigen::Vector3d;
  const double total = g.m_o + 2.0 * g.m_h;
  const V com = (g.m_o * x_new.col(w.o) + g.m_h * (x_new.col(w.h1) + x_new.col(w.h2))) / total;
  const V a1 = x_new.col(w.o) - com, b1 = x_new.col(w.h1) - com, c1 = x_new.col(w.h2) - com;
  const V b0 = x_old.col(w.h1) - x_old.col(w.o), c0 = x_old.col(w.h2) - x_old.col(w.o);
  const V ez = b0.cross(c0).normalized();
  const V ex = a1.cross(ez).normalized();
  const V ey = ez.cross(ex);
  const double xb0 = ex.dot(b0), yb0 = ey.dot(b0), xc0 = ex.dot(c0), yc0 = ey.dot(c0);
  const double za1 = ez.dot(a1);
  const double xb1 = ex.dot(b1), yb1 = ey.dot(b1), zb1 = ez.dot(b1);
  const double xc1 = ex.dot(c1), yc1 = ey.dot(c1), zc1 = ez.dot(c1);
  // φ tilts O out of the plane to its new height, ψ the H–H axis to its tilt.
  const double sinphi = za1 / g.ra, cosphi = std::sqrt(1.0 - sinphi * sinphi);
  const double sinpsi = (zb1 - zc1) / (2.0 * g.rc * cosphi), cospsi = std::sqrt(1.0 - sinpsi * sinpsi);
  const double ya2 = g.ra * cosphi, xb2 = -g.rc * cospsi;
  const double t1 = -g.rb * cosphi, t2 = g.rc * sinpsi * sinphi;
  const double yb2 = t1 - t2, yc2 = t1 + t2;
  // θ about z: the displacements' moment about the centre of mass lies along the old bonds.
  const double alpha = xb2 * (xb0 - xc0) + yb0 * yb2 + yc0 * yc2;
  const double beta = xb2 * (yc0 - yb0) + xb0 * yb2 + xc0 * yc2;
  const double gamma = xb0 * yb1 - xb1 * yb0 + xc0 * yc1 - xc1 * yc0;
  const double a2b2 = alpha * alpha + beta * beta;
  const double sinthe = (alpha * gamma - beta * std::sqrt(a2b2 - gamma * gamma)) / a2b2;
  const double costhe = std::sqrt(1.0 - sinthe * sinthe);
  x_new.col(w.o) = com + ex * (-ya2 * sinthe) + ey * (ya2 * costhe) + ez * za1;
  x_new.col(w.h1) = com + ex * (xb2 * costhe - yb2 * sinthe) + ey * (xb2 * sinthe + yb2 * costhe) + ez * zb1;
  x_new.col(w.h2) = com + ex * (-xb2 * costhe - yc2 * sinthe) + ey * (-xb2 * sinthe + yc2 * costhe) + ez * zc1;
}

// v ← v − M⁻¹Gᵀμ with S μ = G v at x (on the manifold): afterwards no bond length changes. Bonds
// k = 0: O–H1, 1: O–H2, 2: H1–H2, each g_k·v = e_k·(v_j − v_i) for its pair (i, j) as listed;
// S_kl = Σ_p c_kp c_lp w_p e_k·e_l (c = −1 at i, +1 at j, w the inverse masses).
inline void settle_velocities(const SettleGeometry& g, const SettleWater& w, const Eigen::Matrix3Xd& x,
                              Eigen::Matrix3Xd& v) {
  using V = Eigen::Vector3d;
  const double wo = 1.0 / g.m_o, wh = 1.0 / g.m_h;
  const V e0 = (x.col(w.h1) - x.col(w.o)).normalized();
  const V e1 = (x.col(w.h2) - x.col(w.o)).normalized();
  const V e2 = (x.col(w.h2) - x.col(w.h1)).normalized();
  const V vo = v.col(w.o), v1 = v.col(w.h1), v2 = v.col(w.h2);
  const double r0 = e0.dot(v1 - vo), r1 = e1.dot(v2 - vo), r2 = e2.dot(v2 - v1);
  const double s00 = wo + wh, s11 = wo + wh, s22 = 2.0 * wh;
  const double s01 = wo * e0.dot(e1), s02 = -wh * e0.dot(e2), s12 = wh * e1.dot(e2);
  // S⁻¹ by its cofactors (S symmetric).
  const double c00 = s11 * s22 - s12 * s12, c01 = s02 * s12 - s01 * s22, c02 = s01 * s12 - s02 * s11;
  const double c11 = s00 * s22 - s02 * s02, c12 = s01 * s02 - s00 * s12, c22 = s00 * s11 - s01 * s01;
  const double inv_det = 1.0 / (s00 * c00 + s01 * c01 + s02 * c02);
  const double mu0 = (c00 * r0 + c01 * r1 + c02 * r2) * inv_det;
  const double mu1 = (c01 * r0 + c11 * r1 + c12 * r2) * inv_det;
  const double mu2 = (c02 * r0 + c12 * r1 + c22 * r2) * inv_det;
  v.col(w.o) += wo * (mu0 * e0 + mu1 * e1);
  v.col(w.h1) += wh * (mu2 * e2 - mu0 * e0);
  v.col(w.h2) -= wh * (mu1 * e1 + mu2 * e2);
}

}  // namespace stiffmd::bench
