// The deck's k-space terms, `ewald` and `pppm` (docs/decks.md, docs/electrostatics.md): the
// reciprocal-space half of Ewald summation, whose real-space half is the scene's coul/long pair
// style. Read after every other term, so that the real-space term is there to take the splitting
// parameter g the accuracy chooses.
#pragma once

#include <memory>
#include <string>

#include "engine/scene/force_registry.hpp"
#include "forcefields/kspace/charge_sums.hpp"

namespace stiffmd {

struct Scene;

// The sums of every particle's charge in the whole scene's particle order (charge_sums.hpp): the
// loaded particles' (Scene::charge), then each described source's count of its type's charge
// (Scene::described_sources), so a description gives the whole load's numbers to the last bit
// without a per-particle array. The one place a source that is counted, not loaded, adds its
// charges: the k-space terms' parameters (choose_ewald, choose_pppm) and the scene's net-charge
// check read them from here.
ChargeSums charge_sums(const Scene& sc);

// ewald: accuracy (LAMMPS's relative RMS force accuracy), g_ewald (optional: LAMMPS kspace_modify
// gewald), kmax = [kx, ky, kz] (optional: kspace_modify kmax/ewald).
std::unique_ptr<ForceTerm> read_ewald(const std::string& name, Level level, DeckTable& t, TermContext& ctx);
// pppm: accuracy, order (5), mesh = [nx, ny, nz] (optional: kspace_modify mesh), g_ewald (optional).
std::unique_ptr<ForceTerm> read_pppm(const std::string& name, Level level, DeckTable& t, TermContext& ctx);

}  // namespace stiffmd
