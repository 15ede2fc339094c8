// Bonded topology: which particles are bonded (bent and twisted), with which named type, and which
// molecule each particle belongs to. The parameters of a bond or angle type (rest length,
// stiffness, …) belong to the force term that claims that type (forcefields/), as LAMMPS's
// bond_coeff belongs to its bond_style.
#pragma once

#include <array>
#include <string>
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

struct Topology {
  std::vector<Bond> bonds;
  std::vector<std::string> bond_types;  // names from the deck
  std::vector<Angle> angles;
  std::vector<std::string> angle_types;
  std::vector<Dihedral> dihedrals;
  std::vector<std::string> dihedral_types;
  std::vector<int> molecule;  // per particle, 0-based; empty when the scene has no molecules

  static int index_of(const std::vector<std::string>& names, const std::string& name) {
    for (size_t k = 0; k < names.size(); ++k)
      if (names[k] == name) return static_cast<int>(k);
    return -1;
  }
  int bond_type_index(const std::string& name) const { return index_of(bond_types, name); }
  int angle_type_index(const std::string& name) const { return index_of(angle_types, name); }
  int dihedral_type_index(const std::string& name) const { return index_of(dihedral_types, name); }
  // The index of `name`, added if new.
  static int intern(std::vector<std::string>& names, const std::string& name) {
    const int k = index_of(names, name);
    if (k >= 0) return k;
    names.push_back(name);
    return static_cast<int>(names.size()) - 1;
  }
};

// The molecules of n particles: the connected components of the bonded terms (bonds, angles,
// dihedrals), numbered 0, 1, … in the order of their first particle; a lone particle is its own.
// Not the deck's or a data file's molecule ids: a term must never join two molecules, whatever a
// file calls them. What is scaled as one by a barostat and owned by one rank of a decomposed run.
inline std::vector<int> bonded_molecules(const Topology& topology, int n) {
  DisjointSets bonded(n);
  for (const Bond& b : topology.bonds) bonded.join(b.i, b.j);
  for (const Angle& a : topology.angles) bonded.join(a.i, a.j), bonded.join(a.j, a.k);
  for (const Dihedral& d : topology.dihedrals) bonded.join(d.i, d.j), bonded.join(d.j, d.k), bonded.join(d.k, d.l);
  std::vector<int> molecule(static_cast<size_t>(n), -1);
  int molecules = 0;
  for (int i = 0; i < n; ++i) {
    const int root = bonded.root(i);  // the least particle of its component
    molecule[i] = root == i ? molecules++ : molecule[root];
  }
  return molecule;
}

}  // namespace stiffmd
