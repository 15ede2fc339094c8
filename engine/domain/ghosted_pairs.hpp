// A pair term of a decomposed run's part (docs/parallel.md): the deck's term, acting on the part's
// owned particles, evaluated on the extended set (owned and ghosts, Decomposition) so that every
// owned particle meets all its partners. The integrator sees the owned particles only; this term
// fills the extended positions through the halo (the owned columns of whatever array the forces
// are wanted at: x, or the mollified positions), evaluates the pair term there and hands the owned
// particles' forces back. The forces are accumulated onto the owned particles' columns as they
// were (the terms before it already added theirs), in the one-process order: the same bits.
#pragma once

#include <memory>
#include <vector>

#include "engine/domain/decomposition.hpp"
#include "forcefields/force_term.hpp"

namespace stiffmd {

class GhostedPairs final : public ForceTerm {
 public:
  // `owned_term`: the deck's neighbour-list term built on the part's owned particles (its
  // settings; on_particles makes the one that acts on the extended set).
  GhostedPairs(std::unique_ptr<ForceTerm> owned_term, const Decomposition& domains);

  // After Decomposition::select_ghosts: the term on the new extended set, `types` and `bonds` (the
  // owned molecules' bonds) in its indices.
  void retarget(std::vector<int> types, const std::vector<Bond>& bonds, const Box& box);

  double add_forces(const Eigen::Matrix3Xd& x, const Box& box, Eigen::Matrix3Xd& f) const override;
  double virial(const Eigen::Matrix3Xd& x, const Box& box) const override;
  // This rank's share: a pair of an owned particle and a ghost counts half (its owner has the
  // other half), so the ranks' shares add up to the whole system's energy and virial.
  Sums energy_and_virial(const Eigen::Matrix3Xd& x, const Box& box, Eigen::Matrix3Xd& scratch) const override;
  bool uses_neighbor_list() const override { return true; }
  double pair_cutoff() const override { return template_->pair_cutoff(); }
  double pair_skin() const override { return template_->pair_skin(); }
  long neighbor_list_rebuilds() const override {
    return rebuilds_before_ + (extended_ ? extended_->neighbor_list_rebuilds() : 0);
  }
  std::string_view style() const override { return template_->style(); }
  std::string describe() const override { return template_->describe(); }
  void define(ParameterRecord& record) const override { template_->define(record); }

 private:
  std::unique_ptr<ForceTerm> template_, extended_;
  const Decomposition& domains_;
  long rebuilds_before_ = 0;  // of the extended terms before the current one
  mutable Eigen::Matrix3Xd x_, f_;
};

}  // namespace stiffmd
