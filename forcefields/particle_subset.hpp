// A subset of a system's particles, numbered 0, 1, … in the order of their indices in the system:
// what a force term needs to act on them alone (ForceTerm::on_subset, ForceField::on_subset). A
// decomposed run's part is one (docs/parallel.md): the molecules a rank owns.
#pragma once

#include <algorithm>
#include <span>
#include <stdexcept>
#include <string>
#include <string_view>
#include <vector>

#include "core/topology.hpp"

namespace stiffmd {

// Views: what they view must outlive the subset.
struct ParticleSubset {
  std::span<const int> global;  // per particle of the subset, its index in the system, increasing
  std::span<const int> types;   // per particle of the subset, its type
  // The bonds, angles and dihedrals among the subset's particles, in the subset's numbering and in
  // the system's order (the pair terms' special pairs come from its bonds).
  const Topology& topology;
  std::span<const double> charges = {};  // per particle of the subset, in e; empty: uncharged
  // Per particle of the subset, its inverse mass (0: fixed); empty: not carried (a term that needs
  // masses then takes its own of the system's particles).
  std::span<const double> inv_mass = {};

  int size() const { return static_cast<int>(global.size()); }
  // The subset's index of the system's particle g; −1 when g is not in the subset.
  int local(int g) const {
    const auto it = std::lower_bound(global.begin(), global.end(), g);
    return it != global.end() && *it == g ? static_cast<int>(it - global.begin()) : -1;
  }
  // The subset's indices of those of the system's `particles` in it, increasing.
  std::vector<int> select(std::span<const int> particles) const {
    std::vector<int> out;
    for (const int g : particles)
      if (const int l = local(g); l >= 0) out.push_back(l);
    std::sort(out.begin(), out.end());
    return out;
  }
};

// The items (bonds, angles, dihedrals, stiff bonds; their particles the int members `members`) whose
// particles all lie in the subset, renumbered into it, in their order. An item with some but not
// all of its particles there cannot be evaluated on the subset: std::invalid_argument, prefixed with
// `who`, naming it by the system's indices (a subset must hold whole molecules).
template <class Item, class... Members>
std::vector<Item> items_on_subset(const std::vector<Item>& items, const ParticleSubset& subset, const std::string& who,
                                  std::string_view what, Members... members) {
  std::vector<Item> out;
  for (const Item& item : items) {
    Item mapped = item;
    int inside = 0;
    ((inside += (mapped.*members = subset.local(item.*members)) >= 0), ...);
    if (inside == 0) continue;
    if (inside != static_cast<int>(sizeof...(members))) {
      std::string particles;
      ((particles += (particles.empty() ? "" : ", ") + std::to_string(item.*members)), ...);
      throw std::invalid_argument(who + ": the " + std::string(what) + " of particles " + particles +
                                  " lies partly outside the particle subset (a subset must hold whole molecules)");
    }
    out.push_back(mapped);
  }
  return out;
}

// Whether an item of the subset's topology (its particles the int members `members`, in the
// subset's numbering) reaches outside the subset: some particle not in 0 … size − 1 (a subset that
// cuts a molecule holds its items with the particles outside it as −1).
template <class Item, class... Members>
bool reaches_outside(const Item& item, const ParticleSubset& subset, Members... members) {
  const int n = subset.size();
  return ((item.*members < 0 || item.*members >= n) || ...);
}

// The refusal of such an item, named by the system's indices of its particles in the subset and
// "outside" for the others; prefixed with `who`.
template <class Item, class... Members>
[[noreturn]] void refuse_cut_item(const Item& item, const ParticleSubset& subset, const std::string& who,
                                  std::string_view what, Members... members) {
  const int n = subset.size();
  std::string particles;
  const auto name = [&](int p) {
    return p >= 0 && p < n ? std::to_string(subset.global[static_cast<std::size_t>(p)]) : std::string("outside");
  };
  ((particles += (particles.empty() ? "" : ", ") + name(item.*members)), ...);
  throw std::invalid_argument(who + ": the " + std::string(what) + " of particles " + particles +
                              " lies partly outside the particle subset (a subset must hold whole molecules)");
}

}  // namespace stiffmd
