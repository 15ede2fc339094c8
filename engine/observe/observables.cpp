#include "engine/observe/observables.hpp"

#include <algorithm>
#include <cmath>
#include <sstream>
#include <stdexcept>

namespace stiffmd {

Energies energies(const State& s, const ForceField& forces) {
  Energies e;
  e.kinetic = s.kinetic_energy();
  // By level, innermost first: the innermost is the stiff one, the others are U (docs/design.md §1).
  for (int k = forces.num_levels() - 1; k >= 0; --k) {
    const double u = forces.energy(s.x, Level{k});
    e.by_level.push_back(u);
    if (k > 0)
      e.slow += u;
    else
      e.stiff = u;
  }
  std::reverse(e.by_level.begin(), e.by_level.end());
  return e;
}

Dimension thermo_column_dimension(const std::string& c) {
  const auto starts = [&](const char* prefix) { return c.rfind(prefix, 0) == 0; };
  if (c == "time") return Dimension::time;
  if (c == "kinetic" || c == "total" || c == "energy_drift" || c == "ecouple" || c == "econserve" || c == "evdwl" ||
      c == "ecoul" || c == "elong" || starts("potential_"))
    return Dimension::energy;
  if (c == "max_violation" || c == "rg" || c == "end_to_end" || c == "lx" || c == "ly" || c == "lz")
    return Dimension::length;
  if (c == "temperature") return Dimension::temperature;
  if (c == "pressure" || c == "molecular_pressure") return Dimension::pressure;
  if (c == "volume") return Dimension::volume;
  if (c == "density") return Dimension::density;
  if (starts("omega_") || c == "min_gap" || c == "min_resonance") return Dimension::frequency;
  if (starts("action_")) return Dimension::action;
  return Dimension::none;  // step, alerts
}

double max_constraint_violation(const Eigen::Matrix3Xd& x, const StiffBonds* stiff) {
  return stiff ? max_violation(stiff->bonds, x) : 0.0;
}

Thermo::Thermo(const ForceField& forces, const Eigen::VectorXd& inv_mass, const ObservableSettings& settings,
               const Topology* topology)
    : forces_(&forces),
      level_columns_(!(forces.num_levels() == 2 && forces.level_name(Level::fast) == "fast" &&
                       forces.level_name(Level::slow) == "slow")),
      fixman_(settings.fixman),
      thermostat_(settings.thermostat != ThermostatSettings::Style::none) {
  energy_columns();
  // The kinetic temperature's degrees of freedom (integrators/thermostat.hpp): total momentum
  // counts as conserved only without fixed particles, external fields and Langevin noise.
  ThermostatSettings thermostat;
  thermostat.style = settings.thermostat;
  dof_ = stiffmd::degrees_of_freedom(inv_mass, momentum_conserved(forces, inv_mass, thermostat),
                                     settings.rigid_constraints);
  if (settings.barostat && periodic_ && topology) {
    for (Eigen::Index i = 0; i < inv_mass.size(); ++i) mass_ += inv_mass[i] > 0 ? 1.0 / inv_mass[i] : 0.0;
    molecular_ =
        std::make_unique<MolecularPressure>(bonded_molecules(*topology, static_cast<int>(inv_mass.size())), inv_mass);
  }
  if (topology) {
    Eigen::VectorXd mass = inv_mass;
    for (Eigen::Index i = 0; i < mass.size(); ++i) mass[i] = inv_mass[i] > 0 ? 1.0 / inv_mass[i] : 0.0;
    molecules_ = std::make_unique<Molecules>(*topology, inv_mass, mass);
    if (molecules_->empty()) molecules_.reset();
    rg_column_ = molecules_ != nullptr;
    end_to_end_column_ = molecules_ && molecules_->has_end_to_end();  // no chain or ring: none
  }
  const StiffBonds* stiff = forces.stiff_bonds();
  if (settings.actions && stiff) {
    modes_ = std::make_unique<StiffModes>(stiff->bonds, inv_mass, stiff->epsilon, settings.max_cluster_bonds);
    if (modes_->num_skipped_clusters() > 0)
      notes_.push_back("note: actions and frequencies skipped for " + std::to_string(modes_->num_skipped_clusters()) +
                       " constraint cluster(s) with more than observables.max_cluster_bonds = " +
                       std::to_string(settings.max_cluster_bonds) + " bonds");
    const int m = modes_->num_modes();
    omega_.resize(m);
    actions_.resize(m);
    sqrt_eps_ = std::sqrt(stiff->epsilon);
    resonances_ = settings.resonances;
  }
  polymer_and_mode_columns();
}

Thermo::Thermo(const ForceField& forces, const ThermoNumbers& numbers, const ObservableSettings& settings)
    : forces_(&forces),
      level_columns_(!(forces.num_levels() == 2 && forces.level_name(Level::fast) == "fast" &&
                       forces.level_name(Level::slow) == "slow")),
      fixman_(settings.fixman),
      thermostat_(settings.thermostat != ThermostatSettings::Style::none),
      dof_(numbers.degrees_of_freedom),
      rg_column_(numbers.rg),
      end_to_end_column_(numbers.rg && numbers.end_to_end),
      from_numbers_(true) {
  if (settings.actions && forces.stiff_bonds())
    throw std::logic_error("Thermo: the actions need the whole state, not the whole system's numbers");
  energy_columns();
  if (settings.barostat && periodic_)
    throw std::logic_error("Thermo: a barostat's molecular pressure needs the whole state");
  polymer_and_mode_columns();
}

void Thermo::energy_columns() {
  const ForceField& forces = *forces_;
  columns_ = {"time", "step", "kinetic", "potential_slow", "potential_stiff"};
  if (fixman_) columns_.push_back("potential_fixman");
  columns_.insert(columns_.end(), {"total", "energy_drift", "max_violation", "temperature"});
  // The heat exchanged with the thermostat and the energy conserved with it (LAMMPS's ecouple and
  // econserve): econserve drifts only by the integrator's error (docs/design.md §5).
  if (thermostat_) columns_.insert(columns_.end(), {"ecouple", "econserve"});
  // Named r-RESPA levels (other than the default fast and slow): one column each.
  if (level_columns_)
    for (int k = 0; k < forces.num_levels(); ++k) columns_.push_back("potential_" + forces.level_name(Level{k}));
  // A charged scene: the pair energy split as LAMMPS's evdwl (the van der Waals rest, tail and 1-4
  // Lennard-Jones included) and ecoul (real-space and 1-4 Coulomb pairs), and the k-space terms'
  // (elong), all also in potential_*.
  coulomb_column_ = forces.has_charges();
  kspace_column_ = forces.has_kspace();
  if (coulomb_column_) columns_.insert(columns_.end(), {"evdwl", "ecoul"});
  if (kspace_column_) columns_.push_back("elong");
  if (forces.box().periodic.all()) {
    periodic_ = true;
    columns_.push_back("pressure");
  }
}

void Thermo::polymer_and_mode_columns() {
  if (molecular_) columns_.insert(columns_.end(), {"volume", "lx", "ly", "lz", "density", "molecular_pressure"});
  if (rg_column_) columns_.push_back("rg");
  if (end_to_end_column_) columns_.push_back("end_to_end");
  if (modes_) {
    const int m = modes_->num_modes();
    for (int k = 1; k <= m; ++k) columns_.push_back("omega_" + std::to_string(k));
    for (int k = 1; k <= m; ++k) columns_.push_back("action_" + std::to_string(k));
    columns_.push_back("min_gap");
    columns_.push_back("min_resonance");
  }
  columns_.push_back("alerts");  // filled in by the run's Monitor (engine/observe/monitor.hpp)
  values_.resize(columns_.size());
}

int Thermo::column(const std::string& name) const {
  for (size_t k = 0; k < columns_.size(); ++k)
    if (columns_[k] == name) return static_cast<int>(k);
  return -1;
}

std::vector<double> ThermoSums::flat() const {
  std::vector<double> v{kinetic};
  v.insert(v.end(), level_energy.begin(), level_energy.end());
  v.insert(v.end(), {virial, rg, end_to_end, molecules, sized, coulomb, kspace, vdwl});
  return v;
}

void ThermoSums::set_flat(const std::vector<double>& v) {
  const size_t levels = v.size() - 9;
  kinetic = v[0];
  level_energy.assign(v.begin() + 1, v.begin() + 1 + static_cast<std::ptrdiff_t>(levels));
  virial = v[1 + levels], rg = v[2 + levels], end_to_end = v[3 + levels];
  molecules = v[4 + levels], sized = v[5 + levels];
  coulomb = v[6 + levels], kspace = v[7 + levels], vdwl = v[8 + levels];
}

ThermoSums Thermo::sums(const State& s) const {
  if (from_numbers_) throw std::logic_error("Thermo::sums: made from the whole system's numbers, it samples sums only");
  ThermoSums sums;
  sums.kinetic = s.kinetic_energy();
  forces_->energies_and_virial(s.x, sums.level_energy, sums.virial);
  sums.coulomb = forces_->last_coulomb_energy();
  sums.vdwl = forces_->last_vdwl_energy();
  sums.kspace = forces_->last_kspace_energy();
  sums.max_violation = max_constraint_violation(s.x, forces_->stiff_bonds());
  if (molecular_) {
    molecular_->locate(s);
    sums.molecular = molecular_->virial_and_kinetic(s, *forces_, molecular_scratch_).sum();
  }
  if (molecules_) {
    molecules_->sum(s.x, sums.rg, sums.end_to_end);
    sums.molecules = molecules_->count();
    sums.sized = molecules_->sized();
  }
  return sums;
}

const std::vector<double>& Thermo::sample(const State& s, double model_potential, double constraint_virial,
                                          double kinetic_estimate, double heat) {
  return row(s, sums(s), model_potential, constraint_virial, kinetic_estimate, heat);
}

const std::vector<double>& Thermo::sample(const State& s, const ThermoSums& sums, double model_potential,
                                          double constraint_virial, double kinetic_estimate, double heat) {
  if (modes_) throw std::logic_error("Thermo::sample: the actions need the whole state, not sums");
  return row(s, sums, model_potential, constraint_virial, kinetic_estimate, heat);
}

const std::vector<double>& Thermo::row(const State& s, const ThermoSums& sums, double model_potential,
                                       double constraint_virial, double kinetic_estimate, double heat) {
  // The energies by level, innermost first: the innermost is the stiff one, the others are U
  // (docs/design.md §1), added from the outermost in.
  Energies e;
  e.kinetic = sums.kinetic;
  e.by_level = sums.level_energy;
  for (int k = static_cast<int>(e.by_level.size()) - 1; k >= 0; --k)
    if (k > 0)
      e.slow += e.by_level[k];
    else
      e.stiff = e.by_level[k];
  const double thermal_kinetic = kinetic_estimate >= 0.0 ? kinetic_estimate : e.kinetic;
  (fixman_ ? e.fixman : e.stiff) += model_potential;
  const double ecouple = thermostat_ ? 0.0 - heat : 0.0, econserve = e.total() + ecouple;  // 0, not −0, at the start
  if (!have_e0_) {
    e0_ = e.total();
    ec0_ = econserve;
    t0_ = s.t;
    have_e0_ = true;
  }
  values_.clear();
  values_.insert(values_.end(), {s.t, static_cast<double>(s.step), e.kinetic, e.slow, e.stiff});
  if (fixman_) values_.push_back(e.fixman);
  values_.insert(values_.end(),
                 {e.total(), e.total() - e0_, sums.max_violation, dof_ > 0 ? 2.0 * thermal_kinetic / dof_ : 0.0});
  if (thermostat_) values_.insert(values_.end(), {ecouple, econserve});
  if (level_columns_) values_.insert(values_.end(), e.by_level.begin(), e.by_level.end());
  if (coulomb_column_) values_.insert(values_.end(), {sums.vdwl, sums.coulomb});
  if (kspace_column_) values_.push_back(sums.kspace);
  // The pressure (2K + Σ r·f)/(3V) (pressure(), engine/observe/polymer_observables.hpp) and the
  // polymer means, from the sums.
  if (periodic_) {
    const double volume = forces_->box().lengths.prod();
    values_.push_back((2.0 * thermal_kinetic + sums.virial) / (3.0 * volume) + constraint_virial / (3.0 * volume));
    const Eigen::Vector3d& l = forces_->box().lengths;
    if (molecular_)
      values_.insert(values_.end(), {volume, l[0], l[1], l[2], mass_ / volume, sums.molecular / (3.0 * volume)});
  }
  if (rg_column_) values_.push_back(sums.molecules > 0 ? sums.rg / sums.molecules : 0.0);
  if (end_to_end_column_) values_.push_back(sums.sized > 0 ? sums.end_to_end / sums.sized : 0.0);
  if (modes_) {
    modes_->frequencies(s.x, omega_);
    modes_->actions(s.x, s.v, actions_);
    const StiffModes::Validity v = modes_->validity(s.x);
    values_.insert(values_.end(), omega_.begin(), omega_.end());
    values_.insert(values_.end(), actions_.begin(), actions_.end());
    values_.push_back(std::isfinite(v.min_gap) ? v.min_gap : -1.0);
    values_.push_back(std::isfinite(v.min_resonance) ? v.min_resonance : -1.0);
    // Below √ε (paper eqs. (separated), (nonresonant)) the actions need not stay adiabatic
    // invariants: a method that resolves the vibrations shows them jump there, and the effective
    // dynamics, which holds them fixed, loses validity (the slow motion is no longer determined by
    // the actions: Takens chaos) — a warning for the methods that follow it. Rigid bonds without it
    // have no vibrations, and nothing is said.
    auto warn = [&](bool& warned, double value, const char* what) {
      if (resonances_ == ObservableSettings::Resonances::none || warned || !(value < sqrt_eps_)) return;
      warned = true;
      const bool effective = resonances_ == ObservableSettings::Resonances::effective;
      std::ostringstream m;
      m << (effective ? "warning: " : "note: ") << what << " " << value << " < sqrt(eps) = " << sqrt_eps_ << " at step "
        << s.step << " (t = " << s.t << "): the actions need not stay adiabatic invariants"
        << (effective ? " and the effective dynamics, which this method follows, loses validity here"
                      : " here (they may jump)");
      notes_.push_back(m.str());
    };
    warn(warned_gap_, v.min_gap, "frequency gap min|w_j - w_k| =");
    warn(warned_resonance_, v.min_resonance, "resonance min|w_j +- w_k +- w_l| =");
  }
  values_.push_back(0.0);  // alerts
  return values_;
}

ThermoOutput::ThermoOutput(const Thermo& thermo, int num_particles, bool norm, const Units& units)
    : thermo_(thermo), n_(num_particles), columns_(thermo.columns()), divide_(columns_.size(), 0) {
  for (const std::string& c : columns_) scale_.push_back(units.out(thermo_column_dimension(c)));
  if (norm && num_particles > 0)
    for (size_t c = 0; c < columns_.size(); ++c) {
      const std::string& name = columns_[c];  // the energies: kinetic, every potential_*, total, drift, …
      if (name == "kinetic" || name.rfind("potential_", 0) == 0 || name == "total" || name == "energy_drift" ||
          name == "ecouple" || name == "econserve") {
        divide_[c] = 1;
        columns_[c] += "_per_atom";
      }
    }
}

int ThermoOutput::column(const std::string& thermo_name) const {
  return thermo_.column(thermo_name);
}

const std::vector<double>& ThermoOutput::operator()(const std::vector<double>& row) {
  row_ = row;  // same size every call: no allocation after the first
  for (size_t c = 0; c < row_.size(); ++c) {
    if (divide_[c]) row_[c] /= n_;  // a division, so that the value is exactly total / N
    row_[c] *= scale_[c];           // then in the deck's units (× 1 exactly in reduced units)
  }
  return row_;
}

ProjectedMomenta::ProjectedMomenta(const StiffBonds& stiff, const Eigen::VectorXd& inv_mass)
    : toolbox_(stiff.bonds, inv_mass) {}

const Eigen::Matrix3Xd& ProjectedMomenta::operator()(const State& s) {
  p_ = s.v;
  toolbox_.project_velocity(s.x, p_);
  for (int i = 0; i < s.size(); ++i) p_.col(i) *= s.inv_mass[i] > 0.0 ? 1.0 / s.inv_mass[i] : 0.0;
  return p_;
}

}  // namespace stiffmd
