// A run: what a run builds from a prepared scene, as components — the integrator, the observers
// (thermo row and monitor), the outputs and the terminal, the run statistics, the checkpoints —
// driven by step_to(k) and finish() (docs/design.md §8). `stiffmd run` drives one to
// run.t_end, `stiffmd check` builds one without outputs and discards it, and the Python module
// steps one from Python; so what a run refuses, check refuses, and the three see the same
// numbers. Each component saves and loads its own part of a checkpoint.
//
// Step k is at t_k = t0 + (k − k0) h: from the start, and on a restart whose checkpoint is at
// t = k h (the same h throughout), t0 = k0 = 0, so t_k = k h exactly, the uninterrupted run's
// times. After a change of h the run continues from the checkpoint's time (k0 = its step).
#pragma once

#include <cstdint>
#include <cstdio>
#include <ctime>
#include <functional>
#include <memory>
#include <optional>
#include <ostream>
#include <string>
#include <vector>

#include "core/communicator.hpp"
#include "core/parallel.hpp"
#include "core/timing.hpp"
#include "engine/domain/domain_integrator.hpp"
#include "engine/domain/part_load.hpp"
#include "engine/io/writers.hpp"
#include "engine/observe/monitor.hpp"
#include "engine/observe/observables.hpp"
#include "engine/run/checkpoint.hpp"
#include "engine/run/outputs.hpp"
#include "engine/run/progress.hpp"
#include "engine/run/run_statistics.hpp"
#include "engine/run/screen.hpp"
#include "engine/run/signals.hpp"
#include "engine/run/summary.hpp"
#include "engine/scene/scene.hpp"
#include "integrators/integrator.hpp"

namespace stiffmd {

struct RunOptions {
  // Where the outputs go (created if missing); empty: no files at all (check, and the Python
  // module unless asked), the thermo samples and the monitor still on their grid.
  std::string out_dir;
  bool progress = false;  // progress bar with ETA on stderr
  std::string restart;    // checkpoint to continue from ("" = a fresh run)
  // The restart's checkpoint already read by read_checkpoint_for (which loads the force terms'
  // states into the scene); null: the Run reads `restart` itself, before any output.
  const Checkpoint* checkpoint = nullptr;
  // Where the thermo lines go ([output] screen_interval; engine/run/screen.hpp): stdout for the
  // CLI, null (no lines) for `--quiet` and for callers that want no terminal output.
  std::FILE* screen = nullptr;
  // SIGINT/SIGTERM stop the run cleanly after the step in progress (the CLI); the Python module
  // leaves them to Python.
  bool handle_signals = true;
  // More than one process: the run is decomposed over them (engine/domain/domain_integrator.hpp,
  // docs/parallel.md), the deck building each rank's force terms. Every rank gets the same
  // out_dir; rank 0 writes every output but the H5MD file, which with parallel HDF5 every rank
  // writes its particles' rows of (RunOutputs); only rank 0 has a screen and a progress bar;
  // every rank drives its Run through the same steps.
  const Communicator* processes = nullptr;
  // When the process began its work (seconds on the steady clock; negative: not known): the
  // run's set-up time is from then to its first step (summary.json `setup_seconds`).
  double started_at = -1.0;
  // Called once a decomposed run's parts are built, before the first sample (tests: the whole
  // scene made useless there, to show that nothing reads it after the start).
  std::function<void()> started{};
  // This rank's molecules made by their source (engine/domain/part_load.hpp), for a decomposed run
  // to start from instead of cutting its block from the whole scene (collective: every rank calls
  // it, or none). Empty: the whole scene's cut.
  std::function<ScenePart()> part{};
};

class Run {
 public:
  // Restores the checkpoint (or prepares the method's initial data), takes the first sample and
  // only then opens the outputs: whatever fails on the initial state (a foreign checkpoint: exit
  // 2; the method's preparation, a non-finite state: exit 3) fails before any file is touched.
  Run(Scene& scene, const RunOptions& options, std::ostream& log);
  ~Run();
  Run(const Run&) = delete;
  Run& operator=(const Run&) = delete;

  // The step of run.t_end.
  std::int64_t final_step() const { return final_step_; }
  // Macro steps up to step k (or until a SIGINT/SIGTERM: stopped()). After each step but the last
  // one taken, the outputs due, the [monitor] checks, a periodic checkpoint; the last step's are
  // taken by the next step_to or by finish(). Throws NumericalError (exit 3) on a non-finite state
  // or a monitor stop, the outputs written so far readable.
  void step_to(std::int64_t k);
  int stopped() const { return summary_.stopped_by_signal; }
  // Ends the run: the checkpoint, and unless stopped by a signal, every output of the current
  // state (whatever the grids), the files written at the end and summary.json.
  const RunSummary& finish();
  // Closes the outputs without writing more: after a stop every rank of a decomposed run takes
  // at the same point (AgreedStop), whose ranks close the shared H5MD file together. (A Run
  // destroyed unclosed leaves a shared file as a killed writer's: see H5mdWriter::close.)
  void close_outputs();

  // For the Python module: the thermo row of the current state (sampled now, as the run samples;
  // no monitor), the columns as written (ThermoOutput), and a state set from outside (the
  // integrator's cached forces forgotten, energy_drift measured from the new state on).
  const std::vector<double>& sample_now();
  const ThermoOutput& thermo_table() const { return outputs_->thermo_table(); }
  const std::vector<double>& as_written(const std::vector<double>& row) { return outputs_->as_written(row); }
  void state_changed();
  Integrator& integrator() { return *integrator_; }
  const Thermo& thermo() const { return thermo_; }

 private:
  void observe(bool final = false);  // the outputs due at this step (`final`: all)
  // The time of macro step j, t_j = t0 + (j − k0) h: the one formula the steps and the output
  // grids' due steps are computed with.
  double time_at(std::int64_t j) const { return t0_ + static_cast<double>(j - k0_) * h_; }
  const std::vector<double>& sample();
  void after_step();       // what follows a step that is not the run's last
  void checkpoint_step();  // after_step at the checkpoints' due step: the checkpoint, the next due step
  // The checkpoint's parts as of now, with the integrator's words (Integrator::save_state, which
  // every rank of a decomposed run computes together).
  Checkpoint& snapshot(Checkpoint& c, std::vector<double> integrator_state);
  Checkpoint& identity(Checkpoint& c) const;  // the method, h, the stage: snapshot's part every rank knows
  void write_checkpoint_now();
  std::vector<std::int64_t> evaluations_now() const;
  long rebuilds_now() const;
  // A step long enough to time by parts (a mark costs two clock reads, ≈ 50 ns): from kParallelMin
  // particles, or at any size with a k-space term (a mesh or an Ewald sum: a step of milliseconds,
  // whose k-space share the breakdown reports).
  bool timed_by_phase() const { return num_particles_ >= kParallelMin || has_kspace_; }
  bool root() const { return !domain_ || options_.processes->root(); }
  // Whether a decomposed run's thermo row is summed by its ranks' parts (else rank 0 samples the
  // gathered whole state).
  bool sampled_by_parts() const;
  // A decomposed run: rank 0's decision (an output due, a stop) on every rank.
  std::int64_t agreed(std::int64_t rank0_value) const;

  Scene& sc_;
  bool has_kspace_ = false;  // a term in the kspace phase (timed_by_phase)
  State& s_;
  RunOptions options_;
  std::ostream& log_;
  RunSummary summary_;
  Checkpoint resumed_;  // a restart's checkpoint (empty for a fresh run)
  std::unique_ptr<Integrator> integrator_;
  DomainIntegrator* domain_ = nullptr;  // integrator_ when the run is decomposed
  std::string checkpoint_path_;         // rank 0's, on every rank (they write it together)
  bool writes_checkpoints_ = false;     // there is a checkpoint path
  Thermo thermo_;
  Monitor monitor_;
  RunStatistics stats_;
  std::unique_ptr<RunOutputs> outputs_;
  std::unique_ptr<ThermoScreen> screen_;
  std::unique_ptr<Progress> progress_;
  std::optional<IntervalSchedule> checkpoint_due_;
  SignalAtStep signal_at_;
  std::uint64_t fingerprint_ = 0;
  // The scene is its description only (no particle: a decomposed run whose parts their source
  // makes, engine/scene/scene.hpp SceneContent::description): the Run's numbers come from the parts.
  bool described_ = false;
  int num_particles_ = 0;  // the whole system's (a decomposed run: summed from its parts)
  double h_ = 0.0, t0_ = 0.0;
  std::int64_t k0_ = 0, first_step_ = 0, final_step_ = 0;
  long rebuilds_at_start_ = 0;  // this process's rebuild count when the run started
  bool pending_ = false;        // the last step's outputs are still to be taken
  // The next steps at which an output grid, and the periodic checkpoints' grid, are due: the
  // steps between them ask nothing (RunOutputs::next_due_step).
  std::int64_t next_observe_ = 0, next_checkpoint_ = IntervalSchedule::kNever;
  int col_total_, col_drift_, col_violation_, col_alerts_, first_action_, num_actions_;
  int col_econserve_ = -1;  // with a thermostat
  std::vector<double> last_row_;
  Eigen::Matrix3Xd owned_force_;        // a shared H5MD frame's forces of this rank's particles
  int alerts_ = 0;                      // of the last sample
  Checkpoint last_good_;                // with on_alert = "stop": the run as of the last sample without alerts
  Checkpoint now_;                      // snapshot() of the current step, written with the state (no copy)
  PhaseClock clock_;                    // where the step loop's time goes, running inside step_to
  double loop_seconds_ = 0.0;           // the step loop's wall time, measured apart from the clock
  Communicator::Blocked loop_blocked_;  // of the loop's time, inside MPI's exchanges and reductions
  double parallel_seconds_ = 0.0;       // of it, inside the engine's parallel loops (core/parallel.hpp)
  int threads_used_ = 1;                // the most threads a parallel loop of the step loop ran on
  std::clock_t cpu_start_ = 0;
};

// `stiffmd run`: a Run from the scene's state to run.t_end.
RunSummary run_simulation(Scene& scene, const RunOptions& options, std::ostream& log);

// Why a decomposed run of the scene needs the whole scene on every rank (docs/parallel.md, "The
// scene's description"), or "" when a scene of descriptions (no particle; its parts made by their
// source, RunOptions::part) serves it: the outputs and samples that read the whole state or the
// whole topology — the actions and a barostat's molecular pressure (a sample of the gathered
// state), [monitor] on_alert = "stop" (it keeps the gathered state), an H5MD file without
// parallel HDF5 (rank 0 writes the gathered frames), the final LAMMPS data file and the state CSV.
// The trajectories' time-independent data and the histograms are written from the parts.
std::string whole_scene_needed(const Scene& scene);

// `stiffmd check`: a Run without outputs built on the scene and discarded, so that check fails
// where run would fail before its first step. The scene's state is left as it was.
void check_run(Scene& scene, std::ostream& log);

// Throws NumericalError naming the first particle with a non-finite position or velocity, and
// the step and time, if there is one.
void check_finite(const State& s);
// Macro step k of a run (the state is at step k − 1): integrator.step(s, h), then s.step = k and
// s.t = t_k (given, so that time has no accumulated round-off), then check_finite (unless `check` is false,
// or the integrator checked the state in its own last pass: Integrator::checked_finite). A
// NumericalError from the step is re-thrown naming k and the time.
void take_step(Integrator& integrator, State& s, double h, std::int64_t k, double t_k, bool check = true);

}  // namespace stiffmd
