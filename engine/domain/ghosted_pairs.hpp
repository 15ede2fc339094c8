// A pair term of a decomposed run's part (docs/parallel.md): the deck's term, acting on the part's
// owned particles, evaluated on the extended set (owned and ghosts, Decomposition) so that every
// owned particle meets all its partners. The integrator sees the owned particles only; this term
// fills the extended positions through the halo (the owned columns of whatever array the forces
// are wanted at: x, or the mollified positions; wrapped into the box, the frame the pair loop
// reads, so its list makes no wrapped copy), evaluates the pair term there and hands the owned
// particles' forces back. The forces are accumulated onto the owned particles' columns as they
// were (the terms before it already added theirs), in the one-process order: the same bits.
//
// The term on the extended set is built once and moved onto each new extended set in place
// (PairsOnParticles::move_to): its neighbour list keeps its buffers, and the extended set's special
// pairs are the owned term's mapped through the owned → extended slots, not found again.
#pragma once

#include <memory>
#include <span>
#include <vector>

#include "engine/domain/decomposition.hpp"
#include "forcefields/force_term.hpp"
#include "forcefields/pair_term.hpp"

namespace stiffmd {

class GhostedPairs final : public ForceTerm {
 public:
  // `owned_term`: the deck's neighbour-list term built on the part's owned particles and their
  // bonds (its settings and special pairs; on_particles makes the one that acts on the extended
  // set).
  GhostedPairs(std::unique_ptr<ForceTerm> owned_term, const Decomposition& domains);

  // After Decomposition::select_ghosts: the term on the new extended set, `types` per extended
  // particle.
  void retarget(std::span<const int> types, const Box& box);
  // A part built again (molecules migrated) keeps the old part's term on the extended set, and
  // so its buffers; `old` held the same deck term. The next retarget moves it.
  void take_over(GhostedPairs& old);
  // The neighbour list on the extended set brought up to date for the owned positions x (through
  // the halo; collective), as one process builds its list before the step loop.
  void update_list(const Eigen::Matrix3Xd& x, const Box& box);

  double add_forces(const Eigen::Matrix3Xd& x, const Box& box, Eigen::Matrix3Xd& f) const override;
  double virial(const Eigen::Matrix3Xd& x, const Box& box) const override;
  // The owned particles' forces as add_forces, and this rank's share of the virial's diagonal.
  void add_forces_and_virial_diagonal(const Eigen::Matrix3Xd& x, const Box& box, Eigen::Matrix3Xd& f,
                                      ExactDiagonal& w) const override;
  // This rank's share: a pair of an owned particle and a ghost counts half (its owner has the
  // other half), so the ranks' shares add up to the whole system's energy and virial.
  Sums energy_and_virial(const Eigen::Matrix3Xd& x, const Box& box, Eigen::Matrix3Xd& scratch) const override;
  bool uses_neighbor_list() const override { return true; }
  double pair_cutoff() const override { return template_->pair_cutoff(); }
  double pair_skin() const override { return template_->pair_skin(); }
  // The rebuilds while this term held the extended one.
  long neighbor_list_rebuilds() const override {
    return extended_ ? extended_->neighbor_list_rebuilds() - rebuilds_before_ : 0;
  }
  std::string_view style() const override { return template_->style(); }
  std::string describe() const override { return template_->describe(); }
  void define(ParameterRecord& record) const override { template_->define(record); }

 private:
  std::unique_ptr<ForceTerm> template_, extended_;
  const PairsOnParticles* owned_pairs_ = nullptr;  // template_'s
  PairsOnParticles* extended_pairs_ = nullptr;     // extended_'s
  const Decomposition& domains_;
  long rebuilds_before_ = 0;          // of extended_ when this term took it over
  std::vector<SpecialPair> special_;  // the extended set's
  mutable Eigen::Matrix3Xd x_, f_;
};

}  // namespace stiffmd
