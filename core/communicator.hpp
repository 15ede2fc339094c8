// The processes of a run, as the engine sees them (docs/parallel.md): a rank among `size`, and the
// few collective operations a decomposed run needs. The engine never calls MPI itself: the
// executable passes an MPI implementation (engine/run/processes.cpp); everything else (the
// Python module, the tests, a run without a launcher) uses OneProcess, for which every
// collective is the identity. Every rank must call a collective at the same point of the run,
// with the same counts where the operation says so.
#pragma once

#include <cstdint>
#include <string>
#include <vector>

#include "core/errors.hpp"

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
  // Rank `root`'s text on every rank.
  virtual void broadcast(std::string& text, int root) const = 0;
  // Rank 0 receives every rank's `mine`, in rank order (the others receive nothing).
  virtual void gather(const std::vector<double>& mine, std::vector<std::vector<double>>& all) const = 0;
  // The MPI communicator these processes are (a pointer to an MPI_Comm), for a library that takes
  // one (parallel HDF5: engine/io/h5md_writer.cpp); null without MPI.
  virtual const void* native() const { return nullptr; }

  // The wall time this process has spent so far inside the exchanges (exchange, exchange_known:
  // the halo, the migrations, the selections) and inside the reductions, broadcasts and gathers,
  // waiting for the other ranks included: what a rank's step loop loses to the others
  // (docs/parallel.md, "Where two ranks wait"). Zero without MPI.
  struct Blocked {
    double exchanges = 0.0, reductions = 0.0;
  };
  virtual Blocked blocked() const { return {}; }

  // The problem of the lowest rank that has one (`mine`: this rank's, empty for none), on every
  // rank: that rank and its text (rank −1: no rank has one). Collective.
  struct Problem {
    int rank = -1;
    std::string text;
    // "rank r: text" when it is not rank 0's, else the text.
    std::string said() const { return rank > 0 ? "rank " + std::to_string(rank) + ": " + text : text; }
  };
  Problem first_problem(const std::string& mine) const {
    std::int64_t first = mine.empty() ? size() : rank();
    min(&first, 1);
    if (first == size()) return {};
    Problem p{static_cast<int>(first), mine};
    broadcast(p.text, p.rank);
    return p;
  }

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
  void broadcast(std::string&, int) const override {}
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

// An agreement at a defined point of a run on several processes (docs/parallel.md, "Errors"):
// runs `local`, work of this rank alone (no collective call inside, so that a rank that fails
// early cannot leave the others waiting in one), and when it threw InputError on any rank, every
// rank throws AgreedInputError with the first rank's message (said by rank 0). Collective; with
// no communicator, or one process, `local` runs as it is.
template <class Local>
void agree(const Communicator* processes, Local&& local) {
  if (!processes || processes->size() == 1) return local();
  std::string problem;
  try {
    local();
  } catch (const InputError& e) {
    problem = e.what();
    if (problem.empty()) problem = "input error";
  }
  if (const Communicator::Problem first = processes->first_problem(problem); first.rank >= 0)
    throw AgreedInputError(first.said(), processes->root());
}

}  // namespace stiffmd
