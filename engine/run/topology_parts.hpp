// The trajectories' topology.data (the LAMMPS data file of masses, molecule ids, charges, bonded
// items, positions and velocities at t = 0 that MDAnalysis, VMD and OVITO read beside the XYZ or
// H5MD file: README "Outputs") written from the ranks' parts of a decomposed run, the same bytes
// write_scene_lammps_data(whole, path, title, false) (engine/run/outputs.hpp) writes from the
// whole scene, with no rank holding O(N) of it: rank 0 writes the file as it receives it in blocks
// of consecutive global indices (the Atoms and Velocities sections) and of places (the Bonds,
// Angles, Dihedrals and Impropers sections), engine/io/rows_to_root.hpp.
#pragma once

#include <Eigen/Core>
#include <cstdint>
#include <string>

#include "core/communicator.hpp"
#include "engine/domain/part_molecules.hpp"
#include "engine/scene/scene.hpp"

namespace stiffmd {

// `description`: the scene's types, LAMMPS type numbers, box and units (its particles are not
// read: a scene that holds none, Scene::described(), or any); `mine`, x_mine, v_mine: this rank's
// particles (whole molecules; the ranks' parts a partition of the system's num_particles), their
// positions and velocities. Collective; rank 0 writes `path`. Throws on every rank alike:
// AgreedInputError (InputError on one rank) when the file cannot be written, AgreedStop
// (NumericalError) naming the first atom with a non-finite position, velocity or charge, before
// the file is opened — as the whole scene's writer does.
void write_topology_parts(const Scene& description, const PartMolecules& mine, const Eigen::Matrix3Xd& x_mine,
                          const Eigen::Matrix3Xd& v_mine, std::int64_t num_particles, const Communicator& ranks,
                          const std::string& path, const std::string& title);

}  // namespace stiffmd
