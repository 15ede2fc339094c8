#include "integrators/multiple_time_stepping.hpp"

#include <algorithm>
#include <stdexcept>

#include "core/timing.hpp"
#include "forcefields/bond_loop.hpp"
#include "integrators/primitives.hpp"

namespace stiffmd {

// Noise counters of the Langevin force: the closing force of a macro step, and the opening one
// when there is no cached force (first step, after reset()) — LAMMPS's fix langevin setup().
constexpr std::uint64_t kClosingForce = 0x1a3e000000000000ULL, kOpeningForce = kClosingForce + 1;

MultipleTimeStepping::MultipleTimeStepping(std::string method, ForceField& forces, std::vector<Stage> stages,
                                           std::unique_ptr<LangevinNoise> langevin,
                                           std::unique_ptr<LangevinForce> langevin_force,
                                           ThermostatSettings::Splitting splitting)
    : method_(std::move(method)),
      forces_(forces),
      stages_(std::move(stages)),
      force_(stages_.size(), Eigen::Matrix3Xd::Zero(3, forces.num_particles())),
      valid_(stages_.size(), false),
      removed_virial_(stages_.size(), 0.0),
      langevin_(std::move(langevin)),
      langevin_force_(std::move(langevin_force)),
      langevin_part_(Eigen::Matrix3Xd::Zero(3, langevin_force_ ? forces.num_particles() : 0)) {
  if (langevin_ && langevin_force_) throw std::invalid_argument("Langevin either as an O step or as a force, not both");
  if (splitting == ThermostatSettings::Splitting::obabo) obabo_ = std::move(langevin_);  // the step runs as in NVE
  if (stages_.empty()) throw std::invalid_argument("multiple time stepping needs at least one stage");
  for (const Stage& st : stages_)
    if (st.substeps < 1) throw std::invalid_argument("substeps must be >= 1");
  if (stages_.back().kick)
    throw std::invalid_argument("the innermost stage kicks with its plain force (its steps resolve the stiff bonds)");
  const auto plain = std::make_shared<PlainKick>();
  for (size_t k = 0; k + 1 < stages_.size(); ++k)
    if (!stages_[k].kick) stages_[k].kick = plain;
  const std::vector<Level>& inner = stages_.back().levels;
  std::vector<const ForceTerm*> terms;  // in the order compute() sums them
  for (const ForceTerm* term : forces_.evaluation_order())
    if (std::find(inner.begin(), inner.end(), term->level()) != inner.end()) terms.push_back(term);
  // Velocity Verlet with Langevin (BAOAB): its one micro step holds the O step, so it runs plain.
  if (!terms.empty() && !(stages_.size() == 1 && langevin_)) fused_available_ = terms.front()->fused_micro_step();
  rest_.assign(terms.begin() + (terms.empty() ? 0 : 1), terms.end());
  for (const ForceTerm* term : rest_) rest_phase_.push_back(term->phase());
  fused_ = forces.num_particles() <= kSmallFusedParticles ? fused_available_ : nullptr;
  blocked_available_ = fused_available_ && rest_.empty() && stages_.size() >= 2;
  blocked_ = blocked_available_;
  fused_verlet_ = stages_.size() == 1 && !langevin_ && !obabo_ && !langevin_force_;
}

// OBABO: O(½h), the Hamiltonian macro step, O(½h) (noise substeps 0 and 1 of the step).
void MultipleTimeStepping::step_obabo(State& s, double h) {
  heat_ += obabo_->apply_and_measure(s.v, 0.5 * h, s.step, 0).heat();
  advance(s, 0, h);
  const KineticChange closing = obabo_->apply_and_measure(s.v, 0.5 * h, s.step, 1);
  o_step_kinetic_ = closing.after;
  heat_ += closing.heat();
}

// The Langevin force f_L is part of the outermost kick force, which kicks by ½h at the start of
// the macro step and at its end. Its heat counts its impulses ½h M⁻¹f_L as jumps at the on-step
// times: the opening kick's before its conservative part, the closing kick's after it
// (LangevinForce::kick_heat). Kicks commute, so this is the same step, and what lies between the
// jumps is the Hamiltonian step whole, whose energy error is O(h²) and bounded; counted inside
// it, after the opening kick's conservative part, a jump b would leave the Hamiltonian part an
// error −½h f·b per step, f the force: O(h^{3/2}) per step from the noise, an O(h) random walk
// over a time. The opening kick's force is the one cached by the last step (or made now, as
// advance would make it).
void MultipleTimeStepping::step_langevin_force(State& s, double h) {
  if (!valid_[0]) refresh_outer(s, h, kOpeningForce);
  heat_ += langevin_force_->kick_heat(s.v, langevin_part_, 0.5 * h, false);
  advance(s, 0, h);
  heat_ += langevin_force_->kick_heat(s.v, langevin_part_, 0.5 * h, true);
}

void MultipleTimeStepping::refresh(size_t k, const Eigen::Matrix3Xd& x) {
  // Every stage slower than the innermost kicks through its strategy (see the header).
  if (k + 1 < stages_.size()) {
    stages_[k].kick->evaluate(x, forces_, stages_[k].levels, force_[k]);
    removed_virial_[k] = stages_[k].kick->removed_virial();
  } else
    forces_.compute_forces(x, stages_[k].levels, force_[k]);
  valid_[k] = true;
}

void MultipleTimeStepping::refresh_outer(State& s, double dt, std::uint64_t substep) {
  refresh(0, s.x);
  if (langevin_force_) langevin_force_->add(s.v, dt, s.step, substep, force_[0], langevin_part_);
}

// Stage k's force at the new x, reused by the next opening kick; at stage 0 with the Langevin
// force of the step's span (refresh_outer).
void MultipleTimeStepping::closing_force(State& s, size_t k, double span) {
  if (k == 0)
    refresh_outer(s, span, kClosingForce);
  else
    refresh(k, s.x);
}

// The fused micro step of stage k (the innermost) with the stage's other terms: its new force.
inline void MultipleTimeStepping::fused_force(State& s, size_t k, double dt_kick, double dt) {
  {
    const ScopedPhase phase(Phase::bonded);  // the stiff bonds' forces, with the kick and drift fused in
    fused_->kick_drift_force(s.x, s.v, s.inv_mass, force_[k], dt_kick, dt);
  }
  for (size_t t = 0; t < rest_.size(); ++t) {
    const ScopedPhase phase(rest_phase_[t]);
    rest_[t]->add_forces_only(s.x, forces_.box(), force_[k]);
  }
  forces_.count_evaluations(stages_[k].levels);
  valid_[k] = true;
}

// kick(dt_kick), drift(dt), then closing_force. Fused (FusedMicroStep): kick, drift and the
// first term's forces in one pass, then the stage's other terms in evaluation order — what
// compute() sums, in its order: the same bits.
void MultipleTimeStepping::micro_step(State& s, size_t k, double dt_kick, double dt, double span) {
  if (!fused_) {
    kick_drift(s.x, s.v, s.inv_mass, force_[k], dt_kick, dt);
    closing_force(s, k, span);
    return;
  }
  fused_force(s, k, dt_kick, dt);
  if (k == 0 && langevin_force_) langevin_force_->add(s.v, span, s.step, kClosingForce, force_[0], langevin_part_);
}

// advance(0, h) of velocity Verlet (one stage, no thermostat) with a fused micro step and a valid
// cached force, written out: run_innermost's one micro step and its closing kick, the same
// operations without the stage loop's bookkeeping — on a system of a few particles, the size the
// fused step serves, that bookkeeping cost as much as a third of the step (docs/performance.md,
// "The run loop's cost per step").
void MultipleTimeStepping::step_verlet_fused(State& s, double h) {
  fused_force(s, 0, 0.5 * h, h);
  finite_checked_ = kick_checking_finite(s.v, s.x, s.inv_mass, force_[0], 0.5 * h);
}

void MultipleTimeStepping::advance(State& s, size_t k, double dt) {
  if (!valid_[k]) {
    if (k == 0)
      refresh_outer(s, dt, kOpeningForce);
    else
      refresh(k, s.x);
  }
  if (k + 1 == stages_.size()) {  // velocity Verlet: the one stage is the innermost, one step of it
    run_innermost(s, k, dt, 1);   // with Langevin, BAOAB: the O step in the middle of its drift
    return;
  }
  kick(s.v, s.inv_mass, force_[k], 0.5 * dt);
  const int n = stages_[k + 1].substeps;
  const double sub = dt / n;
  if (k + 2 == stages_.size())
    run_innermost(s, k + 1, sub, n);
  else
    for (int i = 0; i < n; ++i) advance(s, k + 1, sub);
  closing_force(s, k, dt);  // x moved
  closing_kick(s, k, 0.5 * dt);
}

void MultipleTimeStepping::closing_kick(State& s, size_t k, double dt) {
  if (k == 0 && !obabo_ && !langevin_force_)
    finite_checked_ = kick_checking_finite(s.v, s.x, s.inv_mass, force_[k], dt);
  else
    kick(s.v, s.inv_mass, force_[k], dt);
}

// n steps of the innermost stage k (velocity Verlet: the one stage, n = 1): kick(½δ) drift(δ)
// [force] kick(½δ), n times. The closing kick of one step and the opening kick of the next use
// the same force, so they are one kick by δ: one pass over the particles per micro step fewer.
//
// With Langevin, one O step over the whole span nδ sits in the middle of the n steps: inside the
// drift of the middle step when n is odd, between the two half kicks at the middle when n is even
// (see the header for why there and not in every micro step).
//
// Fused (fused_micro_step()): kick, drift and the new force in one pass per micro step, the
// same bits (FusedMicroStep: kick_drift, then refresh); the micro step whose drift holds the O
// step (n odd) runs plain.
void MultipleTimeStepping::run_innermost(State& s, size_t k, double dt, int n) {
  if (blocked_ && n >= 2) {
    run_innermost_blocked(s, k, dt, n);
    return;
  }
  if (!valid_[k]) refresh(k, s.x);
  const double span = dt * n;
  for (int i = 0; i < n; ++i) {
    const double dt_kick = i == 0 ? 0.5 * dt : (langevin_ && n % 2 == 0 && i == n / 2) ? 0.5 * dt : dt;
    if (langevin_ && n % 2 == 1 && i == n / 2) {
      kick_drift_o_drift(s, k, dt_kick, dt, span);
      closing_force(s, k, span);
    } else {
      micro_step(s, k, dt_kick, dt, span);
    }
    if (langevin_ && n % 2 == 0 && i == n / 2 - 1) {
      kick(s.v, s.inv_mass, force_[k], 0.5 * dt);
      o_step(s, span);
    }
  }
  closing_kick(s, k, 0.5 * dt);
}

void MultipleTimeStepping::blocked_steps(State& s, size_t k, int steps, double first_kick, double dt) {
  if (steps == 0) return;
  {
    const ScopedPhase phase(Phase::bonded);  // the stiff bonds' forces, with the kicks and drifts
    fused_available_->kick_drift_forces(s.x, s.v, s.inv_mass, force_[k], first_kick, dt, dt, steps);
  }
  for (int i = 0; i < steps; ++i) forces_.count_evaluations(stages_[k].levels);
  valid_[k] = true;
}

// run_innermost's n micro steps (n ≥ 2) in molecule blocks (blocked_micro_steps): the runs of
// micro steps between the O step's passes taken whole by the fused term, with the kicks
// run_innermost gives each — ½δ for the first and the one after an even n's O step, δ for the
// others — and the middle micro step of an odd n, whose drift holds the O step, plain. The same
// operations on each particle in the same order, so the same bits.
void MultipleTimeStepping::run_innermost_blocked(State& s, size_t k, double dt, int n) {
  if (!valid_[k]) refresh(k, s.x);
  const double span = dt * n;
  if (!langevin_) {
    blocked_steps(s, k, n, 0.5 * dt, dt);
  } else if (n % 2 == 0) {
    blocked_steps(s, k, n / 2, 0.5 * dt, dt);
    kick(s.v, s.inv_mass, force_[k], 0.5 * dt);
    o_step(s, span);
    blocked_steps(s, k, n / 2, 0.5 * dt, dt);
  } else {
    const int before = n / 2;  // ≥ 1
    blocked_steps(s, k, before, 0.5 * dt, dt);
    kick_drift_o_drift(s, k, dt, dt, span);
    closing_force(s, k, span);
    blocked_steps(s, k, n - before - 1, dt, dt);
  }
  closing_kick(s, k, 0.5 * dt);
}

std::vector<double> MultipleTimeStepping::save_state() const {
  std::vector<double> w;
  for (size_t k = 0; k < stages_.size(); ++k) {
    w.push_back(valid_[k] ? 1.0 : 0.0);
    w.insert(w.end(), force_[k].data(), force_[k].data() + force_[k].size());
  }
  if (langevin_ || obabo_) w.push_back(o_step_kinetic_);
  w.insert(w.end(), removed_virial_.begin(), removed_virial_.end());
  if (thermostatted()) w.push_back(heat_);
  w.insert(w.end(), langevin_part_.data(), langevin_part_.data() + langevin_part_.size());
  return w;
}

// flags: valid per stage, whether an O step measured the kinetic energy; sums: that kinetic
// energy, the removed virials, the heat; columns: the stages' kick forces, then the Langevin
// force's part of the outermost one (with it).
CarriedState MultipleTimeStepping::carried_state() const {
  CarriedState c;
  for (size_t k = 0; k < stages_.size(); ++k) c.flags.push_back(valid_[k] ? 1.0 : 0.0);
  c.flags.push_back(o_step_kinetic_ >= 0.0 ? 1.0 : 0.0);
  c.sums.push_back(std::max(o_step_kinetic_, 0.0));
  c.sums.insert(c.sums.end(), removed_virial_.begin(), removed_virial_.end());
  c.sums.push_back(heat_);
  c.columns = force_;
  if (langevin_force_) c.columns.push_back(langevin_part_);
  return c;
}

void MultipleTimeStepping::restore_carried_state(CarriedState c) {
  if (c.flags.size() != 1 + stages_.size() || c.sums.size() != 2 + stages_.size() ||
      c.columns.size() != stages_.size() + (langevin_force_ ? 1 : 0))
    throw std::invalid_argument(method_ + ": carried state of another method");
  for (size_t k = 0; k < stages_.size(); ++k) {
    valid_[k] = c.flags[k] != 0.0;
    force_[k] = std::move(c.columns[k]);
  }
  if (langevin_force_) langevin_part_ = std::move(c.columns.back());
  o_step_kinetic_ = c.flags.back() != 0.0 ? c.sums[0] : -1.0;
  removed_virial_.assign(c.sums.begin() + 1, c.sums.end() - 1);
  heat_ = c.sums.back();
}

void MultipleTimeStepping::load_state(const std::vector<double>& w) {
  const size_t per_stage = 1 + 3 * static_cast<size_t>(forces_.num_particles());
  const bool o_steps = langevin_ || obabo_;
  const size_t expected = stages_.size() * (per_stage + 1) + (o_steps ? 1 : 0) + (thermostatted() ? 1 : 0) +
                          static_cast<size_t>(langevin_part_.size());
  if (w.size() != expected)
    throw std::invalid_argument("the checkpoint holds " + std::to_string(w.size()) + " words of " + method_ +
                                " state, expected " + std::to_string(expected) + " (" + std::to_string(stages_.size()) +
                                " stages" + (thermostatted() ? ", Langevin)" : ")"));
  for (size_t k = 0; k < stages_.size(); ++k) {
    const double* p = w.data() + k * per_stage;
    valid_[k] = p[0] != 0.0;
    force_[k] = Eigen::Map<const Eigen::Matrix3Xd>(p + 1, 3, forces_.num_particles());
  }
  const double* tail = w.data() + stages_.size() * per_stage;
  if (o_steps) o_step_kinetic_ = *tail++;
  removed_virial_.assign(tail, tail + stages_.size());
  tail += stages_.size();
  if (thermostatted()) heat_ = *tail++;
  if (langevin_force_) langevin_part_ = Eigen::Map<const Eigen::Matrix3Xd>(tail, 3, forces_.num_particles());
}

// One O step per macro step (see the header), so o_step_kinetic_ is that macro step's.
void MultipleTimeStepping::o_step(State& s, double dt) {
  const KineticChange change = langevin_->apply_and_measure(s.v, dt, s.step, substep_++);
  o_step_kinetic_ = change.after;
  heat_ += change.heat();
}

// kick_drift(dt_kick, ½δ), o_step(span), drift(½δ) — the micro step whose drift holds the O step —
// in one pass (LangevinNoise::kick_drift_o_drift): the same bits.
void MultipleTimeStepping::kick_drift_o_drift(State& s, size_t k, double dt_kick, double dt, double span) {
  const KineticChange change =
      langevin_->kick_drift_o_drift(s.x, s.v, s.inv_mass, force_[k], dt_kick, 0.5 * dt, span, s.step, substep_++);
  o_step_kinetic_ = change.after;
  heat_ += change.heat();
}

}  // namespace stiffmd
