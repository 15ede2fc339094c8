// [ensemble]: one deck, many independent runs (seeds, sweep points). Member k is the deck with
// the command line's --set and then, for every key of `vary`, the k-th value of its list:
//
//   [ensemble]
//   vary = { "thermostat.seed" = [1, 2, 3], "variables.eps" = [0.1, 0.1, 0.05] }
//
// The lists are of equal length, the number of members. Whether each member's deck loads is
// checked where the members are run (engine/run/ensemble.*), by loading it.
#pragma once

#include <optional>
#include <string>
#include <vector>

#include "engine/deck/deck.hpp"

namespace stiffmd {

struct Ensemble {
  std::string where;                         // "file:line: ensemble", for errors about the whole
  std::vector<DeckTable::ValueList> varied;  // one list per key, each of size() values
  int size() const { return static_cast<int>(varied.front().values.size()); }
  // Member k's own overrides, "key=value" as --set takes them.
  std::vector<std::string> overrides(int k) const;
  // "thermostat.seed=2 variables.eps=0.1": what distinguishes member k.
  std::string label(int k) const;
};

// The deck's [ensemble], validated (equal non-empty lists, no other keys); none when absent.
std::optional<Ensemble> read_ensemble(DeckTable& root);

}  // namespace stiffmd
