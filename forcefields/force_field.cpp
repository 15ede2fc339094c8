#include "forcefields/force_field.hpp"

#include <algorithm>

#include "core/parallel.hpp"
#include "core/timing.hpp"

namespace stiffmd {
namespace {

// out = 0, in particle blocks on the threads (a serial 32 000-particle memset, 20 times per macro
// step of the impulse method, is 1.4 % of it); a few particles directly (around a 72-byte clear,
// the parallel machinery costs the pendulum's step 9 ns).
void zero(Eigen::Matrix3Xd& out, Eigen::Index n) {
  if (out.cols() != n) out.resize(3, n);
  const int parts = threads_for(n);
  if (parts == 1) {
    run_as_one_part(n, [&] { std::fill_n(out.data(), 3 * n, 0.0); });
    return;
  }
  parallel_blocks(n, parts, [&](std::int64_t b, std::int64_t e) { out.middleCols(b, e - b).setZero(); });
}

// A term's forces, timed as pair or bonded forces (core/timing.hpp).
double timed_add_forces(const ForceTerm& term, const Eigen::Matrix3Xd& x, const Box& box, Eigen::Matrix3Xd& f) {
  const ScopedPhase phase(term.phase());
  return term.add_forces(x, box, f);
}

// The same, its force alone (ForceTerm::add_forces_only).
void timed_add_forces_only(const ForceTerm& term, const Eigen::Matrix3Xd& x, const Box& box, Eigen::Matrix3Xd& f) {
  const ScopedPhase phase(term.phase());
  term.add_forces_only(x, box, f);
}

}  // namespace

std::unique_ptr<ForceTerm> ForceField::replace(size_t k, std::unique_ptr<ForceTerm> term) {
  if (term->level() != terms_[k]->level() || term->fused_micro_step() || terms_[k]->fused_micro_step())
    throw std::invalid_argument("ForceField::replace: a term of another level or a fused one");
  std::replace(order_.begin(), order_.end(), static_cast<const ForceTerm*>(terms_[k].get()),
               static_cast<const ForceTerm*>(term.get()));
  std::swap(terms_[k], term);
  return term;
}

std::unique_ptr<ForceField> ForceField::on_subset(const ParticleSubset& subset) const {
  auto out = std::make_unique<ForceField>(box_, subset.size(), level_names_);
  for (const auto& term : terms_) out->add(term->on_subset(subset, box_));
  return out;
}

void ForceField::add(std::unique_ptr<ForceTerm> term) {
  const ForceTerm* t = term.get();
  terms_.push_back(std::move(term));
  // The terms that offer a fused step first, then the others, each in the order added.
  const bool fusable = t->fused_micro_step() != nullptr;
  const auto at = fusable ? std::find_if(order_.begin(), order_.end(),
                                         [](const ForceTerm* u) { return u->fused_micro_step() == nullptr; })
                          : order_.end();
  order_.insert(at, t);
}

double ForceField::compute(const Eigen::Matrix3Xd& x, std::span<const Level> levels, Eigen::Matrix3Xd& out) {
  zero(out, x.cols());
  double energy = 0.0;
  for (const ForceTerm* term : order_)
    if (std::find(levels.begin(), levels.end(), term->level()) != levels.end())
      energy += timed_add_forces(*term, x, box_, out);
  for (Level l : levels) ++evaluations_[l.index];
  return energy;
}

double ForceField::compute_unconstrained(const Eigen::Matrix3Xd& x, Eigen::Matrix3Xd& out) {
  zero(out, x.cols());
  double energy = 0.0;
  for (const ForceTerm* term : order_)
    if (!term->stiff_bonds()) energy += timed_add_forces(*term, x, box_, out);
  ++evaluations_[outermost().index];
  return energy;
}

void ForceField::compute_forces(const Eigen::Matrix3Xd& x, std::span<const Level> levels, Eigen::Matrix3Xd& out) {
  zero(out, x.cols());
  for (const ForceTerm* term : order_)
    if (std::find(levels.begin(), levels.end(), term->level()) != levels.end())
      timed_add_forces_only(*term, x, box_, out);
  for (Level l : levels) ++evaluations_[l.index];
}

void ForceField::compute_forces_unconstrained(const Eigen::Matrix3Xd& x, Eigen::Matrix3Xd& out) {
  zero(out, x.cols());
  for (const ForceTerm* term : order_)
    if (!term->stiff_bonds()) timed_add_forces_only(*term, x, box_, out);
  ++evaluations_[outermost().index];
}

double ForceField::energy(const Eigen::Matrix3Xd& x, Level level) const {
  zero(scratch_, x.cols());
  double energy = 0.0;
  for (const ForceTerm* term : order_)
    if (term->level() == level) energy += timed_add_forces(*term, x, box_, scratch_);
  return energy;
}

void ForceField::energies_and_virial(const Eigen::Matrix3Xd& x, std::vector<double>& level_energy,
                                     double& virial) const {
  zero(scratch_, x.cols());
  term_sums_.resize(terms_.size());
  for (size_t k = 0; k < terms_.size(); ++k) {
    const ScopedPhase phase(terms_[k]->phase());
    term_sums_[k] = terms_[k]->energy_and_virial(x, box_, scratch_);
  }
  // Summed as energy(x, level) sums each level (in the evaluation order) and the pressure the
  // virials (in the order the terms were added).
  level_energy.assign(num_levels(), 0.0);
  for (const ForceTerm* term : order_)
    for (size_t k = 0; k < terms_.size(); ++k)
      if (terms_[k].get() == term) level_energy[term->level().index] += term_sums_[k].energy;
  virial = 0.0;
  for (const ForceTerm::Sums& s : term_sums_) virial += s.virial;
}

double ForceField::last_coulomb_energy() const {
  double e = 0.0;
  for (const ForceTerm::Sums& s : term_sums_) e += s.coulomb;
  return e;
}

double ForceField::last_vdwl_energy() const {
  double e = 0.0;
  for (const ForceTerm::Sums& s : term_sums_) e += s.vdwl;
  return e;
}

double ForceField::last_kspace_energy() const {
  double e = 0.0;
  for (size_t k = 0; k < terms_.size() && k < term_sums_.size(); ++k)
    if (terms_[k]->phase() == Phase::kspace) e += term_sums_[k].energy;
  return e;
}

bool ForceField::has_charges() const {
  return std::any_of(terms_.begin(), terms_.end(), [](const auto& t) { return t->uses_charges(); });
}

bool ForceField::has_kspace() const {
  return std::any_of(terms_.begin(), terms_.end(), [](const auto& t) { return t->phase() == Phase::kspace; });
}

bool ForceField::has_level(Level l) const {
  return std::any_of(terms_.begin(), terms_.end(), [l](const auto& t) { return t->level() == l; });
}

std::optional<Level> ForceField::find_level(std::string_view name) const {
  for (int k = 0; k < num_levels(); ++k)
    if (level_names_[k] == name) return Level{k};
  return std::nullopt;
}

std::vector<Level> ForceField::all_levels() const {
  std::vector<Level> out;
  for (int k = 0; k < num_levels(); ++k) out.push_back(Level{k});
  return out;
}

const StiffBonds* ForceField::stiff_bonds() const {
  for (const auto& t : terms_)
    if (const StiffBonds* s = t->stiff_bonds()) return s;
  return nullptr;
}

}  // namespace stiffmd
