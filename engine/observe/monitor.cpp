#include "engine/observe/monitor.hpp"

#include <algorithm>
#include <cmath>
#include <optional>
#include <sstream>

#include "core/errors.hpp"
#include "engine/deck/deck.hpp"
#include "engine/observe/observables.hpp"

namespace stiffmd {

constexpr double kViolationFloor = 1e-8;  // length units

bool MonitorSettings::active() const {
  return energy_error < kOff || violation < kOff || violation_growth < kOff || action_drift < kOff || validity ||
         bond_deviation < kOff || temperature_deviation < kOff || energy_runaway < kOff;
}

MonitorSettings read_monitor(DeckTable& root, const MonitorContext& scene) {
  MonitorSettings m;
  auto t = root.table("monitor");
  if (!t) return m;
  // `needs`: why the check could never fire in this scene ("" = it always can).
  auto threshold = [&](const char* key, double& into, const char* needs) {
    if (const auto v = t->maybe_number(key)) {
      t->require(std::isfinite(*v) && *v > 0.0, key, "expected a threshold > 0");
      if (*needs) t->fail(key, std::string("this check could never fire: it needs ") + needs);
      into = *v;
    }
  };
  const char* no_bonds = scene.stiff_bonds ? "" : "constraint-defining stiff bonds (a stiff-harmonic term)";
  const char* no_actions = scene.actions ? "" : "the actions observed ([observables] actions = true)";
  // A check that is on by default where it applies: a number (0 switches it off) or a boolean
  // (false: off; true: the default).
  auto switchable = [&](const char* key, double fallback, double& into, bool& given, const char* needs,
                        const std::vector<std::string>& related = {}) {
    if (!t->has(key)) return;
    given = true;
    std::optional<bool> flag;
    try {
      flag = t->boolean(key, true);
    } catch (const InputError&) {  // not a boolean: a number
    }
    if (flag) {
      into = *flag ? fallback : MonitorSettings::kOff;
    } else {
      const double v = t->number(key);
      t->require(std::isfinite(v) && v >= 0.0, key, "expected a threshold >= 0 (0 or false: off)");
      into = v > 0.0 ? v : MonitorSettings::kOff;
    }
    if (into < MonitorSettings::kOff && *needs)
      t->fail(key, std::string("this check could never fire: it needs ") + needs, related);
  };
  // apply_defaults switches the bath's checks off at kT = 0 (a quench has no temperature to hold).
  const char* no_thermostat = !scene.thermostat ? "a [thermostat]"
                              : scene.quench
                                  ? "a thermostat at kT > 0 (thermostat.temperature = 0 is a quench, with no bath "
                                    "temperature or energy to compare with)"
                                  : "";
  const std::vector<std::string> bath = {"thermostat.temperature"};
  switchable("energy_error", MonitorSettings::kDefaultEnergyError, m.energy_error, m.energy_error_given, "");
  switchable("bond_deviation", MonitorSettings::kDefaultBondDeviation, m.bond_deviation, m.bond_deviation_given,
             no_bonds);
  switchable("temperature_deviation", MonitorSettings::kDefaultTemperatureDeviation, m.temperature_deviation,
             m.temperature_deviation_given, no_thermostat, bath);
  switchable("energy_runaway", MonitorSettings::kDefaultEnergyRunaway, m.energy_runaway, m.energy_runaway_given,
             no_thermostat, bath);
  threshold("violation", m.violation, no_bonds);
  threshold("violation_growth", m.violation_growth, no_bonds);
  threshold("action_drift", m.action_drift, no_actions);
  // validity defaults to true and then applies when it can; asked for explicitly, it must be able to.
  const bool validity_given = t->has("validity");
  m.validity = t->boolean("validity", true);
  if (validity_given && m.validity && *no_actions)
    t->fail("validity", std::string("this check could never fire: it needs ") + no_actions);
  const std::string on = t->string("on_alert", "warn");
  t->require(on == "warn" || on == "stop", "on_alert", "expected \"warn\" or \"stop\"");
  m.stop = on == "stop";
  t->finish();
  return m;
}

void apply_defaults(MonitorSettings& m, const MonitorScene& scene) {
  m.scene = scene;
  if (!m.energy_error_given && scene.conserves_energy) m.energy_error = MonitorSettings::kDefaultEnergyError;
  if (!m.bond_deviation_given && scene.min_bond_length > 0.0) m.bond_deviation = MonitorSettings::kDefaultBondDeviation;
  if (scene.kT > 0.0) {
    if (!m.temperature_deviation_given) m.temperature_deviation = MonitorSettings::kDefaultTemperatureDeviation;
    if (!m.energy_runaway_given) m.energy_runaway = MonitorSettings::kDefaultEnergyRunaway;
  } else {  // no bath to compare with (kT = 0: a quench)
    m.temperature_deviation = m.energy_runaway = MonitorSettings::kOff;
  }
}

Monitor::Monitor(const MonitorSettings& settings, const Thermo& thermo, double epsilon, bool effective)
    : settings_(settings),
      col_step_(thermo.column("step")),
      col_time_(thermo.column("time")),
      col_total_(thermo.column("total")),
      col_kinetic_(thermo.column("kinetic")),
      col_violation_(thermo.column("max_violation")),
      col_gap_(thermo.column("min_gap")),
      col_resonance_(thermo.column("min_resonance")),
      col_temperature_(thermo.column("temperature")),
      sqrt_eps_(epsilon > 0.0 && effective ? std::sqrt(epsilon) : 0.0),
      warned_(8, 0) {
  const int dof = std::max(1, thermo.degrees_of_freedom());
  temperature_band_ = std::max(settings.temperature_deviation, 6.0 * std::sqrt(2.0 / dof));
  bath_energy_ = 0.5 * dof * settings.scene.kT;
  for (int k = 1; thermo.column("action_" + std::to_string(k)) >= 0; ++k)
    col_actions_.push_back(thermo.column("action_" + std::to_string(k)));
}

int Monitor::check(const std::vector<double>& row, double initial_energy, std::ostream& log) {
  if (!have_reference_) {
    violation0_ = row[col_violation_];
    kinetic0_ = row[col_kinetic_];
    for (int c : col_actions_) actions0_.push_back(row[c]);
    have_reference_ = true;
  }
  last_alert_.clear();
  int alerts = 0;
  auto alert = [&](int kind, const std::string& what) {
    ++alerts;
    std::ostringstream m;
    m.precision(6);
    m << "monitor: " << what << " at step " << static_cast<long long>(row[col_step_]) << " (t = " << row[col_time_]
      << ")";
    if (last_alert_.empty()) last_alert_ = m.str();
    if (!warned_[kind]) {
      warned_[kind] = 1;
      log << "warning: " << m.str() << (settings_.stop ? "" : " (further alerts of this kind: thermo column alerts)")
          << "\n";
    }
  };
  auto over = [](double value, double limit) { return !(value <= limit); };  // NaN counts as over
  std::ostringstream w;
  w.precision(6);

  const double e = row[col_total_];
  // Relative to max(|E(0)|, K(0)) (see MonitorSettings::kDefaultEnergyError); absolute when both are 0.
  const double scale = std::max(std::abs(initial_energy), kinetic0_);
  const double rel = scale > 0.0 ? std::abs(e - initial_energy) / scale : std::abs(e - initial_energy);
  if (settings_.energy_error < MonitorSettings::kOff && over(rel, settings_.energy_error)) {
    w << "relative energy error " << rel << " > [monitor] energy_error = " << settings_.energy_error;
    alert(0, w.str());
    w.str("");
  }
  const MonitorScene& sc = settings_.scene;
  const std::string cause = sc.likely_cause.empty() ? "" : " (" + sc.likely_cause + ")";
  if (settings_.energy_runaway < MonitorSettings::kOff) {
    const double energy_scale = std::max({std::abs(initial_energy), kinetic0_, bath_energy_});
    const double grown = std::abs(e - initial_energy) / energy_scale;
    if (over(grown, settings_.energy_runaway)) {
      w << "energy runaway: |E - E(0)| = " << grown
        << " x max(|E(0)|, K(0), dof kT/2) > [monitor] energy_runaway = " << settings_.energy_runaway << cause;
      alert(6, w.str());
      w.str("");
    }
  }
  if (settings_.temperature_deviation < MonitorSettings::kOff && row[col_time_] > 0.0 &&
      row[col_time_] >= 10.0 * sc.relaxation) {
    const double temperature = row[col_temperature_], off = std::abs(temperature / sc.kT - 1.0);
    if (over(off, temperature_band_)) {
      w << "kinetic temperature " << temperature << " is " << off * 100.0 << " % off the thermostat's " << sc.kT
        << " after ten relaxation times (> [monitor] temperature_deviation = " << temperature_band_ << ")" << cause;
      alert(5, w.str());
      w.str("");
    }
  }
  const double g = row[col_violation_];
  if (settings_.bond_deviation < MonitorSettings::kOff && over(g, settings_.bond_deviation * sc.min_bond_length)) {
    w << "a stiff bond deviates from its rest length by " << g << ", " << g / sc.min_bond_length * 100.0
      << " % of the shortest rest length (> [monitor] bond_deviation = " << settings_.bond_deviation << ")" << cause;
    alert(4, w.str());
    w.str("");
  }
  if (settings_.violation < MonitorSettings::kOff && over(g, settings_.violation)) {
    w << "constraint violation max|g| = " << g << " > [monitor] violation = " << settings_.violation;
    alert(1, w.str());
    w.str("");
  }
  // Growth over the initial violation, floored at kViolationFloor: a state projected onto the
  // constraints (RATTLE, effective) starts at round-off, which may grow tenfold harmlessly.
  const double g0 = std::max(violation0_, kViolationFloor);
  if (settings_.violation_growth < MonitorSettings::kOff && over(g / g0, settings_.violation_growth)) {
    w << "constraint violation grew " << g / g0 << "-fold (max|g| " << violation0_ << " -> " << g
      << ") > [monitor] violation_growth = " << settings_.violation_growth;
    alert(2, w.str());
    w.str("");
  }
  if (settings_.action_drift < MonitorSettings::kOff) {
    // Relative to the largest initial action: a mode that starts (nearly) unexcited has I_k(0) ≈ 0,
    // and its own relative change says nothing.
    double scale = 0.0;
    for (const double i0 : actions0_) scale = std::max(scale, std::abs(i0));
    if (scale == 0.0) scale = 1.0;
    double worst = 0.0;
    int worst_k = 0;
    for (std::size_t k = 0; k < col_actions_.size(); ++k) {
      const double d = std::abs(row[col_actions_[k]] - actions0_[k]) / scale;
      if (!(d <= worst)) {
        worst = d;
        worst_k = static_cast<int>(k);
      }
    }
    if (!col_actions_.empty() && over(worst, settings_.action_drift)) {
      w << "action I_" << worst_k + 1 << " drifted by " << worst
        << " (relative to max_k I_k(0)) > [monitor] action_drift = " << settings_.action_drift;
      alert(3, w.str());
      w.str("");
    }
  }
  if (settings_.validity && sqrt_eps_ > 0.0 && col_gap_ >= 0) {
    // −1 in the thermo columns: no pair (triple) of modes to compare.
    const double gap = row[col_gap_], res = row[col_resonance_];
    const bool near_gap = gap >= 0.0 && gap < sqrt_eps_, near_res = res >= 0.0 && res < sqrt_eps_;
    if (near_gap || near_res) {
      w << (near_gap ? "frequency gap " : "resonance ") << (near_gap ? gap : res) << " < sqrt(eps) = " << sqrt_eps_
        << ": the effective dynamics is not valid here";
      ++alerts;  // Thermo has said it in the log already; count it, and stop if asked to
      if (last_alert_.empty()) {
        std::ostringstream m;
        m << "monitor: " << w.str() << " at step " << static_cast<long long>(row[col_step_])
          << " (t = " << row[col_time_] << ")";
        last_alert_ = m.str();
      }
    }
  }
  return alerts;
}

// Words: have_reference, violation0, the warned flags, then actions0.
std::vector<double> Monitor::save_state() const {
  std::vector<double> w = {have_reference_ ? 1.0 : 0.0, violation0_};
  for (const char c : warned_) w.push_back(c);
  w.insert(w.end(), actions0_.begin(), actions0_.end());
  return w;
}

bool Monitor::load_state(const std::vector<double>& w) {
  const size_t fixed = 2 + warned_.size();
  const bool have = w.size() > 0 && w[0] != 0.0;
  if (w.size() < fixed || w.size() != fixed + (have ? col_actions_.size() : 0)) return false;
  have_reference_ = have;
  violation0_ = w[1];
  for (size_t k = 0; k < warned_.size(); ++k) warned_[k] = w[2 + k] != 0.0;
  actions0_.assign(w.begin() + static_cast<std::ptrdiff_t>(fixed), w.end());
  return true;
}

}  // namespace stiffmd
