// The charges of a k-space term's part (ForceTerm::on_subset; docs/parallel.md, "What is not
// distributed yet": the part's force terms made from their descriptions and the part's data).
#pragma once

#include <stdexcept>
#include <string>
#include <vector>

#include "forcefields/particle_subset.hpp"

namespace stiffmd {

// The subset's charges for a term that keeps the system's (`system`, by index; `who` names it in
// the refusal): the charges the subset carries (a decomposed run's part: its molecules'), never
// the term's of the whole system; without them (a subset made of indices alone), the term's by
// index. std::invalid_argument when an index is not among `system`'s.
inline std::vector<double> subset_charges(const ParticleSubset& subset, const std::vector<double>& system,
                                          const std::string& who) {
  if (subset.charges.size() == subset.global.size()) return {subset.charges.begin(), subset.charges.end()};
  std::vector<double> q;
  q.reserve(subset.global.size());
  for (const int g : subset.global) {
    if (g < 0 || g >= static_cast<int>(system.size()))
      throw std::invalid_argument(who + ": the subset's particle " + std::to_string(g) + " is not among its " +
                                  std::to_string(system.size()) + " charges");
    q.push_back(system[static_cast<std::size_t>(g)]);
  }
  return q;
}

}  // namespace stiffmd
