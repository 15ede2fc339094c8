#include "forcefields/force_field.hpp"

#include <algorithm>

namespace stiffmd {

double ForceField::compute(const Eigen::Matrix3Xd& x, std::span<const Level> levels, Eigen::Matrix3Xd& out) {
  out.setZero(3, x.cols());
  double energy = 0.0;
  for (const auto& term : terms_)
    if (std::find(levels.begin(), levels.end(), term->level()) != levels.end())
      energy += term->add_forces(x, box_, out);
  for (Level l : levels) ++evaluations_[static_cast<int>(l)];
  return energy;
}

double ForceField::compute_unconstrained(const Eigen::Matrix3Xd& x, Eigen::Matrix3Xd& out) {
  out.setZero(3, x.cols());
  double energy = 0.0;
  for (const auto& term : terms_)
    if (!term->stiff_bonds()) energy += term->add_forces(x, box_, out);
  ++evaluations_[static_cast<int>(Level::slow)];
  return energy;
}

double ForceField::energy(const Eigen::Matrix3Xd& x, Level level) const {
  scratch_.setZero(3, x.cols());
  double energy = 0.0;
  for (const auto& term : terms_)
    if (term->level() == level) energy += term->add_forces(x, box_, scratch_);
  return energy;
}

bool ForceField::has_level(Level l) const {
  return std::any_of(terms_.begin(), terms_.end(), [l](const auto& t) { return t->level() == l; });
}

const StiffBonds* ForceField::stiff_bonds() const {
  for (const auto& t : terms_)
    if (const StiffBonds* s = t->stiff_bonds()) return s;
  return nullptr;
}

}  // namespace stiffmd
