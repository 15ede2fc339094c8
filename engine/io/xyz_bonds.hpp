// Import of a configuration from an XYZ file (plain or extended; the first frame) plus a bond list.
//
// XYZ: line 1 the atom count, line 2 a comment, then one line per atom. Plain files have exactly
// "species x y z". Extended files (a "Properties=" key on line 2, as ASE, OVITO and this engine's
// trajectory writer produce) give the columns by name: pos:R:3 is required, species:S:1 and
// velo:R:3 are used, other properties are skipped; an orthorhombic Lattice= (with Origin=) sets the
// box, otherwise lo = hi = 0 (no box). Later frames are ignored.
//
// Types: when every species is a positive integer (LAMMPS dumps) it is the type; otherwise types
// are numbered 1, 2, … in order of first appearance and type_names holds the species. No masses
// (type_mass empty), molecule ids 0, ids 1..N in file order.
//
// Bonds file: one bond per line, "i j [type]" with 0-based atom indices and type >= 1 (default 1);
// '#' starts a comment; blank lines are ignored. Self-bonds and duplicate pairs are errors.
#pragma once

#include <string>

#include "engine/io/lammps_data.hpp"

namespace stiffmd {

ImportedSystem read_xyz_with_bonds(const std::string& xyz_path, const std::string& bonds_path);

}  // namespace stiffmd
