// The files of a run (the deck's [output]): the trajectories (XYZ, H5MD, with topology.data),
// the thermo and state CSV files on their time grids, the checkpoint's path, and at the end the
// LAMMPS data file and the histograms. RunOutputs opens them — fresh, or on a restart cut back
// to the step before the checkpoint and appended to — and decides which are due at each step.
#pragma once

#include <algorithm>
#include <cstdint>
#include <memory>
#include <ostream>
#include <string>
#include <vector>

#include "engine/domain/part_molecules.hpp"
#include "engine/io/h5md_writer.hpp"
#include "engine/io/writers.hpp"
#include "engine/observe/observables.hpp"
#include "engine/scene/scene.hpp"

namespace stiffmd {

// Creates the output directory (or refuses a path that is not one), checks that every output of
// the scene can be written there, and removes a previous summary.json (a summary only ever
// describes a finished run). Throws InputError.
void prepare_output_directory(const Scene& scene, const std::string& dir);

// A rank but 0 of a decomposed run that writes its rows of the shared H5MD file: the directory
// rank 0 prepared must be there for this rank too (not a node-local path of rank 0's machine) and
// writable by it. Throws InputError naming the rank.
void check_rank_directory(const std::string& dir, int rank);

// Writes the scene's current state (after [prepare], before any step when called on a freshly
// loaded scene) as a LAMMPS data file: atom style bond (angle when the scene has angles).
// `force_field`: with the deck's force field as Coeffs sections (Scene::lammps_coeffs), for LAMMPS;
// without, a topology for analysis programs (MDAnalysis's reader stops at a PairIJ Coeffs section).
void write_scene_lammps_data(const Scene& scene, const std::string& path, const std::string& title,
                             bool force_field = true);

// This process's particles in a decomposed run (engine/domain/domain_integrator.hpp): their
// global indices, increasing, their positions and velocities, their forces when the H5MD file
// has them, and their types (the XYZ frame's species; null: the scene's, which then holds every
// particle).
struct ProcessRows {
  const std::vector<int>& ids;
  const Eigen::Matrix3Xd &x, &v;
  const Eigen::Matrix3Xd* f = nullptr;
  const std::vector<int>* type = nullptr;
};

// A decomposed run's particles as the ranks hold them at the start (each rank its molecules, their
// positions and velocities): what the trajectories' time-independent data — topology.data, the
// H5MD file's species, masses, charges and bonds — are written from, collectively, when the scene
// does not hold the particles (a scene's description: engine/io/topology_parts.hpp,
// engine/io/h5md_static_parts.hpp).
struct StaticParts {
  const PartMolecules& mine;
  const Eigen::Matrix3Xd &x, &v;
};

class RunOutputs {
 public:
  // Opens the outputs for the scene's current state. `restart_cut`: null for a fresh run (files
  // are created, an existing one noted on `log`); on a restart the time of the step before the
  // checkpoint, t_{k−1}: every file is cut back to it and appended to, and the schedules resume
  // from there, so that the files end up exactly as an uninterrupted run's. Lists every file it
  // owns in `files`, in the order of the summary (topology.data, XYZ, thermo, state, H5MD,
  // checkpoint). An empty `dir`: no files at all, the time grids (and so the thermo samples) as
  // with files, checkpoint_path() empty.
  //
  // `processes` (a decomposed run; null: one process): every rank has its RunOutputs, on the same
  // grids; rank 0 writes every file, but the H5MD file when HDF5 is parallel
  // (H5mdWriter::shared_files): every rank writes its particles' rows of it (shares_frame()).
  // `num_particles`: the whole system's (a decomposed run's, summed from its parts).
  // `parts` (every rank alike; null: the scene holds every particle): the time-independent data of
  // the trajectories are written from the ranks' parts, the scene's particles not read (its types,
  // box and units are); collective over `processes`.
  RunOutputs(Scene& scene, int num_particles, const std::string& dir, const Thermo& thermo, const double* restart_cut,
             std::vector<std::string>& files, std::ostream& log, const Communicator* processes = nullptr,
             const StaticParts* parts = nullptr);

  // Advances the time grids to t and returns whether a thermo sample is due (for the thermo CSV
  // or an H5MD frame); `final`: every output is due (the last state, whatever the grids). Every
  // grid advances, whether this process writes its file or not, so that next_due_step is the same
  // on every rank of a decomposed run.
  bool due(double t, bool final);
  // The first step after k at which due() finds some grid due (IntervalSchedule::next_due_step;
  // time(j): the run's t_j): at the steps before it nothing is due, and a run need not ask.
  template <class Time>
  std::int64_t next_due_step(std::int64_t k, double h, Time time) const {
    return std::min({thermo_due_.next_due_step(k, h, time), h5md_due_.next_due_step(k, h, time),
                     xyz_due_.next_due_step(k, h, time), state_due_.next_due_step(k, h, time)});
  }
  // Writes what the last due() found due; `row` is the thermo sample when one was due (rank 0's).
  // Called by rank 0 alone, or by every rank when shares_frame(): `mine` its particles (null
  // before the run is distributed: the whole state is then rank 0's to write).
  // `xyz_by_blocks` (every rank alike, with `mine`): the XYZ frame of the ranks' rows, which rank 0
  // gets in blocks of consecutive global indices and writes block by block, holding one: not
  // written from s, nor gathered (collective).
  void write(const State& s, const std::vector<double>& row, const ProcessRows* mine = nullptr,
             bool xyz_by_blocks = false);
  // Whether the last due() found an XYZ frame due (rank 0's file).
  bool xyz_due() const { return xyz_now_; }
  // Whether the last due() found an H5MD frame that every rank writes a part of.
  bool shares_frame() const { return h5md_now_ && shared_h5md_; }
  // The processes that write the H5MD file: all of a decomposed run's (parallel HDF5), else one;
  // 0 without an H5MD file.
  int h5md_writers() const { return h5md_writers_; }
  // Whether the last due() was a sample of the thermo grid (or the final state): the rows the
  // thermo file gets, and the terminal's line may show.
  bool thermo_sampled() const { return thermo_now_; }
  // Whether what the last due() found due is written from the whole state on rank 0 (XYZ, the
  // state file, an H5MD frame not shared among the ranks).
  // `xyz_by_blocks`: the XYZ frame is streamed from the ranks' rows (write), not written from it.
  bool needs_whole_state(bool xyz_by_blocks) const {
    return (xyz_now_ && !xyz_by_blocks) || state_now_ || (h5md_now_ && !shared_h5md_);
  }
  // The thermo columns as written (normalised with [output] thermo_norm, in the deck's units), and the
  // last row written.
  const ThermoOutput& thermo_table() const { return table_; }
  // A thermo row as written (for rows sampled outside the grids: the Python module's thermo()).
  const std::vector<double>& as_written(const std::vector<double>& row) { return table_(row); }
  const std::vector<double>& thermo_row() const { return written_; }
  // After the last step: the LAMMPS data file and the histograms, when asked for.
  void write_final(std::vector<std::string>& files);

  const std::string& checkpoint_path() const { return checkpoint_path_; }
  // Closes every file (a gzip stream gets its end); nothing is written after it. Collective when
  // the ranks share the H5MD file: its destructor leaves a shared file unclosed (H5mdWriter::close),
  // as a rank that fails alone does before it ends the job.
  void close();

 private:
  void write_state(const State& s);
  void write_h5md(const State& s, const ProcessRows* mine);
  void write_xyz_by_blocks(const State& s, const ProcessRows& mine);

  Scene& sc_;
  std::string dir_;
  const Communicator* processes_ = nullptr;  // a decomposed run's
  int num_particles_ = 0;                    // the whole system's (the scene's state may hold none: a description)
  bool root_ = true, shared_h5md_ = false;
  int h5md_writers_ = 0;
  std::unique_ptr<XyzWriter> xyz_;
  std::unique_ptr<CsvWriter> thermo_, state_;
  std::unique_ptr<ProjectedMomenta> projected_;
  std::unique_ptr<H5mdWriter> h5md_;
  IntervalSchedule xyz_due_, thermo_due_, state_due_, h5md_due_;
  ThermoOutput table_;
  std::vector<double> written_;
  bool xyz_now_ = false, thermo_now_ = false, state_now_ = false, h5md_now_ = false;
  std::vector<double> state_row_;
  double velocity_scale_ = 1.0;
  Eigen::Matrix3Xd h5md_velocity_;
  std::vector<int> h5md_columns_;  // every thermo column but time and step
  std::vector<double> h5md_values_;
  Eigen::Matrix3Xd h5md_force_;
  // A shared frame's rows before the run is distributed: rank 0 all, the others none.
  std::vector<int> all_rows_;
  const std::vector<int> no_rows_;
  std::string checkpoint_path_;
};

}  // namespace stiffmd
