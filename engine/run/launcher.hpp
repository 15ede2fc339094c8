// Whether an MPI launcher started this process, and on how many processes: read from the
// environment the launchers set, without MPI (the Python module, built without it, asks too).
#pragma once

#include <algorithm>
#include <cstdlib>

namespace stiffmd {

// Started by an MPI launcher: Open MPI's mpiexec, MPICH's Hydra, or a PMIx launcher (srun).
inline bool started_by_launcher() {
  for (const char* v : {"OMPI_COMM_WORLD_SIZE", "PMI_SIZE", "PMIX_RANK"})
    if (std::getenv(v)) return true;
  return false;
}

// How many processes the launcher started this job on (OMPI_COMM_WORLD_SIZE, PMI_SIZE, or srun's
// SLURM_NTASKS), 1 without a launcher.
inline int launched_processes() {
  if (!started_by_launcher()) return 1;
  for (const char* v : {"OMPI_COMM_WORLD_SIZE", "PMI_SIZE", "SLURM_NTASKS"})
    if (const char* n = std::getenv(v)) return std::max(1, std::atoi(n));
  return 1;
}

}  // namespace stiffmd
