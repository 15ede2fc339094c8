// Which particles an external term acts on, as the deck selects them (particles = [i, …],
// type = "NAME", or all: docs/decks.md): the term's description, O(deck), never a list of the
// system's size. The deck reader (engine/scene/force_registry.cpp) makes the whole system's list
// with it, and a particle subset's term (a decomposed run's part, docs/parallel.md) its own from
// the subset's indices and types: the whole list's members in the subset, increasing.
#pragma once

#include <vector>

#include "forcefields/particle_subset.hpp"

namespace stiffmd {

struct ParticleSelection {
  enum class Kind { listed, type, all };
  Kind kind = Kind::all;
  std::vector<int> listed;  // Kind::listed: the deck's indices
  int type = -1;            // Kind::type: the particle type

  // The selected particles among `subset`'s, in the subset's numbering, increasing.
  std::vector<int> on(const ParticleSubset& subset) const {
    if (kind == Kind::listed) return subset.select(listed);
    std::vector<int> out;
    for (int k = 0; k < subset.size(); ++k)
      if (kind == Kind::all || subset.types[static_cast<size_t>(k)] == type) out.push_back(k);
    return out;
  }
};

// A term with a selection (HarmonicTether, LJ93Wall, forcefields/external_terms.hpp): on a subset
// it selects from the subset; without one (a term made from its list alone) it cuts its list.
class SelectionRule {
 public:
  void set_selection(ParticleSelection selection) {
    selection_ = std::move(selection);
    has_ = true;
  }
  bool has_selection() const { return has_; }
  const ParticleSelection& selection() const { return selection_; }

 protected:
  std::vector<int> selected_on(const ParticleSubset& subset, const std::vector<int>& own) const {
    return has_ ? selection_.on(subset) : subset.select(own);
  }

 private:
  ParticleSelection selection_;
  bool has_ = false;
};

}  // namespace stiffmd
