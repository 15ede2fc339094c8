// Short-range pair styles as force terms: PairTerm over a kernel of pair_potentials.hpp (`lj`,
// `wca`, `soft`, …). Energy E = Σ_{i<j} w_ij E_ab(|x_i − x_j|) with a, b the particle
// types, w_ij the special-bond weight (1 unless i, j are 1-2 or 1-3 bonded neighbours), minimum
// image on periodic axes. Pairs are found through a Verlet list with a skin (neighbor_list.hpp).
#pragma once

#include <algorithm>
#include <span>
#include <stdexcept>
#include <string>
#include <vector>

#include "core/timing.hpp"
#include "core/topology.hpp"
#include "forcefields/force_term.hpp"
#include "forcefields/neighbor_list.hpp"
#include "forcefields/pair_loop.hpp"
#include "forcefields/pair_potentials.hpp"

namespace stiffmd {

// A pair term moved from one particle set onto another of the same molecules, in place: what a
// decomposed run's part (engine/domain/ghosted_pairs.hpp) does to its pair terms at each selection
// of the ghosts. The term keeps its settings and its neighbour list's buffers; only the particles'
// types, special pairs and ghost flags change.
class PairsOnParticles {
 public:
  virtual ~PairsOnParticles() = default;
  // Every pair of the term's particles whose special weight is not 1, sorted by (i, j)
  // (special_pairs of the particles and bonds it was built on or moved to).
  virtual std::span<const SpecialPair> special_pairs() const = 0;
  // The term on another particle set: types[i] per particle, `special` its special pairs as
  // special_pairs gives them (sorted by (i, j); weights from this term's w12, w13, w14), ghost[i]
  // (empty or all 0: none; NeighborList::set_ghosts). The same term, bit for bit, as on_particles
  // builds with the bonds that give `special`, and then set_ghosts; the list is built at the next
  // evaluation, allocating nothing once its buffers have grown. Throws std::invalid_argument for a
  // type or a pair out of range.
  virtual void move_to(std::span<const int> types, std::span<const SpecialPair> special,
                       std::span<const char> ghost) = 0;
  // Its neighbour list rebuilds as `agree` decides (NeighborList::set_rebuild_agreement).
  virtual void set_rebuild_agreement(NeighborList::RebuildAgreement agree) = 0;
  // Whether its neighbour list may miss a pair at x (NeighborList::needs_rebuild: this list's
  // verdict alone, whatever the agreement).
  virtual bool list_stale(const Eigen::Matrix3Xd& x, const Box& box) const = 0;
  // The verdict the next list update takes (NeighborList::set_next_verdict).
  virtual void set_next_list_verdict(bool stale) = 0;
  // NeighborList::set_displacement_limit.
  virtual void set_displacement_limit(double limit) = 0;
  // Its neighbour list brought up to date for x (NeighborList::update), ahead of an evaluation.
  virtual void update_list(const Eigen::Matrix3Xd& x, const Box& box) = 0;
  // The positions it is given are wrapped into the box (NeighborList::set_positions_wrapped).
  virtual void set_positions_wrapped(bool wrapped) = 0;
};

template <class Kernel>
class PairTerm final : public ForceTerm, public PairsOnParticles {
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
  // Both in one pass over the pairs, with ghosts this process's share (accumulate_pair_rows).
  Sums energy_and_virial(const Eigen::Matrix3Xd& x, const Box& box, Eigen::Matrix3Xd& scratch) const override;
  void add_forces_and_virial_diagonal(const Eigen::Matrix3Xd& x, const Box& box, Eigen::Matrix3Xd& f,
                                      ExactDiagonal& w) const override;

  std::string_view style() const override { return Kernel::kStyle; }
  std::string describe() const override;  // the settings and the rebuilds so far
  void define(ParameterRecord& record) const override;
  // The neighbour list's state (NeighborList::restore): empty before the first build, else the
  // rebuild count, the box and the 3N positions of the last build.
  std::vector<double> save_state() const override;
  void load_state(std::span<const double> words) override;

  // No pair of two ghosts is listed from the next evaluation on (NeighborList::set_ghosts).
  // The scaled special pairs are still all evaluated.
  void set_ghosts(const std::vector<char>& ghost) override { list_.set_ghosts(ghost); }

  std::span<const SpecialPair> special_pairs() const override { return special_; }
  void move_to(std::span<const int> types, std::span<const SpecialPair> special, std::span<const char> ghost) override;
  void set_rebuild_agreement(NeighborList::RebuildAgreement agree) override {
    list_.set_rebuild_agreement(std::move(agree));
  }
  void set_positions_wrapped(bool wrapped) override { list_.set_positions_wrapped(wrapped); }
  bool list_stale(const Eigen::Matrix3Xd& x, const Box& box) const override { return list_.needs_rebuild(x, box); }
  void set_next_list_verdict(bool stale) override { list_.set_next_verdict(stale); }
  void set_displacement_limit(double limit) override { list_.set_displacement_limit(limit); }
  void update_list(const Eigen::Matrix3Xd& x, const Box& box) override {
    check_positions(x, nullptr);
    const ScopedPhase phase(Phase::neighbor);
    list_.update(x, box);
  }

  long rebuilds() const { return list_.rebuilds(); }
  long neighbor_list_rebuilds() const override { return list_.rebuilds(); }
  std::int64_t listed_pairs() const override { return static_cast<std::int64_t>(list_.num_pairs()); }
  bool uses_neighbor_list() const override { return true; }
  std::unique_ptr<ForceTerm> on_particles(std::vector<int> types, const std::vector<Bond>& bonds,
                                          const Box& box) const override {
    return std::make_unique<PairTerm>(name(), level(), std::move(types), coeffs_, bonds, weights_, box, list_.skin());
  }
  // The pairs among the subset's particles: its types, the special pairs of its bonds.
  std::unique_ptr<ForceTerm> on_subset(const ParticleSubset& subset, const Box& box) const override {
    return on_particles(std::vector<int>(subset.types.begin(), subset.types.end()), subset.topology.bonds, box);
  }
  double pair_cutoff() const override { return cutoff_; }
  double pair_skin() const override { return list_.skin(); }
  double cutoff() const { return cutoff_; }  // the largest over type pairs
  double skin() const { return list_.skin(); }
  const TypePairMatrix<Coeffs>& coeffs() const { return coeffs_; }
  SpecialWeights weights() const { return weights_; }
  std::size_t excluded_pairs() const { return excluded_; }               // weight 0: never listed
  std::span<const SpecialPair> scaled_pairs() const { return scaled_; }  // 0 < weight < 1
  const NeighborList& neighbor_list() const { return list_; }            // as of the last call

 private:
  void check_positions(const Eigen::Matrix3Xd& x, const Eigen::Matrix3Xd* f) const;
  void set_special(std::span<const SpecialPair> special);

  std::vector<int> types_;
  TypePairMatrix<Coeffs> coeffs_;
  double cutoff_ = 0.0;
  TypePairMatrix<Params> params_;
  SpecialWeights weights_;
  std::size_t excluded_ = 0;
  std::vector<SpecialPair> special_;  // every pair with w ≠ 1
  std::vector<SpecialPair> scaled_;   // those with 0 < w < 1
  // A cache of the positions, not part of the term's value: rebuilt on demand by the const
  // add_forces/virial when the list may miss a pair (NeighborList::update), hence mutable.
  mutable NeighborList list_;
  mutable PairScratch scratch_;  // per-thread force buffers of the pair loop
};

using LennardJonesPair = PairTerm<LennardJones>;
using WcaPair = PairTerm<WeeksChandlerAndersen>;
using SoftPair = PairTerm<SoftCosine>;

// ---------------------------------------------------------------------------------------
// The members, in the header so that a new kernel needs no explicit instantiation. What does
// not depend on the kernel is in pair_term.cpp.

namespace pair_detail {
[[noreturn]] void fail(const std::string& name, std::string_view style, const std::string& what);
// The checks that do not depend on the kernel: particle types in 0 … ntypes − 1, weights in
// [0, 1], skin ≥ 0, a box of at least 2 × (rc + skin) on periodic axes.
void check_pair_inputs(const std::string& name, std::string_view style, const std::vector<int>& types, int ntypes,
                       SpecialWeights weights, const Box& box, double rc, double skin);
// Particle types in 0 … ntypes − 1.
void check_types(const std::string& name, std::string_view style, std::span<const int> types, int ntypes);
std::vector<SpecialPair> special_pairs_of(const std::string& name, std::string_view style, int n,
                                          const std::vector<Bond>& bonds, SpecialWeights weights);
void check_sizes(const std::string& name, std::string_view style, const Eigen::Matrix3Xd& x, const Eigen::Matrix3Xd* f,
                 std::size_t num_types);
std::string describe_pairs(std::string_view style, int num_types, double cutoff, const NeighborList& list,
                           SpecialWeights weights, std::size_t excluded, std::size_t scaled);
// What define() writes besides the coefficients: each particle's type, the cutoff, the skin (it
// decides when the list is rebuilt, and so the order of the pair sums), the special weights and
// the scaled pairs. The excluded pairs follow from the scene's bonds, which the scene writes.
void define_pair_settings(ParameterRecord& record, const std::vector<int>& types, double cutoff, double skin,
                          SpecialWeights weights, std::size_t excluded, std::span<const SpecialPair> scaled);
// The neighbour list's state for checkpoints: its positions, box and rebuild count at the last
// build, from which restore() rebuilds the same list (same pairs, order and images).
std::vector<double> save_list_state(const NeighborList& list);
void load_list_state(const std::string& name, std::string_view style, NeighborList& list, std::span<const double> w,
                     std::size_t n);

// Checks every input of the constructor; returns the largest cutoff over type pairs, which
// sets the list radius.
template <class Kernel>
double validated_cutoff(const std::string& name, const std::vector<int>& types,
                        const TypePairMatrix<typename Kernel::Coeffs>& coeffs, SpecialWeights weights, const Box& box,
                        double skin) {
  const int ntypes = coeffs.num_types();
  if (ntypes < 1) fail(name, Kernel::kStyle, "no particle types given pair coefficients");
  double rc = 0.0;
  for (int a = 0; a < ntypes; ++a)
    for (int b = a; b < ntypes; ++b) {
      const std::string where = "types (" + std::to_string(a) + ", " + std::to_string(b) + "): ";
      if (!coeffs.is_set(a, b)) fail(name, Kernel::kStyle, where + "pair coefficients not given");
      try {
        Kernel::validate(coeffs(a, b));
      } catch (const std::invalid_argument& e) {
        fail(name, Kernel::kStyle, where + e.what());
      }
      rc = std::max(rc, Kernel::cutoff(coeffs(a, b)));
    }
  check_pair_inputs(name, Kernel::kStyle, types, ntypes, weights, box, rc, skin);
  return rc;
}
}  // namespace pair_detail

template <class Kernel>
PairTerm<Kernel>::PairTerm(std::string name, Level level, std::vector<int> types, TypePairMatrix<Coeffs> coeffs,
                           const std::vector<Bond>& bonds, SpecialWeights weights, const Box& box, double skin)
    : ForceTerm(std::move(name), level),
      types_(std::move(types)),
      coeffs_(std::move(coeffs)),
      cutoff_(pair_detail::validated_cutoff<Kernel>(this->name(), types_, coeffs_, weights, box, skin)),
      params_(coeffs_.transform([](const Coeffs& c) { return Kernel::params(c); })),
      weights_(weights),
      list_(cutoff_, skin) {
  const int n = static_cast<int>(types_.size());
  set_special(pair_detail::special_pairs_of(this->name(), Kernel::kStyle, n, bonds, weights));
}

// Every pair with w ≠ 1 leaves the list; the scaled ones (0 < w < 1) go through scaled_.
template <class Kernel>
void PairTerm<Kernel>::set_special(std::span<const SpecialPair> special) {
  list_.set_exclusions(static_cast<int>(types_.size()), special);
  special_.assign(special.begin(), special.end());
  scaled_.clear();
  excluded_ = 0;
  for (const SpecialPair& sp : special_) {
    if (sp.weight > 0.0)
      scaled_.push_back(sp);
    else
      ++excluded_;
  }
}

template <class Kernel>
void PairTerm<Kernel>::move_to(std::span<const int> types, std::span<const SpecialPair> special,
                               std::span<const char> ghost) {
  pair_detail::check_types(name(), Kernel::kStyle, types, coeffs_.num_types());
  types_.assign(types.begin(), types.end());
  set_special(special);
  list_.set_ghosts(ghost);
}

template <class Kernel>
void PairTerm<Kernel>::check_positions(const Eigen::Matrix3Xd& x, const Eigen::Matrix3Xd* f) const {
  pair_detail::check_sizes(name(), Kernel::kStyle, x, f, types_.size());
}

template <class Kernel>
double PairTerm<Kernel>::add_forces(const Eigen::Matrix3Xd& x, const Box& box, Eigen::Matrix3Xd& f) const {
  check_positions(x, &f);
  {
    const ScopedPhase phase(Phase::neighbor);
    list_.update(x, box);
  }
  return accumulate_pairs<Kernel, true, false>(list_, scaled_, params_, types_.data(), x, box, f.data(), scratch_)
      .energy;
}

template <class Kernel>
void PairTerm<Kernel>::add_forces_and_virial_diagonal(const Eigen::Matrix3Xd& x, const Box& box, Eigen::Matrix3Xd& f,
                                                      ExactDiagonal& w) const {
  check_positions(x, &f);
  {
    const ScopedPhase phase(Phase::neighbor);
    list_.update(x, box);
  }
  // With ghosts (a decomposed run's part) this process's share (kShares); without, the whole.
  const PairSums s =
      accumulate_pairs<Kernel, true, true, true>(list_, scaled_, params_, types_.data(), x, box, f.data(), scratch_);
  w.add(s.diagonal);
}

template <class Kernel>
double PairTerm<Kernel>::virial(const Eigen::Matrix3Xd& x, const Box& box) const {
  check_positions(x, nullptr);
  {
    const ScopedPhase phase(Phase::neighbor);
    list_.update(x, box);
  }
  return accumulate_pairs<Kernel, false, true>(list_, scaled_, params_, types_.data(), x, box, nullptr, scratch_)
      .virial;
}

template <class Kernel>
ForceTerm::Sums PairTerm<Kernel>::energy_and_virial(const Eigen::Matrix3Xd& x, const Box& box,
                                                    Eigen::Matrix3Xd& scratch) const {
  (void)scratch;
  check_positions(x, nullptr);
  {
    const ScopedPhase phase(Phase::neighbor);
    list_.update(x, box);
  }
  const PairSums s =
      accumulate_pairs<Kernel, false, true, true>(list_, scaled_, params_, types_.data(), x, box, nullptr, scratch_);
  return {s.energy, s.virial};
}

// The coefficients of every type pair (a, b), a <= b, as the pair loop uses them: after the
// mixing rule and the per-pair overrides.
template <class Kernel>
void PairTerm<Kernel>::define(ParameterRecord& record) const {
  const int n = coeffs_.num_types();
  record.add("particle types", n);
  for (int a = 0; a < n; ++a)
    for (int b = a; b < n; ++b) Kernel::define(record, coeffs_(a, b));
  pair_detail::define_pair_settings(record, types_, cutoff_, list_.skin(), weights_, excluded_, scaled_);
}

template <class Kernel>
std::string PairTerm<Kernel>::describe() const {
  return pair_detail::describe_pairs(Kernel::kStyle, coeffs_.num_types(), cutoff_, list_, weights_, excluded_,
                                     scaled_.size()) +
         ", " + std::to_string(list_.rebuilds()) + " neighbour-list rebuilds so far";
}

template <class Kernel>
std::vector<double> PairTerm<Kernel>::save_state() const {
  return pair_detail::save_list_state(list_);
}

template <class Kernel>
void PairTerm<Kernel>::load_state(std::span<const double> words) {
  pair_detail::load_list_state(name(), Kernel::kStyle, list_, words, types_.size());
}

}  // namespace stiffmd
