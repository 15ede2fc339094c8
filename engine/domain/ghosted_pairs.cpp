#include "engine/domain/ghosted_pairs.hpp"

#include <algorithm>
#include <stdexcept>

namespace stiffmd {

SpecialPartners special_partners(std::span<const SpecialPair> pairs, std::span<const int> global) {
  SpecialPartners s;
  const std::size_t n = global.size();
  s.start.assign(n + 1, 0);
  for (const SpecialPair& p : pairs) {
    if (p.i < 0 || p.j < 0 || static_cast<std::size_t>(p.i) >= n || static_cast<std::size_t>(p.j) >= n)
      throw std::invalid_argument("special_partners: a special pair of a particle outside the set");
    ++s.start[p.i + 1], ++s.start[p.j + 1];
  }
  for (std::size_t k = 0; k < n; ++k) s.start[k + 1] += s.start[k];
  s.partner.resize(s.start.back());
  s.weight.resize(s.start.back());
  s.weight_coul.resize(s.start.back());
  // Sorted by (i, j): each bead's partners below it come first (pairs (j, k) by increasing j), then
  // those above it (pairs (k, j) by increasing j): increasing global indices, as global increases.
  std::vector<int> next(s.start.begin(), s.start.end() - 1);
  for (const SpecialPair& p : pairs)
    for (const auto& [a, b] : {std::pair{p.i, p.j}, std::pair{p.j, p.i}}) {
      const int q = next[a]++;
      s.partner[q] = global[b], s.weight[q] = p.weight, s.weight_coul[q] = p.weight_coul;
    }
  return s;
}

GhostedPairs::GhostedPairs(const ForceTerm& whole_term, Decomposition& domains, int special, GhostedPairs* old)
    : ForceTerm(whole_term.name(), whole_term.level()),
      template_(whole_term),
      domains_(domains),
      special_index_(special) {
  if (!template_.uses_neighbor_list()) throw std::invalid_argument("GhostedPairs: not a neighbour-list term");
  if (old) {  // the old part's term on the pair set, its list's buffers with it
    extended_ = std::move(old->extended_);
    extended_pairs_ = old->extended_pairs_;
    old->extended_pairs_ = nullptr;
    rebuilds_before_ = extended_->neighbor_list_rebuilds();
    selection_ = old->selection_;
    return;
  }
  extended_ = template_.on_particles({}, {}, domains.box());
  extended_pairs_ = extended_ ? dynamic_cast<PairsOnParticles*>(extended_.get()) : nullptr;
  if (!extended_pairs_)
    throw std::invalid_argument("GhostedPairs: term '" + name() + "' cannot act on other particles");
  // Decomposition::forward writes the pair set's positions wrapped into the box, as the pair loop
  // reads them: the list makes no wrapped copy of its own.
  extended_pairs_->set_positions_wrapped(true);
  extended_pairs_->set_ghost_pairs_once(domains.halo_pairs_once());
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
  const std::vector<char>& halo = domains_.halo_flags();
  const PairBeadData& carried = domains_.pair_data();
  const int n = static_cast<int>(domains_.pair_ids().size());
  if (static_cast<int>(carried.type.size()) != n || special_index_ < 0 ||
      static_cast<std::size_t>(special_index_) >= carried.special.size() ||
      (template_.uses_charges() && !carried.charged))
    throw std::logic_error("GhostedPairs: term '" + name() + "': the pair set's beads carried no data for it");
  // The special pairs with a home bead here and both beads in the pair set: a home bead's partners
  // within R are all here, and a pair of two halo beads is not evaluated. Made in (i, j) order: by
  // slot i, then its partners j > i (carried in increasing global index, so in increasing slots).
  // Made in the term's own storage and handed back to it: the term's list is their only copy.
  // With the halo pairs once, a pair of a home bead and a halo bead only where the home bead has
  // the lower slot (global index), as the list takes them (NeighborList::set_ghost_pairs_once).
  const bool once = domains_.halo_pairs_once();
  std::vector<SpecialPair> special = extended_pairs_->take_special_pairs();
  const SpecialPartners& s = carried.special[special_index_];
  const std::vector<int>& ids = domains_.pair_ids();
  for (int e = 0; e < n; ++e) {
    for (int q = s.start[e]; q < s.start[e + 1]; ++q) {
      // A partner of a lower global index has a lower slot, if any: its pair is made from there.
      if (s.partner[q] < ids[e]) continue;
      const int t = domains_.pair_slot_near(s.partner[q], e);
      if (t > e && (!halo[e] || (!once && !halo[t]))) special.push_back({e, t, s.weight[q], s.weight_coul[q]});
    }
  }
  // A charged term's charges follow the beads as their types do.
  extended_pairs_->move_to(
      carried.type, template_.uses_charges() ? std::span<const double>(carried.charge) : std::span<const double>(),
      std::move(special), halo);
  // The whole tail correction on the rank home to particle 0, none on the others.
  const int slot0 = domains_.pair_slot(0);
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
