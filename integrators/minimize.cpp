#include "integrators/minimize.hpp"

#include <algorithm>
#include <cmath>
#include <optional>
#include <sstream>

#include "engine/core/errors.hpp"
#include "integrators/constraints.hpp"

namespace stiffmd {

// FIRE 2.0 as LAMMPS's MinFire::iterate with its defaults (integrator eulerimplicit,
// halfstepback yes, initialdelay yes, vdfmax 2000: more than 2000 steps with P ≤ 0 stop it,
// reported as "vdfmax"), step k = 1, 2, …:
//   P = F·v.  P > 0: mixing factors c1 = 1 − α, c2 = α |v|/|F|; after more than delaystep steps
//     since the last P ≤ 0, dt ← min(dt·dtgrow, tmax·dt0) and α ← α·alphashrink.
//   P ≤ 0: (not within the first delaystep steps) α ← α0 and dt ← dt·dtshrink if that stays
//     ≥ tmin·dt0; x ← x − ½ dt_v v (the half step back); v ← 0.
//   dt_v = dt, reduced so that dt_v · max_{i,c} |v_ic| ≤ dmax (from v = dt M⁻¹F when v was reset);
//   v ← v + dt_v M⁻¹F; if P > 0: v ← c1 v + c2 F; x ← x + dt_v v (semi-implicit Euler), the
//   move scaled down where a coordinate would move further than dmax (below).
// Under rigid bonds F is P(x) f = f − Gᵀλ (G M⁻¹ F = 0: M⁻¹F is a tangent velocity), v is
// projected onto G v = 0 before each move and at the new positions, and every move of x
// (the step and the half step back) is followed by SHAKE (y ← y + M⁻¹G(x_old)ᵀλ, g(y) = 0).
MinimizeReport minimize_fire(ForceField& forces, const StiffBonds* stiff, State& s, const MinimizeSettings& p,
                             std::ostream* progress, const MinimizeObserver& after_move) {
  const Eigen::Index n = s.x.cols();
  std::optional<ConstraintToolbox> toolbox;
  if (p.rigid && stiff && !stiff->bonds.empty()) toolbox.emplace(stiff->bonds, s.inv_mass);
  const std::vector<Level> levels = forces.all_levels();
  Eigen::Matrix3Xd& x = s.x;
  Eigen::Matrix3Xd raw(3, n), f(3, n), fmove(3, n), v = Eigen::Matrix3Xd::Zero(3, n), x_old, last_move;
  const Eigen::Matrix3Xd deck_velocities = s.v;
  MinimizeReport r;

  auto shake_from = [&](const Eigen::Matrix3Xd& from) {
    if (toolbox) toolbox->shake(from, x, nullptr, p.shake_tolerance, 200);
  };
  // E(x); f = the true force (projected under rigid bonds), fmove = the force that moves (f, or
  // the capped force projected). Fixed particles (inverse mass 0) have no force: they do not move.
  auto evaluate = [&]() {
    const double e = toolbox ? forces.compute_unconstrained(x, raw) : forces.compute(x, levels, raw);
    ++r.evaluations;
    if (!std::isfinite(e))
      throw NumericalError("minimize: the potential energy is not finite (" + std::to_string(e) +
                           "): beads on top of each other?");
    for (Eigen::Index i = 0; i < n; ++i)
      if (s.inv_mass[i] == 0.0) raw.col(i).setZero();
    f = raw;
    if (toolbox) toolbox->project_force(x, f);
    if (p.max_force > 0.0) {
      for (Eigen::Index i = 0; i < n; ++i) {
        const double m = raw.col(i).norm();
        if (m > p.max_force) raw.col(i) *= p.max_force / m;
      }
      fmove = raw;
      if (toolbox) toolbox->project_force(x, fmove);
    } else {
      fmove = f;
    }
    return e;
  };
  auto say = [&](auto&&... what) {
    if (!progress) return;
    const auto old = progress->precision(6);
    ((*progress) << ... << what) << std::endl;
    progress->precision(old);
  };

  if (toolbox) shake_from(x);  // start on g = 0
  double e = evaluate(), e_prev = e;
  r.initial_energy = e;
  say("minimize: FIRE on ", n, " particles (potential energy ", e, ", force 2-norm ", f.norm(), ") ...");

  const double dtmax = p.tmax * p.dt, dtmin = p.tmin * p.dt;
  double dt = p.dt, dtv = p.dt, alpha = p.alpha0;  // dt_v: the last step's, for the dmax limit
  long last_negative = 0, uphill = 0;
  constexpr long kMaxUphill = 2000;  // LAMMPS's min_modify vdfmax default
  bool v_reset = true;
  r.stopped_by = "maxiter";
  for (long k = 1; k <= p.maxiter; ++k) {
    const double power = (v.array() * fmove.array()).sum();
    double scale1 = 1.0, scale2 = 0.0;
    if (power > 0.0) {
      const double ff = fmove.squaredNorm();
      scale1 = 1.0 - alpha;
      scale2 = ff <= 1e-20 ? 0.0 : alpha * std::sqrt(v.squaredNorm() / ff);
      if (k - last_negative > p.delaystep) {
        dt = std::min(dt * p.dtgrow, dtmax);
        alpha *= p.alphashrink;
      }
    } else {
      last_negative = k;
      if (++uphill > kMaxUphill) {
        r.stopped_by = "vdfmax";
        break;
      }
      if (k >= p.delaystep) {  // delaystep_start: no reset in the first delaystep steps
        alpha = p.alpha0;
        if (dt * p.dtshrink >= dtmin) dt *= p.dtshrink;
      }
      if (p.halfstepback && !v_reset) {
        x_old = x;
        x -= 0.5 * last_move;  // −½ dt_v v, the half of the last move (as capped by dmax)
        shake_from(x_old);
        e = evaluate();
      }
      v.setZero();
      v_reset = true;
    }

    // The step dt_v: no coordinate moves more than dmax (from the velocity a reset one gets).
    double vmax = 0.0;
    if (v_reset)
      vmax = dt * (fmove * s.inv_mass.asDiagonal()).cwiseAbs().maxCoeff();
    else
      vmax = v.cwiseAbs().maxCoeff();
    dtv = dt * vmax > p.dmax ? p.dmax / vmax : dt;

    v += dtv * (fmove * s.inv_mass.asDiagonal());
    if (power > 0.0) v = scale1 * v + scale2 * fmove;
    if (toolbox) toolbox->project_velocity(x, v);
    // dmax is a hard cap on the move: LAMMPS sizes dt_v by the velocity before the kick, so a
    // large force (an overlap) could still carry a particle far past dmax, and SHAKE with it.
    const double reach = dtv * v.cwiseAbs().maxCoeff();
    x_old = x;
    last_move = (reach > p.dmax ? p.dmax / reach : 1.0) * dtv * v;
    x += last_move;
    shake_from(x_old);
    if (toolbox) toolbox->project_velocity(x, v);
    e_prev = e;
    e = evaluate();
    v_reset = false;
    r.iterations = k;
    if (after_move) after_move(x, e);
    if (k % 1000 == 0) say("minimize: iteration ", k, ": potential energy ", e, ", force 2-norm ", f.norm());

    if (p.etol > 0.0 && k - last_negative > p.delaystep &&
        std::abs(e - e_prev) < p.etol * 0.5 * (std::abs(e) + std::abs(e_prev) + 1e-8)) {
      r.stopped_by = "etol";
      break;
    }
    if (p.ftol > 0.0 && f.squaredNorm() < p.ftol * p.ftol) {
      r.stopped_by = "ftol";
      break;
    }
    if (r.evaluations >= p.maxeval) {
      r.stopped_by = "maxeval";
      break;
    }
  }
  r.energy = e;
  r.fmax = n > 0 ? f.colwise().norm().maxCoeff() : 0.0;
  r.fnorm = f.norm();
  s.v = deck_velocities;
  if (toolbox) {
    r.max_violation = toolbox->max_violation(x);
    toolbox->project_velocity(x, s.v);
  }
  return r;
}

std::string describe(const MinimizeReport& r) {
  std::ostringstream o;
  o.precision(10);
  o << "minimize: FIRE stopped by " << r.stopped_by << " after " << r.iterations << " iterations (" << r.evaluations
    << " force evaluations): E0 " << r.initial_energy << " -> E " << r.energy << ", largest force |f|max = " << r.fmax
    << ", force 2-norm " << r.fnorm;
  return o.str();
}

}  // namespace stiffmd
