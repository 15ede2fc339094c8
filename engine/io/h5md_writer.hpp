// H5MD 1.1 trajectory writer (https://nongnu.org/h5md/h5md.html) on the HDF5 C API.
//
// Layout written (N particles, F frames, S distinct species, m bonds; "time-dependent element" =
// a group with step int64[F], time float64[F], value[F][...], H5MD §"Time-dependent data"):
//
//   /h5md                       +version int32[2] = {1, 1}
//     author                    +name string
//     creator                   +name "stiffmd", +version string
//                               (every string attribute here: fixed-length, null-terminated, ASCII
//                               unless the value needs UTF-8, as §H5MD metadata asks)
//   /particles/all
//     position                  time-dependent, value float64[F][N][3]; periodic axes wrapped into
//                               [origin, origin + L), open axes as the engine keeps them
//     image                     (any axis periodic) value int32[F][N][3]: unwrapped = position + image*L
//     velocity, force           (optional) value float64[F][N][3]
//     species int32[N]          index into the element table, attribute `elements` (string[S])
//     mass float64[N], id int64[N] (0..N-1)       time-independent datasets
//     charge float64[N]                           (H5MD's `charge`, in e; charged scenes only)
//     box                       +dimension int32 = 3, +boundary string[3] ("periodic"/"none")
//       edges                   (any axis periodic) value float64[F][3][3] = diag(L), rows the edge vectors
//       offset float64[3]       (any axis periodic) the box origin, low corner of the wrapping cell
//   /connectivity/bonds int32[m][2]   0-based indices, +particles_group object reference -> /particles/all
//   /observables/<name>         time-dependent scalar, value float64[F], one per H5mdSetup::observables
//   /parameters/vmd_structure   indexOfSpecies int32[S], name/type char[16][S] (the symbols),
//                               bond_from/bond_to int32[m] (1-based): what VMD's H5MD plugin reads
//
// Every step/time except position's is a hard link to position/step and position/time: all elements
// share one time grid (H5MD requires this for image and box/edges; it is allowed for the others).
// Time series are chunked along an unlimited frame axis; gzip (with byte shuffle) applies to the
// per-particle elements only. `unit` attributes (variable-length strings) only in real units
// (H5mdSetup::length_unit, …): reduced units carry none.
//
// Reading it: h5py directly; MDAnalysis 2.4.2 as
//   mda.Universe(topology, "traj.h5", format="H5MD", convert_units=False)
// with any topology holding the atoms (e.g. the run's extended XYZ), or
//   u = mda.Universe.empty(N); u.load_new("traj.h5", format="H5MD", convert_units=False)
// (MDAnalysis cannot build a topology from H5MD, does not know the .h5 suffix, and refuses
// convert_units=True without units). tools/h5md_to_xyz.py converts to extended XYZ.
// While a run writes the file, HDF5's file lock keeps other programs from opening it (set
// HDF5_USE_FILE_LOCKING=FALSE in the reader's environment to peek, at the reader's risk).
// After a kill, the complete frames are the first len(position/step); other series may hold one
// frame more (MDAnalysis iterates exactly the complete frames, though len(u.trajectory) may count
// one more). Appending (a restart) drops the extra frame; see the .cpp for the one rare case where
// a kill inside a flush leaves the file unreadable in places until appending repairs it.
#pragma once

#include <Eigen/Core>
#include <cstdint>
#include <memory>
#include <string>
#include <utility>
#include <vector>

#include "core/box.hpp"

namespace stiffmd {

class Communicator;

struct H5mdSetup {
  int num_particles = 0;
  // The time-independent data, given whole here (species, mass, charge, bonds) and written when
  // the file is created; or, with `by_rows`, written after it by rows (write_particle_rows,
  // write_bond_rows: a decomposed run's rank 0 streams them from the ranks' parts,
  // engine/run/h5md_static_parts.hpp), species, mass, charge and bonds then empty and `elements`,
  // `charged` and `num_bonds` saying what the datasets hold.
  std::vector<std::string> species;        // element symbol per particle (e.g. "C", "Fe")
  Eigen::VectorXd mass;                    // per particle (a fixed particle: its type's mass)
  std::vector<double> charge;              // per particle, in e; empty: uncharged (no `charge` dataset)
  Box box;                                 // open box when no axis is periodic
  std::vector<std::pair<int, int>> bonds;  // 0-based particle indices
  bool by_rows = false;
  std::vector<std::string> elements;     // by rows: the element table, symbols in order of first appearance
  bool charged = false;                  // by rows: a `charge` dataset
  std::int64_t num_bonds = 0;            // by rows
  std::string author;                    // empty: $USER, else the login name
  std::string creator_version;           // stiffmd version string
  bool velocity = false, force = false;  // optional time-dependent elements
  int gzip = 0;                          // 0 = no compression, 1..9 deflate level (always chunked)
  std::vector<std::string> observables;  // scalar observable names (no '/')
  // §Units: the `unit` attribute of position (and box edges), time, velocity, force and of each
  // observable ("" or an empty list: none, as in reduced units).
  std::string length_unit, time_unit, velocity_unit, force_unit;
  std::vector<std::string> observable_units;  // empty, or one per observable
  // Several processes (a decomposed run, docs/parallel.md): with parallel HDF5 (shared_files())
  // every one of them opens the one file and writes its own particles' rows of each frame
  // (collective hyperslabs in global index order); the file is the one process's, byte for byte
  // in its datasets. Null, or one process: this process writes everything.
  const Communicator* processes = nullptr;
};

class H5mdWriter {
 public:
  // Name of the one particle group (H5MD §"Particles group": the name is free).
  static constexpr const char* kParticleGroup = "all";

  // append=false: creates (truncates) the file. append=true: reopens a file this writer made and
  // continues its series after dropping the frames with step >= first_step (a restart from a
  // checkpoint older than the last frame then does not duplicate frames). Throws InputError
  // naming the path when the file cannot be created/opened or does not match the setup.
  H5mdWriter(const std::string& path, const H5mdSetup& setup, bool append = false, std::int64_t first_step = 0);
  ~H5mdWriter();
  H5mdWriter(const H5mdWriter&) = delete;
  H5mdWriter& operator=(const H5mdWriter&) = delete;

  // One frame; x holds unwrapped coordinates, v and f may be null (ignored unless enabled in the
  // setup, required when enabled), observables in the order of setup.observables. The file is
  // flushed before returning, so a kill after this call leaves every frame so far readable.
  //
  // A file shared by several processes (setup.processes): every process calls it for every frame
  // (collective), `ids` the global indices of the columns of x, v and f (each particle on one
  // process; empty: none). Step, time and the observables are rank 0's. One process: `ids` is
  // null.
  void write_frame(std::int64_t step, double time, const Eigen::Matrix3Xd& x, const Eigen::Matrix3Xd* v,
                   const Eigen::Matrix3Xd* f, const std::vector<double>& observables,
                   const std::vector<int>* ids = nullptr);
  std::int64_t frames() const;
  // A file created by rows (H5mdSetup::by_rows; not one appended to): rows [first, first + count)
  // of the time-independent per-particle datasets — species (indices into setup.elements), mass,
  // charge (when setup.charged; else null), and id — and of the bonds (pairs: 2 × count 0-based
  // indices; connectivity/bonds and VMD's bond_from/bond_to). Called by the process that writes
  // the time-independent data (one process, or rank 0 of a shared file: independently), each row
  // once.
  void write_particle_rows(std::int64_t first, std::int64_t count, const int* species, const double* mass,
                           const double* charge);
  void write_bond_rows(std::int64_t first, std::int64_t count, const int* pairs);
  // The box edges of the frames written from now on (a barostat moves them; the origin and the
  // periodic axes stay the setup's). Positions are wrapped into it.
  void set_box_lengths(const Eigen::Vector3d& lengths);
  // Closes the file; nothing is written after it. For a file shared by several processes it is
  // collective, and the one way to close it: a shared file destroyed unclosed is left as a killed
  // writer's (every frame flushed), because its process is leaving the job alone and the others
  // would wait for it in the collective close. One process: the destructor closes it too.
  void close();
  // Whether this build can share a file among processes (HDF5 built with MPI-IO).
  static bool shared_files();

 private:
  struct Impl;  // keeps <hdf5.h> out of this header
  std::unique_ptr<Impl> impl_;
};

}  // namespace stiffmd
