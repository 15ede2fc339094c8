// Observables computed from a state: the thermo row (time, energies, constraint violation
// and, when asked for, frequencies ω_k and actions I_k, docs/design.md §4) and the projected
// momenta P(x)p (paper eq. (proj)).
#pragma once

#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "core/state.hpp"
#include "core/topology.hpp"
#include "core/units.hpp"
#include "engine/observe/polymer_observables.hpp"
#include "forcefields/force_field.hpp"
#include "integrators/barostat.hpp"
#include "integrators/constraints.hpp"
#include "integrators/modes.hpp"
#include "integrators/thermostat.hpp"

namespace stiffmd {

struct Energies {
  double kinetic = 0.0;
  double slow = 0.0;             // U(x): every term on a level outside the innermost
  double stiff = 0.0;            // ε⁻²V(x) and anything else integrated on the fast (innermost) level
  double fixman = 0.0;           // Fixman's U_F (the fixman method's model potential), else 0
  std::vector<double> by_level;  // each level's potential energy, innermost first
  double total() const { return kinetic + slow + stiff + fixman; }
};

Energies energies(const State& s, const ForceField& forces);

// max_b |g_b(x)| = max_b | |x_i − x_j| − ℓ_b | over the constraint-defining bonds (0 if none):
// max_violation (forcefields/stiff_bond.hpp), the toolbox's own.
double max_constraint_violation(const Eigen::Matrix3Xd& x, const StiffBonds* stiff);

struct ObservableSettings {
  bool actions = false;        // ω_k, I_k and the validity monitor in the thermo output
  int max_cluster_bonds = 64;  // clusters with more bonds are skipped (said in the log)
  int rigid_constraints = 0;   // degrees of freedom removed by rigid constraints (RATTLE, effective)
  // [thermostat] style: Langevin noise does not conserve the total momentum (3 more dof).
  ThermostatSettings::Style thermostat = ThermostatSettings::Style::none;
  bool histograms = true;  // bond-length and angle histograms at the end (when there are bonds)
  // The method's model potential is Fixman's U_F, a free energy (kT Σ_k log ω_k up to a constant:
  // on polyethylene −55.8 kcal/mol), not an energy of the springs: it gets its own column potential_fixman
  // (in the total), and potential_stiff stays the stiff level's energy. The effective dynamics'
  // W = Σ I_k ω_k is the averaged energy of the bond vibrations and stays in potential_stiff.
  bool fixman = false;
  // With the actions: what a frequency gap or resonance below √ε means for the method, said once
  // each in the log. effective: a method whose solution follows the effective dynamics
  // (MethodInfo::follows_effective) — a warning that it loses validity there; actions: a method that
  // resolves the vibrations (velocity Verlet, impulse) — a note that the actions may jump there;
  // none: rigid bonds without the effective dynamics (rattle, fixman), which have no vibrations.
  enum class Resonances { none, actions, effective };
  Resonances resonances = Resonances::none;
  // A [barostat]: the columns volume, density and molecular_pressure (integrators/barostat.hpp).
  bool barostat = false;
};

// What the thermo row sums over particles and terms (Thermo::sums): each of a decomposed run's
// ranks sums its part, and the ranks' sums add up to the whole system's (docs/parallel.md).
struct ThermoSums {
  double kinetic = 0.0;                // ½ vᵀMv
  std::vector<double> level_energy;    // the potential energy of each level, innermost first
  double virial = 0.0;                 // Σ r·f of the force terms (the pressure's)
  double coulomb = 0.0, kspace = 0.0;  // ecoul and elong (ForceField::last_coulomb_energy, …)
  double vdwl = 0.0;                   // evdwl (ForceField::last_vdwl_energy)
  double rg = 0.0, end_to_end = 0.0;   // summed over the molecules (Molecules::sum)
  double molecules = 0.0, sized = 0.0;
  double max_violation = 0.0;  // not a sum: the largest over the ranks
  // Under a barostat, 2K_com + W_mol summed over the axes (MolecularPressure); whole state only.
  double molecular = 0.0;
  // The sums as one array (kinetic, level_energy…, virial, rg, end_to_end, molecules, sized,
  // coulomb, kspace, vdwl), to add up over the ranks, and back.
  std::vector<double> flat() const;
  void set_flat(const std::vector<double>& v);
};

// The whole system's numbers that fix a thermo row's columns besides the force field's: what a
// decomposed run sums from its parts at the start (DomainIntegrator::thermo_numbers), so that its
// Thermo reads no per-particle array or topology of the whole system.
struct ThermoNumbers {
  int degrees_of_freedom = 0;  // of the temperature column (degrees_of_freedom, integrators/thermostat.hpp)
  bool rg = false;             // some topology molecule of two or more particles: the rg column
  bool end_to_end = false;     // some of them a linear chain or a ring: the end_to_end column
};

// What a thermo column measures (time, energy, temperature, …), for the units it is written in.
Dimension thermo_column_dimension(const std::string& column);

// One row of thermo output: named columns, fixed for a run. The last column, alerts, is 0 here;
// the run loop's Monitor fills it in (engine/observe/monitor.hpp).
class Thermo {
 public:
  // topology may be null (no molecules, no polymer columns).
  Thermo(const ForceField& forces, const Eigen::VectorXd& inv_mass, const ObservableSettings& settings,
         const Topology* topology = nullptr);
  // The same columns from the whole system's numbers (summed elsewhere: a decomposed run's parts),
  // for rows sampled from sums only (sample(s, sums, …)): the columns that need the whole state — the
  // actions and a barostat's molecular pressure — are refused (std::logic_error), and sums(s) gives
  // no polymer sums. settings.rigid_constraints is not read: the numbers' degrees of freedom count
  // them.
  Thermo(const ForceField& forces, const ThermoNumbers& numbers, const ObservableSettings& settings);
  const std::vector<std::string>& columns() const { return columns_; }
  // Values for the current state; energy_drift is relative to the first call's total energy.
  // model_potential (W of the effective dynamics) is counted in potential_stiff, or under fixman
  // (Fixman's U_F) in potential_fixman; both in the total.
  // constraint_virial (Σ x·F_c of rigid constraints) is added to the pressure's virial.
  // kinetic_estimate (Integrator::kinetic_energy_estimate; < 0: the state's ½vᵀMv) is the kinetic
  // energy of the temperature and of the pressure's kinetic term: under Langevin, that of the
  // velocities at the O step. The kinetic, total and energy_drift columns stay the state's.
  // heat (Integrator::thermostat_heat) gives, with a thermostat, ecouple = −heat and econserve =
  // total + ecouple (docs/design.md §5, the conserved energy).
  const std::vector<double>& sample(const State& s, double model_potential = 0.0, double constraint_virial = 0.0,
                                    double kinetic_estimate = -1.0, double heat = 0.0);
  // The same from sums taken elsewhere (a decomposed run's parts, added up): s gives the time and
  // the step. Not with the actions (modes(): std::logic_error), which need the whole state.
  const std::vector<double>& sample(const State& s, const ThermoSums& sums, double model_potential,
                                    double constraint_virial, double kinetic_estimate, double heat);
  // The sums of the row at state s (of this Thermo's force field: a part's share in a decomposed
  // run).
  ThermoSums sums(const State& s) const;
  // The reference sample's total energy E(0), conserved energy E_c(0) = E(0) + ecouple(0) and time:
  // the first sample's, or the next one's after take_reference_at_next_sample().
  double initial_energy() const { return e0_; }
  double initial_conserved_energy() const { return ec0_; }
  double initial_time() const { return t0_; }
  // A state set from outside: energy_drift (and the conserved energy's drift) from the next sample on.
  void take_reference_at_next_sample() { have_e0_ = false; }
  // For checkpoints: the reference sample's E(0), E_c(0) and time, and which validity warnings
  // were given (each is said once per run).
  std::vector<double> save_state() const {
    return {have_e0_ ? 1.0 : 0.0, e0_, warned_gap_ ? 1.0 : 0.0, warned_resonance_ ? 1.0 : 0.0, ec0_, t0_};
  }
  bool load_state(const std::vector<double>& w) {  // false: not a Thermo state
    if (w.size() != 6) return false;
    have_e0_ = w[0] != 0.0, e0_ = w[1], warned_gap_ = w[2] != 0.0, warned_resonance_ = w[3] != 0.0;
    ec0_ = w[4], t0_ = w[5];
    return true;
  }
  int column(const std::string& name) const;
  // Degrees of freedom of the temperature column, T = 2K/dof.
  int degrees_of_freedom() const { return dof_; }
  // The modes, when actions were asked for (nullptr otherwise).
  const StiffModes* modes() const { return modes_.get(); }
  // Under a barostat: the molecular pressure needs the whole state (no sums by parts).
  bool has_molecular_pressure() const { return molecular_ != nullptr; }
  // The numbers this Thermo's columns were made with: a part's are its share (its molecules' counts).
  int molecules() const { return molecules_ ? molecules_->count() : 0; }
  int sized_molecules() const { return molecules_ ? molecules_->sized() : 0; }
  // Notes for the log: skipped clusters; validity warnings (frequency gap or resonance below
  // √ε, said once each, with step and time; ObservableSettings::resonances). Taken
  // (cleared) by the caller.
  std::vector<std::string> take_notes() { return std::move(notes_); }

 private:
  const ForceField* forces_;  // a pointer: a Thermo made again after a decomposed run's start is assigned
  bool level_columns_;        // a potential_<level> column per named level
  bool coulomb_column_ = false, kspace_column_ = false;  // evdwl and ecoul, elong
  bool fixman_;      // ObservableSettings::fixman: the model potential in potential_fixman
  bool thermostat_;  // a [thermostat]: the ecouple and econserve columns
  int dof_ = 0;
  bool periodic_ = false;  // the box is periodic on every axis: pressure column (V: the box now)
  double mass_ = 0.0;      // Σ m, for the density
  mutable std::unique_ptr<MolecularPressure> molecular_;  // a [barostat]'s columns
  mutable Eigen::Matrix3Xd molecular_scratch_;
  std::unique_ptr<Molecules> molecules_;  // the whole topology's (none when made from ThermoNumbers)
  bool rg_column_ = false, end_to_end_column_ = false;
  bool from_numbers_ = false;  // made from ThermoNumbers: rows from sums only
  std::unique_ptr<StiffModes> modes_;
  Eigen::VectorXd omega_, actions_;
  double sqrt_eps_ = 0.0;
  ObservableSettings::Resonances resonances_ = ObservableSettings::Resonances::none;
  bool warned_gap_ = false, warned_resonance_ = false;
  std::vector<std::string> columns_;
  std::vector<double> values_;
  std::vector<std::string> notes_;
  // The columns up to the energies by level (both constructors' first part), then those after the
  // box's (the barostat's, rg, end_to_end, the actions', alerts).
  void energy_columns();
  void polymer_and_mode_columns();
  // The row of sums taken at s (which gives the time, the step and, for the actions, x and v).
  const std::vector<double>& row(const State& s, const ThermoSums& sums, double model_potential,
                                 double constraint_virial, double kinetic_estimate, double heat);
  bool have_e0_ = false;
  double e0_ = 0.0, ec0_ = 0.0, t0_ = 0.0;
};

// The thermo row as the outputs show it (thermo CSV, H5MD observables, the terminal line, the Python
// module's thermo()): the one place where the written columns are formed from Thermo's. With norm
// (the deck's [output] thermo_norm, LAMMPS's `thermo_modify norm yes`) the extensive columns — the
// energies kinetic, potential_slow, potential_stiff (every potential_* column), total,
// energy_drift, ecouple and econserve — are divided by the number of particles N and named with the suffix "_per_atom";
// intensive ones (temperature, pressure, rg, …) stay. Then each column is in the deck's units:
// times Units::out of its dimension (thermo_column_dimension; real: time in fs, T in K, p in atm).
class ThermoOutput {
 public:
  ThermoOutput(const Thermo& thermo, int num_particles, bool norm, const Units& units);
  const std::vector<std::string>& columns() const { return columns_; }
  int column(const std::string& thermo_name) const;  // index of Thermo's column `thermo_name`, −1 if none
  bool normalised(int column) const { return divide_[column]; }
  // The written row for one of Thermo's rows (valid until the next call).
  const std::vector<double>& operator()(const std::vector<double>& row);

 private:
  const Thermo& thermo_;
  double n_;
  std::vector<std::string> columns_;
  std::vector<char> divide_;
  std::vector<double> scale_;  // per column: engine value → the deck's unit (all 1 in reduced units)
  std::vector<double> row_;
};

// P(x)p as velocities-times-mass: p ↦ M (v − M⁻¹Gᵀμ), S μ = G v (the tangential momenta).
class ProjectedMomenta {
 public:
  ProjectedMomenta(const StiffBonds& stiff, const Eigen::VectorXd& inv_mass);
  const Eigen::Matrix3Xd& operator()(const State& s);

 private:
  ConstraintToolbox toolbox_;
  Eigen::Matrix3Xd p_;
};

}  // namespace stiffmd
