// A scene's types as a LAMMPS data file numbers them: the numbers an [import] gave kept
// (Scene::lammps_types), every other particle/bond/angle/dihedral/improper type numbered after
// them in deck order, and a mass for every atom type number. What the whole scene's data files
// (engine/run/outputs.cpp) and the trajectories' topology.data written from the ranks' parts
// (engine/run/topology_parts.hpp) share: they read only the scene's types, none of its particles.
#pragma once

#include <map>
#include <vector>

#include "engine/scene/scene.hpp"

namespace stiffmd {

struct LammpsTypes {
  // Each scene type's LAMMPS number, by kind.
  std::vector<int> atom, bond, angle, dihedral, improper;
  // The largest number of each kind (0: none).
  int atom_types = 0, bond_types = 0, angle_types = 0, dihedral_types = 0, improper_types = 0;
  // 1 … atom_types: the scene type's mass; a number of the imported file that no scene type took
  // keeps the file's mass, else 1 (LAMMPS needs one per type).
  std::map<int, double> type_mass;
};

LammpsTypes lammps_types(const Scene& scene);

}  // namespace stiffmd
