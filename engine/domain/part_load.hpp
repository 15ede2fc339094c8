// A rank's share of the system made directly by its source, not cut from the whole scene: whole
// molecules with what they carry (PartMolecules, engine/domain/part_molecules.hpp) and their
// positions and velocities, which a decomposed run's start sends to their owners
// (DomainIntegrator::distribute; docs/parallel.md, "What a rank holds"). Each source that can
// make parts has one function that returns the rank's ScenePart; the run takes it in place of the
// whole scene's cut (RunOptions::part, engine/run/run.hpp).
//
// Linear chains built by molecule (engine/scene/chains_by_molecule.hpp) are one such source: a
// rank builds the contiguous block of molecules [r·M/P, (r+1)·M/P) and draws their velocities by
// particle (integrators/part_velocities.hpp); both are the whole build's bits for any partition.
#pragma once

#include <Eigen/Core>
#include <string>

#include "core/communicator.hpp"
#include "engine/deck/deck.hpp"
#include "engine/domain/part_molecules.hpp"
#include "engine/scene/scene.hpp"

namespace stiffmd {

struct ScenePart {
  PartMolecules molecules;
  Eigen::Matrix3Xd x, v;
};

// Why the scene's particles cannot be made by parts from the deck ("": they can): every particle
// from one [[build]] of linear chains with growth = "by-molecule" (no [[particles]], [[bonds]] or
// [import]), velocities by particle ([velocities] by_particle = true) or none, and nothing that
// moves them before the run from the whole state ([prepare], [minimize]) or hands it on (a staged
// protocol's stages). `scene`: the deck's scene as load_scene made it.
std::string chains_part_refusal(const Deck& deck, const Scene& scene);

// This rank's block of molecules [r·M/P, (r+1)·M/P) (r = ranks.rank(), P = ranks.size()) of the
// deck's chains, as the whole scene holds them bit for bit: positions as built, the type's inverse
// mass, charge and Langevin friction, molecule ids, the chains' bonds, angles and dihedrals with
// their places in the whole lists, and the velocities by particle (collective: their sums over the
// ranks). `scene` gives the types, units, box, thermostat style and the topology's type names;
// none of its per-particle arrays or items are read. Only for a deck chains_part_refusal accepts.
ScenePart chains_part(const Deck& deck, const Scene& scene, const Communicator& ranks);

}  // namespace stiffmd
