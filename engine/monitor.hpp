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

struct MonitorSettings {
  static constexpr double kOff = std::numeric_limits<double>::infinity();
  double energy_error = kOff;      // |E(t) − E(0)| / |E(0)|  (absolute when E(0) = 0)
  double violation = kOff;         // max_b |g_b(x)|, in length units
  double violation_growth = kOff;  // max_b |g_b(x)| / max(max_b |g_b(x(0))|, 1e-8)
  double action_drift = kOff;      // max_k |I_k(t) − I_k(0)| / max_k |I_k(0)|  (observables.actions)
  bool validity = true;            // effective: min frequency gap or resonance < √ε (observables.actions)
  bool stop = false;               // on_alert = "stop" (else "warn")

  bool active() const;  // any check configured
};

// What the scene observes, so that a check that could never fire is refused rather than silent.
struct MonitorContext {
  bool stiff_bonds = false;  // a constraint-defining term: violation, violation_growth
  bool actions = false;      // [observables] actions = true: action_drift, validity
};

// Reads [monitor] (absent: the defaults, validity only). Throws InputError at the key of a check
// the scene cannot evaluate (action_drift without observed actions, violation without stiff bonds).
MonitorSettings read_monitor(DeckTable& root, const MonitorContext& scene);

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
  int col_step_, col_time_, col_total_, col_violation_, col_gap_, col_resonance_;
  std::vector<int> col_actions_;
  double sqrt_eps_;
  bool have_reference_ = false;
  double violation0_ = 0.0;
  std::vector<double> actions0_;
  std::vector<char> warned_;
  std::string last_alert_;
};

}  // namespace stiffmd
