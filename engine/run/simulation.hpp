// The simulation loop (docs/design.md §8): step the integrator to t_end, watch for numerical
// failure, write outputs on their time grids, and summarise.
#pragma once

#include <cstdint>
#include <cstdio>
#include <ostream>
#include <string>
#include <vector>

#include "engine/run/outputs.hpp"  // write_scene_lammps_data
#include "engine/scene/scene.hpp"

namespace stiffmd {

struct Checkpoint;

struct RunOptions {
  std::string out_dir;    // created if missing
  bool progress = false;  // progress bar with ETA on stderr
  std::string restart;    // checkpoint to continue from ("" = a fresh run)
  // The restart's checkpoint already read by read_checkpoint_for (which loads the force terms'
  // states into the scene); null: run_simulation reads `restart` itself, before any output.
  const Checkpoint* checkpoint = nullptr;
  // Where the thermo lines go ([output] screen_interval; engine/run/screen.hpp): stdout for the
  // CLI, null (no lines) for `--quiet` and for callers that want no terminal output.
  std::FILE* screen = nullptr;
};

struct RunSummary {
  std::string method;
  std::string units = "lj";  // the deck's: h and t_end are in its time unit (real: fs)
  std::int64_t steps = 0;
  double h = 0.0;
  int micro_steps = 1;
  double t_end = 0.0;
  double wall_seconds = 0.0;
  double cpu_seconds = 0.0;  // process CPU time of the step loop
  double epsilon = 0.0;      // of the stiff bonds (0 if none)
  double initial_energy = 0.0;
  double final_energy = 0.0;
  double max_energy_error = 0.0;      // max |E(t) − E(0)| over the thermo samples
  std::int64_t slow_evaluations = 0;  // of the outermost level
  std::int64_t fast_evaluations = 0;  // of the innermost level
  // Every level's evaluations, innermost first, with its name ([[integrator.levels]] or fast/slow).
  std::vector<std::pair<std::string, std::int64_t>> level_evaluations;
  long neighbor_rebuilds = -1;  // over the run; −1 when the scene has no pair term
  double final_max_violation = 0.0;
  std::vector<double> initial_actions, final_actions;  // when actions are observed
  std::vector<std::string> outputs;
  int stopped_by_signal = 0;  // SIGINT/SIGTERM: stopped early after writing a checkpoint
  std::string checkpoint;     // the last checkpoint written
};

// Runs the scene. Throws NumericalError (exit 3) on NaN/Inf, with the step and time; the
// outputs written up to the last good frame stay readable.
RunSummary run_simulation(Scene& scene, const RunOptions& options, std::ostream& log);

// What `check` asks of a scene beyond load_scene and [prepare]: the run's start on a copy of its
// state — the method's preparation (projection onto the constraints, actions), a finite state and
// the first sample of the observables with its force evaluation — so that `check` fails where
// `run` would fail before its first step (NumericalError, exit 3). The scene's state is left as
// it was.
void check_start(Scene& scene, std::ostream& log);

// Throws NumericalError naming the first particle with a non-finite position or velocity, and
// the step and time, if there is one.
void check_finite(const State& s);
// Macro step k of a run (the state is at step k − 1): integrator.step(s, h), then s.step = k and
// s.t = t_k (given, so that time has no accumulated round-off: t_k = k h from the start), then
// check_finite. A NumericalError from the step is re-thrown naming k and the time.
void take_step(Integrator& integrator, State& s, double h, std::int64_t k, double t_k);

std::string format_summary(const RunSummary& s);
// The summary as JSON (written to DIR/summary.json at the end of a successful run only).
std::string summary_json(const RunSummary& s);

}  // namespace stiffmd
