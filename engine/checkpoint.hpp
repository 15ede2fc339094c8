// Checkpoints: everything a run needs to continue bit for bit (state, the integrator's own
// state such as the effective dynamics' actions, the thermo reference energy), written
// atomically — to a temporary file, fsync, rename — so a checkpoint on disk is always whole.
#pragma once

#include <cstdint>
#include <string>
#include <vector>

#include "engine/state.hpp"

namespace stiffmd {

struct Checkpoint {
  State state;         // x, v, inverse masses, t, step
  std::string method;  // integrator that wrote it
  double h = 0.0;
  std::vector<double> integrator_state;  // Integrator::save_state()
  double initial_energy = 0.0;           // E(0) of the run, for the energy_drift column
};

// Throws InputError naming the path on any I/O failure.
void write_checkpoint(const std::string& path, const Checkpoint& c);
// The same from its parts, without copying the state.
void write_checkpoint(const std::string& path, const State& state, const std::string& method, double h,
                      const std::vector<double>& integrator_state, double initial_energy);
// Throws InputError naming the path if the file is missing, truncated or not a checkpoint.
Checkpoint read_checkpoint(const std::string& path);

}  // namespace stiffmd
