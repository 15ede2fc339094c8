// A decomposed run on N fake ranks (tests/fake_processes.hpp) against one process's, step by step
// as the Run takes them (take_step, engine/run/run.hpp): the harness of the tests that make the
// whole scene useless after the start and still expect one process's trajectory bit for bit
// (tests/test_part_molecules.cpp, tests/test_pair_set_data.cpp).
#pragma once

#include <chrono>
#include <functional>
#include <memory>
#include <sstream>
#include <vector>

#include "core/parallel.hpp"
#include "engine/domain/domain_integrator.hpp"
#include "engine/run/run.hpp"
#include "fake_processes.hpp"
#include "integrators/methods.hpp"

namespace stiffmd::test {

// One thread in the thread that makes it, as the domains_* ctests run both sides with
// OMP_NUM_THREADS=1 (tests/test_domains.py): another thread count sums the pair forces in another
// order, and the fake ranks share the process's OpenMP threads.
struct OneThread {
  int was = max_threads();
  OneThread() { set_max_threads(1); }
  ~OneThread() { set_max_threads(was); }
};

// One process: the deck's method on the whole scene, `steps` steps from its state.
inline void run_one_process(Scene& sc, int steps) {
  const OneThread one_thread;
  const double h = sc.integrator.h;
  auto method = make_integrator(sc.integrator, *sc.forces, sc.state.inv_mass);
  std::ostringstream log;
  method->prepare(sc.state, log);
  for (int k = 1; k <= steps; ++k) take_step(*method, sc.state, h, k, k * h);
}

// What a decomposed run left: rank 0's report and its gathered final state.
struct DomainRun {
  double migrated = 0.0, selections = 0.0;
  Eigen::Matrix3Xd x, v;
};

// `steps` steps of a DomainIntegrator on each of `ranks` fake ranks, each with its own scene from
// make_scene(): once the parts are distributed, started(rank, d, scene, state) (e.g. the whole
// scene made useless), after the steps ended(rank, d). Rank 0's report and final state.
template <class MakeScene>
DomainRun run_on_fake_ranks(
    int ranks, int steps, MakeScene make_scene,
    const std::function<void(int, const DomainIntegrator&, Scene&, State&)>& started,
    const std::function<void(int, const DomainIntegrator&)>& ended = [](int, const DomainIntegrator&) {}) {
  const OneThread one_thread;
  std::vector<DomainRun> out(static_cast<size_t>(ranks));
  std::vector<char> ok(static_cast<size_t>(ranks), 0);
  fake::run_ranks(
      ranks,
      [&](const fake::FakeCommunicator& comm) {
        const OneThread rank_thread;
        const int me = comm.rank();
        Scene sc = make_scene();
        State s = sc.state;
        const double h = sc.integrator.h;
        auto d =
            std::make_unique<DomainIntegrator>(sc, comm, make_integrator(sc.integrator, *sc.forces, sc.state.inv_mass));
        std::ostringstream log;
        d->prepare(s, log);
        d->distribute(s);
        started(me, *d, sc, s);
        for (int k = 1; k <= steps; ++k) take_step(*d, s, h, k, k * h, false);
        ended(me, *d);
        const DomainReport report = d->report();
        out[me].migrated = static_cast<double>(report.migrated_molecules);
        out[me].selections = static_cast<double>(report.redistributions);
        d->gather(s);
        if (comm.root()) out[me].x = s.x, out[me].v = s.v;
        ok[me] = 1;
      },
      std::chrono::seconds(120));
  for (int r = 0; r < ranks; ++r)
    if (!ok[r]) throw std::runtime_error("run_on_fake_ranks: rank " + std::to_string(r) + " did not finish");
  return out[0];
}

}  // namespace stiffmd::test
