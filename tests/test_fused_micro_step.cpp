// The fused micro step (FusedMicroStep, forcefields/force_term.hpp; run_innermost in
// integrators/multiple_time_stepping.cpp) must give the same bits as the plain path: kick_drift,
// f = 0, the bond forces. Bit-identical, not only to round-off, because it performs the same
// floating-point operations on each particle in the same order: the kick and drift of one
// particle are the same expressions, and the bond forces into a particle are added, starting from
// 0, in the owner's work order of the bond loop, which the fused pass keeps (it only interleaves
// the drift of other particles between the blocks). With threads, the owner-computes plan is the
// bond loop's, so the claim holds per thread count. Also: the bond loop's few-bond path gives the
// bits of its gathered blocks.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <numeric>
#include <random>

#include "core/parallel.hpp"
#include "forcefields/stiff_harmonic_bond.hpp"
#include "integrators/multiple_time_stepping.hpp"
#include "integrators/primitives.hpp"
#include "test_support.hpp"

namespace stiffmd {
namespace {

using test::ThreadCount;

// 6 000 beads in 60 chains of 100 beads along x on a jittered lattice (above kParallelMin, so two
// threads split the bonds); with `shuffle`, the particle indices are a random permutation, so
// most bonds join particles of different owners (the halo path) and the pass cannot stream.
struct Chains {
  Eigen::Matrix3Xd x;
  StiffBonds bonds;
};

Chains chains(bool shuffle) {
  const int n_chains = 60, beads = 100;
  std::mt19937 rng(3);
  std::uniform_real_distribution<double> jitter(-0.05, 0.05);
  std::vector<int> index(n_chains * beads);
  std::iota(index.begin(), index.end(), 0);
  if (shuffle) std::shuffle(index.begin(), index.end(), rng);
  Chains c;
  c.x.resize(3, n_chains * beads);
  c.bonds.epsilon = 0.01;
  for (int ch = 0; ch < n_chains; ++ch)
    for (int b = 0; b < beads; ++b) {
      const int p = index[ch * beads + b];
      c.x.col(p) = Eigen::Vector3d(0.97 * b + jitter(rng), 1.1 * (ch % 8) + jitter(rng), 1.1 * (ch / 8) + jitter(rng));
      if (b > 0) c.bonds.bonds.push_back({index[ch * beads + b - 1], p, 0.97, 1.0});
    }
  return c;
}

// Combs: the unshuffled chains, each with a side bead on its bead 50 (numbered after all the
// chains' beads, its bond stretched by 0.02), the side bond listed before the chain's backbone
// or after it.
Chains combs(bool side_first) {
  const Chains c = chains(false);
  const Eigen::Index beads = c.x.cols(), n_chains = beads / 100;
  Chains comb{Eigen::Matrix3Xd(3, beads + n_chains), StiffBonds{}};
  comb.x.leftCols(beads) = c.x;
  comb.bonds.epsilon = c.bonds.epsilon;
  for (Eigen::Index ch = 0; ch < n_chains; ++ch) {
    const int stem = static_cast<int>(100 * ch + 50), side = static_cast<int>(beads + ch);
    comb.x.col(side) = comb.x.col(stem) + Eigen::Vector3d(0.0, 0.0, 0.99);
    const StiffBond side_bond{stem, side, 0.97, 1.0};
    if (side_first) comb.bonds.bonds.push_back(side_bond);
    for (int b = 0; b < 99; ++b) comb.bonds.bonds.push_back(c.bonds.bonds[99 * ch + b]);
    if (!side_first) comb.bonds.bonds.push_back(side_bond);
  }
  return comb;
}

// Random velocities and old forces for n particles (the fused step kicks with the old force).
void random_motion(Eigen::Index n, unsigned seed, Eigen::Matrix3Xd& v, Eigen::Matrix3Xd& f) {
  std::mt19937 rng(seed);
  std::normal_distribution<double> g;
  v.resize(3, n);
  f.resize(3, n);
  for (Eigen::Index i = 0; i < n; ++i)
    for (int a = 0; a < 3; ++a) v(a, i) = g(rng), f(a, i) = 100.0 * g(rng);
}

// One micro step of the term both ways — kick_drift, f = 0, the bond forces; and the fused step —
// with the given thread count: the same bits of x, v and f. Returns the plain path's forces.
Eigen::Matrix3Xd expect_fused_is_plain(const StiffHarmonicBond& term, const Eigen::Matrix3Xd& x,
                                       const Eigen::Matrix3Xd& v, const Eigen::Matrix3Xd& f,
                                       const Eigen::VectorXd& inv_mass, int threads) {
  const ThreadCount tc(threads);
  Eigen::Matrix3Xd x1 = x, v1 = v, f1 = f;
  kick_drift(x1, v1, inv_mass, f1, 0.003, 0.002);
  f1.setZero();
  term.add_forces(x1, Box{}, f1);
  Eigen::Matrix3Xd x2 = x, v2 = v, f2 = f;
  term.fused_micro_step()->kick_drift_force(x2, v2, inv_mass, f2, 0.003, 0.002);
  EXPECT_EQ(x1, x2);
  EXPECT_EQ(v1, v2);
  EXPECT_EQ(f1, f2);
  return f1;
}

// One micro step both ways on the term directly, for 1–4 threads, chain-ordered and shuffled,
// with a fixed particle (inverse mass 0) and unbonded particles at the end.
TEST(FusedMicroStep, TermGivesTheBitsOfKickDriftThenForces) {
  for (bool shuffle : {false, true}) {
    Chains c = chains(shuffle);
    const Eigen::Index bonded = c.x.cols();
    c.x.conservativeResize(3, bonded + 7);  // unbonded particles: kicked and drifted, force 0
    c.x.rightCols(7).setRandom();
    const Eigen::Index n = c.x.cols();
    const StiffHarmonicBond term("bonds", Level::fast, c.bonds);
    ASSERT_NE(term.fused_micro_step(), nullptr);
    Eigen::Matrix3Xd v0, f0;
    random_motion(n, 5, v0, f0);
    Eigen::VectorXd inv_mass = Eigen::VectorXd::Constant(n, 1.0);
    inv_mass(17) = 0.0;
    inv_mass(42) = 0.5;
    for (int threads : {1, 2, 3, 4}) {
      SCOPED_TRACE(testing::Message() << "shuffle " << shuffle << ", " << threads << " threads");
      const Eigen::Matrix3Xd f = expect_fused_is_plain(term, c.x, v0, f0, inv_mass, threads);
      EXPECT_GT(f.cwiseAbs().maxCoeff(), 1.0);  // the bonds are stretched: a real force
    }
  }
}

// Short chain runs (the micro step's blocks, bond_loop.hpp's MicroStepPlan, take runs of two bonds
// or more through chain_block, a lone bond through bond_block; the plain bond loop does a block
// of at most kFewBonds bonds bond by bond): 2 000 chains of 1 to 5 bonds, a fixed bead among them,
// 1–3 threads: the bits of the plain path.
TEST(FusedMicroStep, ShortChainRunsGiveTheBitsOfThePlainPath) {
  std::mt19937 rng(8);
  std::uniform_real_distribution<double> jitter(-0.05, 0.05);
  StiffBonds bonds;
  bonds.epsilon = 0.01;
  std::vector<Eigen::Vector3d> at;
  for (int c = 0; c < 2000; ++c) {
    const int beads = 2 + c % 5;
    const int first = static_cast<int>(at.size());
    for (int b = 0; b < beads; ++b) {
      at.emplace_back(0.97 * b + jitter(rng), 1.1 * (c % 40) + jitter(rng), 1.1 * (c / 40) + jitter(rng));
      if (b > 0) bonds.bonds.push_back({first + b - 1, first + b, 0.97, 1.0});
    }
  }
  const Eigen::Index n = static_cast<Eigen::Index>(at.size());
  Eigen::Matrix3Xd x(3, n), v0, f0;
  for (Eigen::Index i = 0; i < n; ++i) x.col(i) = at[i];
  random_motion(n, 9, v0, f0);
  Eigen::VectorXd inv_mass = Eigen::VectorXd::Constant(n, 1.0);
  inv_mass(3) = 0.0;
  const StiffHarmonicBond term("bonds", Level::fast, bonds);
  for (int threads : {1, 2, 3}) {
    SCOPED_TRACE(testing::Message() << threads << " threads");
    EXPECT_GT(expect_fused_is_plain(term, x, v0, f0, inv_mass, threads).cwiseAbs().maxCoeff(), 1.0);
  }
}

// Combs: each chain of `chains` gets a side bead on bead 50, its bond listed before the chain's
// backbone (the backbone's chain run then meets bead 50 already holding the side bond's force, and
// must add to it, not overwrite it) or after it. Both must give the bits of the plain path.
TEST(FusedMicroStep, SideBondsListedBeforeOrAfterTheBackbone) {
  for (bool side_first : {true, false}) {
    const auto [x, bonds] = combs(side_first);
    const Eigen::Index n = x.cols();
    const StiffHarmonicBond term("bonds", Level::fast, bonds);
    Eigen::Matrix3Xd v0, f0;
    random_motion(n, 6, v0, f0);
    const Eigen::VectorXd inv_mass = Eigen::VectorXd::Constant(n, 1.0);
    for (int threads : {1, 2, 3}) {
      SCOPED_TRACE(testing::Message() << "side bond first " << side_first << ", " << threads << " threads");
      EXPECT_GT(expect_fused_is_plain(term, x, v0, f0, inv_mass, threads).col(50).norm(), 1.0);
    }
  }
}

// Systems of at most kSmallFusedParticles particles take the two-pass path
// (small_kick_drift_bond_forces): molecules of 2 to 16 beads — chains in order, chains numbered
// backwards, a comb whose side bond is listed before the backbone, a ring of 5, and the bonds in a
// shuffled order — with a fixed bead: the bits of the plain path.
TEST(FusedMicroStep, SmallMoleculesGiveTheBitsOfThePlainPath) {
  std::mt19937 rng(12);
  std::uniform_real_distribution<double> jitter(-0.05, 0.05);
  for (int beads = 2; beads <= static_cast<int>(kSmallFusedParticles); ++beads)
    for (int shape = 0; shape < 4; ++shape) {
      SCOPED_TRACE(testing::Message() << beads << " beads, shape " << shape);
      Eigen::Matrix3Xd x(3, beads);
      StiffBonds bonds;
      bonds.epsilon = 0.01;
      for (int b = 0; b < beads; ++b) {
        const double angle = 2.0 * M_PI * b / beads;  // a ring's polygon, a chain's zigzag
        x.col(b) = shape == 3 && beads >= 5 ? Eigen::Vector3d(std::cos(angle), std::sin(angle), jitter(rng))
                                            : Eigen::Vector3d(0.97 * b, 0.3 * (b % 2), 0.0);
        x.col(b) += Eigen::Vector3d(jitter(rng), jitter(rng), jitter(rng));
      }
      const double side = 2.0 * std::sin(M_PI / beads);  // the ring's edge
      for (int b = 1; b < beads; ++b) {
        if (shape == 1)
          bonds.bonds.push_back({beads - b, beads - b - 1, 0.97, 1.0});  // numbered backwards
        else
          bonds.bonds.push_back({b - 1, b, shape == 3 && beads >= 5 ? side : 0.97, 1.0 + 0.1 * b});
      }
      if (shape == 2 && beads >= 4) {  // a comb: the last bead hangs off bead 1, its bond listed first
        bonds.bonds.pop_back();
        bonds.bonds.insert(bonds.bonds.begin(), StiffBond{1, beads - 1, 1.0, 1.2});
        std::shuffle(bonds.bonds.begin() + 1, bonds.bonds.end(), rng);
      }
      if (shape == 3 && beads >= 5) bonds.bonds.push_back({beads - 1, 0, side, 1.0});  // close the ring
      const StiffHarmonicBond term("bonds", Level::fast, bonds);
      Eigen::Matrix3Xd v0, f0;
      random_motion(beads, static_cast<unsigned>(beads), v0, f0);
      Eigen::VectorXd inv_mass = Eigen::VectorXd::Constant(beads, 1.0);
      inv_mass(0) = 0.0;
      if (beads > 2) inv_mass(2) = 0.5;
      for (int threads : {1, 2}) {
        SCOPED_TRACE(testing::Message() << threads << " threads");
        EXPECT_GT(expect_fused_is_plain(term, x, v0, f0, inv_mass, threads).cwiseAbs().maxCoeff(), 1.0);
      }
    }
}

// The bond loop does a block of at most kFewBonds bond by bond and a larger one gathered
// (bond_loop.hpp); both must give the same bits. A 3-bond chain alone (one block of 3) against 30
// copies of it at the same coordinates (90 bonds: blocks of 64 and 26): each copy's forces equal
// the lone chain's bit for bit.
TEST(BondLoop, FewBondsGiveTheBitsOfAGatheredBlock) {
  static_assert(kFewBonds >= 3 && 26 > kFewBonds);
  std::mt19937 rng(9);
  std::uniform_real_distribution<double> u(-0.3, 0.3);
  Eigen::Matrix3Xd one(3, 4);
  for (int p = 0; p < 4; ++p) one.col(p) = Eigen::Vector3d(0.9 * p + u(rng), u(rng), u(rng));
  const int copies = 30;
  Eigen::Matrix3Xd many(3, 4 * copies);
  StiffBonds b1, bn;
  b1.epsilon = bn.epsilon = 0.1;
  for (int q = 0; q < 3; ++q) b1.bonds.push_back({q, q + 1, 0.97 + 0.01 * q, 1.0 + 0.1 * q});
  for (int c = 0; c < copies; ++c) {
    many.middleCols(4 * c, 4) = one;
    for (const StiffBond& b : b1.bonds) bn.bonds.push_back({b.i + 4 * c, b.j + 4 * c, b.length, b.alpha});
  }
  const ThreadCount tc(1);
  const StiffHarmonicBond t1("one", Level::fast, b1), tn("many", Level::fast, bn);
  Eigen::Matrix3Xd f1 = Eigen::Matrix3Xd::Zero(3, 4), fn = Eigen::Matrix3Xd::Zero(3, 4 * copies);
  t1.add_forces(one, Box{}, f1);
  tn.add_forces(many, Box{}, fn);
  ASSERT_GT(f1.cwiseAbs().maxCoeff(), 0.1);
  for (int c = 0; c < copies; ++c) EXPECT_EQ(Eigen::Matrix3Xd(fn.middleCols(4 * c, 4)), f1) << "copy " << c;
}

MultipleTimeStepping& mts(Integrator& integ) {
  auto* m = dynamic_cast<MultipleTimeStepping*>(&integ);
  if (!m) throw std::logic_error("not a MultipleTimeStepping integrator");
  return *m;
}

// Whole trajectories on a melt of 64 chains × 72 beads (4 608 beads, WCA and bending on the slow
// level), fused against plain, for 1 and 2 threads: the impulse family in NVE, with the bending on
// the fast level as well (the micro steps' other term, summed after the fused step), and with a
// Langevin O step in the middle of the micro steps (n odd: inside the middle micro step's drift,
// which runs plain; n even: between two fused micro steps); velocity Verlet in NVE and with
// Langevin as a force (splitting "lammps": its whole step fused, the slow terms after the bonds,
// then the friction and noise force). Every step the same bits of x, v and the integrator's
// cached forces.
class FusedImpulseFamily : public ::testing::TestWithParam<std::string> {};

TEST_P(FusedImpulseFamily, TrajectoryIsBitIdenticalToThePlainPath) {
  const std::vector<std::string> nvt = {"thermostat.style=\"langevin\"", "thermostat.temperature=1.0",
                                        "thermostat.damp=1.0", "thermostat.seed=5"};
  struct Case {
    bool langevin;
    int micro_steps;
    bool bending_fast;
    bool lammps_splitting = false;  // Langevin as a force on the outermost kick, no O step
  };
  const bool vv = GetParam() == "velocity-verlet";
  const std::vector<Case> cases =
      vv ? std::vector<Case>{{false, 1, false}, {true, 1, false, true}}
         : std::vector<Case>{{false, 7, false}, {false, 7, true}, {true, 7, false}, {true, 6, false}};
  for (const Case& c : cases) {
    std::vector<std::string> set = {"build.0.chains=64",
                                    "build.0.beads=72",
                                    "prepare.relax_steps=20",
                                    "integrator.method=\"" + GetParam() + "\"",
                                    vv ? "integrator.h=0.001" : "integrator.h=0.005",
                                    "integrator.micro_steps=" + std::to_string(c.micro_steps)};
    if (c.langevin) set.insert(set.end(), nvt.begin(), nvt.end());
    if (c.lammps_splitting) set.push_back("thermostat.splitting=\"lammps\"");
    if (c.bending_fast) set.push_back("forces.bending.level=\"fast\"");
    const Scene base = test::load("tests/decks/small_melt.toml", set);
    ASSERT_GE(base.state.size(), kParallelMin);
    for (int threads : {1, 2}) {
      SCOPED_TRACE(testing::Message() << (c.langevin ? "Langevin, " : "NVE, ") << c.micro_steps << " micro steps, "
                                      << (c.bending_fast ? "bending fast, " : "") << threads << " threads");
      const ThreadCount tc(threads);
      State a = base.state, b = base.state;
      auto fused = make_integrator(base.integrator, *base.forces, a.inv_mass);
      auto plain = make_integrator(base.integrator, *base.forces, b.inv_mass);
      mts(*fused).use_fused_micro_step(true);
      ASSERT_TRUE(mts(*fused).fused_micro_step());
      mts(*plain).use_fused_micro_step(false);
      ASSERT_FALSE(mts(*plain).fused_micro_step());
      std::ostringstream log;
      fused->prepare(a, log);
      plain->prepare(b, log);
      for (int step = 0; step < 4; ++step) {
        fused->step(a, base.integrator.h);
        plain->step(b, base.integrator.h);
        a.step = b.step = step + 1;  // the O step's noise counter
        ASSERT_EQ(a.x, b.x) << "step " << step;
        ASSERT_EQ(a.v, b.v) << "step " << step;
        ASSERT_EQ(fused->save_state(), plain->save_state()) << "step " << step;
      }
      EXPECT_GT((a.x - base.state.x).cwiseAbs().maxCoeff(), vv ? 1e-4 : 1e-3);  // it moved
    }
  }
}

INSTANTIATE_TEST_SUITE_P(SmallMelt, FusedImpulseFamily,
                         ::testing::Values("impulse", "projected-impulse", "mollified-impulse", "velocity-verlet"),
                         test::method_test_name);

// Where the fused step applies: the first term the innermost stage sums (ForceField::
// evaluation_order: the stiff harmonic bonds) offers it — the impulse family's micro steps, also
// with Langevin and with a second term on the innermost level, and velocity Verlet's step. Not
// velocity Verlet with Langevin (BAOAB: the O step splits its drift).
TEST(FusedMicroStep, IsUsedOnlyWhereItIsTheSamePass) {
  auto fused = [](const std::vector<std::string>& set) {
    Scene sc = test::load("tests/decks/small_melt.toml", set);
    return mts(*make_integrator(sc.integrator, *sc.forces, sc.state.inv_mass)).fused_micro_step_available();
  };
  const std::vector<std::string> nvt = {"thermostat.style=\"langevin\"", "thermostat.temperature=1.0",
                                        "thermostat.damp=1.0", "thermostat.seed=1"};
  auto with = [](std::vector<std::string> a, const std::vector<std::string>& b) {
    a.insert(a.end(), b.begin(), b.end());
    return a;
  };
  EXPECT_TRUE(fused({"integrator.method=\"impulse\""}));
  EXPECT_TRUE(fused(with({"integrator.method=\"impulse\""}, nvt)));
  EXPECT_TRUE(fused({"integrator.method=\"impulse\"", "forces.bending.level=\"fast\""}));
  EXPECT_TRUE(fused({"integrator.method=\"velocity-verlet\""}));
  EXPECT_FALSE(fused(with({"integrator.method=\"velocity-verlet\""}, nvt)));
}

// Used by default only where it is the faster: on at most kSmallFusedParticles particles (the double
// pendulum), not on a melt, whose plain passes are faster.
TEST(FusedMicroStep, RunsByDefaultOnlyOnTheSmallestSystems) {
  for (const char* method : {"impulse", "velocity-verlet"}) {
    SCOPED_TRACE(method);
    const std::string set = std::string("integrator.method=\"") + method + "\"";
    Scene melt = test::load("tests/decks/small_melt.toml", {set});
    const auto on_melt = make_integrator(melt.integrator, *melt.forces, melt.state.inv_mass);
    EXPECT_TRUE(mts(*on_melt).fused_micro_step_available());
    EXPECT_FALSE(mts(*on_melt).fused_micro_step());
    Scene pendulum = test::load("inputs/double_pendulum.toml", {set, "variables.eps=0.01", "integrator.h=1e-4"});
    ASSERT_LE(pendulum.state.size(), kSmallFusedParticles);
    const auto on_pendulum = make_integrator(pendulum.integrator, *pendulum.forces, pendulum.state.inv_mass);
    EXPECT_TRUE(mts(*on_pendulum).fused_micro_step());
  }
}

// Several micro steps in molecule blocks (FusedMicroStep::kick_drift_forces, MicroStepPlan in
// forcefields/bond_loop.hpp) against the plain path's steps (kick_drift, f = 0, the bond forces),
// the first kicking by its own step: the same bits of x, v and f, for 1–3 threads, on chains in
// order and shuffled (one block: the molecules are not index ranges), combs with the side bond
// listed first or last (the side bead numbered after every chain: one block too), rings (a bond
// back to the first bead), molecules of 1 to 6 beads, fixed beads and unbonded particles.
struct Molecules {
  Eigen::Matrix3Xd x;
  StiffBonds bonds;
};

Molecules rings_and_small_molecules() {
  std::mt19937 rng(21);
  std::uniform_real_distribution<double> jitter(-0.05, 0.05);
  Molecules m;
  m.bonds.epsilon = 0.01;
  std::vector<Eigen::Vector3d> at;
  for (int c = 0; c < 900; ++c) {
    const bool ring = c % 3 == 0;
    const int beads = ring ? 5 + c % 7 : 1 + c % 6;
    const int first = static_cast<int>(at.size());
    const double side = 2.0 * std::sin(M_PI / beads);
    for (int b = 0; b < beads; ++b) {
      const double angle = 2.0 * M_PI * b / beads;
      const Eigen::Vector3d base(3.0 * (c % 30), 3.0 * (c / 30), 0.0);
      at.push_back(base +
                   (ring ? Eigen::Vector3d(std::cos(angle), std::sin(angle), 0.0)
                         : Eigen::Vector3d(0.97 * b, 0.3 * (b % 2), 0.0)) +
                   Eigen::Vector3d(jitter(rng), jitter(rng), jitter(rng)));
      if (b > 0) m.bonds.bonds.push_back({first + b - 1, first + b, ring ? side : 0.97, 1.0 + 0.05 * (b % 3)});
    }
    if (ring) m.bonds.bonds.push_back({first + beads - 1, first, side, 1.0});
  }
  m.x.resize(3, static_cast<Eigen::Index>(at.size()));
  for (Eigen::Index i = 0; i < m.x.cols(); ++i) m.x.col(i) = at[i];
  return m;
}

void expect_blocked_steps_are_plain(const Eigen::Matrix3Xd& x, const StiffBonds& bonds, unsigned seed,
                                    const std::string& what) {
  const Eigen::Index n = x.cols();
  const StiffHarmonicBond term("bonds", Level::fast, bonds);
  Eigen::Matrix3Xd v0, f0;
  random_motion(n, seed, v0, f0);
  Eigen::VectorXd inv_mass = Eigen::VectorXd::Constant(n, 1.0);
  inv_mass(7) = 0.0;  // fixed: at rest
  v0.col(7).setZero();
  inv_mass(11) = 0.5;
  const double first_kick = 0.0015, kick = 0.003, dt = 0.002;
  const int steps = 5;
  for (int threads : {1, 2, 3}) {
    SCOPED_TRACE(testing::Message() << what << ", " << threads << " threads");
    const ThreadCount tc(threads);
    Eigen::Matrix3Xd x1 = x, v1 = v0, f1 = f0;
    for (int s = 0; s < steps; ++s) {
      kick_drift(x1, v1, inv_mass, f1, s == 0 ? first_kick : kick, dt);
      f1.setZero();
      term.add_forces(x1, Box{}, f1);
    }
    Eigen::Matrix3Xd x2 = x, v2 = v0, f2 = f0;
    term.fused_micro_step()->kick_drift_forces(x2, v2, inv_mass, f2, first_kick, kick, dt, steps);
    EXPECT_EQ(x1, x2);
    EXPECT_EQ(v1, v2);
    EXPECT_EQ(f1, f2);
    EXPECT_GT(f1.cwiseAbs().maxCoeff(), 1.0);  // stretched bonds: a real force
    EXPECT_EQ(x1.col(7), x.col(7));            // the fixed bead stayed
  }
}

TEST(BlockedMicroSteps, GiveTheBitsOfThePlainSteps) {
  for (bool shuffle : {false, true}) {
    Chains c = chains(shuffle);
    const Eigen::Index bonded = c.x.cols();
    c.x.conservativeResize(3, bonded + 7);  // unbonded particles: kicked and drifted, force 0
    c.x.rightCols(7).setRandom();
    expect_blocked_steps_are_plain(c.x, c.bonds, 3, shuffle ? "shuffled chains" : "chains");
  }
  for (bool side_first : {true, false}) {  // combs, the side beads numbered after the chains
    const auto [x, bonds] = combs(side_first);
    expect_blocked_steps_are_plain(x, bonds, 4, side_first ? "combs, side bond first" : "combs, side bond last");
  }
  {  // combs whose side bead follows its stem's chain: blocks of whole combs
    const Chains c = chains(false);
    const Eigen::Index n_chains = c.x.cols() / 100;
    Eigen::Matrix3Xd x(3, c.x.cols() + n_chains);
    StiffBonds bonds;
    bonds.epsilon = c.bonds.epsilon;
    for (Eigen::Index ch = 0; ch < n_chains; ++ch) {
      const int first = static_cast<int>(101 * ch);
      x.middleCols(first, 100) = c.x.middleCols(100 * ch, 100);
      x.col(first + 100) = x.col(first + 50) + Eigen::Vector3d(0.0, 0.0, 0.99);
      bonds.bonds.push_back({first + 50, first + 100, 0.97, 1.2});
      for (int b = 0; b < 99; ++b) bonds.bonds.push_back({first + b, first + b + 1, 0.97, 1.0});
    }
    expect_blocked_steps_are_plain(x, bonds, 5, "combs in index ranges");
  }
  const Molecules m = rings_and_small_molecules();
  ASSERT_GE(m.x.cols(), kParallelMin);
  expect_blocked_steps_are_plain(m.x, m.bonds, 6, "rings and small molecules");
}

// The impulse family's micro steps run in molecule blocks by default on a melt (not only on the
// smallest systems), and not where a second term shares the innermost level; whole trajectories
// with the default (blocked) and the plain path, NVE and Langevin with n even and odd (the O step
// between two runs of blocked micro steps, or inside the middle micro step's drift), 1 and 2
// threads: the same bits of x, v and the cached forces every step.
TEST(BlockedMicroSteps, OnByDefaultAndTrajectoryBitIdentical) {
  auto load = [](std::vector<std::string> set) {
    set.insert(set.end(), {"build.0.chains=64", "build.0.beads=72", "prepare.relax_steps=20", "integrator.h=0.005"});
    return test::load("tests/decks/small_melt.toml", set);
  };
  {
    Scene bending_fast = load({"integrator.method=\"impulse\"", "forces.bending.level=\"fast\""});
    EXPECT_FALSE(mts(*make_integrator(bending_fast.integrator, *bending_fast.forces, bending_fast.state.inv_mass))
                     .blocked_micro_steps());
  }
  const std::vector<std::string> nvt = {"thermostat.style=\"langevin\"", "thermostat.temperature=1.0",
                                        "thermostat.damp=1.0", "thermostat.seed=5"};
  for (const char* method : {"impulse", "mollified-impulse"})
    for (int micro : {6, 7})
      for (bool langevin : {false, true}) {
        std::vector<std::string> set = {std::string("integrator.method=\"") + method + "\"",
                                        "integrator.micro_steps=" + std::to_string(micro)};
        if (langevin) set.insert(set.end(), nvt.begin(), nvt.end());
        const Scene base = load(set);
        for (int threads : {1, 2}) {
          SCOPED_TRACE(testing::Message() << method << ", " << micro << " micro steps, "
                                          << (langevin ? "Langevin, " : "NVE, ") << threads << " threads");
          const ThreadCount tc(threads);
          State a = base.state, b = base.state;
          auto blocked = make_integrator(base.integrator, *base.forces, a.inv_mass);
          auto plain = make_integrator(base.integrator, *base.forces, b.inv_mass);
          ASSERT_TRUE(mts(*blocked).blocked_micro_steps());
          mts(*plain).use_fused_micro_step(false);
          ASSERT_FALSE(mts(*plain).blocked_micro_steps());
          std::ostringstream log;
          blocked->prepare(a, log);
          plain->prepare(b, log);
          for (int step = 0; step < 3; ++step) {
            const std::int64_t fast0 = base.forces->evaluations(Level::fast);
            blocked->step(a, base.integrator.h);
            const std::int64_t fast1 = base.forces->evaluations(Level::fast);
            plain->step(b, base.integrator.h);
            const std::int64_t fast2 = base.forces->evaluations(Level::fast);
            a.step = b.step = step + 1;
            ASSERT_EQ(a.x, b.x) << "step " << step;
            ASSERT_EQ(a.v, b.v) << "step " << step;
            ASSERT_EQ(blocked->save_state(), plain->save_state()) << "step " << step;
            EXPECT_EQ(fast1 - fast0, fast2 - fast1) << "step " << step;  // the fast force counted per micro step
          }
          EXPECT_GT((a.x - base.state.x).cwiseAbs().maxCoeff(), 1e-3);
        }
      }
}

}  // namespace
}  // namespace stiffmd
