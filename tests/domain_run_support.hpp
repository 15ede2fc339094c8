// A decomposed run on N fake ranks (tests/fake_processes.hpp) against one process's, step by step
// as the Run takes them (take_step, engine/run/run.hpp): the harness of the tests that make the
// whole scene useless after the start and still expect one process's trajectory bit for bit
// (tests/test_part_molecules.cpp, tests/test_pair_set_data.cpp).
#pragma once

#include <algorithm>
#include <chrono>
#include <functional>
#include <memory>
#include <random>
#include <span>
#include <sstream>
#include <vector>

#include "core/parallel.hpp"
#include "core/topology.hpp"
#include "engine/domain/domain_integrator.hpp"
#include "engine/domain/part_molecules.hpp"
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

// This rank's molecules of a random partition (molecule m to rank pick(m), the same on every
// rank): its PartMolecules cut from the scene, with their x, v.
struct Given {
  PartMolecules molecules;
  Eigen::Matrix3Xd x, v;
};
inline Given scattered(const Scene& sc, const State& s, int ranks, int rank, unsigned seed) {
  const int n = s.size();
  const std::vector<int> molecule = bonded_molecules(sc.topology, n);
  const int molecules = n ? *std::max_element(molecule.begin(), molecule.end()) + 1 : 0;
  std::mt19937 rng(seed);
  std::uniform_int_distribution<int> pick(0, ranks - 1);
  std::vector<int> part;
  for (int m = 0; m < molecules; ++m) part.push_back(pick(rng));
  std::vector<int> mine;
  for (int g = 0; g < n; ++g)
    if (part[molecule[g]] == rank) mine.push_back(g);
  const Eigen::VectorXd& friction = sc.integrator.thermostat.friction;
  Given out;
  out.molecules =
      cut_part({std::span<const double>(s.inv_mass.data(), static_cast<size_t>(n)), sc.particle_type, sc.charge,
                sc.topology.molecule, std::span<const double>(friction.data(), static_cast<size_t>(friction.size())),
                sc.topology},
               mine);
  out.x.resize(3, static_cast<Eigen::Index>(mine.size()));
  out.v.resize(3, static_cast<Eigen::Index>(mine.size()));
  for (size_t k = 0; k < mine.size(); ++k) out.x.col(k) = s.x.col(mine[k]), out.v.col(k) = s.v.col(mine[k]);
  return out;
}

}  // namespace stiffmd::test
