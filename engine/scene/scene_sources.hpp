// Where a scene's particles come from besides [[particles]]: the polymer builders ([[build]]),
// imported files ([import]: LAMMPS data, XYZ + bond list), thermal velocities ([velocities]),
// and the preparation of a stiff state ([prepare]). Internal to scene assembly.
#pragma once

#include <Eigen/Core>
#include <cstddef>
#include <optional>
#include <string>
#include <utility>
#include <vector>

#include "engine/deck/deck.hpp"
#include "engine/scene/scene.hpp"

namespace stiffmd {

// Appends particles (type per particle; molecule ids offset past those already used, or one new
// molecule per particle when `molecule` is empty); returns the index of the first one.
int append_particles(Scene& sc, const Eigen::Matrix3Xd& x, const Eigen::Matrix3Xd& v, const std::vector<int>& type,
                     const std::vector<int>& molecule);
int particle_type_index(const Scene& sc, DeckTable& t, std::string_view key, const std::string& name);

// [[build]]s; those at index `describe_from` and after (all of them grown by molecule: load_scene
// checks it) are described, not built (SceneContent::description, scene.hpp).
void read_builders(DeckTable& root, Scene& sc, std::size_t describe_from = static_cast<std::size_t>(-1));
// The [import]; `describe`: a LAMMPS data file counted, not read into arrays
// (SceneContent::description, scene.hpp), when it is the deck's only source of particles.
void read_import(DeckTable& root, Scene& sc, const std::string& deck_dir, bool describe = false);
// The scene's name of LAMMPS type `number` under an [import] type map (atom_types = { "1" = "bead" }):
// the map's name for it; the number itself ("1") for a bonded kind whose map the deck does not
// give (`given` false); nullopt when a given map has no name for it. Shared with a part's import
// (engine/domain/import_part.hpp).
std::optional<std::string> lammps_type_name(const std::vector<std::pair<std::string, std::string>>& map, bool given,
                                            int number);
// After the [[bonds]]: every molecule whole, positions unwrapped (the guarantee of core/state.hpp).
void make_scene_molecules_whole(DeckTable& root, Scene& sc);
void read_velocities(DeckTable& root, Scene& sc);
void read_prepare(DeckTable& root, Scene& sc);   // reads the settings; prepare_scene (scene.hpp) acts
void read_minimize(DeckTable& root, Scene& sc);  // [minimize], read after [integrator]; prepare_scene acts

}  // namespace stiffmd
