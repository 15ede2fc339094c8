// The named primitives every integrator is written from (docs/design.md §11.5, after JAX-MD):
// kick (momentum step) and drift (position step). Fixed particles have inverse mass 0,
// so a kick leaves their velocity at zero and a drift leaves them in place. Large systems
// update in contiguous particle blocks on the OpenMP threads (parallel.hpp): each particle
// is touched by one thread, so the result is the serial one.
#pragma once

#include <Eigen/Core>
#include <cmath>

#include "core/parallel.hpp"
#include "core/timing.hpp"

namespace stiffmd {

// v ← v + dt M⁻¹ f. Plain loops on restrict pointers (v, f and the masses are distinct): for a
// few particles (the pendulum) the Eigen expression on blocks of dynamic size cost more than the
// arithmetic.
inline void kick_range(Eigen::Matrix3Xd& v, const Eigen::VectorXd& inv_mass, const Eigen::Matrix3Xd& f, double dt,
                       std::int64_t first, std::int64_t last) {
  const double* __restrict fp = f.data();
  const double* __restrict w = inv_mass.data();
  double* __restrict vp = v.data();
  for (std::int64_t i = first; i < last; ++i) {
    const double s = dt * w[i];
    for (int a = 0; a < 3; ++a) vp[3 * i + a] += s * fp[3 * i + a];
  }
}
// The same on every particle, in blocks on the threads; kick_range is the pass on particles
// first … last − 1 that a step in molecule blocks makes (integrators/rattle.cpp).
inline void kick(Eigen::Matrix3Xd& v, const Eigen::VectorXd& inv_mass, const Eigen::Matrix3Xd& f, double dt) {
  const ScopedPhase phase(Phase::integrate);
  parallel_blocks(v.cols(), threads_for(v.cols()),
                  [&](std::int64_t b, std::int64_t e) { kick_range(v, inv_mass, f, dt, b, e); });
}

// kick, and in the same pass whether x and the new v are all finite: a step's closing kick, its
// last pass over v, checks its final state without a pass of its own (Integrator::checked_finite).
// A sum with a non-finite term is not finite (∞ + finite = ∞, ∞ − ∞ and NaN + · = NaN), so a
// finite Σ (x + v) says every x and v is finite; a non-finite one (or an overflow of finite
// terms, near 10³⁰⁸) returns false, and the run's own check decides and names the particle.
// v gets the same bits as from kick. Small systems only (below kParallelMin, serial at any thread
// count), where a pass of its own costs more than the sums here (the pendulum's run path, 77.5 →
// 73 ns a step: docs/performance.md, "The run loop's cost per step"); a large system kicks
// plainly (false) and the run checks it in its threads' blocks, a small part of its step.
// Scalar on purpose: vectorised, the loop over a few particles runs through alias checks and
// remainder code longer than itself (as Gravity::add_forces, forcefields/gravity.cpp).
#if defined(__GNUC__) && !defined(__clang__)
__attribute__((optimize("no-tree-vectorize", "no-tree-slp-vectorize")))
#endif
inline bool
kick_checking_finite(Eigen::Matrix3Xd& v, const Eigen::Matrix3Xd& x, const Eigen::VectorXd& inv_mass,
                     const Eigen::Matrix3Xd& f, double dt) {
  if (v.cols() >= kParallelMin) {
    kick(v, inv_mass, f, dt);
    return false;
  }
  const ScopedPhase phase(Phase::integrate);
  const double* __restrict fp = f.data();
  const double* __restrict w = inv_mass.data();
  const double* __restrict xp = x.data();
  double* __restrict vp = v.data();
  double sum[3] = {0.0, 0.0, 0.0};
  for (std::int64_t i = 0; i < v.cols(); ++i) {
    const double s = dt * w[i];
    for (int a = 0; a < 3; ++a) {
      vp[3 * i + a] += s * fp[3 * i + a];
      sum[a] += vp[3 * i + a] + xp[3 * i + a];
    }
  }
  return std::isfinite((sum[0] + sum[1]) + sum[2]);
}

// v ← v + dt M⁻¹ f, and in the same pass kept ← scale · v' (with_before: scale · (v + v')), v and
// v' the velocities before and after the kick.
inline void kick_and_keep_range(Eigen::Matrix3Xd& v, const Eigen::VectorXd& inv_mass, const Eigen::Matrix3Xd& f,
                                double dt, Eigen::Matrix3Xd& kept, double scale, bool with_before, std::int64_t first,
                                std::int64_t last) {
  const double before = with_before ? 1.0 : 0.0;
  const double* __restrict fp = f.data();
  const double* __restrict w = inv_mass.data();
  double* __restrict vp = v.data();
  double* __restrict kp = kept.data();
  for (std::int64_t i = first; i < last; ++i) {
    const double s = dt * w[i];
    for (int a = 0; a < 3; ++a) {
      const double old = vp[3 * i + a];
      vp[3 * i + a] = old + s * fp[3 * i + a];
      kp[3 * i + a] = scale * (before * old + vp[3 * i + a]);
    }
  }
}
// The same on every particle, in blocks on the threads.
inline void kick_and_keep(Eigen::Matrix3Xd& v, const Eigen::VectorXd& inv_mass, const Eigen::Matrix3Xd& f, double dt,
                          Eigen::Matrix3Xd& kept, double scale, bool with_before) {
  const ScopedPhase phase(Phase::integrate);
  parallel_blocks(v.cols(), threads_for(v.cols()), [&](std::int64_t b, std::int64_t e) {
    kick_and_keep_range(v, inv_mass, f, dt, kept, scale, with_before, b, e);
  });
}

// x ← x + dt v
inline void drift(Eigen::Matrix3Xd& x, const Eigen::Matrix3Xd& v, double dt) {
  const ScopedPhase phase(Phase::integrate);
  parallel_blocks(x.cols(), threads_for(x.cols()), [&](std::int64_t b, std::int64_t e) {
    x.middleCols(b, e - b).noalias() += dt * v.middleCols(b, e - b);
  });
}

// x_old ← x, then x ← x + dt v: RATTLE's drift keeps its start for SHAKE and the chord velocity.
inline void keep_and_drift(Eigen::Matrix3Xd& x_old, Eigen::Matrix3Xd& x, const Eigen::Matrix3Xd& v, double dt) {
  const ScopedPhase phase(Phase::integrate);
  parallel_blocks(x.cols(), threads_for(x.cols()), [&](std::int64_t b, std::int64_t e) {
    x_old.middleCols(b, e - b) = x.middleCols(b, e - b);
    x.middleCols(b, e - b).noalias() += dt * v.middleCols(b, e - b);
  });
}

// v ← (x − x_old) / dt: the velocity of the chord from x_old to x.
inline void chord_velocity(Eigen::Matrix3Xd& v, const Eigen::Matrix3Xd& x, const Eigen::Matrix3Xd& x_old, double dt) {
  const ScopedPhase phase(Phase::integrate);
  parallel_blocks(x.cols(), threads_for(x.cols()), [&](std::int64_t b, std::int64_t e) {
    v.middleCols(b, e - b) = (x.middleCols(b, e - b) - x_old.middleCols(b, e - b)) / dt;
  });
}

// ½ vᵀ M v, skipping fixed particles (inverse mass 0), summed in particle blocks on the threads
// (parallel_sum): with one thread the bits of State::kinetic_energy.
inline double kinetic_energy(const Eigen::Matrix3Xd& v, const Eigen::VectorXd& inv_mass) {
  return parallel_sum(v.cols(), threads_for(v.cols()), [&](std::int64_t b, std::int64_t e) {
    double k = 0.0;
    for (std::int64_t i = b; i < e; ++i)
      if (inv_mass[i] > 0.0) k += 0.5 * v.col(i).squaredNorm() / inv_mass[i];
    return k;
  });
}

// kick(v, f, dt_kick) then drift(x, v, dt_drift), in one pass over the particles.
inline void kick_drift(Eigen::Matrix3Xd& x, Eigen::Matrix3Xd& v, const Eigen::VectorXd& inv_mass,
                       const Eigen::Matrix3Xd& f, double dt_kick, double dt_drift) {
  const ScopedPhase phase(Phase::integrate);
  parallel_blocks(x.cols(), threads_for(x.cols()), [&](std::int64_t b, std::int64_t e) {
    const double* __restrict fp = f.data();
    const double* __restrict w = inv_mass.data();
    double* __restrict vp = v.data();
    double* __restrict xp = x.data();
    for (std::int64_t i = b; i < e; ++i) {
      const double s = dt_kick * w[i];
      for (int a = 0; a < 3; ++a) {
        vp[3 * i + a] += s * fp[3 * i + a];
        xp[3 * i + a] += dt_drift * vp[3 * i + a];
      }
    }
  });
}

}  // namespace stiffmd
