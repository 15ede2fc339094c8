// Self-monitoring of a run (the deck's [monitor] table): at every thermo sample, the relative
// energy error, the constraint violation and its growth, the actions' drift (when observed) and
// the validity of the effective dynamics (frequency gap or resonance below √ε, paper §4) are
// compared with thresholds. A check over its threshold is an alert: logged with step and time
// the first time it happens, counted in the thermo column `alerts`, and, with on_alert = "stop",
// the end of the run (NumericalError, exit 3) after the last state within the thresholds has been
// written as the checkpoint. Non-finite positions or velocities stop every run anyway (exit 3).
#pragma once

#include <limits>
#include <ostream>
#include <string>
#include <vector>

namespace stiffmd {

class DeckTable;
class Thermo;

// What the defaults and the temperature check need to know of the scene (engine units).
struct MonitorScene {
  bool conserves_energy = true;  // no thermostat
  double min_bond_length = 0.0;  // of the stiff bonds; 0: none
  double kT = 0.0;               // the thermostat's; 0: none
  double relaxation = 0.0;       // the thermostat's slowest relaxation time (1/γ, or csvr's tau)
  // Appended to a bond-deviation or temperature alert: what most likely made the run leave its
  // model (load_scene: e.g. a temperature in kelvin in reduced units).
  std::string likely_cause;
};

struct MonitorSettings {
  static constexpr double kOff = std::numeric_limits<double>::infinity();
  // The energy check every energy-conserving run gets unless its deck says otherwise. The error is
  // |E(t) − E(0)| / max(|E(0)|, K(0)), K the kinetic energy of the first sample: relative to |E(0)|
  // alone it is meaningless when E(0) ≈ 0 (a liquid whose potential cancels its kinetic energy),
  // and K(0) is the thermal energy scale, so 1 % of it is a temperature error of about 1 %.
  // Measured on the bundled decks' own runs (inputs/*.toml): at most 0.3 % (the LAMMPS chain's
  // bond-thermalisation transient) apart from the hanging chain's documented breakdown, while runs
  // that have left their model reach 3 % (lammps_chain to t = 10) and 11 % (the melt at projected
  // impulse, t = 40): 1 % separates the two.
  static constexpr double kDefaultEnergyError = 0.01;
  double energy_error = kOff;       // see kDefaultEnergyError; kOff: no energy check
  bool energy_error_given = false;  // the deck set energy_error (a number, 0 or false = off)

  // The checks that catch a run which has left its model without a non-finite number (a
  // temperature in kelvin in reduced units, a step the thermostat cannot hold). Each is on by
  // default where it applies (apply_defaults), and off with 0 or false.
  // A stiff bond deviating from its rest length by more than this fraction of it, max_b |g_b| >
  // f min_b ℓ_b, is no longer a stiff bond. The loosest bundled deck, inputs/nvt_trimers.toml
  // (rms vibration ε√kT/α = 0.1 ℓ), reaches 0.44 ℓ over its 400 bonds and 100 samples (4.4
  // standard deviations); a bond as long again as its rest length, or collapsed, is 10.
  static constexpr double kDefaultBondDeviation = 1.0;
  double bond_deviation = kOff;
  bool bond_deviation_given = false;
  // Thermostatted runs, once the bath has had ten relaxation times: the kinetic temperature
  // further from the thermostat's than this fraction of it, or than six standard deviations of
  // its equilibrium fluctuation (√(2/dof) relative), whichever is larger.
  static constexpr double kDefaultTemperatureDeviation = 0.5;
  double temperature_deviation = kOff;
  bool temperature_deviation_given = false;
  // Thermostatted runs: |E − E(0)| beyond this many times max(|E(0)|, K(0), dof kT/2), the energy
  // scale of the start and of the bath (NVE runs have energy_error).
  static constexpr double kDefaultEnergyRunaway = 10.0;
  double energy_runaway = kOff;
  bool energy_runaway_given = false;
  double violation = kOff;         // max_b |g_b(x)|, in length units
  double violation_growth = kOff;  // max_b |g_b(x)| / max(max_b |g_b(x(0))|, 1e-8)
  double action_drift = kOff;      // max_k |I_k(t) − I_k(0)| / max_k |I_k(0)|  (observables.actions)
  bool validity = true;            // effective: min frequency gap or resonance < √ε (observables.actions)
  bool stop = false;               // on_alert = "stop" (else "warn")
  MonitorScene scene;              // apply_defaults

  bool active() const;  // any check configured
};

// What the scene observes, so that a check that could never fire is refused rather than silent.
struct MonitorContext {
  bool stiff_bonds = false;  // a constraint-defining term: violation, violation_growth, bond_deviation
  bool actions = false;      // [observables] actions = true: action_drift, validity
  bool thermostat = false;   // a [thermostat]: temperature_deviation, energy_runaway
  bool quench = false;       // the thermostat's kT is 0: no bath temperature or energy to compare with
};

// Reads [monitor] (absent: the defaults, validity only; energy_error is set by
// apply_energy_default). Throws InputError at the key of a check
// the scene cannot evaluate (action_drift without observed actions, violation without stiff bonds,
// temperature_deviation or energy_runaway without a thermostat at kT > 0).
MonitorSettings read_monitor(DeckTable& root, const MonitorContext& scene);

// The defaults of the checks the deck did not set, where they apply: the energy check
// (kDefaultEnergyError) for a run whose energy should be conserved (a thermostatted run exchanges
// energy with its bath by design), the bond deviation with stiff bonds, the temperature and the
// energy runaway with a thermostat at kT > 0. Keeps the scene's facts for Monitor.
void apply_defaults(MonitorSettings& m, const MonitorScene& scene);

class Monitor {
 public:
  // epsilon: of the stiff bonds (0: no validity check). The validity check applies to the
  // effective dynamics only (effective = true): the other methods do not rely on it.
  Monitor(const MonitorSettings& settings, const Thermo& thermo, double epsilon, bool effective);

  // Checks one thermo row (Thermo::sample's columns); returns the number of alerts. Logs each
  // kind of alert the first time it occurs. The first row is the reference (t = 0; a restart
  // takes it from the checkpoint, load_state).
  int check(const std::vector<double>& row, double initial_energy, std::ostream& log);
  // The message of the first alert of the last check (for a stop).
  const std::string& last_alert() const { return last_alert_; }
  bool stops() const { return settings_.stop; }
  // For checkpoints: the reference (first) sample and which alerts were logged already.
  std::vector<double> save_state() const;
  bool load_state(const std::vector<double>& w);  // false: not a state of this monitor

 private:
  MonitorSettings settings_;
  int col_step_, col_time_, col_total_, col_kinetic_, col_violation_, col_gap_, col_resonance_, col_temperature_;
  double temperature_band_ = 0.0;  // relative: max(temperature_deviation, 6 √(2/dof))
  double bath_energy_ = 0.0;       // dof kT / 2
  std::vector<int> col_actions_;
  double sqrt_eps_;
  bool have_reference_ = false;
  double violation0_ = 0.0;
  double kinetic0_ = 0.0;
  std::vector<double> actions0_;
  std::vector<char> warned_;
  std::string last_alert_;
};

}  // namespace stiffmd
