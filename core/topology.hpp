// Bonded topology: which particles are bonded (bent and twisted), with which named type, and which
// molecule each particle belongs to. The parameters of a bond or angle type (rest length,
// stiffness, …) belong to the force term that claims that type (forcefields/), as LAMMPS's
// bond_coeff belongs to its bond_style.
#pragma once

#include <array>
#include <string>
#include <utility>
#include <vector>

#include "core/disjoint_sets.hpp"

namespace stiffmd {

struct Bond {
  int i = 0;
  int j = 0;
  int type = 0;  // index into Topology::bond_types
};

struct Angle {
  int i = 0, j = 0, k = 0;  // j is the vertex
  int type = 0;             // index into Topology::angle_types
};

// A proper dihedral (torsion) i–j–k–l about the j–k bond; φ = 180° is trans (IUPAC, as LAMMPS).
struct Dihedral {
  int i = 0, j = 0, k = 0, l = 0;
  int type = 0;  // index into Topology::dihedral_types
};

// An improper i–j–k–l as LAMMPS lists it: for the harmonic and cvff styles the angle between the
// planes (i, j, k) and (j, k, l), for umbrella the angle between the i–l axis and the plane
// (i, j, k); i is the central atom (LAMMPS's convention for those styles).
struct Improper {
  int i = 0, j = 0, k = 0, l = 0;
  int type = 0;  // index into Topology::improper_types
};

struct Topology {
  std::vector<Bond> bonds;
  std::vector<std::string> bond_types;  // names from the deck
  std::vector<Angle> angles;
  std::vector<std::string> angle_types;
  std::vector<Dihedral> dihedrals;
  std::vector<std::string> dihedral_types;
  std::vector<Improper> impropers;
  std::vector<std::string> improper_types;
  std::vector<int> molecule;  // per particle, 0-based; empty when the scene has no molecules

  static int index_of(const std::vector<std::string>& names, const std::string& name) {
    for (size_t k = 0; k < names.size(); ++k)
      if (names[k] == name) return static_cast<int>(k);
    return -1;
  }
  int bond_type_index(const std::string& name) const { return index_of(bond_types, name); }
  int angle_type_index(const std::string& name) const { return index_of(angle_types, name); }
  int dihedral_type_index(const std::string& name) const { return index_of(dihedral_types, name); }
  int improper_type_index(const std::string& name) const { return index_of(improper_types, name); }
  // The index of `name`, added if new.
  static int intern(std::vector<std::string>& names, const std::string& name) {
    const int k = index_of(names, name);
    if (k >= 0) return k;
    names.push_back(name);
    return static_cast<int>(names.size()) - 1;
  }
};

// The molecules of n particles: the connected components of the bonded terms (bonds, angles,
// dihedrals, impropers), numbered 0, 1, … in the order of their first particle; a lone particle is its own.
// Not the deck's or a data file's molecule ids: a term must never join two molecules, whatever a
// file calls them. What is scaled as one by a barostat and owned by one rank of a decomposed run.
inline std::vector<int> bonded_molecules(const Topology& topology, int n) {
  std::vector<std::pair<int, int>> joins;
  joins.reserve(topology.bonds.size() + 2 * topology.angles.size() + 3 * topology.dihedrals.size() +
                3 * topology.impropers.size());
  for (const Bond& b : topology.bonds) joins.emplace_back(b.i, b.j);
  for (const Angle& a : topology.angles) joins.emplace_back(a.i, a.j), joins.emplace_back(a.j, a.k);
  for (const Dihedral& d : topology.dihedrals)
    joins.emplace_back(d.i, d.j), joins.emplace_back(d.j, d.k), joins.emplace_back(d.k, d.l);
  for (const Improper& d : topology.impropers)
    joins.emplace_back(d.i, d.j), joins.emplace_back(d.i, d.k), joins.emplace_back(d.i, d.l);
  return connected_components(n, joins);
}

}  // namespace stiffmd
