// RATTLE (Andersen 1983; HLW §VII.1.4) on the constrained system: the stiff bonds become
// rigid constraints g(x) = 0, and the force is that of every other term,
//
//   v½ = v + ½h M⁻¹(f(x) − G(x)ᵀλ),  x' = x + h v½,  g(x') = 0          (SHAKE)
//   v' = v½ + ½h M⁻¹(f(x') − G(x')ᵀμ),  G(x') v' = 0                    (velocity projection)
//
// A ModelPotential (integrators/model_potential.hpp) adds its force to f: W(I, x) = Σ_k I_k ω_k
// makes this the effective dynamics (paper eq. EHS) — the ε → 0 limit of the stiff system
// (Rubin–Ungar, Takens, Bornemann); Fixman's U_F with a thermostat makes it the thermal stiff
// limit (docs/design.md §5). Plain RATTLE (no model potential) is the "rigid" limit most engines
// use, which differs by O(1) when the bonds carry vibrational energy.
//
// Langevin dynamics, splitting "baoab" (the default): constrained BAOAB (Leimkuhler & Matthews,
// Proc. R. Soc. A 472, 20160138 (2016)): B(½h) A(½h) O(h) A(½h) B(½h), every A a RATTLE position
// step (SHAKE, then the velocity projection) and the O step followed by the velocity projection,
// so that friction and noise act on the tangent space {G v = 0} only. The temperature reads the
// velocities just after the projected O step (kinetic_energy_estimate, integrators/integrator.hpp).
// Two SHAKEs and two velocity projections per step (the two at x_{n+1} merged: rattle.cpp).
//
// Splitting "obabo" (Bussi & Parrinello, Phys. Rev. E 75, 056707 (2007); Leimkuhler & Matthews,
// "Molecular Dynamics" (2015) §7.3): O(½h), then the Hamiltonian RATTLE step above, then O(½h)
// and the velocity projection. One SHAKE and one projection per step: the Hamiltonian step's
// closing projection and the O step's are one projection after the unprojected O step (P is
// linear: rattle.cpp), the constraint force formed when the pressure asks for it. The first O step needs no
// projection of its own: SHAKE's x' = x + h v + M⁻¹G(x)ᵀλ and the chord velocity (x' − x)/h do
// not depend on the part M⁻¹G(x)ᵀa of v normal to the manifold at x (λ absorbs h·a), exactly
// as the first half kick's normal part is absorbed in plain RATTLE. Its configurations are those
// of velocity Verlet with an exact O(h) between steps: second order, without BAOAB's exact
// harmonic configurational law (tests/test_thermostat.cpp: the finite-step variances of both).
// The temperature reads the on-step velocities (after the last projected O step).
//
// Both keep the Maxwell law on the tangent space only with one Langevin friction on each cluster
// of stiff bonds (integrators/thermostat.hpp, uneven_friction_in_cluster): the constructor
// refuses per-type frictions that differ inside a cluster.
#pragma once

#include <memory>
#include <string>

#include "integrators/constraints.hpp"
#include "integrators/integrator.hpp"
#include "integrators/model_potential.hpp"
#include "integrators/thermostat.hpp"

namespace stiffmd {

class Rattle final : public Integrator {
 public:
  // model == nullptr: plain RATTLE; langevin == nullptr: Hamiltonian dynamics; splitting: where
  // the O steps go, baoab or obabo (the factory refuses lammps, integrators/factory.cpp).
  Rattle(std::string method, ForceField& forces, ConstraintToolbox toolbox, std::unique_ptr<ModelPotential> model,
         std::unique_ptr<LangevinNoise> langevin = nullptr,
         ThermostatSettings::Splitting splitting = ThermostatSettings::Splitting::baoab);
  // The model potential holds a pointer to toolbox_ (ModelPotential::attach): not movable.
  Rattle(Rattle&&) = delete;
  Rattle& operator=(Rattle&&) = delete;

  // Projects (x, v) M-orthogonally onto {g = 0, G v = 0} (paper eq. ACIV); the model potential
  // is prepared from the state before projection (the actions of the effective dynamics).
  void prepare(State& s, std::ostream& log) override;
  void step(State& s, double h) override;
  // The O step's kinetic energy is of the velocities before the change: the temperature reads the
  // state's ½vᵀMv again until the next step, as before the first.
  void reset() override {
    valid_ = model_value_current_ = false;
    o_step_kinetic_ = -1.0;
  }
  std::string_view method() const override { return method_; }
  // The constraint force at the end of the last step is the velocity projection's impulse over
  // the closing half step: F_c = M Δv / (h/2) = −Gᵀμ / (h/2) (with BAOAB, plus the last half
  // drift's centrifugal share over h/4: rattle.cpp). With Langevin it is formed here, at the first
  // call after the step, from the velocities the step kept (the step's projections at x_{n+1}
  // merged into one). Molecules are whole (unwrapped positions) and F_c sums to zero on each, so
  // Σ_i x_i·F_c,i equals the pairwise virial.
  double constraint_virial(const State& s) override;
  // W (or U_F) at x: the value the step's closing force evaluation computed when x is the state it
  // left (one decomposition per step, shared with the thermo row); computed afresh otherwise (before
  // the first step, after a restart: the same computation at the same x, so the same bits).
  double model_potential(const Eigen::Matrix3Xd& x) override {
    if (!model_) return 0.0;
    return model_value_current_ ? model_value_ : model_->force(x, correction_);
  }
  double kinetic_energy_estimate(const State& s) const override {
    return o_step_kinetic_ >= 0.0 ? o_step_kinetic_ : s.kinetic_energy();
  }
  // The O steps' heat, each measured on tangent velocities (rattle.cpp): K after the projected O
  // step less K of the velocity the Hamiltonian step left, projected (ConstraintToolbox::
  // normal_kinetic_energy: one more solve at a configuration whose S is factored, per O step
  // whose input is not tangent).
  double thermostat_heat() const override { return heat_; }

  // With Langevin: whether the closing projections are merged (always: rattle.cpp), and for tests
  // a switch to the projections as written, before the first step.
  bool merged_projection() const { return merged_projection_; }
  void set_merged_projection(bool on) { merged_projection_ = on && langevin_; }

  // Whether the step runs in molecule blocks (ConstraintToolbox::blocks_available): the passes
  // that act molecule by molecule — the kicks, drifts and chord velocities, SHAKE, the velocity
  // projections, the O steps and their kinetic energies — for one block of whole clusters before
  // the next, while its particles are in cache; the forces at the new x (and the model
  // potential's) between the step's two runs of blocks, whole. Each particle and cluster gets the
  // operations of the whole-system passes in the same order, and the sums are added as those add
  // them (ParticleSum, integrators/thermostat.hpp): the same bits at any thread count. Available
  // where the toolbox has blocks, for NVE and the merged projections (not as written: tests); on
  // by default (docs/performance.md, "The constrained step in molecule blocks").
  bool blocked_step() const { return blocked_ && blocked_available(); }
  void use_blocked_step(bool on) { blocked_ = on; }
  bool blocked_available() const { return toolbox_.blocks_available() && (!langevin_ || merged_projection_); }
  ConstraintToolbox& toolbox() { return toolbox_; }  // tests: the blocks' size

  // The model potential's state (actions), the cached force f(x) with its validity and the
  // constraint force of the last step (for the pressure of the first sample after a restart);
  // with Langevin, the kinetic energy at the last O step and the heat.
  std::vector<double> invariants() const override { return model_ ? model_->invariants() : std::vector<double>{}; }
  void set_invariants(const std::vector<double>& w) override {
    if (model_)
      model_->set_invariants(w);
    else
      Integrator::set_invariants(w);
  }
  std::vector<double> save_state() const override;
  CarriedState carried_state() const override;
  void restore_carried_state(CarriedState c) override;
  void load_state(const std::vector<double>& s) override;

 private:
  void refresh(const Eigen::Matrix3Xd& x);
  void rattle_drift(State& s, double dt);  // x ← x + dt v on g = 0; v ← the tangential chord velocity
  void step_blocked(State& s, double h);

  std::string method_;
  ForceField& forces_;
  ConstraintToolbox toolbox_;
  std::unique_ptr<ModelPotential> model_;
  std::unique_ptr<LangevinNoise> langevin_;
  bool obabo_ = false;  // langevin_ as O(½h) around the RATTLE step instead of constrained BAOAB
  // The step's SHAKE stops at LAMMPS's tolerance when the stiff-bond term gives one
  // (StiffBonds::shake_tolerance; 0: to max |g| ≤ 1e-12). The initial projection is exact.
  double shake_tolerance_ = 0.0;
  // With Langevin: the closing projections merged (rattle.cpp) — BAOAB's two at x_{n+1}, OBABO's
  // kick and O-step projections (the friction is one number on each cluster: the constructor
  // refuses anything else); as written only when a test asks.
  bool merged_projection_ = false;
  Eigen::Matrix3Xd f_, correction_, x_old_, constraint_force_;
  // With Langevin (merged_projection_): z, from which the last step's constraint force is
  // M(Pz − z) — (2/h) × the velocity after the closing kick, unprojected (OBABO), or (2/h) × the
  // sum of the unprojected chord velocity and the kicked one (BAOAB) — and whether
  // constraint_force_ has been formed from it since.
  Eigen::Matrix3Xd kicked_;
  bool constraint_force_current_ = true;
  bool blocked_ = true;                               // blocked_step() where available
  ParticleSum sum_before_, sum_after_, sum_kinetic_;  // the blocked step's sums over particles
  bool valid_ = false;
  double model_value_ = 0.0;          // the model potential at the x of the last refresh
  bool model_value_current_ = false;  // … and x has not moved since
  double o_step_kinetic_ = -1.0;      // ½vᵀMv just after the last (projected) O step; −1: none yet
  double heat_ = 0.0;                 // thermostat_heat()
};

}  // namespace stiffmd
