// What a run counts for its summary, carried by checkpoints so that a restarted run's summary is
// the whole run's: the largest energy error sampled, the force evaluations of every level and the
// neighbour-list rebuilds of the run so far, and the actions at its start.
#pragma once

#include <algorithm>
#include <cstdint>
#include <string>
#include <vector>

namespace stiffmd {

struct RunStatistics {
  double max_energy_error = 0.0;          // max |E(t) − E(0)| over the thermo samples
  double max_conserved_error = 0.0;       // with a thermostat: max |E_c(t) − E_c(0)|, E_c = E + ecouple
  std::vector<std::int64_t> evaluations;  // per level, innermost first, before this process
  long neighbor_rebuilds = 0;             // in the run, before this process
  std::vector<double> initial_actions;    // I_k(0), when actions are observed

  explicit RunStatistics(int levels = 2) : evaluations(static_cast<size_t>(std::max(levels, 1)), 0) {}

  // Checkpoint words (format version 5): max error, the outermost and the innermost level's
  // evaluations, the rebuilds, the conserved energy's max error, those of the levels in between
  // (innermost first), the actions.
  // `evaluations_now` and `rebuilds_now`: this process's counts, added to the saved ones.
  std::vector<double> save(const std::vector<std::int64_t>& evaluations_now, long rebuilds_now) const {
    const size_t n = evaluations.size();
    std::vector<double> w = {max_energy_error, static_cast<double>(evaluations[n - 1] + evaluations_now[n - 1]),
                             static_cast<double>(evaluations[0] + evaluations_now[0]),
                             static_cast<double>(rebuilds_now), max_conserved_error};
    for (size_t k = 1; k + 1 < n; ++k) w.push_back(static_cast<double>(evaluations[k] + evaluations_now[k]));
    w.insert(w.end(), initial_actions.begin(), initial_actions.end());
    return w;
  }
  // The inverse of save; an empty string, or what does not fit this scene's levels.
  std::string load(const std::vector<double>& w) {
    const size_t n = evaluations.size(), between = n >= 2 ? n - 2 : 0;
    if (w.size() < 5 + between) return "run statistics do not fit this scene's levels";
    max_energy_error = w[0];
    evaluations[n - 1] = static_cast<std::int64_t>(w[1]);
    evaluations[0] = static_cast<std::int64_t>(w[2]);
    neighbor_rebuilds = static_cast<long>(w[3]);
    max_conserved_error = w[4];
    for (size_t k = 0; k < between; ++k) evaluations[k + 1] = static_cast<std::int64_t>(w[5 + k]);
    initial_actions.assign(w.begin() + static_cast<std::ptrdiff_t>(5 + between), w.end());
    return "";
  }
};

}  // namespace stiffmd
