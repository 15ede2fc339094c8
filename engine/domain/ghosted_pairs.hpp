// A pair term of a decomposed run's part (docs/parallel.md): the deck's term, evaluated where the
// beads are. The part's integrator hands it its owned particles' positions and forces; the term
// sends them to the ranks whose pair sets hold them (Decomposition::forward: positions to the
// home and the halo ranks, wrapped into the box, the frame the pair loop reads, so its list makes
// no wrapped copy; the forces so far to the home), evaluates the pair term on this rank's pair
// set, and sends its home beads' forces back to their owners (Decomposition::reverse). A home
// bead's pair forces are added onto its owner's forces so far, in the one-process order: the
// same bits as one process.
//
// Before each evaluation one max-reduction asks whether a rank's list would be rebuilt. If one
// would, every list rebuilds, on the pair sets as they are while no bead has moved more than
// (R − r_c − skin)/2 since their selection (then the list built on a pair set is one process's
// list restricted to it); past that the pair sets are selected again first, and the term moves
// onto the new pair set in place (PairsOnParticles::move_to): its neighbour list keeps its
// buffers, and the pair set's types, charges and special pairs are those its beads carried to it
// from their owners (Decomposition::pair_data): the whole system's among its beads. Between
// builds a list counts as stale once a bead may have moved (R − r_c)/2 since the selection, where
// a pair within r_c could leave the pair set.
#pragma once

#include <memory>
#include <span>
#include <vector>

#include "engine/domain/decomposition.hpp"
#include "forcefields/force_term.hpp"
#include "forcefields/pair_term.hpp"

namespace stiffmd {

// The special partners by bead of a term's particle set (PairsOnParticles::special_pairs, in the
// set's numbering: sorted by (i, j)), the partners by global index: global[k] is particle k's. A
// part's pair term gives its molecules' (the special pairs of their bonds with the term's weights):
// for each of its beads the rows the whole system's term gives it, with global = 0 … N − 1.
SpecialPartners special_partners(std::span<const SpecialPair> pairs, std::span<const int> global);

class GhostedPairs final : public ForceTerm {
 public:
  // `whole_term`: the whole scene's neighbour-list term (its settings alone; on_particles makes
  // the one that acts on the pair set); it must outlive the term. The pair set's types, charges
  // (for a term that uses_charges) and special pairs are what its beads carried to it
  // (Decomposition::pair_data: the types, the charges, and `special`, this term's index in its
  // special partners per term). `old`: a part built again (molecules migrated) takes the old
  // part's term on the pair set over, and so its list's buffers (the same deck term); null: a new one.
  GhostedPairs(const ForceTerm& whole_term, Decomposition& domains, int special, GhostedPairs* old = nullptr);

  // The neighbour list on the pair set brought up to date for the owned positions x (collective),
  // as one process builds its list before the step loop.
  void update_list(const Eigen::Matrix3Xd& x, const Box& box);

  double add_forces(const Eigen::Matrix3Xd& x, const Box& box, Eigen::Matrix3Xd& f) const override;
  // The same forces without the energy: the pair set's term's force-only pass between the same
  // forward and reverse.
  void add_forces_only(const Eigen::Matrix3Xd& x, const Box& box, Eigen::Matrix3Xd& f) const override;
  double virial(const Eigen::Matrix3Xd& x, const Box& box) const override;
  // The owned particles' forces as add_forces, and this rank's share of the virial's diagonal.
  void add_forces_and_virial_diagonal(const Eigen::Matrix3Xd& x, const Box& box, Eigen::Matrix3Xd& f,
                                      ExactDiagonal& w) const override;
  // This rank's share: a pair of a home bead and a halo bead counts half (the halo bead's home
  // has the other half), so the ranks' shares add up to the whole system's energy and virial.
  Sums energy_and_virial(const Eigen::Matrix3Xd& x, const Box& box, Eigen::Matrix3Xd& scratch) const override;
  bool uses_neighbor_list() const override { return true; }
  bool uses_charges() const override { return template_.uses_charges(); }
  double pair_cutoff() const override { return template_.pair_cutoff(); }
  double pair_skin() const override { return template_.pair_skin(); }
  // The rebuilds while this term held the pair set's.
  long neighbor_list_rebuilds() const override {
    return extended_ ? extended_->neighbor_list_rebuilds() - rebuilds_before_ : 0;
  }
  std::int64_t listed_pairs() const override { return extended_ ? extended_->listed_pairs() : 0; }
  std::string_view style() const override { return template_.style(); }
  std::string describe() const override { return template_.describe(); }
  void define(ParameterRecord& record) const override { template_.define(record); }

 private:
  // The pair set's positions x_ (and with f, the home beads' forces so far f_) for the owned
  // positions x, the pair sets selected again first when stale or when a rank's list would be
  // rebuilt (collective), this term moved onto the current pair set.
  void forward(const Eigen::Matrix3Xd& x, const Box& box, Eigen::Matrix3Xd* f) const;
  void retarget() const;

  const ForceTerm& template_;
  std::unique_ptr<ForceTerm> extended_;
  PairsOnParticles* extended_pairs_ = nullptr;  // extended_'s
  Decomposition& domains_;
  int special_index_;         // this term's in Decomposition::pair_data().special
  long rebuilds_before_ = 0;  // of extended_ when this term took it over
  // The pair set this term was last moved onto (Decomposition::selections).
  mutable long selection_ = -1;
  mutable Eigen::Matrix3Xd x_, f_;
};

}  // namespace stiffmd
