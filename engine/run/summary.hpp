// The summary of a run: what the terminal prints at its end and summary.json holds (written only
// for a finished run).
#pragma once

#include <cstdint>
#include <optional>
#include <string>
#include <utility>
#include <vector>

#include "core/timing.hpp"
#include "engine/domain/decomposition.hpp"
#include "engine/scene/scene.hpp"
#include "integrators/minimize.hpp"

namespace stiffmd {

struct RunSummary {
  StageIdentity stage;  // a staged protocol's stage (number 0: a run without stages)
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
  double max_energy_error = 0.0;  // max |E(t) − E(0)| over the thermo samples
  // The energy conserved with the thermostat's heat, E_c = E + ecouple (E itself without one:
  // docs/design.md §5): E_c(0), E_c(end), max |E_c − E_c(0)| over the samples, and its drift
  // (E_c(end) − E_c(0)) / (N t) per particle and time unit (the deck's: real, kcal/mol per fs).
  bool thermostat = false;
  int particles = 0;
  double initial_conserved_energy = 0.0, final_conserved_energy = 0.0, max_conserved_error = 0.0;
  double conserved_energy_drift = 0.0;
  std::int64_t slow_evaluations = 0;  // of the outermost level
  std::int64_t fast_evaluations = 0;  // of the innermost level
  // Every level's evaluations, innermost first, with its name ([[integrator.levels]] or fast/slow).
  std::vector<std::pair<std::string, std::int64_t>> level_evaluations;
  long neighbor_rebuilds = -1;       // over the run; −1 when the scene has no pair term
  std::int64_t neighbor_pairs = -1;  // in the lists as last built (all ranks); −1: no pair term
  double final_max_violation = 0.0;
  std::vector<double> initial_actions, final_actions;  // when actions are observed
  std::vector<std::string> outputs;
  int stopped_by_signal = 0;  // SIGINT/SIGTERM: stopped early after writing a checkpoint
  // Where the step loop's wall time went (core/timing.hpp): seconds per phase, in the
  // order of kPhaseNames, adding up to loop_seconds; and the share of the loop outside the
  // engine's parallel loops (−1: not measured, a step too short to time by parts: below
  // kParallelMin particles without a k-space term).
  double loop_seconds = 0.0;
  std::vector<double> phase_seconds;
  double serial_share = -1.0;
  int threads = 1;  // the most threads a loop of the step loop ran on (1 for a small system)
  // A decomposed run (ranks > 1): the step loop's wall time per rank (mean and max: the load
  // imbalance; loop_seconds is the max) and the decomposition's counts.
  double rank_loop_seconds_mean = 0.0, rank_loop_seconds_max = 0.0;
  // Of each rank's step loop, the time inside MPI's exchanges (the halo, migrations, selections)
  // and inside its reductions and broadcasts, waits for the other ranks included: mean and max.
  double rank_exchange_seconds_mean = 0.0, rank_exchange_seconds_max = 0.0;
  double rank_reduction_seconds_mean = 0.0, rank_reduction_seconds_max = 0.0;
  // Each phase's seconds, mean and max over the ranks (a decomposed run's load imbalance by phase).
  std::vector<double> rank_phase_seconds_mean, rank_phase_seconds_max;
  // Peak resident set in MiB (core/peak_memory.hpp; set-up included): this process's, and in a
  // decomposed run the largest and the mean over the ranks (memory per rank, docs/parallel.md).
  double peak_rss_mib = 0.0;
  double rank_peak_rss_mib_mean = 0.0, rank_peak_rss_mib_max = 0.0;
  // Wall seconds from the process's start to the first step (reading the deck, building and
  // preparing the scene, the parts, the first sample and the outputs opened; −1: not measured):
  // this process's, and in a decomposed run the largest and the mean over the ranks.
  double setup_seconds = -1.0;
  double rank_setup_seconds_mean = 0.0, rank_setup_seconds_max = 0.0;
  DomainReport domains;
  // How a decomposed run's parts were made: "whole" (cut from the whole scene every rank built) or
  // "parts" (each rank's molecules made by their source, engine/domain/part_load.hpp).
  std::string domain_setup;
  // What every rank loaded of the deck: "whole" (the whole scene) or "description" (its
  // description only, no particle: engine/scene/scene.hpp SceneContent::description).
  std::string domain_scene;
  int h5md_writers = 0;    // a decomposed run's processes that wrote the H5MD file (parallel HDF5: all)
  std::string checkpoint;  // the last checkpoint written
  // [minimize] before the run (a fresh run's; a restart does not minimise): in summary.json as
  // "minimize": {style, stopped_by, iterations, evaluations, initial_energy, energy, fmax, fnorm, max_violation}.
  std::optional<MinimizeReport> minimize;
};

std::string format_summary(const RunSummary& s);
// The summary as JSON (written to DIR/summary.json at the end of a successful run only).
std::string summary_json(const RunSummary& s);

}  // namespace stiffmd
