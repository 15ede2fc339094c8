// Velocity Verlet on the double pendulum (inputs/double_pendulum.toml: 3 particles, the pivot
// fixed, two stiff springs and gravity g = (0, −1, 0)) written by hand, on plain arrays: the floor
// the engine's run path is measured against (tools/benchmarks/kernels.cpp,
// BM_PendulumVsHandWritten and BM_PendulumRunVsHandWritten), and the reference its trajectory is
// checked against bit for bit (tests/test_run_loop.cpp).
//
// One step: v ← v + (½h m⁻¹) f, x ← x + h v, f ← f(x), v ← v + (½h m⁻¹) f, with
// f = Σ_b −k_b (r_b − ℓ_b) d_b / r_b over the springs (d_b = x_i − x_j, r_b = |d_b|, k_b = (α_b/ε)²),
// then gravity −m e_y: the springs first, as the engine sums them (ForceField::evaluation_order),
// and every product grouped as the engine groups it, so that both give the same bits.
#pragma once

#include <cmath>
#include <stdexcept>

#include "core/state.hpp"
#include "forcefields/stiff_bond.hpp"

namespace stiffmd {

class HandPendulum {
 public:
  // The springs of `bonds` (two) and the state `s` (three particles; a fixed particle has
  // inv_mass 0 and feels no gravity).
  HandPendulum(const StiffBonds& bonds, const State& s) {
    if (s.size() != 3 || bonds.bonds.size() != 2)
      throw std::invalid_argument("the hand-written pendulum is 3 particles and 2 bonds");
    for (int b = 0; b < 2; ++b) {
      const StiffBond& sb = bonds.bonds[static_cast<size_t>(b)];
      bi_[b] = sb.i, bj_[b] = sb.j;
      k_[b] = sb.alpha * sb.alpha / (bonds.epsilon * bonds.epsilon);
      l_[b] = sb.length;
    }
    load(s);
  }
  // Positions and velocities from `s`, and the force at its x.
  void load(const State& s) {
    for (int p = 0; p < 3; ++p) {
      for (int a = 0; a < 3; ++a) x_[p][a] = s.x(a, p), v_[p][a] = s.v(a, p);
      w_[p] = s.inv_mass[p];
      m_[p] = w_[p] > 0.0 ? 1.0 / w_[p] : 0.0;
    }
    forces();
  }
  void step(double h) {
    for (int p = 0; p < 3; ++p)
      for (int a = 0; a < 3; ++a) {
        v_[p][a] += 0.5 * h * w_[p] * f_[p][a];
        x_[p][a] += h * v_[p][a];
      }
    forces();
    for (int p = 0; p < 3; ++p)
      for (int a = 0; a < 3; ++a) v_[p][a] += 0.5 * h * w_[p] * f_[p][a];
  }
  double x(int a, int p) const { return x_[p][a]; }
  double v(int a, int p) const { return v_[p][a]; }
  const double* positions() const { return &x_[0][0]; }

 private:
  void forces() {
    for (int p = 0; p < 3; ++p)
      for (int a = 0; a < 3; ++a) f_[p][a] = 0.0;
    for (int b = 0; b < 2; ++b) {
      double d[3];
      for (int a = 0; a < 3; ++a) d[a] = x_[bi_[b]][a] - x_[bj_[b]][a];
      const double r = std::sqrt(d[0] * d[0] + d[1] * d[1] + d[2] * d[2]);
      const double sc = -k_[b] * (r - l_[b]) / r;
      for (int a = 0; a < 3; ++a) {
        f_[bi_[b]][a] += sc * d[a];
        f_[bj_[b]][a] -= sc * d[a];
      }
    }
    for (int p = 0; p < 3; ++p) f_[p][1] -= m_[p];
  }

  double x_[3][3], v_[3][3], f_[3][3], w_[3], m_[3];
  int bi_[2], bj_[2];
  double k_[2], l_[2];
};

}  // namespace stiffmd
