// [prepare]: an initial state made ready for a stiff run — projected onto the constraint
// manifold, relaxed off a builder's overlaps with rigid bonds, given thermal bond vibrations.
// The deck side (reading the table, errors at its file:line) is engine/scene/scene_sources.cpp.
#pragma once

#include <cstdint>
#include <ostream>
#include <string>

#include "core/state.hpp"
#include "forcefields/force_field.hpp"
#include "forcefields/stiff_bond.hpp"

namespace stiffmd {

struct PrepareSettings {
  bool project = true;   // positions onto g = 0 (SHAKE), velocities onto the tangent space
  long relax_steps = 0;  // capped steepest descent on the non-stiff terms, rigid bonds
  double relax_max_displacement = 0.02;
  double vibrational_temperature = 0.0;  // thermal bond vibrations
  std::uint64_t seed = 1;
};

// Applies the settings to `s` in the order project, relax, vibrate, and returns what it did as
// one line ("prepare: projected …; relaxed …; bond vibrations …"; empty if nothing was asked).
// `forces` gives the non-stiff terms for the relaxation (compute_unconstrained). Throws
// NumericalError when SHAKE does not converge, InputError for stiff bonds the toolbox refuses.
// `progress` (null: silent) gets a line as each stage starts and, while relaxing, the energy and
// the largest force about every tenth of the steps: a large system's preparation takes a while.
std::string prepare_state(ForceField& forces, const StiffBonds& stiff, State& s, const PrepareSettings& p,
                          std::ostream* progress = nullptr);

}  // namespace stiffmd
