// Bonded topology: which particles are bonded, and with which named bond type. The
// parameters of a bond type (rest length, stiffness, …) belong to the force term that
// claims that type (forcefields/), as LAMMPS's bond_coeff belongs to its bond_style.
#pragma once

#include <string>
#include <vector>

namespace stiffmd {

struct Bond {
  int i = 0;
  int j = 0;
  int type = 0;  // index into Topology::bond_types
};

struct Topology {
  std::vector<Bond> bonds;
  std::vector<std::string> bond_types;  // names from the deck

  int bond_type_index(const std::string& name) const {
    for (size_t k = 0; k < bond_types.size(); ++k)
      if (bond_types[k] == name) return static_cast<int>(k);
    return -1;
  }
};

}  // namespace stiffmd
