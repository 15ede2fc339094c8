// Where a scene's particles come from besides [[particles]]: the polymer builders ([[build]]),
// imported files ([import]: LAMMPS data, XYZ + bond list), thermal velocities ([velocities]),
// and the preparation of a stiff state ([prepare]). Internal to scene assembly.
#pragma once

#include <Eigen/Core>
#include <string>

#include "engine/deck/deck.hpp"
#include "engine/scene/scene.hpp"

namespace stiffmd {

// Appends particles (type per particle; molecule ids offset past those already used, or one new
// molecule per particle when `molecule` is empty); returns the index of the first one.
int append_particles(Scene& sc, const Eigen::Matrix3Xd& x, const Eigen::Matrix3Xd& v, const std::vector<int>& type,
                     const std::vector<int>& molecule);
int particle_type_index(const Scene& sc, DeckTable& t, std::string_view key, const std::string& name);

void read_builders(DeckTable& root, Scene& sc);
void read_import(DeckTable& root, Scene& sc, const std::string& deck_dir);
// After the [[bonds]]: every molecule whole, positions unwrapped (the guarantee of core/state.hpp).
void make_scene_molecules_whole(DeckTable& root, Scene& sc);
void read_velocities(DeckTable& root, Scene& sc);
void read_prepare(DeckTable& root, Scene& sc);  // reads the settings; prepare_scene (scene.hpp) acts
void read_minimize(DeckTable& root, Scene& sc);  // [minimize], read after [integrator]; prepare_scene acts

}  // namespace stiffmd
