#include "engine/domain/ghosted_pairs.hpp"

#include <algorithm>
#include <stdexcept>

namespace stiffmd {

SpecialPartners::SpecialPartners(std::span<const SpecialPair> pairs, int num_particles)
    : start(static_cast<size_t>(num_particles) + 1, 0) {
  for (const SpecialPair& p : pairs) ++start[p.i + 1], ++start[p.j + 1];
  for (int g = 0; g < num_particles; ++g) start[g + 1] += start[g];
  partner.resize(start.back());
  weight.resize(start.back());
  weight_coul.resize(start.back());
  std::vector<int> next(start.begin(), start.end() - 1);
  for (const SpecialPair& p : pairs) {
    partner[next[p.i]] = p.j, weight[next[p.i]] = p.weight, weight_coul[next[p.i]++] = p.weight_coul;
    partner[next[p.j]] = p.i, weight[next[p.j]] = p.weight, weight_coul[next[p.j]++] = p.weight_coul;
  }
}

GhostedPairs::GhostedPairs(const ForceTerm& whole_term, Decomposition& domains, std::span<const int> types,
                           std::span<const double> charges, const SpecialPartners& special, GhostedPairs* old)
    : ForceTerm(whole_term.name(), whole_term.level()),
      template_(whole_term),
      domains_(domains),
      whole_types_(types),
      whole_charges_(whole_term.uses_charges() ? charges : std::span<const double>()),
      whole_special_(special) {
  if (whole_term.uses_charges() && charges.size() != types.size())
    throw std::invalid_argument("GhostedPairs: term '" + name() + "' reads charges, but " +
                                std::to_string(charges.size()) + " were given for " + std::to_string(types.size()) +
                                " particles");
  if (!template_.uses_neighbor_list()) throw std::invalid_argument("GhostedPairs: not a neighbour-list term");
  if (old) {  // the old part's term on the pair set, its list's buffers with it
    extended_ = std::move(old->extended_);
    extended_pairs_ = old->extended_pairs_;
    old->extended_pairs_ = nullptr;
    rebuilds_before_ = extended_->neighbor_list_rebuilds();
    selection_ = old->selection_;
    types_ = std::move(old->types_);
    charges_ = std::move(old->charges_);
    special_ = std::move(old->special_);
    return;
  }
  extended_ = template_.on_particles({}, {}, domains.box());
  extended_pairs_ = extended_ ? dynamic_cast<PairsOnParticles*>(extended_.get()) : nullptr;
  if (!extended_pairs_)
    throw std::invalid_argument("GhostedPairs: term '" + name() + "' cannot act on other particles");
  // Decomposition::forward writes the pair set's positions wrapped into the box, as the pair loop
  // reads them: the list makes no wrapped copy of its own.
  extended_pairs_->set_positions_wrapped(true);
  // Until its first build (forward): past (R − r_c)/2 since the selection the pair set may miss a
  // pair within r_c.
  extended_pairs_->set_displacement_limit(0.5 * (domains.radius() - template_.pair_cutoff()));
}

void GhostedPairs::forward(const Eigen::Matrix3Xd& x, const Box& box, Eigen::Matrix3Xd* f) const {
  // Moved onto a pair set selected since this term's last evaluation (by another term, or by the
  // step driver after a migration): its list is built there at this evaluation.
  const bool moved = selection_ != domains_.selections();
  if (moved) retarget();
  domains_.forward(x, x_, f, f ? &f_ : nullptr);
  if (!moved) {
    // One max-reduction decides for every rank whether the lists rebuild: a rank's list would —
    // its fast beads' test, or a bead of its pair set moved past the list's displacement limit
    // (below). Every list then rebuilds together: a rank rebuilding alone would hold the others up
    // at the next exchange.
    double stale = extended_pairs_->list_stale(x_, box) ? 1.0 : 0.0;
    domains_.comm().max(&stale, 1);
    if (stale == 0.0) {
      extended_pairs_->set_next_list_verdict(false);  // the list's own test, just made
      return;
    }
  }
  // The lists rebuild at x. A pair set selected at x_s holds, for each home bead i, every bead
  // within R = r_c + margin of i's domain at x_s. A pair within r_c + skin at x, with no bead
  // displaced more than D since the selection, was within r_c + skin + 2D at x_s: the list built
  // now on the pair set is one process's list restricted to it (docs/parallel.md) while
  // r_c + skin + 2D ≤ R. Else the pair sets are selected again here, at x. Each bead is owned once,
  // so D is one pass over the owned beads and one max-reduction, made at rebuilds only.
  const double cutoff = template_.pair_cutoff(), skin = template_.pair_skin();
  double moved_since = domains_.displacement_since_selection(x);
  const bool box_changed = box.lengths != domains_.box().lengths || box.origin != domains_.box().origin;
  if (!(cutoff + skin + 2.0 * moved_since <= domains_.radius()) || box_changed) {
    domains_.select_pair_set(x);
    retarget();
    domains_.forward(x, x_, f, f ? &f_ : nullptr);
    moved_since = 0.0;
  }
  // Between builds a pair within r_c of a home bead is in the pair set while no bead has moved
  // (R − r_c)/2 since the selection: the list counts as stale once a bead has moved
  // (R − r_c)/2 − D since this build (NeighborList::set_displacement_limit; at least skin/2 by the
  // test above), whatever its fast beads' test says.
  extended_pairs_->set_displacement_limit(0.5 * (domains_.radius() - cutoff) - moved_since);
  extended_pairs_->set_next_list_verdict(true);
}

void GhostedPairs::retarget() const {
  selection_ = domains_.selections();
  const std::vector<int>& ids = domains_.pair_ids();
  const std::vector<char>& halo = domains_.halo_flags();
  const int n = static_cast<int>(ids.size());
  types_.resize(n);
  for (int e = 0; e < n; ++e) types_[e] = whole_types_[ids[e]];
  // A charged term's charges follow the beads as their types do.
  charges_.resize(whole_charges_.empty() ? 0 : n);
  for (int e = 0; e < static_cast<int>(charges_.size()); ++e) charges_[e] = whole_charges_[ids[e]];
  // The special pairs of the whole system with a home bead here and both beads in the pair set: a
  // home bead's partners within R are all here, and a pair of two halo beads is not evaluated.
  // Made in (i, j) order: by slot i, then its partners j > i sorted (a handful).
  special_.clear();
  const SpecialPartners& s = whole_special_;
  for (int e = 0; e < n; ++e) {
    const int g = ids[e];
    const size_t first = special_.size();
    for (int q = s.start[g]; q < s.start[g + 1]; ++q) {
      const int t = domains_.pair_slot(s.partner[q]);
      if (t > e && (!halo[e] || !halo[t])) special_.push_back({e, t, s.weight[q], s.weight_coul[q]});
    }
    // Insertion sort: a bead has a handful of special partners (two on a chain with 1-2 pairs
    // alone), where std::sort's call costs more than the sorting.
    for (size_t q = first + 1; q < special_.size(); ++q)
      for (size_t r = q; r > first && special_[r - 1].j > special_[r].j; --r) std::swap(special_[r - 1], special_[r]);
  }
  extended_pairs_->move_to(types_, charges_, special_, halo);
  // The whole tail correction on the rank home to particle 0, none on the others.
  const int slot0 = whole_types_.empty() ? -1 : domains_.pair_slot(0);
  extended_pairs_->set_tail_share(slot0 >= 0 && !halo[slot0] ? 1.0 : 0.0);
}

void GhostedPairs::update_list(const Eigen::Matrix3Xd& x, const Box& box) {
  forward(x, box, nullptr);
  extended_pairs_->update_list(x_, box);
}

double GhostedPairs::add_forces(const Eigen::Matrix3Xd& x, const Box& box, Eigen::Matrix3Xd& f) const {
  forward(x, box, &f);
  const double energy = extended_->add_forces(x_, box, f_);
  domains_.reverse(f_, f);
  return energy;
}

void GhostedPairs::add_forces_only(const Eigen::Matrix3Xd& x, const Box& box, Eigen::Matrix3Xd& f) const {
  forward(x, box, &f);
  extended_->add_forces_only(x_, box, f_);
  domains_.reverse(f_, f);
}

void GhostedPairs::add_forces_and_virial_diagonal(const Eigen::Matrix3Xd& x, const Box& box, Eigen::Matrix3Xd& f,
                                                  ExactDiagonal& w) const {
  forward(x, box, &f);
  extended_->add_forces_and_virial_diagonal(x_, box, f_, w);
  domains_.reverse(f_, f);
}

double GhostedPairs::virial(const Eigen::Matrix3Xd& x, const Box& box) const {
  forward(x, box, nullptr);
  return extended_->virial(x_, box);
}

ForceTerm::Sums GhostedPairs::energy_and_virial(const Eigen::Matrix3Xd& x, const Box& box,
                                                Eigen::Matrix3Xd& scratch) const {
  (void)scratch;
  forward(x, box, nullptr);
  return extended_->energy_and_virial(x_, box, f_);
}

}  // namespace stiffmd
