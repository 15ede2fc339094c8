#include "integrators/barostat.hpp"

#include <cmath>
#include <sstream>
#include <stdexcept>

#include "core/communicator.hpp"
#include "core/errors.hpp"
#include "core/timing.hpp"
#include "integrators/integrator.hpp"
#include "integrators/thermostat.hpp"

namespace stiffmd {

namespace {

// The cell move's own stream, apart from the thermostats' (integrators/thermostat.cpp).
constexpr std::uint64_t kCellSubstep = 0xba40000000000000ULL;

}  // namespace

std::string_view coupling_name(BarostatSettings::Coupling c) {
  switch (c) {
    case BarostatSettings::Coupling::isotropic:
      return "isotropic";
    case BarostatSettings::Coupling::semi_isotropic:
      return "semi-isotropic";
    case BarostatSettings::Coupling::anisotropic:
      return "anisotropic";
  }
  return "?";
}

MolecularPressure::MolecularPressure(std::vector<int> molecule, const Eigen::VectorXd& inv_mass,
                                     const Communicator* processes)
    : molecule_(std::move(molecule)), inv_mass_(inv_mass), processes_(processes) {
  if (molecule_.size() != static_cast<size_t>(inv_mass.size()))
    throw std::invalid_argument("molecular pressure: one molecule per particle needed");
  int count = 0;
  for (int m : molecule_) count = std::max(count, m + 1);
  molecule_mass_.setZero(count);
  for (size_t i = 0; i < molecule_.size(); ++i) {
    if (!(inv_mass[static_cast<Eigen::Index>(i)] > 0.0))
      throw std::invalid_argument("molecular pressure: a fixed particle cannot be scaled with the box");
    molecule_mass_[molecule_[i]] += 1.0 / inv_mass[static_cast<Eigen::Index>(i)];
  }
  centre_.setZero(3, count);
  velocity_.setZero(3, count);
}

void MolecularPressure::locate(const State& s) {
  centre_.setZero();
  velocity_.setZero();
  for (int i = 0; i < s.size(); ++i) {
    const double m = 1.0 / inv_mass_[i];
    centre_.col(molecule_[i]) += m * s.x.col(i);
    velocity_.col(molecule_[i]) += m * s.v.col(i);
  }
  for (Eigen::Index k = 0; k < centre_.cols(); ++k) {
    centre_.col(k) /= molecule_mass_[k];
    velocity_.col(k) /= molecule_mass_[k];
  }
}

Eigen::Vector3d MolecularPressure::virial_and_kinetic(const State& s, const ForceField& forces,
                                                      Eigen::Matrix3Xd& scratch) {
  scratch.setZero(3, s.size());
  // Every sum exact (ExactDiagonal): the same bits for any thread count and number of processes.
  ExactDiagonal w;
  for (const auto& term : forces.terms())
    if (term->uses_neighbor_list()) term->add_forces_and_virial_diagonal(s.x, forces.box(), scratch, w);
  // W_aa = Σ_pairs d_a f_a − Σ_i δ_{i,a} f_{i,a}: the pair virial less what the forces do inside
  // each molecule (docs/design.md §5b).
  for (int i = 0; i < s.size(); ++i)
    for (int a = 0; a < 3; ++a) w.axis[a].add(-(s.x(a, i) - centre_(a, molecule_[i])) * scratch(a, i));
  for (Eigen::Index k = 0; k < velocity_.cols(); ++k)  // 2 K_a
    for (int a = 0; a < 3; ++a) w.axis[a].add(molecule_mass_[k] * velocity_(a, k) * velocity_(a, k));
  if (processes_) {
    constexpr int n = SignedExactSum::kWords;
    std::int64_t words[3 * n];
    for (int a = 0; a < 3; ++a) w.axis[a].to_words(words + n * a);
    processes_->sum(words, 3 * n);
    for (int a = 0; a < 3; ++a) w.axis[a].from_words(words + n * a);
  }
  return {w.axis[0].value(), w.axis[1].value(), w.axis[2].value()};
}

Eigen::Vector3d MolecularPressure::pressure(const State& s, const ForceField& forces, Eigen::Matrix3Xd& scratch) {
  locate(s);
  const Eigen::Vector3d w = virial_and_kinetic(s, forces, scratch);
  return w / forces.box().lengths.prod();
}

Eigen::Vector3d cell_scaling(const BarostatSettings& b, const Eigen::Vector3d& p, double volume, double dt,
                             std::int64_t step) {
  // The groups of coupled axes: their first axis and size.
  int first[3], size[3], groups = 0;
  switch (b.coupling) {
    case BarostatSettings::Coupling::isotropic:
      first[0] = 0, size[0] = 3, groups = 1;
      break;
    case BarostatSettings::Coupling::semi_isotropic:
      first[0] = 0, size[0] = 2, first[1] = 2, size[1] = 1, groups = 2;
      break;
    case BarostatSettings::Coupling::anisotropic:
      for (int a = 0; a < 3; ++a) first[a] = a, size[a] = 1;
      groups = 3;
      break;
  }
  const std::uint64_t key = noise_key(b.seed, step, kCellSubstep);
  double xi[4];
  normal_pair(noise_word(key, 0), xi[0], xi[1]);
  normal_pair(noise_word(key, 1), xi[2], xi[3]);
  Eigen::Vector3d mu;
  for (int g = 0; g < groups; ++g) {
    const double k = size[g];
    double pg = 0.0;
    for (int a = first[g]; a < first[g] + size[g]; ++a) pg += p[a];
    pg /= k;
    const double p0 = b.pressure[first[g]];
    const double drift = k * b.compressibility * (pg - p0) / (3.0 * b.tau) * dt;
    const double noise = std::sqrt(2.0 * k * b.temperature * b.compressibility * dt / (3.0 * volume * b.tau)) * xi[g];
    const double scale = std::exp((drift + noise) / k);
    for (int a = first[g]; a < first[g] + size[g]; ++a) mu[a] = scale;
  }
  return mu;
}

namespace {

class CellRescaled final : public Integrator {
 public:
  CellRescaled(std::unique_ptr<Integrator> inner, const BarostatSettings& b, ForceField& forces,
               const Eigen::VectorXd& inv_mass)
      : inner_(std::move(inner)), settings_(b), forces_(forces), pressure_(b.molecule, inv_mass, b.processes) {
    if (b.interval < 1) throw std::invalid_argument("barostat: interval must be >= 1");
    if (!(b.tau > 0.0) || !(b.compressibility > 0.0) || !(b.temperature > 0.0))
      throw std::invalid_argument("barostat: tau, compressibility and temperature must be > 0");
    for (const auto& term : forces.terms())
      min_length_ = std::max(min_length_, 2.0 * (term->pair_cutoff() + term->pair_skin()));
  }
  void prepare(State& s, std::ostream& log) override { inner_->prepare(s, log); }
  void step(State& s, double h) override {
    inner_->step(s, h);
    // s.step is still the step this one started from: the move follows steps interval, 2·interval, …
    if ((s.step + 1) % settings_.interval != 0) return;
    const ScopedPhase phase(Phase::thermostat);
    const Box& box = forces_.box();
    const Eigen::Vector3d p = pressure_.pressure(s, forces_, scratch_);
    if (!p.allFinite()) throw NumericalError("the barostat's molecular pressure is not finite");
    const Eigen::Vector3d mu = cell_scaling(settings_, p, box.lengths.prod(), settings_.interval * h, s.step + 1);
    Box moved = box;
    moved.lengths = box.lengths.cwiseProduct(mu);
    for (int a = 0; a < 3; ++a)
      if (!(moved.lengths[a] >= min_length_)) {
        std::ostringstream m;
        m.precision(10);
        m << "the barostat shrank the box to L_" << static_cast<char>('x' + a) << " = " << moved.lengths[a]
          << " < 2 × (pair cutoff + skin) = " << min_length_
          << "; the pressure is far above what the scene can hold at this size: raise tau or start denser";
        throw NumericalError(m.str());
      }
    const Eigen::Vector3d shift = mu - Eigen::Vector3d::Ones();
    const Eigen::Vector3d slow = Eigen::Vector3d::Ones() - mu.cwiseInverse();
    const Eigen::Matrix3Xd& centre = pressure_.centres();
    const Eigen::Matrix3Xd& velocity = pressure_.velocities();
    const std::vector<int>& molecule = pressure_.molecule();
    for (int i = 0; i < s.size(); ++i) {
      const int k = molecule[i];
      s.x.col(i) += shift.cwiseProduct(centre.col(k) - box.origin);
      s.v.col(i) -= slow.cwiseProduct(velocity.col(k));
    }
    forces_.set_box(moved);
    inner_->reset();
  }
  void reset() override { inner_->reset(); }
  std::string_view method() const override { return inner_->method(); }
  double thermostat_heat() const override { return inner_->thermostat_heat(); }
  double model_potential(const Eigen::Matrix3Xd& x) override { return inner_->model_potential(x); }
  double constraint_virial(const State& s) override { return inner_->constraint_virial(s); }
  double kinetic_energy_estimate(const State& s) const override { return inner_->kinetic_energy_estimate(s); }
  std::vector<double> invariants() const override { return inner_->invariants(); }
  void set_invariants(const std::vector<double>& w) override { inner_->set_invariants(w); }
  std::vector<double> save_state() const override { return inner_->save_state(); }
  CarriedState carried_state() const override { return inner_->carried_state(); }
  void restore_carried_state(CarriedState c) override { inner_->restore_carried_state(std::move(c)); }
  void load_state(const std::vector<double>& s) override { inner_->load_state(s); }

 private:
  std::unique_ptr<Integrator> inner_;
  BarostatSettings settings_;
  ForceField& forces_;
  MolecularPressure pressure_;
  Eigen::Matrix3Xd scratch_;
  double min_length_ = 0.0;
};

}  // namespace

std::unique_ptr<Integrator> with_cell_rescaling(std::unique_ptr<Integrator> inner, const BarostatSettings& settings,
                                                ForceField& forces, const Eigen::VectorXd& inv_mass) {
  return std::make_unique<CellRescaled>(std::move(inner), settings, forces, inv_mass);
}

}  // namespace stiffmd
