#include "engine/run/processes.hpp"

#include <cstdlib>
#include <string>

#ifdef STIFFMD_MPI
#include <mpi.h>
#endif

namespace stiffmd {

namespace {

// Started by an MPI launcher: Open MPI's mpiexec, MPICH's Hydra, or a PMIx launcher (srun).
bool started_by_launcher() {
  for (const char* v : {"OMPI_COMM_WORLD_SIZE", "PMI_SIZE", "PMIX_RANK"})
    if (std::getenv(v)) return true;
  return false;
}

}  // namespace

#ifdef STIFFMD_MPI

struct Processes::Group {
  MPI_Comm comm = MPI_COMM_NULL;
};

Processes::Processes(int& argc, char**& argv) {
  if (!started_by_launcher()) return;
  MPI_Init(&argc, &argv);
  mpi_ = true;
  MPI_Comm_rank(MPI_COMM_WORLD, &rank_);
  MPI_Comm_size(MPI_COMM_WORLD, &size_);
}

Processes::~Processes() {
  if (!mpi_) return;
  if (group_) MPI_Comm_free(&group_->comm);
  MPI_Finalize();
}

int Processes::split(int groups) {
  const int group = rank_ % groups;
  if (mpi_) {
    group_ = std::make_unique<Group>();
    MPI_Comm_split(MPI_COMM_WORLD, group, rank_, &group_->comm);
  }
  return group;
}

std::vector<std::string> Processes::gather(const std::string& text) const {
  if (!mpi_) return {text};
  const int length = static_cast<int>(text.size());
  std::vector<int> lengths(rank_ == 0 ? size_ : 0), offsets(lengths.size());
  MPI_Gather(&length, 1, MPI_INT, lengths.data(), 1, MPI_INT, 0, MPI_COMM_WORLD);
  int total = 0;
  for (size_t r = 0; r < lengths.size(); ++r) offsets[r] = total, total += lengths[r];
  std::string all(static_cast<size_t>(total), '\0');
  MPI_Gatherv(text.data(), length, MPI_CHAR, all.data(), lengths.data(), offsets.data(), MPI_CHAR, 0, MPI_COMM_WORLD);
  std::vector<std::string> out;
  for (size_t r = 0; r < lengths.size(); ++r) out.push_back(all.substr(offsets[r], lengths[r]));
  return out;
}

int Processes::broadcast(int value) const {
  if (mpi_) MPI_Bcast(&value, 1, MPI_INT, 0, MPI_COMM_WORLD);
  return value;
}

#else

struct Processes::Group {};

Processes::Processes(int&, char**&) {
  if (!started_by_launcher()) return;
  for (const char* v : {"OMPI_COMM_WORLD_SIZE", "PMI_SIZE"})
    if (const char* n = std::getenv(v); n && std::atoi(n) > 1)
      problem_ = "started on " + std::string(n) +
                 " processes, but this stiffmd is built without MPI (install Open MPI, e.g. bash tools/setup.sh, and "
                 "build again)";
}
Processes::~Processes() = default;
int Processes::split(int groups) {
  return rank_ % groups;
}
std::vector<std::string> Processes::gather(const std::string& text) const {
  return {text};
}
int Processes::broadcast(int value) const {
  return value;
}

#endif

}  // namespace stiffmd
