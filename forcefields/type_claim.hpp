// A bonded term's claim on a topology's types (the deck's bond_types, angle_types, dihedral_types,
// improper_types: the reader maps each type it claims onto the term's coefficients), so that on a
// particle subset the term takes its items from the subset's own topology
// (ParticleSubset::topology) instead of cutting its own list of the whole system: a decomposed
// run's part (docs/parallel.md) is then built again at a migration without reading any item of
// the whole system.
#pragma once

#include <memory>
#include <string>
#include <string_view>
#include <utility>
#include <vector>

#include "core/topology.hpp"
#include "forcefields/particle_subset.hpp"

namespace stiffmd {

// The items of `items` whose type `index` claims (index[type] ≥ 0), in their order, each type
// renumbered into the claimer's coefficients (index[type]).
template <class Item>
std::vector<Item> claimed_items(const std::vector<Item>& items, const std::vector<int>& index) {
  std::vector<Item> out;
  for (Item it : items)
    if (index[static_cast<std::size_t>(it.type)] >= 0) {
      it.type = index[static_cast<std::size_t>(it.type)];
      out.push_back(it);
    }
  return out;
}

// A topology's list of one kind of item.
inline const std::vector<Bond>& topology_items(const Topology& t, const Bond*) {
  return t.bonds;
}
inline const std::vector<Angle>& topology_items(const Topology& t, const Angle*) {
  return t.angles;
}
inline const std::vector<Dihedral>& topology_items(const Topology& t, const Dihedral*) {
  return t.dihedrals;
}
inline const std::vector<Improper>& topology_items(const Topology& t, const Improper*) {
  return t.impropers;
}

class TypeClaim {
 public:
  // Per type of the topology the term was read from, the index of its coefficients (−1: not this
  // term's type). Empty (a term made from its items alone): the term cuts its own list.
  void set_type_claim(std::vector<int> index) { claim_ = std::move(index); }
  const std::vector<int>& type_claim() const { return claim_; }

 protected:
  // A term made on a subset keeps the claim: it is the same description, and a subset of it
  // takes its items from its topology as well.
  template <class Term>
  std::unique_ptr<Term> keeping_claim(std::unique_ptr<Term> term) const {
    term->set_type_claim(claim_);
    return term;
  }
  // The term's items on `subset`. With a claim: the claimed items of the subset's topology, which
  // is the system's restricted to the subset, in its order (ParticleSubset), so they are the
  // term's own items on the subset in the term's order — the term's list was the system's
  // claimed items — and the term's own list is not read. Without a claim, or when a claimed item
  // of the subset's topology reaches outside the subset or an item has a type the claim does not
  // know (a subset that cuts a molecule, or a topology that is not the system's): items_on_subset on the term's
  // own list, which names what it refuses; a claimed item of the subset's topology that reaches
  // outside it is refused even when that list no longer holds it.
  template <class Item, class... Members>
  std::vector<Item> subset_items(const std::vector<Item>& own, const ParticleSubset& subset, const std::string& who,
                                 std::string_view what, Members... members) const {
    if (claim_.empty()) return items_on_subset(own, subset, who, what, members...);
    const std::vector<Item>& listed = topology_items(subset.topology, static_cast<const Item*>(nullptr));
    const int types = static_cast<int>(claim_.size());
    bool inside = true;  // every type known, and every claimed item within the subset
    for (const Item& it : listed)
      inside = inside && it.type >= 0 && it.type < types &&
               (claim_[static_cast<std::size_t>(it.type)] < 0 || !reaches_outside(it, subset, members...));
    if (inside) return claimed_items(listed, claim_);
    std::vector<Item> cut = items_on_subset(own, subset, who, what, members...);
    for (const Item& it : listed)
      if (it.type >= 0 && it.type < types && claim_[static_cast<std::size_t>(it.type)] >= 0 &&
          reaches_outside(it, subset, members...))
        refuse_cut_item(it, subset, who, what, members...);
    return cut;
  }

 private:
  std::vector<int> claim_;
};

}  // namespace stiffmd
