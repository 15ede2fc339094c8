// The processes of one job: MPI's when stiffmd is built with it (STIFFMD_MPI) and started by a
// launcher (mpiexec, srun), else this one process alone. Only the command line uses it (it is
// compiled into the stiffmd executable, not the engine library): an ensemble's members are
// divided among the processes (engine/run/ensemble.hpp), each runs whole members; one run is
// decomposed over them (engine/domain/, docs/parallel.md) through communicator().
//
// A process not started by a launcher does not initialise MPI at all (a singleton MPI_Init costs
// Open MPI a few tenths of a second): the serial run is the plain code path, with or without MPI.
#pragma once

#include <memory>
#include <string>
#include <vector>

#include "core/communicator.hpp"

namespace stiffmd {

class Processes {
 public:
  Processes(int& argc, char**& argv);  // MPI_Init when started by a launcher
  ~Processes();                        // MPI_Finalize
  Processes(const Processes&) = delete;
  Processes& operator=(const Processes&) = delete;

  int rank() const { return rank_; }
  int size() const { return size_; }

  // Splits the processes into `groups` groups, process r into group r % groups (MPI_Comm_split):
  // each group runs its members on its own communicator. Returns this process's group.
  int split(int groups);
  // Every process's text, on rank 0 in rank order (elsewhere empty). Collective.
  std::vector<std::string> gather(const std::string& text) const;
  // Rank 0's value, on every process. Collective.
  int broadcast(int value) const;
  // The processes as the engine's Communicator (MPI_COMM_WORLD; one process without MPI): a
  // decomposed run's collectives.
  const Communicator& communicator() const { return *communicator_; }
  // Ends every process of the job with `code` (MPI_Abort): an error on one rank that the others,
  // waiting in a collective, cannot learn of. Without MPI: nothing (the caller returns the code).
  void abort(int code) const;
  // Why this job cannot run (started by a launcher on several processes, but built without MPI:
  // each would run everything into the same files); empty when it can.
  const std::string& problem() const { return problem_; }

 private:
  int rank_ = 0, size_ = 1;
  bool mpi_ = false;
  std::string problem_;
  struct Group;  // the group's communicator (with MPI), freed at the end
  std::unique_ptr<Group> group_;
  std::unique_ptr<Communicator> communicator_ = std::make_unique<OneProcess>();
};

}  // namespace stiffmd
