#include "engine/domain/ghosted_pairs.hpp"

#include <stdexcept>

namespace stiffmd {

GhostedPairs::GhostedPairs(std::unique_ptr<ForceTerm> owned_term, const Decomposition& domains)
    : ForceTerm(owned_term->name(), owned_term->level()), template_(std::move(owned_term)), domains_(domains) {
  if (!template_->uses_neighbor_list()) throw std::invalid_argument("GhostedPairs: not a neighbour-list term");
  owned_pairs_ = dynamic_cast<const PairsOnParticles*>(template_.get());
  if (!owned_pairs_) throw std::invalid_argument("GhostedPairs: term '" + name() + "' cannot act on other particles");
}

void GhostedPairs::retarget(std::span<const int> types, const Box& box) {
  if (!extended_) {
    extended_ = template_->on_particles({}, {}, box);
    extended_pairs_ = extended_ ? dynamic_cast<PairsOnParticles*>(extended_.get()) : nullptr;
    if (!extended_pairs_)
      throw std::invalid_argument("GhostedPairs: term '" + name() + "' cannot act on other particles");
    // The halo writes the extended positions wrapped into the box, as the pair loop reads them:
    // the list makes no wrapped copy of its own.
    extended_pairs_->set_positions_wrapped(true);
    // Every evaluation runs on every rank at once (the halo is collective), so the ranks can
    // rebuild their lists together: one rebuilding alone would hold the others up at the next
    // halo for as long as its build takes.
    const Communicator& comm = domains_.comm();
    extended_pairs_->set_rebuild_agreement([&comm](bool stale) {
      double any = stale ? 1.0 : 0.0;
      comm.max(&any, 1);
      return any > 0.0;
    });
  }
  // The owned particles' bonds join owned particles only (molecules are whole), so the extended
  // set's special pairs are the owned term's through the owned → extended slots; the slots
  // increase with the owned index, so the pairs stay sorted by (i, j), as special_pairs gives them.
  const std::span<const SpecialPair> owned = owned_pairs_->special_pairs();
  special_.resize(owned.size());
  for (std::size_t p = 0; p < owned.size(); ++p)
    special_[p] = {domains_.extended_slot(owned[p].i), domains_.extended_slot(owned[p].j), owned[p].weight};
  extended_pairs_->move_to(types, special_, domains_.ghost_flags());
}

void GhostedPairs::take_over(GhostedPairs& old) {
  if (!old.extended_) return;
  extended_ = std::move(old.extended_);
  extended_pairs_ = old.extended_pairs_;
  old.extended_pairs_ = nullptr;
  rebuilds_before_ = extended_->neighbor_list_rebuilds();
  special_ = std::move(old.special_);
}

void GhostedPairs::update_list(const Eigen::Matrix3Xd& x, const Box& box) {
  domains_.halo(x, x_);
  extended_pairs_->update_list(x_, box);
}

double GhostedPairs::add_forces(const Eigen::Matrix3Xd& x, const Box& box, Eigen::Matrix3Xd& f) const {
  domains_.halo(x, x_);
  const int owned = domains_.num_owned();
  f_.resize(3, x_.cols());  // no allocation once sized
  for (const int e : domains_.ghost_slots()) f_.col(e).setZero();
  for (int k = 0; k < owned; ++k) f_.col(domains_.extended_slot(k)) = f.col(k);
  const double energy = extended_->add_forces(x_, box, f_);
  for (int k = 0; k < owned; ++k) f.col(k) = f_.col(domains_.extended_slot(k));
  return energy;
}

void GhostedPairs::add_forces_and_virial_diagonal(const Eigen::Matrix3Xd& x, const Box& box, Eigen::Matrix3Xd& f,
                                                  ExactDiagonal& w) const {
  domains_.halo(x, x_);
  const int owned = domains_.num_owned();
  f_.resize(3, x_.cols());
  for (const int e : domains_.ghost_slots()) f_.col(e).setZero();
  for (int k = 0; k < owned; ++k) f_.col(domains_.extended_slot(k)) = f.col(k);
  extended_->add_forces_and_virial_diagonal(x_, box, f_, w);
  for (int k = 0; k < owned; ++k) f.col(k) = f_.col(domains_.extended_slot(k));
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
