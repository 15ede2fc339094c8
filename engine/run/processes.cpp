#include "engine/run/processes.hpp"

#include <chrono>
#include <cstdlib>
#include <string>

#include "engine/run/launcher.hpp"

#ifdef STIFFMD_MPI
#include <mpi.h>
#endif

namespace stiffmd {

#ifdef STIFFMD_MPI

struct Processes::Group {
  MPI_Comm comm = MPI_COMM_NULL;
};

namespace {

// Adds the wall time of its scope to `total`: the time inside one MPI call (Communicator::blocked).
class BlockedTime {
 public:
  explicit BlockedTime(double& total) : total_(total), start_(std::chrono::steady_clock::now()) {}
  ~BlockedTime() { total_ += std::chrono::duration<double>(std::chrono::steady_clock::now() - start_).count(); }
  BlockedTime(const BlockedTime&) = delete;
  BlockedTime& operator=(const BlockedTime&) = delete;

 private:
  double& total_;
  std::chrono::steady_clock::time_point start_;
};

// The engine's collectives on MPI_COMM_WORLD (core/communicator.hpp).
class MpiCommunicator final : public Communicator {
 public:
  MpiCommunicator() {
    MPI_Comm_rank(MPI_COMM_WORLD, &rank_);
    MPI_Comm_size(MPI_COMM_WORLD, &size_);
    requests_.reserve(2 * static_cast<size_t>(size_));
  }
  int rank() const override { return rank_; }
  int size() const override { return size_; }
  const void* native() const override { return &world_; }
  Blocked blocked() const override { return blocked_; }
  void sum(double* v, int n) const override {
    BlockedTime t(blocked_.reductions);
    MPI_Allreduce(MPI_IN_PLACE, v, n, MPI_DOUBLE, MPI_SUM, MPI_COMM_WORLD);
  }
  void sum(std::int64_t* v, int n) const override {
    BlockedTime t(blocked_.reductions);
    MPI_Allreduce(MPI_IN_PLACE, v, n, MPI_INT64_T, MPI_SUM, MPI_COMM_WORLD);
  }
  void max(double* v, int n) const override {
    BlockedTime t(blocked_.reductions);
    MPI_Allreduce(MPI_IN_PLACE, v, n, MPI_DOUBLE, MPI_MAX, MPI_COMM_WORLD);
  }
  void min(std::int64_t* v, int n) const override {
    BlockedTime t(blocked_.reductions);
    MPI_Allreduce(MPI_IN_PLACE, v, n, MPI_INT64_T, MPI_MIN, MPI_COMM_WORLD);
  }
  void broadcast(std::int64_t* v, int n) const override {
    BlockedTime t(blocked_.reductions);
    MPI_Bcast(v, n, MPI_INT64_T, 0, MPI_COMM_WORLD);
  }
  void broadcast(double* v, int n) const override {
    BlockedTime t(blocked_.reductions);
    MPI_Bcast(v, n, MPI_DOUBLE, 0, MPI_COMM_WORLD);
  }
  void broadcast(std::string& text, int root) const override {
    BlockedTime t(blocked_.reductions);
    long long n = static_cast<long long>(text.size());
    MPI_Bcast(&n, 1, MPI_LONG_LONG, root, MPI_COMM_WORLD);
    text.resize(static_cast<size_t>(n));
    MPI_Bcast(text.data(), static_cast<int>(n), MPI_CHAR, root, MPI_COMM_WORLD);
  }
  void exchange(const std::vector<std::vector<double>>& send, std::vector<std::vector<double>>& recv) const override {
    std::vector<long long> out(size_), in(size_);
    for (int r = 0; r < size_; ++r) out[r] = static_cast<long long>(send[r].size());
    {
      BlockedTime t(blocked_.exchanges);
      MPI_Alltoall(out.data(), 1, MPI_LONG_LONG, in.data(), 1, MPI_LONG_LONG, MPI_COMM_WORLD);
    }
    recv.resize(size_);
    for (int r = 0; r < size_; ++r) recv[r].resize(static_cast<size_t>(in[r]));
    exchange_known(send, recv);
  }
  void exchange_known(const std::vector<std::vector<double>>& send,
                      std::vector<std::vector<double>>& recv) const override {
    requests_.clear();
    constexpr int kTag = 17;
    for (int r = 0; r < size_; ++r)
      if (!recv[r].empty()) {
        requests_.emplace_back();
        MPI_Irecv(recv[r].data(), static_cast<int>(recv[r].size()), MPI_DOUBLE, r, kTag, MPI_COMM_WORLD,
                  &requests_.back());
      }
    for (int r = 0; r < size_; ++r)
      if (!send[r].empty()) {
        requests_.emplace_back();
        MPI_Isend(send[r].data(), static_cast<int>(send[r].size()), MPI_DOUBLE, r, kTag, MPI_COMM_WORLD,
                  &requests_.back());
      }
    BlockedTime t(blocked_.exchanges);
    MPI_Waitall(static_cast<int>(requests_.size()), requests_.data(), MPI_STATUSES_IGNORE);
  }
  void gather(const std::vector<double>& mine, std::vector<std::vector<double>>& all) const override {
    const long long n = static_cast<long long>(mine.size());
    std::vector<long long> counts(size_);
    BlockedTime t(blocked_.reductions);
    MPI_Gather(&n, 1, MPI_LONG_LONG, counts.data(), 1, MPI_LONG_LONG, 0, MPI_COMM_WORLD);
    std::vector<int> c(size_), offsets(size_);
    long long total = 0;
    for (int r = 0; r < size_; ++r)
      c[r] = static_cast<int>(counts[r]), offsets[r] = static_cast<int>(total), total += counts[r];
    std::vector<double> flat(rank_ == 0 ? static_cast<size_t>(total) : 0);
    MPI_Gatherv(mine.data(), static_cast<int>(n), MPI_DOUBLE, flat.data(), c.data(), offsets.data(), MPI_DOUBLE, 0,
                MPI_COMM_WORLD);
    all.clear();
    if (rank_ != 0) return;
    for (int r = 0; r < size_; ++r) all.emplace_back(flat.begin() + offsets[r], flat.begin() + offsets[r] + c[r]);
  }

 private:
  int rank_ = 0, size_ = 1;
  MPI_Comm world_ = MPI_COMM_WORLD;
  mutable std::vector<MPI_Request> requests_;
  mutable Blocked blocked_;
};

}  // namespace

Processes::Processes(int& argc, char**& argv) {
  if (!started_by_launcher()) return;
  MPI_Init(&argc, &argv);
  mpi_ = true;
  MPI_Comm_rank(MPI_COMM_WORLD, &rank_);
  MPI_Comm_size(MPI_COMM_WORLD, &size_);
  communicator_ = std::make_unique<MpiCommunicator>();
}

void Processes::abort(int code) const {
  if (mpi_ && size_ > 1) MPI_Abort(MPI_COMM_WORLD, code);
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
void Processes::abort(int) const {}

#endif

}  // namespace stiffmd
