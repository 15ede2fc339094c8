// [minimize], FIRE 2.0 (integrators/minimize.*): the Lennard-Jones dimer's minimum to 1e-6
// relative, each stopping rule reported by name, rigid bonds exact after every move, and two
// overlapping builders relaxed and run through the CLI.
#include <gtest/gtest.h>

#include <cmath>
#include <filesystem>
#include <sstream>
#include <string>
#include <vector>

#include "cli_support.hpp"
#include "test_support.hpp"
#include "engine/deck/deck.hpp"
#include "engine/scene/scene.hpp"
#include "integrators/constraints.hpp"
#include "integrators/minimize.hpp"

namespace stiffmd {
namespace {

using test::cli;
using test::CliResult;
using test::scratch_dir;
using test::slurp;

// Two LJ beads (ε = σ = 1, cut at r_c = 2.5 and shifted) a distance r0 apart.
Scene lj_dimer(double r0, const std::string& minimize) {
  std::ostringstream d;
  d.precision(17);
  d << "[types.a]\nmass = 1.0\n[[particles]]\ntype = \"a\"\nposition = [0, 0, 0]\n"
    << "[[particles]]\ntype = \"a\"\nposition = [" << r0 << ", 0, 0]\n"
    << "[forces.lj]\nstyle = \"lj\"\nepsilon = 1.0\nsigma = 1.0\ncutoff = 2.5\n"
    << "[integrator]\nmethod = \"velocity-verlet\"\nh = 0.005\n[run]\nt_end = 0.01\n"
    << "[minimize]\n"
    << minimize << "\n";
  const Deck deck(Deck::Text{"dimer.toml", d.str()}, {});
  return load_scene(deck);
}

// E(r) = 4[(1/r)¹² − (1/r)⁶] − 4[(1/r_c)¹² − (1/r_c)⁶]: at r = 2^(1/6), −1 minus the shift.
double lj_shifted_minimum() {
  const double rc = 2.5;
  return -1.0 - 4.0 * (std::pow(rc, -12) - std::pow(rc, -6));
}

TEST(Minimize, LennardJonesDimerReachesTheMinimumStoppedByFtol) {
  for (const double r0 : {1.5, 1.0}) {  // stretched and compressed
    Scene sc = lj_dimer(r0, "ftol = 1e-10");
    std::ostringstream log;
    prepare_scene(sc, log);
    ASSERT_TRUE(sc.minimized);
    const MinimizeReport& r = *sc.minimized;
    const double dist = (sc.state.x.col(1) - sc.state.x.col(0)).norm();
    SCOPED_TRACE(log.str());
    EXPECT_EQ(r.stopped_by, "ftol");
    EXPECT_LT(r.fnorm, 1e-10);
    EXPECT_NEAR(dist, std::pow(2.0, 1.0 / 6.0), 1e-9);
    const double e = lj_shifted_minimum();  // −0.98368310…
    EXPECT_NEAR(r.energy, e, 1e-6 * std::abs(e));
    EXPECT_NEAR(r.energy, e, 1e-12);
    EXPECT_NE(log.str().find("minimize: FIRE stopped by ftol after "), std::string::npos);
    EXPECT_NE(log.str().find("largest force |f|max = "), std::string::npos);
  }
}

TEST(Minimize, MaxiterAndMaxevalAreReportedWhenTheyStopIt) {
  {
    Scene sc = lj_dimer(1.5, "ftol = 1e-10\nmaxiter = 5");
    std::ostringstream log;
    prepare_scene(sc, log);
    EXPECT_EQ(sc.minimized->stopped_by, "maxiter");
    EXPECT_EQ(sc.minimized->iterations, 5);
    EXPECT_NE(log.str().find("stopped by maxiter after 5 iterations"), std::string::npos) << log.str();
  }
  {
    Scene sc = lj_dimer(1.5, "ftol = 1e-10\nmaxeval = 7");
    std::ostringstream log;
    prepare_scene(sc, log);
    EXPECT_EQ(sc.minimized->stopped_by, "maxeval");
    EXPECT_GE(sc.minimized->evaluations, 7);  // a half step back costs one more in an iteration
    EXPECT_LE(sc.minimized->evaluations, 8);
  }
}

// etol (LAMMPS): |E_k − E_{k−1}| < etol · ½(|E_k| + |E_{k−1}| + 1e-8), checked only more than
// delaystep (20) steps after the last uphill move; the last two energies must satisfy it.
TEST(Minimize, EtolStopsOnTheRelativeEnergyChange) {
  Scene sc = lj_dimer(1.5, "ftol = 0\netol = 1e-6");
  std::vector<double> energies{};
  const MinimizeReport r =
      minimize_fire(*sc.forces, nullptr, sc.state, sc.minimize, nullptr,
                    [&](const Eigen::Matrix3Xd&, double e) { energies.push_back(e); });
  ASSERT_EQ(r.stopped_by, "etol");
  ASSERT_GE(energies.size(), 2u);
  const double e1 = energies.back(), e0 = energies[energies.size() - 2];
  EXPECT_LT(std::abs(e1 - e0), 1e-6 * 0.5 * (std::abs(e1) + std::abs(e0) + 1e-8));
  EXPECT_EQ(static_cast<long>(energies.size()), r.iterations);
  EXPECT_NEAR(r.energy, lj_shifted_minimum(), 1e-3);
}

// A chain of 30 beads with stiff bonds held rigid (rattle), cosine bending and WCA, built with
// close contacts: after every FIRE move max |g| is within the SHAKE tolerance, the energy at the
// end is below the start, and the deck's velocities come back tangent (G v = 0).
TEST(Minimize, RigidBondsHoldAfterEveryMove) {
  const std::string deck_text = R"(
[types.bead]
mass = 1.0
[[build]]
style = "linear-chains"
beads = 30
bond_length = 0.97
bond_type = "b"
angle_type = "bend"
min_distance = 0.5
seed = 3
[velocities]
temperature = 1.0
[forces.bonds]
style = "stiff-harmonic"
epsilon = 1e-3
bond_types.b = { length = 0.97, alpha = 1.0 }
[forces.bending]
style = "cosine-angle"
angle_types.bend = { k = 2.0 }
[forces.wca]
style = "wca"
special_bonds = [0.0, 1.0]
[integrator]
method = "rattle"
h = 0.005
[run]
t_end = 0.01
[minimize]
ftol = 1e-8
maxiter = 5000
)";
  const Deck deck(Deck::Text{"chain.toml", deck_text}, {});
  Scene sc = load_scene(deck);
  ASSERT_TRUE(sc.minimize.rigid);
  const StiffBonds& stiff = *sc.forces->stiff_bonds();
  ConstraintToolbox toolbox(stiff.bonds, sc.state.inv_mass);
  double worst = 0.0;
  long moves = 0;
  const MinimizeReport r = minimize_fire(*sc.forces, &stiff, sc.state, sc.minimize, nullptr,
                                         [&](const Eigen::Matrix3Xd& x, double) {
                                           worst = std::max(worst, toolbox.max_violation(x));
                                           ++moves;
                                         });
  EXPECT_EQ(moves, r.iterations);
  EXPECT_LE(worst, sc.minimize.shake_tolerance);
  EXPECT_LE(r.max_violation, sc.minimize.shake_tolerance);
  EXPECT_LT(r.energy, r.initial_energy);
  EXPECT_EQ(r.stopped_by, "ftol") << describe(r);
  Eigen::Matrix3Xd v = sc.state.v;
  toolbox.project_velocity(sc.state.x, v);
  EXPECT_LT((v - sc.state.v).cwiseAbs().maxCoeff(), 1e-12);
  EXPECT_GT(sc.state.v.cwiseAbs().maxCoeff(), 0.1);  // the deck's thermal velocities, kept
}

// inputs/minimize_overlap.toml: two builders 0.2 σ apart, relaxed with the force cap, then a
// RATTLE run with no SHAKE failure; stderr and summary.json report the rule and the forces.
TEST(Minimize, OverlappingBuildersRelaxAndRun) {
  const auto dir = scratch_dir("minimize_overlap");
  const std::string deck = test::source_path("inputs/minimize_overlap.toml");
  const CliResult r = cli("run " + deck + " --no-progress -o " + (dir / "out").string(), "timeout 120 ");
  ASSERT_EQ(r.code, 0) << r.err;
  EXPECT_NE(r.err.find("minimize: FIRE stopped by ftol after "), std::string::npos) << r.err;
  // The overlap a deck without [minimize] is refused for (tests/bad_decks/builders_overlap.toml)
  // is named, and left to the minimiser.
  EXPECT_NE(r.err.find("are 0.2 apart at the start, closer than sigma/2 = 0.5"), std::string::npos) << r.err;
  EXPECT_NE(r.err.find("[minimize] relaxes them before the run"), std::string::npos) << r.err;
  const std::string summary = slurp(dir / "out" / "summary.json");
  EXPECT_NE(summary.find("\"minimize\": {\"style\": \"fire\", \"stopped_by\": \"ftol\""), std::string::npos)
      << summary;
  EXPECT_NE(summary.find("\"fnorm\": "), std::string::npos);
  std::filesystem::remove_all(dir);
}

}  // namespace
}  // namespace stiffmd
