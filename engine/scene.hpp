// A Scene is everything a run needs, assembled from a deck: particles, topology, box, the
// force terms the deck names (and only those: design.md §1), and the run's settings.
#pragma once

#include <memory>
#include <string>
#include <utility>
#include <vector>

#include "engine/box.hpp"
#include "engine/deck.hpp"
#include "engine/monitor.hpp"
#include "engine/observables.hpp"
#include "engine/state.hpp"
#include "engine/topology.hpp"
#include "forcefields/force_field.hpp"
#include "integrators/integrator.hpp"

namespace stiffmd {

struct ParticleType {
  std::string name;
  double mass = 1.0;
  std::string element;  // chemical symbol written as the species in trajectories (ASE, OVITO)
};

struct RunSettings {
  double t_end = 0.0;
};

struct OutputSettings {
  std::string xyz;            // extended XYZ trajectory file name ("" = none)
  double xyz_interval = 0.0;  // time between frames
  bool xyz_velocities = false;
  std::string thermo;  // thermo CSV file name ("" = none)
  double thermo_interval = 0.0;
  std::string state;  // CSV of x and P(x)p per particle, for error measurements ("" = none)
  double state_interval = 0.0;
  std::string h5md;  // H5MD 1.1 trajectory file name ("" = none)
  double h5md_interval = 0.0;
  bool h5md_velocity = false, h5md_force = false;
  int h5md_gzip = 0;                          // deflate level 0..9
  std::string author;                         // H5MD author (default: the user name)
  std::string lammps_data;                    // the final state as a LAMMPS data file ("" = none)
  std::string checkpoint = "checkpoint.bin";  // written at the end, on SIGINT/SIGTERM, and every N steps
  long checkpoint_every = 0;                  // N (0 = only at the end and on a signal)
};

struct Scene {
  std::string deck_path;
  State state;
  Box box;
  Topology topology;
  std::vector<ParticleType> types;
  std::vector<int> particle_type;  // index into types, per particle
  std::unique_ptr<ForceField> forces;
  IntegratorSettings integrator;
  RunSettings run;
  OutputSettings output;
  ObservableSettings observables;
  MonitorSettings monitor;         // [monitor]
  bool box_from_source = false;    // a builder's density or an imported file set the box
  std::vector<std::string> notes;  // what assembly did beyond the obvious (projection, thermalisation)

  std::int64_t num_steps() const;  // macro steps to reach run.t_end
};

// Reads and validates the whole deck; throws InputError naming file, line and key.
Scene load_scene(const Deck& deck);

// The files a run of the scene writes into its output directory, with the deck key that names
// each under [output] ("xyz", "thermo", …; "" for histograms.csv and summary.json, fixed names).
std::vector<std::pair<std::string, std::string>> output_files(const Scene& scene);

// Before the first step: throws InputError when an output file of the scene (or the temporary
// file an atomic writer renames into place) exists in `dir` as a directory, or `dir` is not
// writable.
void check_output_paths(const Scene& scene, const std::string& dir);

// Human-readable inventory of a scene (for `stiffmd check`).
std::string describe(const Scene& scene);

}  // namespace stiffmd
