// Short-range pair styles as force terms: `lj`, `wca`, `soft` (pair_potentials.hpp), each a
// PairTerm over its kernel. Energy E = Σ_{i<j} w_ij E_ab(|x_i − x_j|) with a, b the particle
// types, w_ij the special-bond weight (1 unless i, j are 1-2 or 1-3 bonded neighbours), minimum
// image on periodic axes. Pairs are found through a Verlet list with a skin (neighbor_list.hpp).
#pragma once

#include <span>
#include <string>
#include <vector>

#include "engine/topology.hpp"
#include "forcefields/force_term.hpp"
#include "forcefields/neighbor_list.hpp"
#include "forcefields/pair_loop.hpp"
#include "forcefields/pair_potentials.hpp"

namespace stiffmd {

template <class Kernel>
class PairTerm final : public ForceTerm {
 public:
  using Coeffs = typename Kernel::Coeffs;
  using Params = typename Kernel::Params;

  // types[i]: the type of particle i, in 0 … coeffs.num_types() − 1; every type pair must have
  // coefficients. bonds: the scene's bonds, from which the 1-2 and 1-3 pairs of `weights` are
  // found. box: checked to be at least 2 × (cutoff + skin) on periodic axes. skin ≥ 0: the
  // Verlet skin (length). Throws std::invalid_argument, naming the term, on any bad input.
  PairTerm(std::string name, Level level, std::vector<int> types, TypePairMatrix<Coeffs> coeffs,
           const std::vector<Bond>& bonds, SpecialWeights weights, const Box& box, double skin = 0.3);

  // Rebuild the neighbour list if stale, then the forces (add_forces) or Σ r_ij·f_ij (virial).
  // Not safe to call concurrently on one term: they update the list.
  double add_forces(const Eigen::Matrix3Xd& x, const Box& box, Eigen::Matrix3Xd& f) const override;
  double virial(const Eigen::Matrix3Xd& x, const Box& box) const override;

  std::string_view style() const override { return Kernel::kStyle; }
  std::string describe() const override;  // definition() and the rebuilds so far
  std::string definition() const override;
  // The neighbour list's state (NeighborList::restore): empty before the first build, else the
  // rebuild count, the box and the 3N positions of the last build.
  std::vector<double> save_state() const override;
  void load_state(std::span<const double> words) override;

  long rebuilds() const { return list_.rebuilds(); }
  long neighbor_list_rebuilds() const override { return list_.rebuilds(); }
  bool uses_neighbor_list() const override { return true; }
  double cutoff() const { return cutoff_; }  // the largest over type pairs
  double skin() const { return list_.skin(); }
  const TypePairMatrix<Coeffs>& coeffs() const { return coeffs_; }
  SpecialWeights weights() const { return weights_; }
  std::size_t excluded_pairs() const { return excluded_; }               // weight 0: never listed
  std::span<const SpecialPair> scaled_pairs() const { return scaled_; }  // 0 < weight < 1
  const NeighborList& neighbor_list() const { return list_; }            // as of the last call

 private:
  void check_positions(const Eigen::Matrix3Xd& x, const Eigen::Matrix3Xd* f) const;

  std::vector<int> types_;
  TypePairMatrix<Coeffs> coeffs_;
  double cutoff_ = 0.0;
  TypePairMatrix<Params> params_;
  SpecialWeights weights_;
  std::size_t excluded_ = 0;
  std::vector<SpecialPair> scaled_;
  // A cache of the positions, not part of the term's value: rebuilt on demand by the const
  // add_forces/virial when particles have moved more than skin/2, hence mutable.
  mutable NeighborList list_;
  mutable PairScratch scratch_;  // per-thread force buffers of the pair loop
};

extern template class PairTerm<LennardJones>;
extern template class PairTerm<WeeksChandlerAndersen>;
extern template class PairTerm<SoftCosine>;

using LennardJonesPair = PairTerm<LennardJones>;
using WcaPair = PairTerm<WeeksChandlerAndersen>;
using SoftPair = PairTerm<SoftCosine>;

}  // namespace stiffmd
