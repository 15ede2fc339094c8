// A rank's part of a deck's LAMMPS data file import, ready for the decomposition's start
// (Decomposition::start, DomainIntegrator::distribute(PartMolecules, x, v, s)): the molecules the
// rank keeps, each particle and bonded item as the whole scene holds it — the scene's particle
// type, inverse mass, charge, molecule id and friction, the items by global index with the scene's
// type and their places in the whole scene's lists — read by parts (read_lammps_data_part,
// engine/io/lammps_data_parts.hpp), never the whole file's arrays (docs/parallel.md, "The set-up by
// parts").
//
// What it reproduces is the whole import (read_import, engine/scene/scene_sources.cpp) of a deck
// whose [import] is its only source of particles and topology (no [[particles]], [[build]] or
// [[bonds]]: their particles and items would come first or after, with other numbers): for the
// particles `global` it returns, `molecules` is cut_part(whole scene, global)
// (engine/domain/part_molecules.hpp) bit for bit, and x, v are the whole scene's columns after
// load_scene (before [velocities], which replaces v, and before [prepare] and [minimize]);
// tests/test_import_part.cpp checks it on the decks that import.
//
// Every rank reads the same file and the same deck, so the O(types) description (the box, the type
// names, the LAMMPS type numbers and "… Coeffs" sections a scene keeps) is the same everywhere, and
// a mapping the deck cannot give (a type without a name, an unknown type, a mass that disagrees)
// is refused on every rank alike, with the whole import's message at the same deck key. The
// file's own faults are the part reader's, in its words (engine/io/lammps_data_parts.hpp): the
// structure and every line's types and atoms on every rank, but a malformed number in a line only
// one rank reads whole (a coordinate, a velocity) and what concerns one molecule's positions (a
// bond longer than half the box, a zero-length bond) only the rank that keeps it finds — a caller
// on several ranks agrees on the failure before going on.
#pragma once

#include <Eigen/Core>
#include <cstdint>
#include <span>
#include <string>
#include <utility>
#include <vector>

#include "core/box.hpp"
#include "core/topology.hpp"
#include "engine/deck/deck.hpp"
#include "engine/domain/part_molecules.hpp"
#include "engine/io/lammps_data_parts.hpp"
#include "engine/scene/scene.hpp"

namespace stiffmd {

// The deck's [import] of a LAMMPS data file, the keys read_import reads (docs/decks.md, [import]).
struct LammpsImportDeck {
  using TypeMap = std::vector<std::pair<std::string, std::string>>;
  std::string file;  // lammps_data as the deck gives it (what coefficients = "data" names)
  std::string path;  // the same, resolved against the deck's directory
  std::string atom_style = "auto";
  TypeMap atom_types;
  // A bonded kind's map, and whether the deck gives it (without it, each type is named by its
  // number in the file: "1", "2", …).
  TypeMap bond_types, angle_types, dihedral_types, improper_types;
  bool bond_types_given = false, angle_types_given = false, dihedral_types_given = false, improper_types_given = false;
  bool velocities = true;
  // For messages, as the whole import words them: "file:line: import" and, per key the deck gives,
  // "file:line: import.KEY" (empty: the table's).
  std::string where, where_lammps_data, where_atom_types, where_bond_types, where_angle_types, where_dihedral_types,
      where_improper_types;
};

// The [import] table's keys (it must give lammps_data), read as read_import reads them; the table
// is not finished (its reader is the whole load's).
LammpsImportDeck read_lammps_import(DeckTable& import, const std::string& deck_dir);

// What the whole import takes from the scene besides the deck's [import].
struct ImportTypes {
  std::span<const ParticleType> types;  // the deck's [types]: names, masses, charges
  double velocity_unit = 1.0;           // the deck's velocity unit in the engine's (Units::velocity_in(1.0))
  // Per particle type (empty: the particles carry none): the Langevin friction each particle of
  // the type gets, γ × the type's [thermostat.scale] factor, the product read_thermostat
  // (engine/scene/thermostat_deck.cpp) forms per particle.
  std::span<const double> friction;
};

// Which molecules the rank keeps: those whose anchor `keep` keeps (the domain grid's answer;
// needs image flags when the file has bonded terms), or, without `keep`, block `block` of the
// file's molecules (whole_block's blocks; a start from them migrates each molecule to its
// anchor's rank anyway).
struct ImportSelection {
  KeepAnchor keep;
  KeepBlock block;
};

struct ImportedMolecules {
  PartMolecules molecules;  // global indices increasing; items in the whole scene's order
  Eigen::Matrix3Xd x, v;    // per particle of `molecules`: whole (unwrapped) positions; velocities
  // The O(types) rest of what read_import puts into a scene, the same on every rank: the box
  // (periodic, the file's), the bonded type names in the whole import's order (no items, no
  // molecule ids), the LAMMPS type numbers and masses, and what coefficients = "data" reads.
  Box box;
  Topology names;
  LammpsTypeNumbers lammps_types;
  LammpsDataCoeffs lammps_data_coeffs;
  int num_particles = 0;  // the file's atoms
  int num_molecules = 0;  // the file's bonded molecules (bonded_molecules' count)
};

// The rank's part of the import. Throws InputError where the whole import would (the file, a type
// without a name, an unknown type, a mass that disagrees with the deck's, a molecule that cannot
// be made whole), naming the same deck keys.
//
// A run's part path would call, on every rank r of P:
//   LammpsImportDeck d = read_lammps_import(*root.table("import"), deck_dir);
//   ImportedMolecules p = import_part(d, {scene.types, scene.units.velocity_in(1.0), friction_by_type},
//                                     {nullptr, KeepBlock{r, P}});
//   (the Scene's box, topology type names, lammps_types, lammps_data_coeffs from p's)
//   domain_integrator.distribute(std::move(p.molecules), std::move(p.x), std::move(p.v), s);
ImportedMolecules import_part(const LammpsImportDeck& deck, const ImportTypes& types, const ImportSelection& selection);

}  // namespace stiffmd
