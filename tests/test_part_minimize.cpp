// [minimize] on a decomposed run's parts (DomainIntegrator::minimize, engine/domain/part_minimize.cpp;
// integrators/minimize.hpp, minimize on MinimizeParts): FIRE, CG or SD on each rank's part, its
// sums over the particles exact, gives one process's minimisation bit for bit. What must hold, on 1–4 fake
// ranks (tests/fake_processes.hpp), each started from a random partition of the molecules:
//   - a melt built by molecule (inputs/melt_by_molecule.toml made small: its chains overlap), with
//     the soft start (max_force, dmax), its bonds rigid (rattle) or stiff springs: the positions
//     at the end, the iterations, force evaluations, stop and force norms are one process's bits,
//     the energies one process's to round-off (bits on one rank);
//   - the same with a field that drives the molecules across the domains (they migrate within the
//     minimisation, besides the start's moves);
//   - the same by the line searches, cg and sd (rigid and not, with the drift): g, h and the
//     forces travel with the migrating molecules;
//   - a plain floating-point sum in place of the exact ones does not give one process's bits on
//     several ranks (what the test would see if the sums were not exact), by FIRE and by CG.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <memory>
#include <random>
#include <sstream>
#include <string>
#include <vector>

#include "core/errors.hpp"
#include "domain_run_support.hpp"
#include "engine/deck/deck.hpp"
#include "engine/domain/domain_integrator.hpp"
#include "engine/domain/part_molecules.hpp"
#include "engine/scene/scene.hpp"
#include "fake_processes.hpp"
#include "integrators/methods.hpp"
#include "integrators/minimize.hpp"
#include "test_support.hpp"

namespace stiffmd {
namespace {

using fake::FakeCommunicator;
using fake::run_ranks;

// inputs/melt_by_molecule.toml at 12 chains of 16 beads (box ≈ 6.1 σ), its [minimize] as the deck
// has it with fewer iterations, by `style`.
std::vector<std::string> melt_overrides(const std::string& method, long maxiter, const std::string& style = "fire") {
  return {"build.0.chains=12", "build.0.beads=16", "integrator.method=" + method,
          "minimize.maxiter=" + std::to_string(maxiter), "minimize.style=\"" + style + "\""};
}

Scene melt(const std::vector<std::string>& overrides, bool drift) {
  std::vector<std::string> o = overrides;
  if (drift) {  // a field mostly along z and y: the molecules slide across the domains while FIRE runs
    o.push_back("forces.drift.style=gravity");
    o.push_back("forces.drift.g=[1.0, 4.0, 8.0]");
  }
  const Deck deck(test::source_path("inputs/melt_by_molecule.toml"), o);
  return load_scene(deck);
}

struct Minimized {
  MinimizeReport report;
  Eigen::Matrix3Xd x, v;
  double migrated = 0.0;
  std::vector<MinimizeReport> reports;  // every rank's
};

// One process's FIRE on the whole scene, as prepare_scene runs it.
Minimized one_process(const std::vector<std::string>& overrides, bool drift) {
  const test::OneThread one_thread;
  Scene sc = melt(overrides, drift);
  Minimized m;
  m.report = minimize(*sc.forces, sc.forces->stiff_bonds(), sc.state, sc.minimize);
  m.x = sc.state.x;
  m.v = sc.state.v;
  return m;
}

// The same on `ranks` fake ranks from a random partition: rank 0's gathered state.
Minimized on_parts(int ranks, unsigned seed, const std::vector<std::string>& overrides, bool drift,
                   SumRule rule = SumRule::exact) {
  Minimized out;
  out.reports.resize(static_cast<size_t>(ranks));
  run_ranks(
      ranks,
      [&](const FakeCommunicator& comm) {
        const test::OneThread rank_thread;
        Scene sc = melt(overrides, drift);
        State s = sc.state;
        auto d =
            std::make_unique<DomainIntegrator>(sc, comm, make_integrator(sc.integrator, *sc.forces, sc.state.inv_mass));
        test::Given given = test::scattered(sc, s, comm.size(), comm.rank(), seed);
        d->distribute(std::move(given.molecules), std::move(given.x), std::move(given.v), s);
        out.reports[comm.rank()] = d->minimize(sc.minimize, nullptr, {}, rule);
        const double migrated = static_cast<double>(d->report().migrated_molecules);
        d->gather(s);
        if (comm.root()) out.x = s.x, out.v = s.v, out.report = out.reports[0], out.migrated = migrated;
      },
      std::chrono::seconds(300));
  return out;
}

void expect_same_report(const MinimizeReport& a, const MinimizeReport& b, bool energies_bits) {
  EXPECT_EQ(a.stopped_by, b.stopped_by);
  EXPECT_EQ(a.iterations, b.iterations);
  EXPECT_EQ(a.evaluations, b.evaluations);
  EXPECT_EQ(a.fmax, b.fmax);
  EXPECT_EQ(a.fnorm, b.fnorm);
  EXPECT_EQ(a.max_violation, b.max_violation);
  EXPECT_EQ(a.rigid, b.rigid);
  if (energies_bits) {
    EXPECT_EQ(a.initial_energy, b.initial_energy);
    EXPECT_EQ(a.energy, b.energy);
  } else {  // the ranks' shares in floating point: the whole energy to round-off
    EXPECT_NEAR(a.initial_energy, b.initial_energy, 1e-13 * std::abs(b.initial_energy));
    EXPECT_NEAR(a.energy, b.energy, 1e-12 * (std::abs(b.energy) + 1.0));
  }
}

struct Case {
  std::string method;
  bool drift;
  std::string style = "fire";
  bool capped = true;  // the deck's soft start; without it CG's directions are conjugate (β > 0)
};
void PrintTo(const Case& c, std::ostream* os) {
  *os << c.style << ", " << c.method << (c.drift ? " with a drift" : "") << (c.capped ? "" : ", no force cap");
}

class PartMinimize : public ::testing::TestWithParam<std::tuple<int, Case>> {};

TEST_P(PartMinimize, IsOneProcesssMinimisationBitForBit) {
  const auto [ranks, c] = GetParam();
  std::vector<std::string> overrides = melt_overrides(c.method, 400, c.style);
  if (!c.capped) overrides.push_back("minimize.max_force=0");
  const Minimized serial = one_process(overrides, c.drift);
  // The deck's soft start acts: forces capped, and the minimiser moved the beads apart.
  EXPECT_GT(serial.report.initial_energy, 1e6);
  EXPECT_LT(serial.report.energy, 1e-3 * serial.report.initial_energy);
  EXPECT_EQ(serial.report.rigid, c.method == "rattle");
  for (const unsigned seed : {1u, 2u}) {
    const Minimized parts = on_parts(ranks, seed, overrides, c.drift);
    EXPECT_TRUE(parts.x == serial.x) << "seed " << seed << ": largest difference "
                                     << (parts.x - serial.x).cwiseAbs().maxCoeff();
    EXPECT_TRUE(parts.v == serial.v) << "seed " << seed;
    expect_same_report(parts.report, serial.report, ranks == 1);
    for (const MinimizeReport& r : parts.reports) {  // every rank's report is rank 0's
      EXPECT_EQ(r.energy, parts.report.energy);
      EXPECT_EQ(r.iterations, parts.report.iterations);
    }
    if (c.drift && ranks > 1) {
      EXPECT_GE(parts.migrated, 1.0) << "no molecule migrated during the minimisation";
    }
  }
}

INSTANTIATE_TEST_SUITE_P(
    Ranks, PartMinimize,
    ::testing::Combine(::testing::Values(1, 2, 3, 4),
                       ::testing::Values(Case{"rattle", false}, Case{"velocity-verlet", false}, Case{"rattle", true},
                                         Case{"rattle", false, "cg"}, Case{"rattle", false, "cg", false},
                                         Case{"velocity-verlet", false, "cg", false}, Case{"rattle", true, "cg"},
                                         Case{"rattle", true, "cg", false}, Case{"rattle", true, "sd"})),
    [](const ::testing::TestParamInfo<std::tuple<int, Case>>& info) {
      const Case& c = std::get<1>(info.param);
      std::string m = c.method;
      std::replace(m.begin(), m.end(), '-', '_');
      return std::to_string(std::get<0>(info.param)) + "_ranks_" + c.style + "_" + m + (c.drift ? "_drift" : "") +
             (c.capped ? "" : "_uncapped");
    });

// The break the test above must catch: each rank's floating-point sums added over the ranks.
TEST(PartMinimize, PlainSumsOverTheRanksAreNotOneProcesssBits) {
  for (const char* style : {"fire", "cg"}) {
    const std::vector<std::string> overrides = melt_overrides("rattle", 400, style);
    const Minimized serial = one_process(overrides, false);
    for (const int ranks : {2, 3}) {
      const Minimized plain = on_parts(ranks, 1u, overrides, false, SumRule::plain);
      EXPECT_FALSE(plain.x == serial.x) << style << " on " << ranks << " ranks";
    }
  }
}

}  // namespace
}  // namespace stiffmd
