// Short-range pair styles as force terms: PairTerm over a kernel of pair_potentials.hpp (`lj`,
// `wca`, `soft`, …) or of coulomb_potentials.hpp (the charged styles: `coul/cut`, `lj/cut/coul/long`,
// …). Energy E = Σ_{i<j} w_ij E_ab(|x_i − x_j|) with a, b the particle types, w_ij the special-bond
// weight (1 unless i, j are 1-2 or 1-3 bonded neighbours), minimum image on periodic axes; a charged
// kernel weights its van der Waals and Coulomb parts apart (special_lj, special_coul) and reads the
// particles' charges. Pairs are found through a Verlet list with a skin (neighbor_list.hpp).
#pragma once

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <limits>
#include <memory>
#include <span>
#include <stdexcept>
#include <string>
#include <vector>

#include "core/timing.hpp"
#include "core/topology.hpp"
#include "forcefields/coulomb_potentials.hpp"
#include "forcefields/ewald_real_space.hpp"
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
  // The charge of each of its particles (charged styles); empty for an uncharged style.
  virtual std::span<const double> charges() const = 0;
  // The term on another particle set: types[i] per particle, charges[i] per particle (a charged
  // style; an uncharged one takes none), `special` its special pairs as special_pairs gives them
  // (sorted by (i, j); weights from this term's w12, w13, w14 and Coulomb weights), ghost[i]
  // (empty or all 0: none; NeighborList::set_ghosts). The same term, bit for bit, as on_particles
  // builds with the bonds that give `special`, and then set_ghosts; the list is built at the next
  // evaluation, allocating nothing once its buffers have grown. Throws std::invalid_argument for a
  // type or a pair out of range, or charges of another count.
  virtual void move_to(std::span<const int> types, std::span<const double> charges,
                       std::span<const SpecialPair> special, std::span<const char> ghost) = 0;
  // The same with `special` handed over: the term keeps that vector as its list. With
  // take_special_pairs, which hands the term's list's storage out emptied (its capacity kept),
  // a caller that makes the next particle set's special pairs fills the term's own storage: the
  // term's list is their only copy, and nothing is allocated once it has grown.
  virtual void move_to(std::span<const int> types, std::span<const double> charges, std::vector<SpecialPair>&& special,
                       std::span<const char> ghost) = 0;
  virtual std::vector<SpecialPair> take_special_pairs() = 0;
  // The share of the long-range tail correction (PairTerm::set_tail) this particle set adds to
  // the energy and the virial: 1 (the default) on one process, on a decomposed run's ranks 1 on
  // the rank that is home to particle 0 and 0 on the others, so that the ranks' shares add up to
  // the whole, exactly. No effect without the tail correction.
  virtual void set_tail_share(double share) = 0;
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
  // Each pair of a particle and a ghost evaluated by one process only, counted whole there
  // (NeighborList::set_ghost_pairs_once); its special pairs are then given that way too.
  virtual void set_ghost_pairs_once(bool once) = 0;
};

// What a charged pair term needs besides an uncharged one's inputs.
struct Electrostatics {
  std::vector<double> charges;  // per particle, in e
  double qqrd2e = 1.0;          // the Coulomb constant in the run's units (Units::coulomb)
  SpecialWeights coul;          // LAMMPS special_bonds coul w12 w13 w14
};

namespace pair_detail {
[[noreturn]] void fail(const std::string& name, std::string_view style, const std::string& what);
// The checks that do not depend on the kernel: particle types in 0 … ntypes − 1, weights in
// [0, 1], skin ≥ 0, a box of at least 2 × (rc + skin) on periodic axes.
void check_pair_inputs(const std::string& name, std::string_view style, const std::vector<int>& types, int ntypes,
                       SpecialWeights weights, const Box& box, double rc, double skin);
// Particle types in 0 … ntypes − 1.
void check_types(const std::string& name, std::string_view style, std::span<const int> types, int ntypes);
std::vector<SpecialPair> special_pairs_of(const std::string& name, std::string_view style, int n,
                                          const std::vector<Bond>& bonds, SpecialWeights weights, SpecialWeights coul);
// v in the shortest form that reads back (for describe()).
std::string number_text(double v);
// Coulomb weights in [0, 1], a charge per particle (finite), qqrd2e finite and > 0.
void check_electrostatics(const std::string& name, std::string_view style, const Electrostatics& e,
                          std::size_t particles);
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

template <class Derived, bool kLong>
class PairEwaldPart {};  // an uncharged or a cut-off Coulomb style: no Ewald sum

// The coul/long family's EwaldRealSpace, on the PairTerm (CRTP).
template <class Derived>
class PairEwaldPart<Derived, true> : public EwaldRealSpace {
 public:
  double coulomb_cutoff() const override { return static_cast<const Derived&>(*this).one_coulomb_cutoff(); }
  void set_ewald_splitting(double g) override { static_cast<Derived&>(*this).set_splitting(g); }
  double ewald_splitting() const override { return static_cast<const Derived&>(*this).splitting(); }
};

template <class Kernel>
class PairTerm final : public ForceTerm,
                       public PairsOnParticles,
                       public PairEwaldPart<PairTerm<Kernel>, EwaldKernel<Kernel>> {
 public:
  using Coeffs = typename Kernel::Coeffs;
  using Params = typename Kernel::Params;
  static constexpr bool kCharged = ChargedKernel<Kernel>;
  static constexpr bool kEwald = EwaldKernel<Kernel>;
  static constexpr bool kHasTail = requires(const Coeffs& c, double& e, double& p) { Kernel::tail(c, e, p); };

  // types[i]: the type of particle i, in 0 … coeffs.num_types() − 1; every type pair must have
  // coefficients. bonds: the scene's bonds, from which the 1-2 and 1-3 pairs of `weights` are
  // found. box: checked to be at least 2 × (cutoff + skin) on periodic axes. skin ≥ 0: the
  // Verlet skin (length). Throws std::invalid_argument, naming the term, on any bad input.
  // A charged kernel needs `electrostatics`: a charge per particle (none for no particle), the
  // Coulomb constant and the Coulomb special weights (`weights` are then the van der Waals ones).
  // A coul/long kernel's Coulomb cutoff must be the same for every type pair.
  PairTerm(std::string name, Level level, std::vector<int> types, TypePairMatrix<Coeffs> coeffs,
           const std::vector<Bond>& bonds, SpecialWeights weights, const Box& box, double skin = 0.3,
           Electrostatics electrostatics = {});

  // Rebuild the neighbour list if stale, then the forces (add_forces) or Σ r_ij·f_ij (virial).
  // Not safe to call concurrently on one term: they update the list.
  double add_forces(const Eigen::Matrix3Xd& x, const Box& box, Eigen::Matrix3Xd& f) const override;
  // The same forces, bit for bit, without the energy: the force-only pair loop
  // (accumulate_pair_forces_rows: the kernel on the interacting pairs alone, no sums).
  void add_forces_only(const Eigen::Matrix3Xd& x, const Box& box, Eigen::Matrix3Xd& f) const override;
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
  std::span<const double> charges() const override { return charges_; }
  void move_to(std::span<const int> types, std::span<const double> charges, std::span<const SpecialPair> special,
               std::span<const char> ghost) override;
  void move_to(std::span<const int> types, std::span<const double> charges, std::vector<SpecialPair>&& special,
               std::span<const char> ghost) override;
  std::vector<SpecialPair> take_special_pairs() override {
    std::vector<SpecialPair> storage = std::move(special_);
    special_.clear();
    storage.clear();
    return storage;
  }
  void set_tail_share(double share) override { tail_share_ = share; }
  void set_rebuild_agreement(NeighborList::RebuildAgreement agree) override {
    list_.set_rebuild_agreement(std::move(agree));
  }
  void set_positions_wrapped(bool wrapped) override { list_.set_positions_wrapped(wrapped); }
  void set_ghost_pairs_once(bool once) override { list_.set_ghost_pairs_once(once); }
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
  void release_buffers() const override { list_.release(); }  // the next evaluation builds the list
  bool uses_neighbor_list() const override { return true; }
  bool uses_charges() const override { return kCharged; }
  // A charged term on particles other than its own takes charges it does not know: only on none
  // (a decomposed run's term on the pair set, which move_to then gives their charges).
  std::unique_ptr<ForceTerm> on_particles(std::vector<int> types, const std::vector<Bond>& bonds,
                                          const Box& box) const override {
    if (kCharged && !types.empty())
      pair_detail::fail(name(), Kernel::kStyle, "a charged pair term on other particles needs their charges");
    return copy_on(std::move(types), {}, bonds, box);
  }
  // The pairs among the subset's particles: its types, its charges (subset.charges; without them
  // this term's of the subset's particles, subset.global), the special pairs of its bonds; the tail
  // correction's whole-system type counts and the Ewald splitting as this term's.
  std::unique_ptr<ForceTerm> on_subset(const ParticleSubset& subset, const Box& box) const override {
    std::vector<double> q;
    if constexpr (kCharged) {
      if (subset.charges.size() == subset.global.size())
        q.assign(subset.charges.begin(), subset.charges.end());
      else
        for (const int g : subset.global) q.push_back(charges_.at(static_cast<std::size_t>(g)));
    }
    return copy_on(std::vector<int>(subset.types.begin(), subset.types.end()), std::move(q), subset.topology.bonds,
                   box);
  }
  double pair_cutoff() const override { return cutoff_; }
  double pair_skin() const override { return list_.skin(); }
  double cutoff() const { return cutoff_; }  // the largest over type pairs
  double skin() const { return list_.skin(); }
  const TypePairMatrix<Coeffs>& coeffs() const { return coeffs_; }
  SpecialWeights weights() const { return weights_; }  // special_lj for a charged style
  SpecialWeights coulomb_weights() const { return electrostatics_.coul; }
  double qqrd2e() const { return electrostatics_.qqrd2e; }
  // Weight 0 (both weights, charged styles): never listed, and never evaluated but by a coul/long
  // kernel (the Ewald exclusion correction, in scaled_pairs).
  std::size_t excluded_pairs() const { return excluded_; }
  // The special pairs evaluated apart from the list: 0 < weight < 1 (either weight, charged
  // styles); with a coul/long kernel every special pair.
  std::span<const SpecialPair> scaled_pairs() const { return scaled_; }
  const NeighborList& neighbor_list() const { return list_; }  // as of the last call

  // The long-range tail correction (LAMMPS pair_modify tail yes) of a kernel with `tail`: the
  // energy Σ_ab N_a N_b etail_ab / V and the virial 3 Σ_ab N_a N_b ptail_ab / V (ptail/V per diagonal
  // component), V the box's volume at each evaluation (so it follows a barostat), N_a the counts
  // of the types of this term's particles now (the whole system's: copies keep them) and of
  // `counted` (per type, particles of the system this term does not hold: a scene's description
  // counts its chains' beads, engine/scene/scene.hpp; empty for none). The counts are integers
  // summed in double, exact, so the sums are the same bits as a term holding every particle.
  // Needs a fully periodic box (std::invalid_argument at the evaluation otherwise).
  void set_tail(bool on, std::span<const std::int64_t> counted = {});
  bool tail() const { return tail_; }
  // Σ_ab N_a N_b etail_ab and Σ_ab N_a N_b ptail_ab (0 without the tail).
  double tail_energy_volume() const { return etail_; }
  double tail_pressure_volume() const { return ptail_; }
  // The latest energy_and_virial's Coulomb part (LAMMPS's ecoul; this process's share with ghosts).
  double coulomb_energy() const { return coulomb_energy_; }
  ForceTerm::Sums energy_and_virial(const Eigen::Matrix3Xd& x, const Box& box) const;

  // PairEwaldPart's (coul/long kernels).
  double one_coulomb_cutoff() const {
    if constexpr (kCharged) return Kernel::coulomb_cutoff(coeffs_(0, 0));
    return 0.0;
  }
  void set_splitting(double g) { set_splitting(g, nullptr); }
  double splitting() const { return g_ewald_; }

 private:
  void check_positions(const Eigen::Matrix3Xd& x, const Eigen::Matrix3Xd* f) const;
  // g and its table (null: made here; a copy's: the original's, the same for the same g).
  void set_splitting(double g, std::shared_ptr<const EwaldRealSpaceTable> table);
  void set_special(std::span<const SpecialPair> special);
  // special_ given: the list's exclusions and scaled_ from it.
  void apply_special();
  // move_to's types, charges and their checks.
  void take_types(std::span<const int> types, std::span<const double> charges);
  void set_charges(std::vector<double> q);
  void find_uniform_type() {
    uniform_type_ = types_.empty() ? -1 : types_[0];
    for (const int t : types_)
      if (t != uniform_type_) uniform_type_ = -1;
  }
  void check_ready(const Box& box) const;
  PairCharges loop_charges() const { return {charges_.data(), electrostatics_.qqrd2e}; }
  // The tail's energy and virial at this box (0, 0 without it).
  std::pair<double, double> tail_at(const Box& box) const;
  std::unique_ptr<ForceTerm> copy_on(std::vector<int> types, std::vector<double> q, const std::vector<Bond>& bonds,
                                     const Box& box) const;

  std::vector<int> types_;
  int uniform_type_ = -1;  // the type of every particle when they have one, else −1 (the force-only loop)
  TypePairMatrix<Coeffs> coeffs_;
  double cutoff_ = 0.0;
  TypePairMatrix<Params> params_;
  SpecialWeights weights_;
  std::size_t excluded_ = 0;
  std::vector<SpecialPair> special_;                           // every pair with w ≠ 1 (either weight)
  std::vector<SpecialPair> scaled_;                            // those evaluated (see scaled_pairs)
  Electrostatics electrostatics_;                              // coul weights and qqrd2e (charged kernels)
  std::vector<double> charges_;                                // per particle (charged kernels), else empty
  double g_ewald_ = std::numeric_limits<double>::quiet_NaN();  // coul/long kernels
  std::shared_ptr<const EwaldRealSpaceTable> table_;           // E, G at g (coul/long kernels)
  bool tail_ = false;
  double etail_ = 0.0, ptail_ = 0.0;  // Σ N_a N_b etail_ab, Σ N_a N_b ptail_ab
  double tail_share_ = 1.0;
  mutable double coulomb_energy_ = 0.0;
  // A cache of the positions, not part of the term's value: rebuilt on demand by the const
  // add_forces/virial when the list may miss a pair (NeighborList::update), hence mutable.
  mutable NeighborList list_;
  mutable PairScratch scratch_;  // per-thread force buffers of the pair loop
};

using LennardJonesPair = PairTerm<LennardJones>;
using WcaPair = PairTerm<WeeksChandlerAndersen>;
using SoftPair = PairTerm<SoftCosine>;
using CoulombCutPair = PairTerm<CoulombCut>;
using CoulombDebyePair = PairTerm<CoulombDebye>;
using CoulombLongPair = PairTerm<CoulombLong>;
using LjCutCoulCutPair = PairTerm<LjCutCoulCut>;
using LjCutCoulDebyePair = PairTerm<LjCutCoulDebye>;
using LjCutCoulLongPair = PairTerm<LjCutCoulLong>;
using LjCharmmCoulLongPair = PairTerm<LjCharmmCoulLong>;

// ---------------------------------------------------------------------------------------
// The members, in the header so that a new kernel needs no explicit instantiation. What does
// not depend on the kernel is in pair_term.cpp.

template <class Kernel>
PairTerm<Kernel>::PairTerm(std::string name, Level level, std::vector<int> types, TypePairMatrix<Coeffs> coeffs,
                           const std::vector<Bond>& bonds, SpecialWeights weights, const Box& box, double skin,
                           Electrostatics electrostatics)
    : ForceTerm(std::move(name), level),
      types_(std::move(types)),
      coeffs_(std::move(coeffs)),
      cutoff_(pair_detail::validated_cutoff<Kernel>(this->name(), types_, coeffs_, weights, box, skin)),
      params_(coeffs_.transform([](const Coeffs& c) { return Kernel::params(c); })),
      weights_(weights),
      list_(cutoff_, skin) {
  const int n = static_cast<int>(types_.size());
  if constexpr (kCharged) {
    pair_detail::check_electrostatics(this->name(), Kernel::kStyle, electrostatics, types_.size());
    if constexpr (kEwald)
      for (int a = 0; a < coeffs_.num_types(); ++a)
        for (int b = a; b < coeffs_.num_types(); ++b)
          if (Kernel::coulomb_cutoff(coeffs_(a, b)) != one_coulomb_cutoff())
            pair_detail::fail(this->name(), Kernel::kStyle,
                              "the Coulomb cutoff of an Ewald sum must be one for every type pair (types (" +
                                  std::to_string(a) + ", " + std::to_string(b) + ") differ from (0, 0))");
    charges_ = std::move(electrostatics.charges);
    electrostatics_ = std::move(electrostatics);
    electrostatics_.charges.clear();
  } else {
    electrostatics_.coul = weights;
  }
  set_special(pair_detail::special_pairs_of(this->name(), Kernel::kStyle, n, bonds, weights, electrostatics_.coul));
  find_uniform_type();
}

// Every pair with w ≠ 1 (either weight) leaves the list; those evaluated (scaled_pairs) go through
// scaled_.
template <class Kernel>
void PairTerm<Kernel>::set_special(std::span<const SpecialPair> special) {
  special_.assign(special.begin(), special.end());
  apply_special();
}

template <class Kernel>
void PairTerm<Kernel>::apply_special() {
  list_.set_exclusions(static_cast<int>(types_.size()), special_);
  scaled_.clear();
  excluded_ = 0;
  for (const SpecialPair& sp : special_) {
    const bool excluded = kCharged ? sp.weight == 0.0 && sp.weight_coul == 0.0 : !(sp.weight > 0.0);
    if (excluded) ++excluded_;
    if (!excluded || kEwald) scaled_.push_back(sp);
  }
}

template <class Kernel>
void PairTerm<Kernel>::move_to(std::span<const int> types, std::span<const double> charges,
                               std::span<const SpecialPair> special, std::span<const char> ghost) {
  take_types(types, charges);
  set_special(special);
  list_.set_ghosts(ghost);
}

template <class Kernel>
void PairTerm<Kernel>::move_to(std::span<const int> types, std::span<const double> charges,
                               std::vector<SpecialPair>&& special, std::span<const char> ghost) {
  take_types(types, charges);
  special_ = std::move(special);
  apply_special();
  list_.set_ghosts(ghost);
}

template <class Kernel>
void PairTerm<Kernel>::take_types(std::span<const int> types, std::span<const double> charges) {
  pair_detail::check_types(name(), Kernel::kStyle, types, coeffs_.num_types());
  if (charges.size() != (kCharged ? types.size() : 0))
    pair_detail::fail(name(), Kernel::kStyle,
                      std::to_string(charges.size()) + " charges for " + std::to_string(types.size()) + " particles (" +
                          (kCharged ? "one per particle" : "an uncharged style takes none") + ")");
  types_.assign(types.begin(), types.end());
  find_uniform_type();
  charges_.assign(charges.begin(), charges.end());
}

template <class Kernel>
std::unique_ptr<ForceTerm> PairTerm<Kernel>::copy_on(std::vector<int> types, std::vector<double> q,
                                                     const std::vector<Bond>& bonds, const Box& box) const {
  Electrostatics e = electrostatics_;
  e.charges = std::move(q);
  auto term = std::make_unique<PairTerm>(name(), level(), std::move(types), coeffs_, bonds, weights_, box, list_.skin(),
                                         std::move(e));
  term->tail_ = tail_;
  term->etail_ = etail_;
  term->ptail_ = ptail_;
  if constexpr (kEwald)
    if (!std::isnan(g_ewald_)) term->set_splitting(g_ewald_, table_);
  return term;
}

template <class Kernel>
void PairTerm<Kernel>::set_tail(bool on, std::span<const std::int64_t> counted) {
  tail_ = false;
  etail_ = ptail_ = 0.0;
  if (!on) return;
  if constexpr (!kHasTail) {
    pair_detail::fail(name(), Kernel::kStyle, "this style has no long-range tail correction");
  } else {
    const int nt = coeffs_.num_types();
    std::vector<double> count(static_cast<std::size_t>(nt), 0.0);
    for (const int t : types_) count[static_cast<std::size_t>(t)] += 1.0;
    if (!counted.empty() && counted.size() != count.size())
      pair_detail::fail(name(), Kernel::kStyle,
                        "the tail correction's counted particles are given for " + std::to_string(counted.size()) +
                            " types, not its " + std::to_string(nt));
    for (std::size_t a = 0; a < counted.size(); ++a) count[a] += static_cast<double>(counted[a]);
    for (int a = 0; a < nt; ++a)  // as LAMMPS's Pair::init: i <= j, an unlike pair twice
      for (int b = a; b < nt; ++b) {
        double e = 0.0, p = 0.0;
        Kernel::tail(coeffs_(a, b), e, p);
        const double nn = count[a] * count[b] * (a == b ? 1.0 : 2.0);
        etail_ += nn * e;
        ptail_ += nn * p;
      }
    tail_ = true;
  }
}

template <class Kernel>
std::pair<double, double> PairTerm<Kernel>::tail_at(const Box& box) const {
  if (!tail_ || tail_share_ == 0.0) return {0.0, 0.0};
  if (!(box.periodic[0] && box.periodic[1] && box.periodic[2]))
    pair_detail::fail(name(), Kernel::kStyle, "the tail correction needs a box periodic on every axis");
  const double volume = box.lengths[0] * box.lengths[1] * box.lengths[2];
  return {tail_share_ * etail_ / volume, tail_share_ * 3.0 * ptail_ / volume};
}

template <class Kernel>
void PairTerm<Kernel>::set_splitting(double g, std::shared_ptr<const EwaldRealSpaceTable> table) {
  if (!(g > 0.0) || !std::isfinite(g))
    pair_detail::fail(name(), Kernel::kStyle,
                      "the Ewald splitting g must be finite and > 0 (got " + std::to_string(g) + ")");
  g_ewald_ = g;
  if constexpr (kEwald) {
    table_ = table && table->g() == g ? std::move(table)
                                      : std::make_shared<const EwaldRealSpaceTable>(g, one_coulomb_cutoff());
    const int nt = params_.num_types();
    for (int a = 0; a < nt; ++a)
      for (int b = a; b < nt; ++b) {
        Params p = params_(a, b);
        p.g_ewald = g;
        p.table = table_.get();
        params_.set(a, b, p);
      }
  }
}

// Before an evaluation: a coul/long kernel's splitting set (by the k-space term).
template <class Kernel>
void PairTerm<Kernel>::check_ready(const Box& box) const {
  (void)box;
  if constexpr (kEwald)
    if (std::isnan(g_ewald_))
      pair_detail::fail(name(), Kernel::kStyle,
                        "the Ewald splitting g was never set: the real-space Coulomb sum needs a k-space term "
                        "(ewald or pppm) that sets it");
}

template <class Kernel>
void PairTerm<Kernel>::check_positions(const Eigen::Matrix3Xd& x, const Eigen::Matrix3Xd* f) const {
  pair_detail::check_sizes(name(), Kernel::kStyle, x, f, types_.size());
}

template <class Kernel>
double PairTerm<Kernel>::add_forces(const Eigen::Matrix3Xd& x, const Box& box, Eigen::Matrix3Xd& f) const {
  check_positions(x, &f);
  check_ready(box);
  {
    const ScopedPhase phase(Phase::neighbor);
    list_.update(x, box);
  }
  return accumulate_pairs<Kernel, true, false>(list_, scaled_, params_, types_.data(), x, box, f.data(), scratch_,
                                               loop_charges())
             .energy +
         tail_at(box).first;
}

template <class Kernel>
void PairTerm<Kernel>::add_forces_only(const Eigen::Matrix3Xd& x, const Box& box, Eigen::Matrix3Xd& f) const {
  check_positions(x, &f);
  check_ready(box);
  {
    const ScopedPhase phase(Phase::neighbor);
    list_.update(x, box);
  }
  accumulate_pairs<Kernel, true, false, false, false>(list_, scaled_, params_, types_.data(), x, box, f.data(),
                                                      scratch_, loop_charges(), uniform_type_);
}

template <class Kernel>
void PairTerm<Kernel>::add_forces_and_virial_diagonal(const Eigen::Matrix3Xd& x, const Box& box, Eigen::Matrix3Xd& f,
                                                      ExactDiagonal& w) const {
  check_positions(x, &f);
  check_ready(box);
  {
    const ScopedPhase phase(Phase::neighbor);
    list_.update(x, box);
  }
  // With ghosts (a decomposed run's part) this process's share (kShares); without, the whole.
  const PairSums s = accumulate_pairs<Kernel, true, true, true>(list_, scaled_, params_, types_.data(), x, box,
                                                                f.data(), scratch_, loop_charges());
  w.add(s.diagonal);
  if (const double tail_virial = tail_at(box).second; tail_virial != 0.0)
    for (int a = 0; a < 3; ++a) w.axis[a].add(tail_virial / 3.0);
}

template <class Kernel>
double PairTerm<Kernel>::virial(const Eigen::Matrix3Xd& x, const Box& box) const {
  check_positions(x, nullptr);
  check_ready(box);
  {
    const ScopedPhase phase(Phase::neighbor);
    list_.update(x, box);
  }
  return accumulate_pairs<Kernel, false, true>(list_, scaled_, params_, types_.data(), x, box, nullptr, scratch_,
                                               loop_charges())
             .virial +
         tail_at(box).second;
}

template <class Kernel>
ForceTerm::Sums PairTerm<Kernel>::energy_and_virial(const Eigen::Matrix3Xd& x, const Box& box,
                                                    Eigen::Matrix3Xd& scratch) const {
  (void)scratch;
  return energy_and_virial(x, box);
}

template <class Kernel>
ForceTerm::Sums PairTerm<Kernel>::energy_and_virial(const Eigen::Matrix3Xd& x, const Box& box) const {
  check_positions(x, nullptr);
  check_ready(box);
  {
    const ScopedPhase phase(Phase::neighbor);
    list_.update(x, box);
  }
  const PairSums s = accumulate_pairs<Kernel, false, true, true>(list_, scaled_, params_, types_.data(), x, box,
                                                                 nullptr, scratch_, loop_charges());
  const auto [tail_energy, tail_virial] = tail_at(box);
  coulomb_energy_ = s.coulomb;
  return {s.energy + tail_energy, s.virial + tail_virial, s.coulomb, s.energy - s.coulomb + tail_energy};
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
  if (tail_) record.add("tail", 1);
  if constexpr (kCharged) {
    record.add("charges", std::span<const double>(charges_));
    record.add("qqrd2e", electrostatics_.qqrd2e);
    record.add("coul w12", electrostatics_.coul.w12);
    record.add("coul w13", electrostatics_.coul.w13);
    record.add("coul w14", electrostatics_.coul.w14);
    for (const SpecialPair& p : scaled_) record.add("weight_coul", p.weight_coul);
  }
  if constexpr (kEwald) record.add("g_ewald", g_ewald_);
}

template <class Kernel>
std::string PairTerm<Kernel>::describe() const {
  std::string s = pair_detail::describe_pairs(Kernel::kStyle, coeffs_.num_types(), cutoff_, list_, weights_, excluded_,
                                              scaled_.size());
  if constexpr (kCharged) {
    const SpecialWeights& c = electrostatics_.coul;
    s += ", special coul w12 = " + pair_detail::number_text(c.w12) + ", w13 = " + pair_detail::number_text(c.w13) +
         ", w14 = " + pair_detail::number_text(c.w14);
  }
  if constexpr (kEwald)
    s += ", Ewald g = " + (std::isnan(g_ewald_) ? std::string("not set") : pair_detail::number_text(g_ewald_));
  if (tail_) s += ", tail correction";
  return s + ", " + std::to_string(list_.rebuilds()) + " neighbour-list rebuilds so far";
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
