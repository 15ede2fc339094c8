// A Scene is everything a run needs, assembled from a deck: particles, topology, box, the
// force terms the deck names (and only those: docs/design.md §1), and the run's settings.
#pragma once

#include <algorithm>

#include <cstdint>
#include <map>
#include <memory>
#include <optional>
#include <ostream>
#include <string>
#include <utility>
#include <vector>

#include "core/box.hpp"
#include "core/state.hpp"
#include "core/topology.hpp"
#include "core/units.hpp"
#include "engine/deck/deck.hpp"
#include "engine/observe/monitor.hpp"
#include "engine/observe/observables.hpp"
#include "engine/scene/overlap_rule.hpp"
#include "engine/scene/parallel_settings.hpp"
#include "forcefields/force_field.hpp"
#include "integrators/integrator.hpp"
#include "integrators/minimize.hpp"
#include "integrators/prepare.hpp"

namespace stiffmd {

struct ParticleType {
  std::string name;
  double mass = 1.0;
  std::string element;  // chemical symbol written as the species in trajectories (ASE, OVITO)
  double charge = 0.0;  // in units of the elementary charge e (both `lj` and `real`), the default of its particles
};

struct RunSettings {
  double t_end = 0.0;      // engine time; with `steps`, steps × h
  std::int64_t steps = 0;  // run.steps: the final macro step, counted from t = 0 (0: run to t_end)
};

// One stage of a staged protocol (engine/scene/stage_deck.hpp): its number 1..count and name;
// number 0: a plain run. A stage's run may have no steps (steps = 0: t_end = 0, a stage that only
// minimises); its steps and time count from 0.
struct StageIdentity {
  int number = 0, count = 0;
  std::string name;
  bool staged() const { return number > 0; }
};

struct OutputSettings {
  std::string xyz;            // extended XYZ trajectory file name ("" = none)
  double xyz_interval = 0.0;  // time between frames
  bool xyz_velocities = false;
  std::string thermo;  // thermo CSV file name ("" = none)
  double thermo_interval = 0.0;
  bool thermo_norm = false;      // extensive columns per particle (ThermoOutput, engine/observe/observables.hpp)
  double screen_interval = 0.0;  // time between thermo lines on stdout (at thermo samples; 0 = none)
  std::string state;             // CSV of x and P(x)p per particle, for error measurements ("" = none)
  double state_interval = 0.0;
  std::string h5md;  // H5MD 1.1 trajectory file name ("" = none)
  double h5md_interval = 0.0;
  bool h5md_velocity = false, h5md_force = false;
  int h5md_gzip = 0;                          // deflate level 0..9
  std::string author;                         // H5MD author (default: the user name)
  std::string lammps_data;                    // the final state as a LAMMPS data file ("" = none)
  std::string checkpoint = "checkpoint.bin";  // written at the end, on SIGINT/SIGTERM, and every N steps
  double checkpoint_interval = 0.0;           // a time (0 = only at the end and on a signal)
};

// [prepare]: how the initial state is made ready for a stiff run (prepare_scene, which calls
// prepare_state in integrators/prepare.hpp with these settings).
struct PrepareTable : PrepareSettings {
  bool requested = false;  // the deck has a [prepare] table
  std::string where;       // "file:line" of that table, for errors
};

// [minimize]: FIRE 2.0, CG or SD on the prepared state (prepare_scene, which calls minimize in
// integrators/minimize.hpp with these settings).
struct MinimizeTable : MinimizeSettings {
  bool requested = false;  // the deck has a [minimize] table
  std::string where;       // "file:line" of that table, for errors
};

// Macro steps of size h to cover a time span: the nearest whole number when span/h is one up to
// a relative 1e-9 (run.t_end must be: read_run), else rounded up (a span that is not a whole
// number of steps, as the Python module's run_to may ask for, ends at the first step after it).
std::int64_t whole_steps(double span, double h);

// Where a run of particles came from: a [[particles]] entry, a [[build]] or the [import], for
// messages that name a particle (the overlap check of the pair terms).
struct ParticleSource {
  int first = 0, count = 0;
  std::string what;  // "file:line: build[1]", as DeckTable::where() names the table
};

// The force field as LAMMPS read_data sections, for a data file written back (engine/run/outputs.cpp):
// each force style's reader gives the coefficients of the types it claims where LAMMPS has a
// style of the same functional form (README's force-style table), in LAMMPS's convention
// (harmonic K = k/2, angles in degrees). A kind whose types need two LAMMPS styles, or one
// LAMMPS lacks, is not representable and is left out of the file.
struct LammpsCoeffs {
  struct Section {
    std::string style;  // the LAMMPS style ("harmonic", "lj/cut"); "" while no term gave rows
    bool representable = true;
    // Per scene type index (pair terms: per type pair a <= b) the coefficients after the type(s).
    std::map<std::pair<int, int>, std::string> rows;
    // A term of `lammps_style` gives rows; a second style of the same kind, a second pair term or
    // "" (no LAMMPS equivalent) makes the section unrepresentable.
    void claim(const std::string& lammps_style) {
      if (lammps_style.empty() || (!style.empty() && (style != lammps_style || pairwise))) representable = false;
      style = lammps_style;
    }
    bool pairwise = false;  // PairIJ rows: one term only (two would need pair_style hybrid/overlay)
  };
  Section pair, bond, angle, dihedral, improper;
};

// The LAMMPS type numbers an [import] of a data file gave each scene type (index: the scene's
// particle type, or its bond / angle / dihedral / improper type; 0: none), and the file's masses, so
// that a data file written back numbers them as the imported one did.
struct LammpsTypeNumbers {
  std::vector<int> atom, bond, angle, dihedral, improper;
  std::map<int, double> masses;
};

// What a force term's `coefficients = "data"` reads (engine/scene/force_registry.cpp): the imported
// LAMMPS data file's "… Coeffs" sections as text, and per scene bond / angle / dihedral / improper
// type every LAMMPS type number the [import] mapped onto it (several numbers may share a name).
struct LammpsDataCoeffs {
  std::string file;  // the data file as the deck names it; "" when no LAMMPS data file was imported
  struct Section {
    std::string name;               // "Angle Coeffs"
    std::string style;              // the hint after '#' ("charmm"), "" without one
    std::vector<std::string> rows;  // each row: the type, then the coefficients
  };
  std::vector<Section> sections;
  std::vector<std::vector<int>> bond, angle, dihedral, improper;  // per scene type, its LAMMPS numbers
};

// What load_scene makes of the deck's particle sources.
enum class SceneContent {
  whole,        // every particle, item and per-particle array
  description,  // [[build]]s of linear chains grown by molecule, and an [import] of a LAMMPS data
                // file that makes every particle, counted, not built or read into arrays (below)
};

// A source that a description counted instead of building or reading (SceneContent::description):
// what its particles and items would be, by count and type. Its molecules are made by parts
// (chains_part and data_file_part, engine/domain/part_load.hpp): a [[build]] of linear chains
// grown by molecule (one particle type, one type per item kind), or the [import] of a LAMMPS data
// file (its types as the file uses them, its charges the file's q column or the types').
struct DescribedSource {
  int first = 0, count = 0;  // its particles' indices in the whole scene: [first, first + count)
  int molecules = 0;         // its molecules (a chain each; an import's distinct molecule ids)
  // Per particle type (index into Scene::types; as many entries as types): its particles.
  std::vector<std::int64_t> particles_of_type;
  // Per type of each item kind (index into the topology's names): its items.
  std::vector<std::int64_t> bonds_of_type, angles_of_type, dihedrals_of_type, impropers_of_type;
  // Per particle type: the Langevin friction of its particles (read_thermostat); empty without Langevin.
  std::vector<double> friction_of_type;
  // The charges. Carried by type (`summed` false): each particle has its type's charge, summed
  // particle by particle where needed. Or given per particle (a data file's q column) and summed
  // by the reader in the whole scene's order: their sum, largest magnitude, and the first charged
  // particle's whole-scene index (−1: none) and charge.
  bool summed = false;
  double charge_sum = 0.0, charge_scale = 0.0, first_charge = 0.0;
  int first_charged = -1;

  static std::int64_t total(const std::vector<std::int64_t>& of_type) {
    std::int64_t n = 0;
    for (const std::int64_t c : of_type) n += c;
    return n;
  }
  static std::int64_t of(const std::vector<std::int64_t>& of_type, std::size_t k) {
    return k < of_type.size() ? of_type[k] : 0;
  }
  std::int64_t bonds() const { return total(bonds_of_type); }
};

struct Scene {
  std::string deck_path;
  Units units;  // `units`: the deck's values and the outputs in them, the engine's internal (core/units.hpp)
  State state;
  Box box;
  Topology topology;
  std::vector<ParticleType> types;
  std::vector<int> particle_type;  // index into types, per particle
  // Per particle, in units of e: the type's charge, a [[particles]] row's, or a LAMMPS data
  // file's q column (atom_style full). All 0 in an uncharged scene; read by the terms that say
  // ForceTerm::uses_charges (the Coulomb styles), refused with any other (it would be lost).
  std::vector<double> charge;
  // A described scene is charged when a described source's particles are: a type of its
  // particles has a charge, or the charges it gives (a data file's q column) are not all 0.
  bool charged() const {
    const auto described_charged = [&](const DescribedSource& d) {
      if (d.summed) return d.first_charged >= 0;
      for (std::size_t k = 0; k < d.particles_of_type.size(); ++k)
        if (d.particles_of_type[k] > 0 && types[k].charge != 0.0) return true;
      return false;
    };
    return std::any_of(charge.begin(), charge.end(), [](double q) { return q != 0.0; }) ||
           std::any_of(described_sources.begin(), described_sources.end(), described_charged);
  }
  // Particles a description did not load (SceneContent::description): the by-molecule chains'
  // beads or the data file's atoms, counted; 0 for a whole scene. When > 0 the state, particle_type, charge and
  // topology items hold none of them (they are made by parts: engine/domain/part_load.hpp), and described_sources says
  // what they are. The loaded particles come first: a described source is never followed by a loaded one, so a loaded
  // particle's index is its whole-scene index.
  std::int64_t undescribed_particles = 0;
  std::vector<DescribedSource> described_sources;  // in particle order
  bool described() const { return undescribed_particles > 0; }
  // A description's pair terms' rules for overlapping particles at the start, in the deck's order
  // of the terms: the whole load checks its particles (an InputError naming the closest two
  // unless [minimize] relaxes them), a description has no positions of its counted chains, so a
  // decomposed run applies them to the parts at the start (engine/domain/part_overlaps.hpp).
  // Empty for a whole scene.
  std::vector<OverlapRule> overlap_rules;
  // The whole scene's particle count: those loaded and those described.
  std::int64_t whole_particles() const { return state.size() + undescribed_particles; }
  std::unique_ptr<ForceField> forces;
  IntegratorSettings integrator;
  RunSettings run;
  StageIdentity stage;  // of a staged protocol's stage (number 0: a plain run)
  OutputSettings output;
  ObservableSettings observables;
  MonitorSettings monitor;                  // [monitor]
  PrepareTable prepare;                     // [prepare], applied by prepare_scene
  MinimizeTable minimize;                   // [minimize], applied by prepare_scene after [prepare]
  std::optional<MinimizeReport> minimized;  // what [minimize] did (a fresh run's prepare_scene)
  ParallelSettings parallel;                // [parallel]
  bool box_from_source = false;             // a builder's density or an imported file set the box
  std::vector<ParticleSource> sources;      // in particle order, covering every particle
  LammpsCoeffs lammps_coeffs;               // filled by the force styles' readers
  LammpsTypeNumbers lammps_types;           // filled by a LAMMPS [import]
  LammpsDataCoeffs lammps_data_coeffs;      // filled by a LAMMPS [import], read by coefficients = "data"
  std::vector<std::string> notes;           // what assembly did beyond the obvious (projection, thermalisation)
  // A decomposed run's part (engine/domain/domain_integrator.*; it may hold no particle): the
  // whole system's index of each particle here. Empty: the whole system.
  std::vector<int> global_id;

  std::int64_t num_steps() const;  // macro steps to reach run.t_end (run.steps when given)
  // A [thermostat] acts (canonical ensemble): energy is not conserved, momentum not with Langevin.
  bool thermostatted() const { return integrator.thermostat.on(); }
};

// "particle 12 (file:line: build[1])": a particle and the deck table that made it.
std::string particle_and_source(const Scene& scene, int i);

// Reads and validates the whole deck; throws InputError naming file, line and key. Does not
// change the deck's initial state: [prepare] is applied by prepare_scene. A deck with [[stage]]
// tables is refused: its scenes are its stages' (engine/scene/stage_deck.hpp), each loaded with
// its `stage` identity.
//
// SceneContent::description loads the deck's description only, O(types + deck) in memory: every
// [[build]] of linear chains with growth = "by-molecule" that no loaded source follows registers
// its type names, its `sources` entry and its box as the whole load does, and appends no particle
// or item (Scene::described_sources counts them); so does an [import] of a LAMMPS data file that
// makes every particle (no [[particles]], [[build]] or [[bonds]]), from one streaming pass over
// the file that counts its atoms and items by type and sums its charges
// (read_lammps_data_description, engine/io/lammps_data_parts.hpp), its box, masses, type maps and
// "… Coeffs" sections read as the whole import reads them. Everything else is the whole load's:
// the other sources, the types, units, box, settings, levels, monitor, LAMMPS coefficients and
// the force terms, whose descriptions (ForceTerm::on_subset on no particle) are the whole terms'.
// The checks that need the described particles are not made here (docs/parallel.md, "The scene's
// description": the overlap of the pair terms, the bonded terms' domain at the initial state, a
// chain that cannot be grown; a data file's lines that hold positions, velocities and charges,
// which each rank checks in its block, data_file_part). A deck the description cannot stand for —
// an XYZ [import], [[bonds]], [barostat], a pair term's tail correction, a term whose parameters
// or checks read every particle (ewald or pppm with a data file, charmm-dihedral, gravity, a
// tether or a wall; stiff-harmonic unless its bonds are the builder's chains' by type, no rigid
// angle among them) — is loaded whole (described() false).
Scene load_scene(const Deck& deck, const StageIdentity& stage = {}, SceneContent content = SceneContent::whole);

// Applies [prepare] (projection, relaxation, thermal bond vibrations) and [minimize] (after the
// relaxation, before the vibrations) to the scene's state and says what they did on `log`. Called for `check` and for a
// fresh run; a restart takes its state from the checkpoint instead. Throws InputError naming the [prepare] table when
// it fails. `progress` (null: silent) gets what it is doing while it does it (prepare_state).
void prepare_scene(Scene& scene, std::ostream& log, std::ostream* progress = nullptr);

// The files a run of the scene writes into its output directory, with the deck key that names
// each under [output] ("xyz", "thermo", …; "" for histograms.csv and summary.json, fixed names).
// Written at the start of every run with a trajectory (xyz or h5md): bonds, masses and molecule
// ids as a LAMMPS data file, for MDAnalysis, VMD and OVITO (engine/run/simulation.cpp).
inline constexpr const char* kTopologyFile = "topology.data";
std::vector<std::pair<std::string, std::string>> output_files(const Scene& scene);

// Before the first step: throws InputError when an output file of the scene (or the temporary
// file an atomic writer renames into place) exists in `dir` as a directory, or `dir` is not
// writable.
void check_output_paths(const Scene& scene, const std::string& dir);

// Human-readable inventory of a scene (for `stiffmd check`): what it holds (particles, box,
// topology, force terms) and how it is run (integrator, thermostat, run, outputs), the two parts
// also apart (describe_settings: a staged protocol's stages share the first).
std::string describe(const Scene& scene);
std::string describe_scene(const Scene& scene);
std::string describe_settings(const Scene& scene);

// The whole scene's constraint-defining stiff bonds: the loaded particles' (the term's list) and,
// in a description, the described sources' bonds of the types the stiff-harmonic term claims.
std::int64_t whole_stiff_bonds(const Scene& scene);

}  // namespace stiffmd
