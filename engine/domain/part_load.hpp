// A rank's share of the system made directly by its source, not cut from the whole scene: whole
// molecules with what they carry (PartMolecules, engine/domain/part_molecules.hpp) and their
// positions and velocities, which a decomposed run's start sends to their owners
// (DomainIntegrator::distribute; docs/parallel.md, "What a rank holds"). Each source that can
// make parts has one function that returns the rank's ScenePart; the run takes it in place of the
// whole scene's cut (RunOptions::part, engine/run/run.hpp).
//
// Two sources make parts: linear chains built by molecule (engine/scene/chains_by_molecule.hpp),
// of which a rank builds the contiguous block of molecules [r·M/P, (r+1)·M/P), and a LAMMPS data
// file read by parts (engine/domain/import_part.hpp), of which a rank reads the same block of the
// file's molecules; velocities by particle (integrators/part_velocities.hpp). Each is the whole
// scene's bits for any partition.
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

// A source that makes this rank's part of the scene's particles (collective: every rank calls it).
using PartMaker = ScenePart (*)(const Deck& deck, const Scene& scene, const Communicator& ranks);

// The source a fresh decomposed run starts from, or why it cuts its parts from the whole scene.
struct PartSource {
  PartMaker make = nullptr;  // null: no source makes the particles by parts
  std::string refusal;       // why not, when make is null
};

// Which source makes the deck's particles by parts (docs/parallel.md, "The start from the
// source's parts"): every particle from one [[build]] of linear chains with growth = "by-molecule"
// (chains_part), or from the [import] of a LAMMPS data file (data_file_part) — no [[particles]] or
// [[bonds]] beside it —; velocities from the source, by particle ([velocities] by_particle = true)
// or none; nothing that acts on the whole state before the run ([prepare]'s bond vibrations from
// one stream over the bonds, the effective dynamics, whose actions are taken from the whole
// state) or hands it on (a staged protocol's stages). [prepare] (its vibrations by_particle),
// [minimize] and a rigid method's projection onto g = 0 are the Run's, on the parts after the
// start (DomainIntegrator::prepare_parts, minimize, project_parts). `scene`: the deck's scene as load_scene made it,
// whole or its description (the settings alone are read).
PartSource part_source(const Deck& deck, const Scene& scene);

// This rank's block of molecules [r·M/P, (r+1)·M/P) (r = ranks.rank(), P = ranks.size()) of the
// deck's chains, as the whole scene holds them bit for bit: positions as built, the type's inverse
// mass, charge and Langevin friction, molecule ids, the chains' bonds, angles and dihedrals with
// their places in the whole lists, and the velocities by particle (collective: their sums over the
// ranks). `scene` gives the types, units, box, thermostat style and the topology's type names;
// none of its per-particle arrays or items are read, so the scene's description
// (SceneContent::description, engine/scene/scene.hpp) gives the same part. Only for a deck whose
// source it is.
ScenePart chains_part(const Deck& deck, const Scene& scene, const Communicator& ranks);

// This rank's block of the [import]ed data file's molecules [r·M/P, (r+1)·M/P) in the file's
// molecule order (import_part by block, engine/domain/import_part.hpp), as the whole scene holds
// them bit for bit: each particle's type, inverse mass, charge, molecule id and Langevin friction,
// the bonded items with their places, x whole, and v the file's (velocities = true, in the deck's
// units), zero, or drawn by particle. The file's faults that only this rank reads (a malformed
// number in one of its lines, a bond longer than half the box, a particle far from the box) are
// agreed before anything else: every rank throws AgreedInputError with the lowest failing rank's
// message, which that rank words as the whole load does by loading the deck whole (on that fault
// alone: the run goes no further), so that the message is one process's (collective). `scene`
// gives the types, units and thermostat; none of its per-particle arrays or items are read, so
// the scene's description gives the same part.
ScenePart data_file_part(const Deck& deck, const Scene& scene, const Communicator& ranks);

}  // namespace stiffmd
