// [prepare] on a decomposed run's parts (DomainIntegrator::prepare_parts, engine/domain/part_prepare.cpp;
// integrators/prepare.hpp, prepare_state on PrepareParts) and a rigid method's initial projection
// there (project_parts). What must hold, on 1–4 fake ranks (tests/fake_processes.hpp), each
// started from a random partition of the molecules of a stiff melt built by molecule
// (inputs/stiff_melt_by_parts.toml made small):
//   - projection, relaxation and the bond vibrations drawn by particle give one process's
//     positions and velocities bit for bit, also while a field drives the molecules across the
//     domains (they migrate between relaxation steps), and every rank's note is rank 0's;
//   - the rigid methods' projection of the parts is Rattle::prepare's on the whole state, bit for
//     bit, and its log line is the same;
//   - the vibrations drawn by particle are thermal: bond-length deviations of variance Tε²/α² and
//     ½T of kinetic energy normal to the manifold per bond, within the sampling error of 3 000 bonds.
#include <gtest/gtest.h>

#include <cmath>
#include <memory>
#include <sstream>
#include <string>
#include <vector>

#include "domain_run_support.hpp"
#include "engine/deck/deck.hpp"
#include "engine/domain/domain_integrator.hpp"
#include "engine/scene/scene.hpp"
#include "fake_processes.hpp"
#include "integrators/constraints.hpp"
#include "integrators/prepare.hpp"
#include "test_support.hpp"

namespace stiffmd {
namespace {

using fake::FakeCommunicator;
using fake::run_ranks;

// inputs/stiff_melt_by_parts.toml at 12 chains of 16 beads, its [prepare] without [minimize].
std::vector<std::string> small_melt(const std::string& method, bool drift) {
  std::vector<std::string> o = {"build.0.chains=12", "build.0.beads=16", "integrator.method=" + method,
                                "prepare.relax_steps=60"};
  if (drift) {  // a field mostly along z and y, which moves the dilute molecules across the domains
    o.push_back("forces.drift.style=gravity");
    o.push_back("forces.drift.g=[1.0, 40.0, 80.0]");
    o.push_back("build.0.density=0.05");
    o.push_back("prepare.relax_max_displacement=0.12");
  }
  return o;
}

Scene melt(const std::vector<std::string>& overrides) {
  const Deck deck(test::source_path("inputs/stiff_melt_by_parts.toml"), overrides);
  Scene sc = load_scene(deck);
  sc.minimize.requested = false;
  return sc;
}

struct Prepared {
  Eigen::Matrix3Xd x, v;
  std::vector<std::string> notes;  // every rank's
  double migrated = 0.0;
};

Prepared one_process(const std::vector<std::string>& overrides) {
  const test::OneThread one_thread;
  Scene sc = melt(overrides);
  Prepared p;
  p.notes.push_back(prepare_state(*sc.forces, *sc.forces->stiff_bonds(), sc.state, sc.prepare));
  p.x = sc.state.x;
  p.v = sc.state.v;
  return p;
}

// The same on `ranks` fake ranks from a random partition: rank 0's gathered state.
Prepared on_parts(int ranks, unsigned seed, const std::vector<std::string>& overrides) {
  Prepared out;
  out.notes.resize(static_cast<size_t>(ranks));
  run_ranks(
      ranks,
      [&](const FakeCommunicator& comm) {
        const test::OneThread rank_thread;
        Scene sc = melt(overrides);
        State s = sc.state;
        auto d =
            std::make_unique<DomainIntegrator>(sc, comm, make_integrator(sc.integrator, *sc.forces, sc.state.inv_mass));
        test::Given given = test::scattered(sc, s, comm.size(), comm.rank(), seed);
        d->distribute(std::move(given.molecules), std::move(given.x), std::move(given.v), s);
        out.notes[static_cast<size_t>(comm.rank())] = d->prepare_parts(sc.prepare);
        const double migrated = static_cast<double>(d->report().migrated_molecules);
        d->gather(s);
        if (comm.root()) out.x = s.x, out.v = s.v, out.migrated = migrated;
      },
      std::chrono::seconds(300));
  return out;
}

class PartPrepare : public ::testing::TestWithParam<std::tuple<int, bool>> {};

TEST_P(PartPrepare, IsOneProcesssPrepareBitForBit) {
  const auto [ranks, drift] = GetParam();
  const std::vector<std::string> overrides = small_melt("mollified-impulse", drift);
  const Prepared serial = one_process(overrides);
  // The deck's preparation acts: relaxed, and the bonds given their vibrations.
  EXPECT_NE(serial.notes[0].find("relaxed 60 steps"), std::string::npos) << serial.notes[0];
  EXPECT_NE(serial.notes[0].find("bond vibrations thermalised"), std::string::npos) << serial.notes[0];
  for (const unsigned seed : {1u, 2u}) {
    const Prepared parts = on_parts(ranks, seed, overrides);
    ASSERT_EQ(parts.x.cols(), serial.x.cols());
    EXPECT_TRUE(parts.x == serial.x) << "seed " << seed << ": largest difference "
                                     << (parts.x - serial.x).cwiseAbs().maxCoeff();
    EXPECT_TRUE(parts.v == serial.v) << "seed " << seed << ": largest difference "
                                     << (parts.v - serial.v).cwiseAbs().maxCoeff();
    for (const std::string& note : parts.notes) EXPECT_EQ(note, parts.notes[0]);
    if (drift && ranks > 1) {
      EXPECT_GE(parts.migrated, 1.0) << "no molecule migrated during the relaxation";
    }
  }
}

INSTANTIATE_TEST_SUITE_P(Ranks, PartPrepare, ::testing::Combine(::testing::Values(1, 2, 3, 4), ::testing::Bool()),
                         [](const ::testing::TestParamInfo<std::tuple<int, bool>>& info) {
                           return std::to_string(std::get<0>(info.param)) + "_ranks" +
                                  (std::get<1>(info.param) ? "_drift" : "");
                         });

TEST(PartPrepare, RigidMethodsProjectThePartsAsRattleProjectsTheWholeState) {
  for (const char* method : {"rattle", "fixman"}) {
    std::vector<std::string> overrides = small_melt(method, false);
    overrides.push_back("prepare.project=false");  // the method's projection does it all
    overrides.push_back("prepare.relax_steps=0");
    overrides.push_back("prepare.vibrational_temperature=0");
    Scene whole = melt(overrides);
    std::ostringstream log;
    {
      const test::OneThread one_thread;
      make_integrator(whole.integrator, *whole.forces, whole.state.inv_mass)->prepare(whole.state, log);
    }
    for (const int ranks : {2, 3}) {
      Eigen::Matrix3Xd x, v;
      std::string line;
      run_ranks(ranks, [&](const FakeCommunicator& comm) {
        const test::OneThread rank_thread;
        Scene sc = melt(overrides);
        State s = sc.state;
        auto d =
            std::make_unique<DomainIntegrator>(sc, comm, make_integrator(sc.integrator, *sc.forces, sc.state.inv_mass));
        test::Given given = test::scattered(sc, s, comm.size(), comm.rank(), 3u);
        d->distribute(std::move(given.molecules), std::move(given.x), std::move(given.v), s);
        const std::string mine = d->project_parts();
        d->gather(s);
        if (comm.root()) x = s.x, v = s.v, line = mine;
      });
      EXPECT_TRUE(x == whole.state.x) << method << " on " << ranks << " ranks";
      EXPECT_TRUE(v == whole.state.v) << method << " on " << ranks << " ranks";
      EXPECT_EQ(line + "\n", log.str()) << method << " on " << ranks << " ranks";
    }
  }
}

TEST(PartPrepare, VibrationsByParticleAreThermal) {
  const test::OneThread one_thread;
  // 200 chains of 16 beads: 3 000 bonds, none relaxed or minimised (the statistics are the draws').
  Scene sc = melt({"build.0.chains=200", "build.0.beads=16", "build.0.density=0.3", "prepare.relax_steps=0",
                   "prepare.vibrational_temperature=2.0"});
  const StiffBonds& stiff = *sc.forces->stiff_bonds();
  // Rest at g = 0 first, so that what is measured is the vibrations alone.
  sc.state.v.setZero();
  PrepareSettings p = sc.prepare;
  p.relax_steps = 0;
  prepare_state(*sc.forces, stiff, sc.state, p);
  ASSERT_TRUE(p.by_particle);
  const double kT = p.vibrational_temperature;
  const auto m = static_cast<double>(stiff.bonds.size());
  double g2 = 0.0;  // Σ g_b² / (kT ε²/α_b²)
  for (const StiffBond& b : stiff.bonds) {
    const double g = (sc.state.x.col(b.i) - sc.state.x.col(b.j)).norm() - b.length;
    g2 += g * g / (kT * stiff.epsilon * stiff.epsilon / (b.alpha * b.alpha));
  }
  // Each term is χ²(1): mean 1, variance 2; 4σ of the mean of 3 000 is 0.10.
  EXPECT_NEAR(g2 / m, 1.0, 4.0 * std::sqrt(2.0 / m));
  // The normal velocities u − Pu of thermal u: ½ (Gv)ᵀS⁻¹(Gv) is ½kT per bond (the linearised
  // bonds' normal modes in equipartition; the velocities were 0 before). Each mode's energy is
  // ½kT χ²(1); the mean of 3 000 within 4σ.
  ConstraintToolbox toolbox(stiff.bonds, sc.state.inv_mass);
  const double normal = toolbox.normal_kinetic_energy(sc.state.x, sc.state.v);
  EXPECT_NEAR(normal / (0.5 * kT * m), 1.0, 4.0 * std::sqrt(2.0 / m));
}

}  // namespace
}  // namespace stiffmd
