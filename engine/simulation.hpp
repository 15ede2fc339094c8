// The simulation loop (design.md §6): step the integrator to t_end, watch for numerical
// failure, write outputs on their time grids, and summarise.
#pragma once

#include <cstdint>
#include <ostream>
#include <string>
#include <vector>

#include "engine/scene.hpp"

namespace stiffmd {

struct RunOptions {
  std::string out_dir;   // created if missing
  bool progress = false; // progress bar with ETA on stderr
};

struct RunSummary {
  std::string method;
  std::int64_t steps = 0;
  double h = 0.0;
  int micro_steps = 1;
  double t_end = 0.0;
  double wall_seconds = 0.0;
  double initial_energy = 0.0;
  double final_energy = 0.0;
  double max_energy_error = 0.0;  // max |E(t) − E(0)| over the thermo samples
  std::int64_t slow_evaluations = 0;
  std::int64_t fast_evaluations = 0;
  std::vector<std::string> outputs;
};

// Runs the scene. Throws NumericalError (exit 3) on NaN/Inf, with the step and time; the
// outputs written up to the last good frame stay readable.
RunSummary run_simulation(Scene& scene, const RunOptions& options, std::ostream& log);

std::string format_summary(const RunSummary& s);

}  // namespace stiffmd
