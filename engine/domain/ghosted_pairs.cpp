#include "engine/domain/ghosted_pairs.hpp"

#include <stdexcept>

namespace stiffmd {

GhostedPairs::GhostedPairs(std::unique_ptr<ForceTerm> owned_term, const Decomposition& domains)
    : ForceTerm(owned_term->name(), owned_term->level()), template_(std::move(owned_term)), domains_(domains) {
  if (!template_->uses_neighbor_list()) throw std::invalid_argument("GhostedPairs: not a neighbour-list term");
}

void GhostedPairs::retarget(std::vector<int> types, const std::vector<Bond>& bonds, const Box& box) {
  if (extended_) rebuilds_before_ += extended_->neighbor_list_rebuilds();
  extended_ = template_->on_particles(std::move(types), bonds, box);
  if (!extended_) throw std::invalid_argument("GhostedPairs: term '" + name() + "' cannot act on other particles");
  extended_->set_ghosts(domains_.ghost_flags());
}

double GhostedPairs::add_forces(const Eigen::Matrix3Xd& x, const Box& box, Eigen::Matrix3Xd& f) const {
  domains_.halo(x, x_);
  const int owned = domains_.num_owned();
  f_.resize(3, x_.cols());  // no allocation once sized
  f_.setZero();
  for (int k = 0; k < owned; ++k) f_.col(domains_.extended_slot(k)) = f.col(k);
  const double energy = extended_->add_forces(x_, box, f_);
  for (int k = 0; k < owned; ++k) f.col(k) = f_.col(domains_.extended_slot(k));
  return energy;
}

double GhostedPairs::virial(const Eigen::Matrix3Xd& x, const Box& box) const {
  domains_.halo(x, x_);
  return extended_->virial(x_, box);
}

ForceTerm::Sums GhostedPairs::energy_and_virial(const Eigen::Matrix3Xd& x, const Box& box,
                                                Eigen::Matrix3Xd& scratch) const {
  (void)scratch;
  domains_.halo(x, x_);
  return extended_->energy_and_virial(x_, box, f_);
}

}  // namespace stiffmd
