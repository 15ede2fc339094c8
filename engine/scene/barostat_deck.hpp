// The deck's [barostat] table (docs/decks.md): stochastic cell rescaling around the method
// (integrators/barostat.hpp), refused on a scene it cannot serve.
#pragma once

#include "engine/deck/deck.hpp"

namespace stiffmd {

struct Scene;

// After [thermostat] and [forces]: fills sc.integrator.barostat, or fails at the key (exit 2).
void read_barostat(DeckTable& root, Scene& sc);

}  // namespace stiffmd
