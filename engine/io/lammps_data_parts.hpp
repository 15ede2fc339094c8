// A LAMMPS data file read by parts: each rank streams the file and keeps only the molecules whose
// anchor lies in its domain, never the whole system's arrays (docs/parallel.md, "What a rank
// holds"). Every rank reads the same file and applies the same rule to the same numbers, so the
// parts of any number of ranks tile the whole import, each molecule in exactly one part.
//
// A molecule is a connected component of the file's bonded terms (bonds, angles, dihedrals,
// impropers; a lone atom is a molecule of one), the molecules of bonded_molecules
// (core/topology.hpp) that the decomposition integrates whole. Its anchor is its centre of mass
// Σ m_i x_i / Σ m_i with x unwrapped by the image flags and m = 1/(1/m_type), summed over its atoms in
// file order: for a file that lists its atoms by increasing id (write_lammps_data's, and stiffmd's
// own topology.data) these are exactly the numbers of Decomposition's anchor of the imported
// scene (its masses come back from the inverse masses), so a rank keeps the molecules that
// Decomposition::distribute would give it (tests/test_lammps_parts.cpp).
//
// What a rank holds while it reads, beyond its part: one int per atom of the file (the union–find
// of the molecules, then each atom's molecule), the file's atom ids when they are not 1 … N in
// order (one long each), the file's molecule ids (one int per run of equal ids in the Atoms
// section, then per distinct id), and four doubles and a flag per molecule (the anchors' sums) —
// none of them the state, the topology or the force terms of the whole system, and all freed on
// return. The file is read three times (the structure and the bonded terms; the anchors; the
// part; by block twice, without the anchors), by lines, never held whole. The checks are the
// whole reader's where they concern a kept line (its columns, numbers, atoms in the Atoms
// section), every line's atom or item type, molecule id and atoms (the same answer on every
// rank), and the header's counts for every section; a duplicate bond elsewhere in the file is the
// whole reader's to find (`stiffmd check` reads it whole).
#pragma once

#include <Eigen/Core>
#include <array>
#include <cstdint>
#include <functional>
#include <map>
#include <string>
#include <vector>

#include "engine/io/lammps_data.hpp"

namespace stiffmd {

// Whether this part keeps the molecule whose anchor is `anchor` (the same answer on every rank
// for a given anchor: the domain grid's).
using KeepAnchor = std::function<bool(const Eigen::Vector3d& anchor)>;

// The molecules of block `part` of `parts`: molecules [M·part/parts, M·(part + 1)/parts) of the
// file's M, numbered as bonded_molecules numbers them (by their least atom index, the atoms by
// increasing id) — whole_block's blocks (engine/domain/part_molecules.hpp) of the import. No
// anchor is computed, so a file with bonded terms needs no image flags here.
struct KeepBlock {
  int part = 0, parts = 1;
};

struct ImportedPart {
  // The kept atoms by increasing id, as read_lammps_data returns the whole file's (x unwrapped, v,
  // types, molecule ids, charges), and the bonded terms whose atoms are kept, by part index, in
  // file order; the masses, the box, the type counts and the "… Coeffs" sections whole.
  ImportedSystem system;
  std::vector<int> global;  // per kept atom: its index in read_lammps_data's import (0 … N − 1)
  // Per kept bond, angle, dihedral and improper (system's lists): its index in read_lammps_data's
  // list of its kind, which is its entry's index in the file's section.
  std::vector<std::int64_t> bond_place, angle_place, dihedral_place, improper_place;
  // Per kept atom: the rank of its molecule id among the whole file's distinct molecule ids
  // (0, 1, … in increasing id; every atom 0 in a style without molecule ids), the dense ids a
  // scene gives an import's molecules.
  std::vector<int> molecule_rank;
  // The type numbers the whole file's atoms and bonded terms use: the atoms' in increasing order;
  // each bonded section's in the order of their first entry (which is the order in which an import
  // names the types it maps them to).
  struct TypesUsed {
    std::vector<int> atom, bond, angle, dihedral, improper;
  } types_used;
  int num_atoms = 0;      // in the whole file
  int num_molecules = 0;  // in the whole file (connected components of its bonded terms)
};

// The box of the file's header (LAMMPS's default −0.5 … 0.5 on an axis it does not give): what a
// decomposed run's domain grid needs before it reads its part. Reads the header only.
struct ImportedBox {
  Eigen::Vector3d lo, hi;
};
ImportedBox read_lammps_data_box(const std::string& path);

// What a scene's description (SceneContent::description, engine/scene/scene.hpp) needs of the
// whole file, from one streaming pass over it (the structure pass of the reader by parts, without
// the union–find): the header, the masses and the "… Coeffs" sections, the types the file uses, and
// per type its atoms or items, counted — no per-atom array beyond the atom ids when they are not
// 1 … N in order (and the file's distinct molecule ids) while it reads.
struct ImportedDescription {
  Eigen::Vector3d lo, hi;
  std::map<int, double> type_mass;
  std::vector<ImportedSystem::CoeffSection> coeffs;
  int num_atoms = 0;
  int num_molecule_ids = 0;  // the file's distinct molecule ids (1 in a style without them)
  // The types used: atom types ordered by the index of their first atom (by increasing id), each
  // bonded section's by their first entry (the order an import names the types it maps them to).
  ImportedPart::TypesUsed types_used;
  // Per atom type number: its atoms, and the index (by increasing id) of its first atom.
  std::vector<std::int64_t> atoms_of_type;
  std::vector<int> first_atom_of_type;
  // Per bonded section (Bonds, Angles, Dihedrals, Impropers), per type number: its entries.
  std::array<std::vector<std::int64_t>, 4> items_of_type;
  // The q column (atom_style full): whether the file has one, and its values' sum over the atoms in
  // the file's order (the order of increasing id, which the whole import sums in, for a file that
  // lists its atoms so), their largest magnitude, and the first charged atom's index and charge.
  // Without a q column, with `type_charge` given (per atom type number), the same of the types'
  // charges.
  bool charge_column = false;
  double charge_sum = 0.0, charge_scale = 0.0, first_charge = 0.0;
  int first_charged = -1;
};
ImportedDescription read_lammps_data_description(const std::string& path, const std::string& atom_style,
                                                 const std::vector<double>* type_charge = nullptr);

// atom_style as read_lammps_data's. Throws InputError, one line naming the file and line, for a
// file the whole reader refuses in the lines it reads; and when a Velocities, Bonds, Angles,
// Dihedrals or Impropers section comes before the Atoms section (LAMMPS refuses it too).
ImportedPart read_lammps_data_part(const std::string& path, const std::string& atom_style, const KeepAnchor& keep);
// The same for a block of molecules in the file's order (KeepBlock): two passes over the file (no
// anchors), and image flags not required.
ImportedPart read_lammps_data_part(const std::string& path, const std::string& atom_style, const KeepBlock& block);

}  // namespace stiffmd
