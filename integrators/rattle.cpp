#include "integrators/rattle.hpp"

#include <sstream>
#include <stdexcept>
#include <string>

#include "core/timing.hpp"
#include "integrators/prepare.hpp"
#include "integrators/primitives.hpp"

namespace stiffmd {

Rattle::Rattle(std::string method, ForceField& forces, ConstraintToolbox toolbox, std::unique_ptr<ModelPotential> model,
               std::unique_ptr<LangevinNoise> langevin, ThermostatSettings::Splitting splitting)
    : method_(std::move(method)),
      forces_(forces),
      toolbox_(std::move(toolbox)),
      model_(std::move(model)),
      langevin_(std::move(langevin)),
      obabo_(langevin_ && splitting == ThermostatSettings::Splitting::obabo),
      shake_tolerance_(forces.stiff_bonds() ? forces.stiff_bonds()->shake_tolerance : 0.0),
      f_(Eigen::Matrix3Xd::Zero(3, forces.num_particles())),
      correction_(f_),
      x_old_(f_),
      constraint_force_(f_),
      kicked_(f_) {
  if (model_) model_->attach(toolbox_);
  // The constrained O step is exact only with one friction on each cluster (thermostat.hpp,
  // uneven_friction_in_cluster); with it OBABO's closing projections merge too: P(C·Pw + Σξ) =
  // P(C·w + Σξ) needs C(w − Pw), normal to the manifold, to stay normal. Constrained BAOAB's merge
  // holds whatever the friction (no O step between the two projections: step).
  if (langevin_) {
    if (const auto u = uneven_friction_in_cluster(toolbox_.clusters(), langevin_->inv_mass(), langevin_->friction()))
      throw std::invalid_argument(
          "Langevin friction " + std::to_string(langevin_->friction()[u->a]) + " on particle " + std::to_string(u->a) +
          " and " + std::to_string(langevin_->friction()[u->b]) + " on particle " + std::to_string(u->b) +
          " of one rigid cluster: the constrained O step keeps the Maxwell law only with one friction per cluster");
    merged_projection_ = true;
  }
}

void Rattle::prepare(State& s, std::ostream& log) {
  if (model_) model_->prepare(s, log);
  const InitialProjection projection = project_initial_data(toolbox_, s);
  valid_ = model_value_current_ = false;
  log << describe(method_, projection) << "\n";
}

void Rattle::refresh(const Eigen::Matrix3Xd& x) {
  forces_.compute_forces_unconstrained(x, f_);
  if (model_) {
    const ScopedPhase phase(Phase::constraints);           // the model potential: the modes' W or Fixman's U_F
    model_value_ = model_->add_force(x, f_, correction_);  // f += −∇W(I, x) or −∇U_F(x)
    model_value_current_ = true;
  }
  valid_ = true;
}

// x' = x + dt v + M⁻¹G(x)ᵀλ with g(x') = 0 (SHAKE), v ← (x' − x)/dt: the velocity including the
// constraint impulse.
void Rattle::rattle_drift(State& s, double dt) {
  keep_and_drift(x_old_, s.x, s.v, dt);
  toolbox_.shake(x_old_, s.x, nullptr, 1e-12, 50, shake_tolerance_);
  chord_velocity(s.v, s.x, x_old_, dt);
}

void Rattle::step(State& s, double h) {
  if (blocked_step()) {
    step_blocked(s, h);
    return;
  }
  if (!valid_) refresh(s.x);
  model_value_current_ = false;  // x moves below; the closing refresh makes it current again
  // OBABO's first O(½h): not projected (rattle.hpp: SHAKE and the chord velocity absorb the
  // normal part, as they absorb the half kick's). Substep 0 of the step's noise, the closing O 1.
  // Its heat: the step continues from P(x)v, so K(Pv) − K(v_n), v_n tangent (the last step's
  // projection left it so).
  if (obabo_) {
    const KineticChange o = langevin_->apply_and_measure(s.v, 0.5 * h, s.step, 0);
    heat_ += o.heat() - toolbox_.normal_kinetic_energy(s.x, s.v);
  }
  kick(s.v, s.inv_mass, f_, 0.5 * h);
  if (!merged_projection_)  // the velocity projections at x_{n+1} add their shares
    parallel_blocks(s.x.cols(), threads_for(s.x.cols()),
                    [&](std::int64_t b, std::int64_t e) { constraint_force_.middleCols(b, e - b).setZero(); });
  if (!langevin_ || obabo_) {
    rattle_drift(s, h);
  } else {
    // Constrained BAOAB: A(½h), O(h) then the velocity projection (friction and noise on the
    // tangent space; P is linear, so projecting once after O equals projecting before and after),
    // A(½h).
    rattle_drift(s, 0.5 * h);
    // The heat: K after the projected O step less K of the chord velocity a projected, which is
    // what the A step's own projection (merged into the O step's) leaves: K(Pa) = K(a) − ½(Ga)ᵀS⁻¹(Ga).
    // K(a) itself would count the normal part of the chord velocity, O(h²) of kinetic energy that
    // the constraint takes every step whatever the thermostat, as heat.
    const double normal = toolbox_.normal_kinetic_energy(s.x, s.v);
    const KineticChange o = langevin_->apply_and_measure(s.v, h, s.step, 0);
    toolbox_.project_velocity(s.x, s.v);
    o_step_kinetic_ = kinetic_energy(s.v, s.inv_mass);
    heat_ += o_step_kinetic_ - (o.before - normal);
    rattle_drift(s, 0.5 * h);
    // The chord velocity q of a drift over τ leaves the tangent space at x' by τ|v|²/(2ℓ) along
    // each bond: its projection is the centrifugal share of the constraint force, M Δv / (τ/2). Over
    // τ = h/2 that is twice the factor of the closing kick's share (below): taken apart, else the
    // pressure would miss half the centrifugal force (kT per bond in the virial). The projection
    // adds M Δv · rate itself (−rate Gᵀμ, none at fixed particles). Merged (below), this projection
    // and the closing kick's are one.
    if (!merged_projection_) toolbox_.project_velocity(s.x, s.v, &constraint_force_, 4.0 / h);
  }
  refresh(s.x);
  if (merged_projection_) {
    // The closing projections merged into one (P linear, P² = P), and the constraint force kept as
    // the z of M(Pz − z), projected only when the pressure asks for it (constraint_virial):
    //  - BAOAB: the chord velocity q's projection and, after the kick k, Pq + k's are one,
    //    P(Pq + k) = P(q + k); their forces (4/h) M(Pq − q) + (2/h) M(Pk − k) have
    //    z = (4/h) q + (2/h) k = (2/h)(q + q + k), the velocities before and after the kick.
    //  - OBABO: the kick's projection and the closing O step's (v ← c v + σξ, its noise
    //    independent of v, c one number on each cluster: the constructor) are one,
    //    P(c·Pw + σξ) = P(c·w + σξ) for the kicked w; the kick's force has z = (2/h) w. The O
    //    step's projection is no constraint force (as BAOAB's is not); the temperature reads
    //    these on-step velocities.
    kick_and_keep(s.v, s.inv_mass, f_, 0.5 * h, kicked_, 2.0 / h, /*with_before=*/!obabo_);
    constraint_force_current_ = false;
    if (!obabo_) {
      toolbox_.project_velocity(s.x, s.v);
      return;
    }
    // OBABO's heat: K of the on-step velocity less K(Pw), w the kicked velocity, where the
    // Hamiltonian RATTLE step would have ended.
    const double normal = toolbox_.normal_kinetic_energy(s.x, s.v);
    const KineticChange o = langevin_->apply_and_measure(s.v, 0.5 * h, s.step, 1);
    toolbox_.project_velocity(s.x, s.v);
    o_step_kinetic_ = kinetic_energy(s.v, s.inv_mass);
    heat_ += o_step_kinetic_ - (o.before - normal);
    return;
  }
  kick(s.v, s.inv_mass, f_, 0.5 * h);
  // G(x') v' = 0. Without Langevin (and under OBABO, whose drift is RATTLE's) the chord over h
  // and the kick over h/2 share the factor: F_c = M Δv / (h/2).
  toolbox_.project_velocity(s.x, s.v, &constraint_force_, 2.0 / h);
  if (obabo_) {  // the projections as written (tests: set_merged_projection): the closing O(½h) on the tangent space
    const KineticChange o = langevin_->apply_and_measure(s.v, 0.5 * h, s.step, 1);
    toolbox_.project_velocity(s.x, s.v);
    o_step_kinetic_ = kinetic_energy(s.v, s.inv_mass);
    heat_ += o_step_kinetic_ - o.before;
  }
}

namespace {

// The whole-system passes of integrators/primitives.hpp on particles first … last − 1, with their
// expressions (the same bits): kick, then keep_and_drift; keep_and_drift; chord_velocity. The
// kicks on a range are primitives.hpp's kick_range and kick_and_keep_range.
void kick_keep_drift(Eigen::Matrix3Xd& x, Eigen::Matrix3Xd& x_old, Eigen::Matrix3Xd& v, const Eigen::VectorXd& inv_mass,
                     const Eigen::Matrix3Xd& f, double dt_kick, double dt, std::int64_t first, std::int64_t last) {
  double* __restrict xp = x.data();
  double* __restrict op = x_old.data();
  double* __restrict vp = v.data();
  const double* __restrict fp = f.data();
  const double* __restrict w = inv_mass.data();
  for (std::int64_t i = first; i < last; ++i) {
    const double c = dt_kick * w[i];
    for (int a = 0; a < 3; ++a) {
      vp[3 * i + a] += c * fp[3 * i + a];
      op[3 * i + a] = xp[3 * i + a];
      xp[3 * i + a] += dt * vp[3 * i + a];
    }
  }
}

void keep_drift(Eigen::Matrix3Xd& x, Eigen::Matrix3Xd& x_old, const Eigen::Matrix3Xd& v, double dt, std::int64_t first,
                std::int64_t last) {
  double* __restrict xp = x.data();
  double* __restrict op = x_old.data();
  const double* __restrict vp = v.data();
  for (std::int64_t k = 3 * first; k < 3 * last; ++k) {
    op[k] = xp[k];
    xp[k] += dt * vp[k];
  }
}

void chord(Eigen::Matrix3Xd& v, const Eigen::Matrix3Xd& x, const Eigen::Matrix3Xd& x_old, double dt, std::int64_t first,
           std::int64_t last) {
  double* __restrict vp = v.data();
  const double* __restrict xp = x.data();
  const double* __restrict op = x_old.data();
  for (std::int64_t k = 3 * first; k < 3 * last; ++k) vp[k] = (xp[k] - op[k]) / dt;
}

// kinetic_energy's terms (integrators/primitives.hpp) of the mobile particles first … last − 1.
void add_kinetic(ParticleSum& sum, const Eigen::Matrix3Xd& v, const Eigen::VectorXd& inv_mass, std::int64_t first,
                 std::int64_t last) {
  for (std::int64_t i = first; i < last; ++i)
    if (inv_mass[i] > 0.0) sum.add(i, 0.5 * v.col(i).squaredNorm() / inv_mass[i]);
}

}  // namespace

// step's passes in molecule blocks (rattle.hpp, blocked_step): each block goes through the passes
// up to the forces at x_{n+1}, then (after the forces) through the closing ones. Per block, in
// step's order: NVE: kick, drift, SHAKE, chord velocity | kick, projection with the constraint
// force. BAOAB: kick, drift, SHAKE, chord, the normal kinetic energy, O, projection, K, drift,
// SHAKE, chord | kick (keeping z), projection. OBABO: O, the normal kinetic energy, kick, drift,
// SHAKE, chord | kick (keeping w), the normal kinetic energy, O, projection, K. The sums (the O
// steps' K before and after, K after the projected O step, the normal kinetic energies) are formed
// after each run of blocks, in the whole-system passes' order.
void Rattle::step_blocked(State& s, double h) {
  if (!valid_) refresh(s.x);
  model_value_current_ = false;  // x moves below; the closing refresh makes it current again
  const std::int64_t n = s.x.cols();
  const int parts = threads_for(n);
  const Eigen::VectorXd& w = s.inv_mass;
  auto first = [&](int b) { return toolbox_.block_first(b); };
  auto last = [&](int b) { return toolbox_.block_last(b); };
  auto shake = [&](int b) { toolbox_.shake_block(b, x_old_, s.x, 1e-12, 50, shake_tolerance_); };
  toolbox_.begin_blocks();
  if (langevin_) langevin_->set_step(obabo_ ? 0.5 * h : h);
  {
    const ScopedPhase phase(Phase::constraints);
    if (!langevin_) {
      toolbox_.for_each_block(parts, [&](int b) {
        const std::int64_t p = first(b), q = last(b);
        constraint_force_.middleCols(p, q - p).setZero();
        kick_keep_drift(s.x, x_old_, s.v, w, f_, 0.5 * h, h, p, q);
        shake(b);
        chord(s.v, s.x, x_old_, h, p, q);
      });
    } else if (!obabo_) {
      sum_before_.start(n, parts);
      sum_kinetic_.start(n, parts);
      toolbox_.for_each_block(parts, [&](int b) {
        const std::int64_t p = first(b), q = last(b);
        kick_keep_drift(s.x, x_old_, s.v, w, f_, 0.5 * h, 0.5 * h, p, q);
        shake(b);
        chord(s.v, s.x, x_old_, 0.5 * h, p, q);
        toolbox_.normal_energy_block(b, s.x, s.v);
        langevin_->apply_range(s.v, s.step, 0, p, q, &sum_before_, nullptr);
        toolbox_.project_velocity_block(b, s.x, s.v);
        add_kinetic(sum_kinetic_, s.v, w, p, q);
        keep_drift(s.x, x_old_, s.v, 0.5 * h, p, q);
        shake(b);
        chord(s.v, s.x, x_old_, 0.5 * h, p, q);
      });
      const double normal = toolbox_.normal_energy_sum();
      o_step_kinetic_ = sum_kinetic_.total(w);
      heat_ += o_step_kinetic_ - (sum_before_.total(w) - normal);
    } else {
      sum_before_.start(n, parts);
      sum_after_.start(n, parts);
      toolbox_.for_each_block(parts, [&](int b) {
        const std::int64_t p = first(b), q = last(b);
        langevin_->apply_range(s.v, s.step, 0, p, q, &sum_before_, &sum_after_);
        toolbox_.normal_energy_block(b, s.x, s.v);
        kick_keep_drift(s.x, x_old_, s.v, w, f_, 0.5 * h, h, p, q);
        shake(b);
        chord(s.v, s.x, x_old_, h, p, q);
      });
      const KineticChange o{sum_before_.total(w), sum_after_.total(w)};
      heat_ += o.heat() - toolbox_.normal_energy_sum();
    }
  }
  // The forces at x_{n+1}: the model potential's (Fixman's U_F) block by block below where it can,
  // each block's before its closing kick (refresh's bits: the other forces first, then the
  // model's on each cluster).
  const bool model_blocks = model_ && model_->blocks();
  if (model_blocks) {
    forces_.compute_forces_unconstrained(s.x, f_);
    valid_ = true;
  } else {
    refresh(s.x);
  }
  const ScopedPhase phase(Phase::constraints);
  auto model_force = [&](int b) {
    if (model_blocks) model_->add_block_force(b, s.x, f_);
  };
  if (!langevin_) {
    // G(x') v' = 0, F_c = M Δv / (h/2) (step).
    toolbox_.for_each_block(parts, [&](int b) {
      model_force(b);
      kick_range(s.v, w, f_, 0.5 * h, first(b), last(b));
      toolbox_.project_velocity_block(b, s.x, s.v, &constraint_force_, 2.0 / h);
    });
  } else if (!obabo_) {
    toolbox_.for_each_block(parts, [&](int b) {
      model_force(b);
      kick_and_keep_range(s.v, w, f_, 0.5 * h, kicked_, 2.0 / h, true, first(b), last(b));
      toolbox_.project_velocity_block(b, s.x, s.v);
    });
  } else {
    sum_before_.start(n, parts);
    sum_kinetic_.start(n, parts);
    toolbox_.for_each_block(parts, [&](int b) {
      const std::int64_t p = first(b), q = last(b);
      model_force(b);
      kick_and_keep_range(s.v, w, f_, 0.5 * h, kicked_, 2.0 / h, false, p, q);
      toolbox_.normal_energy_block(b, s.x, s.v);
      langevin_->apply_range(s.v, s.step, 1, p, q, &sum_before_, nullptr);
      toolbox_.project_velocity_block(b, s.x, s.v);
      add_kinetic(sum_kinetic_, s.v, w, p, q);
    });
    const double normal = toolbox_.normal_energy_sum();
    o_step_kinetic_ = sum_kinetic_.total(w);
    heat_ += o_step_kinetic_ - (sum_before_.total(w) - normal);
  }
  if (langevin_) constraint_force_current_ = false;
  if (model_blocks) {
    model_value_ = model_->blocked_value();
    model_value_current_ = true;
  }
}

double Rattle::constraint_virial(const State& s) {
  if (!constraint_force_current_) {
    // F_c = M(P z − z) with the kept z (step: (2/h) w under OBABO, (2/h)(q + q + k) under BAOAB),
    // the projection at x adding −Gᵀμ itself (x_old_ is free between steps). At the x of the step
    // the toolbox still holds S's factors.
    const Eigen::Index n = s.x.cols();
    parallel_blocks(n, threads_for(n), [&](std::int64_t b, std::int64_t e) {
      constraint_force_.middleCols(b, e - b).setZero();
      x_old_.middleCols(b, e - b) = kicked_.middleCols(b, e - b);
    });
    toolbox_.project_velocity(s.x, x_old_, &constraint_force_, 1.0);
    constraint_force_current_ = true;
  }
  return parallel_sum(s.x.cols(), threads_for(s.x.cols()), [&](std::int64_t b, std::int64_t e) {
    return (s.x.middleCols(b, e - b).array() * constraint_force_.middleCols(b, e - b).array()).sum();
  });
}

// [the model potential's state (the effective dynamics' actions)][valid][f (3N)][constraint force
// (3N); OBABO: the kicked velocity (2/h) w it is formed from][Langevin: the kinetic energy at the
// last O step, the heat]
std::vector<double> Rattle::save_state() const {
  std::vector<double> w = model_ ? model_->save_state() : std::vector<double>{};
  w.push_back(valid_ ? 1.0 : 0.0);
  w.insert(w.end(), f_.data(), f_.data() + f_.size());
  const Eigen::Matrix3Xd& force_or_kicked = merged_projection_ ? kicked_ : constraint_force_;
  w.insert(w.end(), force_or_kicked.data(), force_or_kicked.data() + force_or_kicked.size());
  if (langevin_) w.insert(w.end(), {o_step_kinetic_, heat_});
  return w;
}

// flags: valid, whether an O step measured the kinetic energy; sums: that kinetic energy and the
// heat (with Langevin); columns: the cached force and
// the constraint force (or, under OBABO's merged projection, the kicked velocities it is formed
// from). The model's actions are invariants, handed over apart.
CarriedState Rattle::carried_state() const {
  CarriedState c;
  c.flags.push_back(valid_ ? 1.0 : 0.0);
  c.flags.push_back(o_step_kinetic_ >= 0.0 ? 1.0 : 0.0);
  if (langevin_) c.sums.insert(c.sums.end(), {std::max(o_step_kinetic_, 0.0), heat_});
  c.columns = {f_, merged_projection_ ? kicked_ : constraint_force_};
  return c;
}

void Rattle::restore_carried_state(CarriedState c) {
  if (c.flags.size() != 2 || c.sums.size() != (langevin_ ? 2u : 0u) || c.columns.size() != 2)
    throw std::invalid_argument(method_ + ": carried state of another method");
  valid_ = c.flags[0] != 0.0;
  model_value_current_ = false;
  f_ = std::move(c.columns[0]);
  (merged_projection_ ? kicked_ : constraint_force_) = std::move(c.columns[1]);
  constraint_force_current_ = !merged_projection_;
  if (langevin_) {
    o_step_kinetic_ = c.flags[1] != 0.0 ? c.sums[0] : -1.0;
    heat_ = c.sums[1];
  }
}

void Rattle::load_state(const std::vector<double>& w) {
  const size_t n3 = static_cast<size_t>(f_.size()), own = 1 + 2 * n3 + (langevin_ ? 2 : 0);
  if (w.size() < own)
    throw std::invalid_argument("the checkpoint holds " + std::to_string(w.size()) + " words of " + method_ +
                                " state, this scene needs at least " + std::to_string(own) + " (forces of " +
                                std::to_string(n3 / 3) + " particles)");
  const size_t m = w.size() - own;  // the model potential's words
  const std::vector<double> model_words(w.begin(), w.begin() + static_cast<std::ptrdiff_t>(m));
  if (model_)
    model_->load_state(model_words);
  else
    Integrator::load_state(model_words);
  valid_ = w[m] != 0.0;
  model_value_current_ = false;  // recomputed at the first sample: the same bits
  f_ = Eigen::Map<const Eigen::Matrix3Xd>(w.data() + m + 1, 3, f_.cols());
  (merged_projection_ ? kicked_ : constraint_force_) =
      Eigen::Map<const Eigen::Matrix3Xd>(w.data() + m + 1 + n3, 3, f_.cols());
  constraint_force_current_ = !merged_projection_;
  if (langevin_) {
    o_step_kinetic_ = w[w.size() - 2];
    heat_ = w.back();
  }
}

}  // namespace stiffmd
