// The processes of a run, as the engine sees them (docs/parallel.md): a rank among `size`, and the
// few collective operations a decomposed run needs. The engine never calls MPI itself: the
// executable passes an MPI implementation (engine/run/processes.cpp); everything else (the
// Python module, the tests, a run without a launcher) uses OneProcess, for which every
// collective is the identity. Every rank must call a collective at the same point of the run,
// with the same counts where the operation says so.
#pragma once

#include <cstdint>
#include <vector>

namespace stiffmd {

class Communicator {
 public:
  virtual ~Communicator() = default;
  virtual int rank() const = 0;
  virtual int size() const = 0;
  bool root() const { return rank() == 0; }

  // In place, element-wise over the ranks (the same n on every rank).
  virtual void sum(double* values, int n) const = 0;
  virtual void sum(std::int64_t* values, int n) const = 0;
  virtual void max(double* values, int n) const = 0;
  virtual void min(std::int64_t* values, int n) const = 0;
  // Rank 0's values on every rank.
  virtual void broadcast(std::int64_t* values, int n) const = 0;
  virtual void broadcast(double* values, int n) const = 0;
  // Each rank sends send[r] to rank r and receives into recv[r] what rank r sent it (the
  // receiver does not know the counts in advance). Point to point with the ranks whose message
  // is not empty on either side, after one exchange of the counts.
  virtual void exchange(const std::vector<std::vector<double>>& send, std::vector<std::vector<double>>& recv) const = 0;
  // The same with the counts known on both sides: recv[r] already has the size rank r sends (a
  // halo's fixed plan). No allocation.
  virtual void exchange_known(const std::vector<std::vector<double>>& send,
                              std::vector<std::vector<double>>& recv) const = 0;
  // Rank 0 receives every rank's `mine`, in rank order (the others receive nothing).
  virtual void gather(const std::vector<double>& mine, std::vector<std::vector<double>>& all) const = 0;
  // The MPI communicator these processes are (a pointer to an MPI_Comm), for a library that takes
  // one (parallel HDF5: engine/io/h5md_writer.cpp); null without MPI.
  virtual const void* native() const { return nullptr; }

  double sum(double v) const {
    sum(&v, 1);
    return v;
  }
  double max(double v) const {
    max(&v, 1);
    return v;
  }
};

// One process: every collective is the identity.
class OneProcess final : public Communicator {
 public:
  int rank() const override { return 0; }
  int size() const override { return 1; }
  void sum(double*, int) const override {}
  void sum(std::int64_t*, int) const override {}
  void max(double*, int) const override {}
  void min(std::int64_t*, int) const override {}
  void broadcast(std::int64_t*, int) const override {}
  void broadcast(double*, int) const override {}
  void exchange(const std::vector<std::vector<double>>& send, std::vector<std::vector<double>>& recv) const override {
    recv = send;
  }
  void exchange_known(const std::vector<std::vector<double>>& send,
                      std::vector<std::vector<double>>& recv) const override {
    recv[0] = send[0];
  }
  void gather(const std::vector<double>& mine, std::vector<std::vector<double>>& all) const override {
    all.assign(1, mine);
  }
};

}  // namespace stiffmd
