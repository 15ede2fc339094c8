// Multiple time stepping as data (docs/design.md §3, §11.4; r-RESPA, Tuckerman, Berne &
// Martyna 1992): a list of stages, outermost first. Stage k kicks with the forces of its
// levels for half its step, runs `substeps` steps of stage k+1 (the innermost stage drifts
// instead), then kicks again:
//
//     kick(½Δ_k) ∘ [stage k+1]^{n_{k+1}} ∘ kick(½Δ_k),   Δ_{k+1} = Δ_k / n_{k+1}.
//
// velocity Verlet = one stage {fast, slow}; the impulse method = {slow} ×1, {fast} ×n; N-level
// r-RESPA = one stage per level of the deck's [[integrator.levels]] (integrators/factory.cpp).
// The closing kick's force of every stage is cached and reused by the next opening kick,
// so the outer (slow) force is evaluated once per macro step. How a stage turns raw forces
// into its kick (plain, projected P(x)f, mollified α′(x)ᵀf(α(x))) is a strategy, Stage::kick,
// not a copy of the step. The innermost stage holds the stiff bonds and its force is always
// plain; by default (integrators/factory.cpp) the method's kick is that of every other stage.
// Why every slower stage and not only the outermost: a kick of step Δ_k ≫ ε/ω by a force with a
// component along the stiff directions is an impulse the stiff oscillators feel; at Δ_k ω/ε near
// a multiple of π it pumps their actions (docs/design.md §3; the seed paper's argument for the
// projected and mollified kicks does not use which level the kick belongs to, only that its step
// does not resolve the stiff period). A stage whose step does resolve the stiff period needs no
// such kick, and a deck may kick it plainly ([[integrator.levels]] kick = "plain"): its kicks then
// follow the true force, whereas the mollified kick is the force of U(α(x)), not of U(x), and the
// projected one drops the bond-normal part of f — a difference the true energy carries (the
// peptide in docs/performance.md: +0.34 kcal/mol/atom when the 1 fs level is mollified too).
// Test: tests/test_respa_levels.cpp (a medium-level angle term whose step does not resolve the
// bonds: actions kept by the method's kick on every slower level, lost by the plain kick and by
// projecting the outermost kick alone; a plain middle level under a mollified outermost one).
//
// Langevin dynamics. Velocity Verlet (one stage) becomes BAOAB (Leimkuhler & Matthews 2013):
// its drift becomes A(½h) O(h) A(½h). The impulse family becomes BAOAB-RESPA with the fast flow
// as the A step:
//
//     B_slow(½h)  Φ_fast(½h)  O(h)  Φ_fast(½h)  B_slow(½h),    Φ_fast(½h) = n/2 micro steps,
//
// one O step over the whole macro step, in the middle of the micro steps (generally: once per
// step of the stage enclosing the innermost, over that step's span; with N levels that is
// n_{N−1}···n_2 O steps per macro step, each in the middle of its run of innermost steps, and
// together they cover the macro step once). The kicks (plain, projected,
// mollified) are those of the deterministic method. Why not an O step in every micro step (as
// OpenMM's MTSLangevinIntegrator does): a Gaussian per particle component costs more than the
// stiff bond forces of a micro step — measured on data.chain (32 000 beads, n = 20), noise in
// every micro step made a macro step 4x slower — while the O step is exact over any span, so
// one per macro step thermalises the bond vibrations as well (the trimer tests: stiff law,
// Maxwell velocities). Noise counter: (State::step, the O steps taken in this macro step).
// The temperature reads the velocities just after the O step (kinetic_energy_estimate): in BAOAB
// those are exact in law for harmonic forces at any stable h, the on-step ones low by (hω)²/4.
//
// OBABO (splitting = "obabo"; Bussi & Parrinello 2007): an exact O step of ½h before and after the
// Hamiltonian macro step, which then runs as in NVE (fused where it can). The temperature reads
// the on-step velocities, just after the closing O step.
//
// Langevin as a force (splitting = "lammps", LangevinForce): no O step; the friction and noise
// force of the velocities at the moment the outermost kick force is computed is added to it (as
// LAMMPS's fix langevin does in post_force, on the outermost r-RESPA level), so it serves the
// closing half kick of this step and the opening one of the next and is cached and checkpointed
// with it. The temperature reads the on-step velocities: for harmonic forces this scheme's on-step
// velocities are exact in law, its positions are not (⟨x²⟩ = kT/k · (1 + O((hω)², γh))).
#pragma once

#include <functional>
#include <memory>
#include <string>
#include <vector>

#include "integrators/integrator.hpp"
#include "integrators/thermostat.hpp"

namespace stiffmd {

// Forms a stage's kick force K(x) from the force field (every stage but the innermost).
class KickForce {
 public:
  virtual ~KickForce() = default;
  virtual void evaluate(const Eigen::Matrix3Xd& x, ForceField& forces, const std::vector<Level>& levels,
                        Eigen::Matrix3Xd& out) = 0;
  // Σ x·(f(x) − K(x)) of the last evaluate: the virial of the force the kick left out (the
  // bond-normal part a projection removes), 0 when it removes none.
  virtual double removed_virial() const { return 0.0; }
};

// K(x) = f(x): the plain impulse / r-RESPA kick.
class PlainKick final : public KickForce {
 public:
  void evaluate(const Eigen::Matrix3Xd& x, ForceField& forces, const std::vector<Level>& levels,
                Eigen::Matrix3Xd& out) override {
    forces.compute_forces(x, levels, out);
  }
};

struct Stage {
  std::vector<Level> levels;
  int substeps = 1;  // steps of this stage per step of the enclosing stage
  // This stage's kick strategy; null: plain. Stages may share one (and with it its scratch and
  // constraint toolbox: each evaluate is complete before the next). The innermost stage has none:
  // its force is the plain force, which its micro steps resolve.
  std::shared_ptr<KickForce> kick = nullptr;
};

class MultipleTimeStepping final : public Integrator {
 public:
  MultipleTimeStepping(std::string method, ForceField& forces, std::vector<Stage> stages,
                       std::unique_ptr<LangevinNoise> langevin = nullptr,
                       std::unique_ptr<LangevinForce> langevin_force = nullptr,
                       ThermostatSettings::Splitting splitting = ThermostatSettings::Splitting::baoab);

  void step(State& s, double h) override {
    substep_ = 0;
    finite_checked_ = false;
    if (fused_verlet_ && fused_ && valid_[0])
      step_verlet_fused(s, h);
    else if (obabo_)
      step_obabo(s, h);
    else if (langevin_force_)
      step_langevin_force(s, h);
    else
      advance(s, 0, h);
  }
  // The O step's kinetic energy is of the velocities before the change: the temperature reads the
  // state's ½vᵀMv again until the next step, as before the first.
  void reset() override {
    std::fill(valid_.begin(), valid_.end(), false);
    o_step_kinetic_ = -1.0;
  }
  std::string_view method() const override { return method_; }
  bool checked_finite() const override { return finite_checked_; }
  // Whether the innermost steps run fused (FusedMicroStep: kick, drift and the first term's new
  // force in one pass, then the stage's other terms). Available when the first term
  // (ForceField::evaluation_order: those that offer it first) on the innermost stage's levels
  // offers it — the stiff harmonic bonds: the impulse family's micro steps, and velocity Verlet's
  // whole step. On by default on at most kSmallFusedParticles particles (forcefields/bond_loop.hpp:
  // there the fused step is two plain passes without the thread plan), where the passes' fixed costs
  // dominate; above, the plain passes (kick_drift, then the bond loop's chain blocks) are faster
  // (measured: docs/performance.md, "The fused micro step against the plain one").
  // With Langevin, the micro step whose drift holds the O step (n odd) and velocity Verlet's
  // step (BAOAB: its drift is split by the O step) run plain. Either way gives the same bits
  // (tests, benchmarks switch it).
  bool fused_micro_step() const { return fused_ != nullptr; }
  bool fused_micro_step_available() const { return fused_available_ != nullptr; }
  // On, also the micro steps in molecule blocks where available (blocked_micro_steps); off, the
  // plain path throughout.
  void use_fused_micro_step(bool on) {
    fused_ = on ? fused_available_ : nullptr;
    blocked_ = on && blocked_available_;
  }
  // Whether the impulse family's micro steps run in molecule blocks: every micro step of a block of
  // whole molecules before the next block (FusedMicroStep::kick_drift_forces; forcefields/
  // bond_loop.hpp, MicroStepPlan), all n of them — n/2 and n/2 around the O step with Langevin.
  // Available when the fused term is alone on the innermost level (its force couples a molecule's
  // particles only) and there are two stages or more; on by default at every size, as it reads the
  // particles from memory once per run of micro steps, not three times per micro step
  // (docs/performance.md, "The 256 000-bead melts"). The same bits as the plain path.
  bool blocked_micro_steps() const { return blocked_; }
  void use_blocked_micro_steps(bool on) { blocked_ = on && blocked_available_; }
  double kinetic_energy_estimate(const State& s) const override {
    return o_step_kinetic_ >= 0.0 ? o_step_kinetic_ : s.kinetic_energy();
  }
  // The O steps' ½vᵀMv after − before (BAOAB, OBABO), or the Langevin force's share of the
  // outermost kicks (LangevinForce::kick_heat), summed over the run.
  double thermostat_heat() const override { return heat_; }
  // The projected kick leaves out the bond-normal part f − P(x)f of its level's force (the
  // mollified kick f(α) − α′ᵀf(α)). In the stiff system the bonds stretch until their tension
  // cancels that part on average, so the tension belongs in the pressure although no spring in
  // this dynamics carries it: the virial of −(f − Pf), as RATTLE's constraint force enters its
  // pressure (docs/design.md §3, §4). Summed over the stages, each with its own kick's (0 for a
  // plain one). The cached kick forces are at the current x after a step, so these virials are too.
  double constraint_virial(const State&) override {
    double w = 0.0;
    for (size_t k = 0; k + 1 < stages_.size(); ++k) w -= removed_virial_[k];
    return w;
  }
  // The cached kick force of every stage with its validity (per stage: 1 word, then 3N): a
  // recomputation after a restart could differ in the last bit (the neighbour list may have been
  // moved on by an observation since the force was computed), so the cache itself is saved.
  // With O steps (BAOAB or OBABO), one more word: the kinetic energy at the last O step (−1: none
  // yet); then one word per stage, the kick's removed virial (constraint_virial); with a
  // thermostat inside the step, its heat (thermostat_heat); with the Langevin force, its part of
  // the outermost kick force (3N).
  std::vector<double> save_state() const override;
  CarriedState carried_state() const override;
  void restore_carried_state(CarriedState c) override;
  void load_state(const std::vector<double>& s) override;

 private:
  void advance(State& s, size_t k, double dt);
  void step_obabo(State& s, double h);           // O(½h), the Hamiltonian macro step, O(½h)
  void step_verlet_fused(State& s, double h);    // velocity Verlet's fused step (fused_verlet_)
  void step_langevin_force(State& s, double h);  // the macro step, its outermost kicks' Langevin heat
  bool thermostatted() const { return langevin_ || obabo_ || langevin_force_; }
  void refresh(size_t k, const Eigen::Matrix3Xd& x);
  void run_innermost(State& s, size_t k, double dt, int n);
  void closing_force(State& s, size_t k, double span);
  void micro_step(State& s, size_t k, double dt_kick, double dt, double span);
  void fused_force(State& s, size_t k, double dt_kick, double dt);
  void run_innermost_blocked(State& s, size_t k, double dt, int n);
  // `steps` micro steps of stage k (the innermost) in molecule blocks, the first kicking by first_kick
  void blocked_steps(State& s, size_t k, int steps, double first_kick, double dt);
  void o_step(State& s, double dt);  // the O step, and the kinetic energy just after it
  void kick_drift_o_drift(State& s, size_t k, double dt_kick, double dt, double span);  // in one pass
  // Stage k's closing half kick; the step's last pass over v when k = 0 and no O step or
  // Langevin heat follows it, which then checks the final x and v (checked_finite).
  void closing_kick(State& s, size_t k, double dt);
  // refresh(0), plus the Langevin force when Langevin is a force
  void refresh_outer(State& s, double dt, std::uint64_t substep);

  std::string method_;
  ForceField& forces_;
  std::vector<Stage> stages_;            // every stage but the innermost with its kick (plain where none was given)
  std::vector<Eigen::Matrix3Xd> force_;  // per-stage cached kick force (docs/design.md §11.3)
  std::vector<char> valid_;  // per stage: force_[k] is the force at the current x (char: a plain load per step)
  std::vector<double> removed_virial_;               // per stage: the kick's removed_virial() at its last refresh
  std::unique_ptr<LangevinNoise> langevin_;          // null: Hamiltonian dynamics (or Langevin as a force, or OBABO)
  std::unique_ptr<LangevinNoise> obabo_;             // OBABO: the O(½h) steps around the macro step, else null
  std::uint64_t substep_ = 0;                        // innermost steps taken in this macro step (noise counter)
  double o_step_kinetic_ = -1.0;                     // ½vᵀMv just after the last O step (−1: no step yet)
  const FusedMicroStep* fused_available_ = nullptr;  // the innermost term's fused micro step, if any
  const FusedMicroStep* fused_ = nullptr;            // the one in use (null: kick_drift, then refresh)
  bool blocked_available_ = false;                   // blocked_micro_steps() possible
  bool blocked_ = false;                             // … and in use
  // The innermost stage's terms after the fused one, in evaluation order: the fused step, then
  // these, sum what compute() sums, in its order (ForceField::evaluation_order).
  std::vector<const ForceTerm*> rest_;
  std::vector<Phase> rest_phase_;  // their phases (ForceTerm::phase), looked up once
  // Langevin as a force inside the outermost kick force (splitting "lammps"), or null.
  std::unique_ptr<LangevinForce> langevin_force_;
  Eigen::Matrix3Xd langevin_part_;  // its part of force_[0] (3 × N, sized only with it)
  double heat_ = 0.0;               // thermostat_heat()
  bool finite_checked_ = false;     // checked_finite()
  // One stage, no thermostat: velocity Verlet in NVE, whose step is, when fused, one fused micro
  // step and the closing kick (step_verlet_fused).
  bool fused_verlet_ = false;
};

}  // namespace stiffmd
