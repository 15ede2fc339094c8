// The integrator interface: one macro step of size h, state and h passed as arguments
// (docs/design.md §11.5). Integrators see forces only through ForceField's levels.
#pragma once

#include <array>
#include <memory>
#include <optional>
#include <ostream>
#include <stdexcept>
#include <string>
#include <string_view>
#include <vector>

#include "core/state.hpp"
#include "forcefields/force_field.hpp"
#include "integrators/barostat.hpp"
#include "integrators/thermostat.hpp"

namespace stiffmd {

// How the impulse family turns a slower level's forces into its kick (integrators/kick_forces.hpp;
// docs/design.md §3): K(x) = f(x), P(x) f(x), or α′(x)ᵀ f(α(x)).
enum class Kick { plain, projected, mollified };

inline constexpr std::array<std::string_view, 3> kKickNames = {"plain", "projected", "mollified"};
inline std::string_view kick_name(Kick k) {
  return kKickNames[static_cast<size_t>(k)];
}
// The kick named `name` (as in the deck), or none.
inline std::optional<Kick> find_kick(std::string_view name) {
  for (size_t k = 0; k < kKickNames.size(); ++k)
    if (kKickNames[k] == name) return static_cast<Kick>(k);
  return std::nullopt;
}

// One r-RESPA level of the deck's [[integrator.levels]], innermost first (LAMMPS's numbering):
// substeps is LAMMPS's loop factor, the steps of the next inner level per step of this one
// (1 on the innermost level, which has none). kick: this level's kick strategy, on a level slower
// than the innermost of an impulse-family method; none: the method's own.
struct LevelSettings {
  std::string name;
  int substeps = 1;
  std::optional<Kick> kick;
};

struct IntegratorSettings {
  std::string method = "velocity-verlet";
  double h = 0.0;       // macro step
  int micro_steps = 1;  // n micro steps δ = h/n per macro step (impulse family)
  // Empty: the two levels fast and slow, micro_steps fast steps per slow one. Otherwise the
  // force field's levels (the same names, the same order), and micro_steps is the product of
  // their substeps for the impulse family.
  std::vector<LevelSettings> levels;
  ThermostatSettings thermostat;  // [thermostat]: none, Langevin inside the step, or csvr around it
  BarostatSettings barostat;      // [barostat]: the cell rescaled around the (thermostatted) step
};

// An integrator's state between steps, by kind (Integrator::carried_state).
struct CarriedState {
  std::vector<double> flags;              // the same on every process
  std::vector<double> sums;               // sums over particles: each process its share
  std::vector<Eigen::Matrix3Xd> columns;  // one column per particle
};

// Integrator::save_state() laid out by what it holds, for a checkpoint written by blocks of
// particles (engine/run/checkpoint.hpp): runs of words as they are, and carried columns (column ≥ 0:
// CarriedState::columns[column], its 3 N words where the run stands).
struct WordRun {
  std::vector<double> words;
  int column = -1;
};

class Integrator {
 public:
  virtual ~Integrator() = default;
  // Once, before the first step of a fresh run: methods that live on the constraint
  // manifold project the initial data onto it (paper eq. ACIV) and say so in the log.
  virtual void prepare(State&, std::ostream&) {}
  virtual void step(State& s, double h) = 0;
  // Whether the step just taken found its final x and v finite in its own last pass over them (a
  // closing kick that reads x as it writes v), so that the run needs no pass of its own for the
  // check (engine/run/run.cpp, take_step). false: not checked there, or not finite — the run
  // checks, and names the particle.
  virtual bool checked_finite() const { return false; }
  // Forget cached forces: call when the state was changed other than by step().
  virtual void reset() {}
  virtual std::string_view method() const = 0;
  // Potential energy the integrator's model adds to the force field's at x: W(I, x) =
  // Σ I_k ω_k(x) for the effective dynamics (the averaged energy of the bond vibrations, so
  // that kinetic + U + W is the conserved H_eff of paper eq. (CH)); 0 for the others.
  virtual double model_potential(const Eigen::Matrix3Xd&) { return 0.0; }
  // Σ_i x_i·F_c,i of the rigid-constraint forces at the current state (RATTLE, effective), for
  // the pressure; 0 for methods without rigid constraints. Not const: a method may form the
  // constraint force of its last step only when it is asked for (Rattle under OBABO).
  virtual double constraint_virial(const State&) { return 0.0; }
  // The kinetic energy the temperature and the pressure's kinetic term read. Under Langevin
  // dynamics it is that of the velocities just after the last O step (BAOAB's mid-step
  // velocities): BAOAB's on-step velocities of a vibration of frequency ω read kT(1 − (hω)²/4),
  // those at the O step read kT exactly for harmonic forces (Leimkuhler & Matthews 2013, 2016).
  // Otherwise, and before the first step, the state's ½vᵀMv.
  virtual double kinetic_energy_estimate(const State& s) const { return s.kinetic_energy(); }
  // The heat the thermostat has put into this process's particles since the run began: the sum of
  // the kinetic-energy changes of every velocity change it made (an O step, a Langevin force's
  // share of a kick, a rescaling), each measured on the velocities the Hamiltonian step continues
  // from — under constraints after the velocity projection, whose normal part SHAKE would absorb.
  // E − heat (LAMMPS's econserve; ecouple = −heat) changes only by the integrator's error
  // (docs/design.md §5, the conserved energy). 0 without a thermostat. Part of save_state, a sum
  // in carried_state.
  virtual double thermostat_heat() const { return 0.0; }
  // State the integrator carries beyond (x, v) — cached forces, the constraint force, the
  // effective dynamics' actions — for checkpoints: restoring it (and skipping prepare())
  // continues a run bit for bit. Everything a later step or observable reads must be in it.
  // Constants the method took from the initial state and keeps (the effective dynamics' actions
  // I_k, one per stiff mode in the modes' order: integrators/modes.hpp): what a run whose
  // particles are redistributed among processes must hand to the integrator of each part
  // (docs/parallel.md); the rest of save_state() is recomputed after reset(). Default: none.
  virtual std::vector<double> invariants() const { return {}; }
  virtual void set_invariants(const std::vector<double>& w) {
    if (!w.empty()) throw std::invalid_argument("this integrator keeps no invariants, got some");
  }
  virtual std::vector<double> save_state() const { return {}; }
  // save_state() split by what it belongs to, for a run that redistributes its particles among
  // processes (docs/parallel.md): per-particle columns (the cached kick forces, the constraint
  // force) move with the particles, sums over particles (a kinetic energy, a virial) are each
  // process's share, flags are alike everywhere; the invariants are not in it. After
  // restore_carried_state on an integrator of the particles the columns now belong to (same
  // method and settings), every later step is the one the carrying integrator would have taken.
  virtual CarriedState carried_state() const { return {save_state(), {}, {}}; }
  virtual void restore_carried_state(CarriedState c) { load_state(c.flags); }
  virtual void load_state(const std::vector<double>& s) {
    if (!s.empty()) throw std::invalid_argument("this integrator carries no state, the checkpoint has some");
  }
};

// Builds the integrator named by settings.method (the table in integrators/methods.hpp); throws std::invalid_argument
// for an unknown name or a method the scene cannot run.
std::unique_ptr<Integrator> make_integrator(const IntegratorSettings& settings, ForceField& forces,
                                            const Eigen::VectorXd& inv_mass);

}  // namespace stiffmd
