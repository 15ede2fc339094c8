// N ranks in one process, for unit tests of code written against Communicator
// (core/communicator.hpp) without mpiexec: run_ranks(n, body) runs body(comm) on n threads, each
// with its own FakeCommunicator, whose collectives have MPI's semantics over shared memory.
//
// Each collective is a rendezvous of all ranks in two barriers: every rank publishes a pointer to
// its arguments in its slot, barrier 1 (every slot written, every argument ready), each rank reads
// what it needs from the others' arguments into its own outputs, barrier 2 (nobody reads a rank's
// arguments any more, so it may return and change them). In-place reductions compute into a
// private buffer before barrier 2 and copy it out after, since another rank may still be reading
// the values in place until then. Sums add the ranks' values in rank order.
//
// Misuse fails the test instead of hanging it:
//   - the ranks must call the same collective at the same point, with the same count where the
//     operation says so (the same root for a string's broadcast; exchange_known's recv sizes the
//     senders' sizes): every rank checks every slot after barrier 1, so all throw
//     std::logic_error alike;
//   - a rank that throws aborts the others: a rank waiting in a collective (or reaching one
//     later) throws RankAborted, and run_ranks rethrows the first exception that was not one;
//   - a rank that returns while others wait in a collective makes them throw std::logic_error
//     (they would wait forever under MPI);
//   - a wait longer than `timeout` (a rank stuck in its own work) throws std::runtime_error.
//
// The ranks share the process: its globals (PhaseClock::current, core/timing.hpp) and OpenMP's
// threads. Code under test that keeps per-process state in globals is not separated by rank.
#pragma once

#include <algorithm>
#include <chrono>
#include <condition_variable>
#include <cstdint>
#include <cstring>
#include <exception>
#include <mutex>
#include <stdexcept>
#include <string>
#include <thread>
#include <vector>

#include "core/communicator.hpp"

namespace stiffmd::fake {

// What a rank throws when another rank failed (the other's exception is the one reported).
struct RankAborted : std::runtime_error {
  using std::runtime_error::runtime_error;
};

namespace fake_detail {

// One collective call of one rank, as it is published to the others.
struct Slot {
  const char* op = "";  // the operation's name
  long count = -1;      // the element count the ranks must agree on (−1: none)
  int root = 0;         // broadcast(string)'s root
  const void* in = nullptr;
  const void* out = nullptr;
};

class Shared {
 public:
  Shared(int n, std::chrono::milliseconds timeout) : n_(n), timeout_(timeout), slots_(static_cast<size_t>(n)) {}

  int size() const { return n_; }
  Slot& slot(int rank) { return slots_[static_cast<size_t>(rank)]; }
  const Slot& slot(int rank) const { return slots_[static_cast<size_t>(rank)]; }

  // Waits until every rank has arrived (a reusable barrier: each completion starts a new
  // generation), unless the run is aborted, a rank has returned, or the wait times out.
  void arrive(int rank, const char* op) {
    std::unique_lock lock(mutex_);
    if (aborted_) throw RankAborted("rank " + std::to_string(rank) + " in " + op + ": another rank failed");
    const long generation = generation_;
    if (++arrived_ == n_) {
      arrived_ = 0;
      ++generation_;
      changed_.notify_all();
      return;
    }
    const bool woken =
        changed_.wait_for(lock, timeout_, [&] { return generation_ != generation || aborted_ || returned_ >= 0; });
    if (generation_ != generation) return;
    if (aborted_) throw RankAborted("rank " + std::to_string(rank) + " in " + op + ": another rank failed");
    aborted_ = true;
    changed_.notify_all();
    if (!woken)
      throw std::runtime_error("rank " + std::to_string(rank) + " waited more than " +
                               std::to_string(timeout_.count()) + " ms in " + op + ": some rank never reached it");
    throw std::logic_error("rank " + std::to_string(rank) + " waits in " + op + ", but rank " +
                           std::to_string(returned_) + " returned without calling it");
  }

  // A rank's body ended: normally (the others must not wait for it any more) or by an exception.
  void returned(int rank) {
    std::lock_guard lock(mutex_);
    if (returned_ < 0) returned_ = rank;
    changed_.notify_all();
  }
  void failed(std::exception_ptr e, bool aborted_by_another) {
    std::lock_guard lock(mutex_);
    aborted_ = true;
    if (!aborted_by_another && !first_) first_ = e;
    if (!any_) any_ = e;
    changed_.notify_all();
  }
  // The first exception that was not an abort (else any), or null.
  std::exception_ptr first() const { return first_ ? first_ : any_; }

 private:
  const int n_;
  const std::chrono::milliseconds timeout_;
  std::vector<Slot> slots_;
  std::mutex mutex_;
  std::condition_variable changed_;
  int arrived_ = 0;
  long generation_ = 0;
  bool aborted_ = false;
  int returned_ = -1;  // the first rank whose body returned normally
  std::exception_ptr first_, any_;
};

}  // namespace fake_detail

class FakeCommunicator final : public Communicator {
 public:
  FakeCommunicator(fake_detail::Shared& shared, int rank) : shared_(shared), rank_(rank) {}
  int rank() const override { return rank_; }
  int size() const override { return shared_.size(); }
  using Communicator::max;  // the one-value forms, hidden by the overrides below
  using Communicator::sum;
  // The collective calls this rank has made (first_problem's two count as two).
  long collectives() const { return collectives_; }

  void sum(double* v, int n) const override {
    reduce(v, n, "sum(double)", [](double a, double b) { return a + b; });
  }
  void sum(std::int64_t* v, int n) const override {
    reduce(v, n, "sum(int64)", [](std::int64_t a, std::int64_t b) { return a + b; });
  }
  void max(double* v, int n) const override {
    reduce(v, n, "max(double)", [](double a, double b) { return std::max(a, b); });
  }
  void min(std::int64_t* v, int n) const override {
    reduce(v, n, "min(int64)", [](std::int64_t a, std::int64_t b) { return std::min(a, b); });
  }
  void broadcast(std::int64_t* v, int n) const override { broadcast_values(v, n, "broadcast(int64)"); }
  void broadcast(double* v, int n) const override { broadcast_values(v, n, "broadcast(double)"); }
  void broadcast(std::string& text, int root) const override {
    if (root < 0 || root >= size()) throw std::logic_error("broadcast(string): root " + std::to_string(root));
    collective(
        {"broadcast(string)", -1, root, &text, nullptr},
        [&] {
          for (int r = 0; r < size(); ++r)
            if (shared_.slot(r).root != root)
              throw std::logic_error("broadcast(string): rank " + std::to_string(r) + " names root " +
                                     std::to_string(shared_.slot(r).root) + ", rank " + std::to_string(rank_) +
                                     " root " + std::to_string(root));
        },
        [&] {
          if (rank_ != root) text = *static_cast<const std::string*>(shared_.slot(root).in);
        });
  }

  void exchange(const std::vector<std::vector<double>>& send, std::vector<std::vector<double>>& recv) const override {
    check_send(send, "exchange");
    collective(
        {"exchange", -1, 0, &send, nullptr}, [] {},
        [&] {
          recv.resize(static_cast<size_t>(size()));
          for (int r = 0; r < size(); ++r) recv[r] = sent_by(r)[rank_];
        });
  }
  void exchange_known(const std::vector<std::vector<double>>& send,
                      std::vector<std::vector<double>>& recv) const override {
    check_send(send, "exchange_known");
    if (static_cast<int>(recv.size()) != size())
      throw std::logic_error("exchange_known: recv has " + std::to_string(recv.size()) + " ranks' buffers, not " +
                             std::to_string(size()));
    collective(
        {"exchange_known", -1, 0, &send, &recv},
        [&] {
          // Every pair's counts, on every rank (so all throw alike): what s sends r is what r expects.
          for (int s = 0; s < size(); ++s)
            for (int r = 0; r < size(); ++r) {
              const auto& expected = (*static_cast<const std::vector<std::vector<double>>*>(shared_.slot(r).out))[s];
              if (sent_by(s)[r].size() != expected.size())
                throw std::logic_error("exchange_known: rank " + std::to_string(s) + " sends " +
                                       std::to_string(sent_by(s)[r].size()) + " values to rank " + std::to_string(r) +
                                       ", which expects " + std::to_string(expected.size()));
            }
        },
        [&] {
          for (int r = 0; r < size(); ++r)
            std::copy(sent_by(r)[rank_].begin(), sent_by(r)[rank_].end(), recv[r].begin());
        });
  }
  void gather(const std::vector<double>& mine, std::vector<std::vector<double>>& all) const override {
    collective(
        {"gather", -1, 0, &mine, nullptr}, [] {},
        [&] {
          all.clear();
          if (rank_ != 0) return;
          for (int r = 0; r < size(); ++r) all.push_back(*static_cast<const std::vector<double>*>(shared_.slot(r).in));
        });
  }

 private:
  const std::vector<std::vector<double>>& sent_by(int r) const {
    return *static_cast<const std::vector<std::vector<double>>*>(shared_.slot(r).in);
  }
  void check_send(const std::vector<std::vector<double>>& send, const char* op) const {
    if (static_cast<int>(send.size()) != size())
      throw std::logic_error(std::string(op) + ": send has " + std::to_string(send.size()) + " ranks' buffers, not " +
                             std::to_string(size()));
  }

  // The rendezvous: publish, barrier, check (the same on every rank), read, barrier. A rank that
  // fails between the barriers still reaches the second before it throws: the others may be
  // reading its arguments until then.
  template <class Check, class Read>
  void collective(fake_detail::Slot mine, Check&& check, Read&& read) const {
    ++collectives_;
    shared_.slot(rank_) = mine;
    shared_.arrive(rank_, mine.op);
    std::exception_ptr failure;
    try {
      for (int r = 0; r < size(); ++r) {
        const fake_detail::Slot& s = shared_.slot(r);
        if (std::strcmp(s.op, mine.op) != 0)
          throw std::logic_error("rank " + std::to_string(rank_) + " calls " + mine.op + " while rank " +
                                 std::to_string(r) + " calls " + s.op);
        if (s.count != mine.count)
          throw std::logic_error(std::string(mine.op) + ": rank " + std::to_string(r) + " passes " +
                                 std::to_string(s.count) + " values, rank " + std::to_string(rank_) + " " +
                                 std::to_string(mine.count));
      }
      check();
      read();
    } catch (...) {
      failure = std::current_exception();
    }
    try {
      shared_.arrive(rank_, mine.op);
    } catch (...) {
      if (!failure) throw;
    }
    if (failure) std::rethrow_exception(failure);
  }

  template <class T, class Op>
  void reduce(T* v, int n, const char* op, Op combine) const {
    std::vector<T> result(static_cast<size_t>(std::max(n, 0)));
    collective(
        {op, n, 0, v, nullptr}, [] {},
        [&] {
          for (int k = 0; k < n; ++k) {
            T acc = static_cast<const T*>(shared_.slot(0).in)[k];
            for (int r = 1; r < size(); ++r) acc = combine(acc, static_cast<const T*>(shared_.slot(r).in)[k]);
            result[k] = acc;
          }
        });
    for (int k = 0; k < n; ++k) v[k] = result[k];  // after barrier 2: nobody reads v any more
  }

  template <class T>
  void broadcast_values(T* v, int n, const char* op) const {
    collective(
        {op, n, 0, v, nullptr}, [] {},
        [&] {
          if (rank_ != 0)
            for (int k = 0; k < n; ++k) v[k] = static_cast<const T*>(shared_.slot(0).in)[k];
        });
  }

  fake_detail::Shared& shared_;
  int rank_;
  mutable long collectives_ = 0;
};

// Runs body(comm) for comm (a const FakeCommunicator&, a Communicator) of rank 0 … n − 1, each on
// its own thread, and returns when all have returned; rethrows the first exception of a rank (not
// a RankAborted it caused in the others). `timeout`: the longest wait in one collective.
template <class F>
void run_ranks(int n, F&& body, std::chrono::milliseconds timeout = std::chrono::seconds(30)) {
  if (n < 1) throw std::invalid_argument("run_ranks: n < 1");
  fake_detail::Shared shared(n, timeout);
  std::vector<std::thread> threads;
  threads.reserve(static_cast<size_t>(n));
  for (int r = 0; r < n; ++r)
    threads.emplace_back([&shared, &body, r] {
      const FakeCommunicator comm(shared, r);
      try {
        body(comm);
        shared.returned(r);
      } catch (const RankAborted&) {
        shared.failed(std::current_exception(), true);
      } catch (...) {
        shared.failed(std::current_exception(), false);
      }
    });
  for (std::thread& t : threads) t.join();
  if (std::exception_ptr e = shared.first()) std::rethrow_exception(e);
}

}  // namespace stiffmd::fake
