// The constrained step in molecule blocks (Rattle::blocked_step, integrators/rattle.hpp;
// ConstraintToolbox's blocks, integrators/constraints.hpp) must give the bits of the whole-system
// passes: each particle and cluster gets the same operations in the same order, and the sums over
// particles and clusters are added in the whole-system passes' order (ParticleSum,
// integrators/thermostat.hpp). Compared step by step: x, v, the saved state (the cached force, the
// constraint force or the kept velocities, the O step's kinetic energy, the heat), the temperature
// estimate, the heat and the constraint virial.
#include <gtest/gtest.h>

#include <memory>
#include <sstream>
#include <string>
#include <vector>

#include "core/parallel.hpp"
#include "integrators/fixman.hpp"
#include "integrators/model_potential.hpp"
#include "integrators/rattle.hpp"
#include "test_support.hpp"

namespace stiffmd {
namespace {

using test::ThreadCount;

// 64 chains of 72 beads (4 608, above kParallelMin: 2 and 3 threads split the particles).
Scene melt() {
  return test::load("tests/decks/small_melt.toml", {"build.0.chains=64", "build.0.beads=72", "prepare.relax_steps=20",
                                                    "integrator.method=\"rattle\""});
}

// A bond of the length the particles have now: on the manifold from the start.
StiffBond bond_as_is(const Eigen::Matrix3Xd& x, int i, int j) {
  return {i, j, (x.col(i) - x.col(j)).norm(), 1.0};
}

struct Topology {
  std::string name;
  std::vector<StiffBond> bonds;
  std::vector<int> fixed;  // particles of inverse mass 0
  bool blocks = true;      // whether the toolbox can cut it into blocks
};

// The melt's chains, and on the same beads: rings (each fourth chain closed), combs (its last two
// beads hung from bead 35 instead of bead 69), molecules of six beads (chains cut) and chains with
// a fixed end bead; and a fixed middle bead, shared by the two clusters it joins (no blocks).
std::vector<Topology> topologies(const Scene& sc) {
  const std::vector<StiffBond>& chain_bonds = sc.forces->stiff_bonds()->bonds;
  const Eigen::Matrix3Xd& x = sc.state.x;
  std::vector<Topology> t(3);
  t[0] = {"chains", chain_bonds, {}, true};
  t[1].name = "rings, combs, short molecules, fixed ends";
  for (int ch = 0; ch < 64; ++ch) {
    const int first = 72 * ch;
    for (int k = 0; k < 71; ++k) {
      const bool cut = (ch % 4 == 2 && k == 69) || (ch % 4 == 3 && k % 6 == 5);
      if (!cut) t[1].bonds.push_back(chain_bonds[static_cast<std::size_t>(71 * ch + k)]);
    }
    if (ch % 4 == 1) t[1].bonds.push_back(bond_as_is(x, first, first + 71));
    if (ch % 4 == 2) t[1].bonds.push_back(bond_as_is(x, first + 35, first + 70));
    if (ch % 8 == 0) t[1].fixed.push_back(first);
  }
  t[2] = {"a fixed middle bead", chain_bonds, {72 * 5 + 30}, false};
  return t;
}

struct Method {
  std::string name;
  bool fixman = false, langevin = false, obabo = false;
};

std::unique_ptr<Rattle> make(Scene& sc, const Topology& t, const Method& m, const Eigen::VectorXd& inv_mass) {
  std::unique_ptr<ModelPotential> model;
  if (m.fixman) model = std::make_unique<FixmanCorrection>(FixmanPotential(t.bonds, inv_mass), 1.0);
  std::unique_ptr<LangevinNoise> noise;
  if (m.langevin) {
    ThermostatSettings ts;
    ts.style = ThermostatSettings::Style::langevin;
    ts.temperature = 1.0;
    ts.friction = Eigen::VectorXd::Constant(inv_mass.size(), 2.0);
    ts.seed = 7;
    noise = std::make_unique<LangevinNoise>(ts, inv_mass);
  }
  return std::make_unique<Rattle>(
      m.name, *sc.forces, ConstraintToolbox(t.bonds, inv_mass), std::move(model), std::move(noise),
      m.obabo ? ThermostatSettings::Splitting::obabo : ThermostatSettings::Splitting::baoab);
}

TEST(BlockedConstrainedStep, GivesTheBitsOfTheWholeSystemPasses) {
  Scene sc = melt();
  const std::vector<Method> methods = {{"rattle", false, false, false},
                                       {"rattle", false, true, false},
                                       {"rattle-obabo", false, true, true},
                                       {"fixman", true, true, false},
                                       {"fixman-obabo", true, true, true}};
  for (const Topology& t : topologies(sc)) {
    State s0 = sc.state;
    for (int p : t.fixed) {
      s0.inv_mass[p] = 0.0;
      s0.v.col(p).setZero();
    }
    for (const Method& m : methods)
      for (int threads : {1, 2, 3})
        for (std::int64_t block : {std::int64_t{256}, std::int64_t{40}}) {
          if (threads == 3 && block == 256) continue;
          SCOPED_TRACE(testing::Message() << t.name << ", " << m.name << (m.langevin ? " Langevin, " : " NVE, ")
                                          << threads << " threads, blocks of " << block << "+ particles");
          const ThreadCount tc(threads);
          State a = s0, b = s0;
          auto blocked = make(sc, t, m, s0.inv_mass);
          auto whole = make(sc, t, m, s0.inv_mass);
          blocked->toolbox().set_block_particles(block);
          whole->use_blocked_step(false);
          ASSERT_EQ(blocked->blocked_step(), t.blocks);
          ASSERT_FALSE(whole->blocked_step());
          if (t.blocks) {
            ASSERT_GE(blocked->toolbox().num_blocks(), static_cast<int>(a.size() / (block + 72)));
          }
          std::ostringstream log;
          blocked->prepare(a, log);
          whole->prepare(b, log);
          const double h = 0.005;
          for (int step = 0; step < 3; ++step) {
            a.step = b.step = step;
            blocked->step(a, h);
            whole->step(b, h);
            ASSERT_EQ(a.x, b.x) << "step " << step;
            ASSERT_EQ(a.v, b.v) << "step " << step;
            ASSERT_EQ(blocked->kinetic_energy_estimate(a), whole->kinetic_energy_estimate(b)) << "step " << step;
            ASSERT_EQ(blocked->thermostat_heat(), whole->thermostat_heat()) << "step " << step;
            ASSERT_EQ(blocked->model_potential(a.x), whole->model_potential(b.x)) << "step " << step;
            if (step == 1) {
              ASSERT_EQ(blocked->constraint_virial(a), whole->constraint_virial(b));
            }
            ASSERT_EQ(blocked->save_state(), whole->save_state()) << "step " << step;
          }
          for (int p : t.fixed) EXPECT_EQ(a.x.col(p), s0.x.col(p));
          EXPECT_GT((a.x - s0.x).cwiseAbs().maxCoeff(), 1e-3);  // the melt moved
          if (m.langevin) {
            EXPECT_NE(blocked->thermostat_heat(), 0.0);
          }
        }
  }
}

// On by default for the factory's rattle and fixman on a melt; off where the projections run as
// written (tests: set_merged_projection).
TEST(BlockedConstrainedStep, OnByDefaultWhereAvailable) {
  Scene sc = melt();
  auto r = make_integrator(sc.integrator, *sc.forces, sc.state.inv_mass);
  auto& rattle = dynamic_cast<Rattle&>(*r);
  EXPECT_TRUE(rattle.blocked_step());
  EXPECT_GT(rattle.toolbox().num_blocks(), 10);
  Scene nvt = test::load(
      "tests/decks/small_melt.toml",
      {"build.0.chains=64", "build.0.beads=72", "prepare.relax_steps=20", "integrator.method=\"fixman\"",
       "thermostat.style=\"langevin\"", "thermostat.temperature=1.0", "thermostat.damp=1.0", "thermostat.seed=5"});
  auto f = make_integrator(nvt.integrator, *nvt.forces, nvt.state.inv_mass);
  auto& fixman = dynamic_cast<Rattle&>(*f);
  EXPECT_TRUE(fixman.blocked_step());
  fixman.set_merged_projection(false);
  EXPECT_FALSE(fixman.blocked_step());
}

}  // namespace
}  // namespace stiffmd
