// [thermostat]: the canonical ensemble (integrators/thermostat.hpp). Internal to scene assembly.
#pragma once

#include "engine/deck/deck.hpp"
#include "engine/scene/scene.hpp"

namespace stiffmd {

// Reads [thermostat] into sc.integrator.thermostat (after the types, the particles and
// [integrator]): style, temperature, damp or friction and [thermostat.scale] per type
// (langevin), tau (csvr), seed. Refuses a method that needs a temperature without one.
void read_thermostat(DeckTable& root, Scene& sc);

}  // namespace stiffmd
