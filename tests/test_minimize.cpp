// [minimize] (integrators/minimize.*), FIRE 2.0 and the line-search styles cg and sd: the
// Lennard-Jones dimer's minimum to 1e-6 relative, each stopping rule reported by name, rigid bonds
// exact after every move, the line searches never raising the energy, FIRE and CG at one minimum,
// and two overlapping builders relaxed and run through the CLI.
#include <gtest/gtest.h>

#include <cmath>
#include <filesystem>
#include <map>
#include <optional>
#include <sstream>
#include <string>
#include <vector>

#include "cli_support.hpp"
#include "engine/deck/deck.hpp"
#include "engine/scene/scene.hpp"
#include "forcefields/force_field.hpp"
#include "integrators/constraints.hpp"
#include "integrators/minimize.hpp"
#include "test_support.hpp"

namespace stiffmd {
namespace {

using test::cli;
using test::CliResult;
using test::scratch_dir;
using test::slurp;

// Two LJ beads (ε = σ = 1, cut at r_c = 2.5 and shifted) a distance r0 apart.
Scene lj_dimer(double r0, const std::string& minimize, const std::vector<std::string>& overrides = {}) {
  std::ostringstream d;
  d.precision(17);
  d << "[types.a]\nmass = 1.0\n[[particles]]\ntype = \"a\"\nposition = [0, 0, 0]\n"
    << "[[particles]]\ntype = \"a\"\nposition = [" << r0 << ", 0, 0]\n"
    << "[forces.lj]\nstyle = \"lj\"\nepsilon = 1.0\nsigma = 1.0\ncutoff = 2.5\n"
    << "[integrator]\nmethod = \"velocity-verlet\"\nh = 0.005\n[run]\nt_end = 0.01\n"
    << "[minimize]\n"
    << minimize << "\n";
  const Deck deck(Deck::Text{"dimer.toml", d.str()}, overrides);
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
  const MinimizeReport r = minimize_fire(*sc.forces, nullptr, sc.state, sc.minimize, nullptr,
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
  const MinimizeReport r =
      minimize_fire(*sc.forces, &stiff, sc.state, sc.minimize, nullptr, [&](const Eigen::Matrix3Xd& x, double) {
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
  EXPECT_NE(summary.find("\"minimize\": {\"style\": \"fire\", \"stopped_by\": \"ftol\""), std::string::npos) << summary;
  EXPECT_NE(summary.find("\"fnorm\": "), std::string::npos);
  std::filesystem::remove_all(dir);
}

// ---------------------------------------------------------------------------------------------
// The line-search styles (cg, sd)

// The 30-bead chain of RigidBondsHoldAfterEveryMove (rigid bonds under rattle, cosine bending,
// WCA, close contacts from the builder), `minimize` the table's text.
Scene rigid_chain(const std::string& minimize) {
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
)" + minimize + "\n";
  const Deck deck(Deck::Text{"chain.toml", deck_text}, {});
  return load_scene(deck);
}

// E = ½k|x|² on every particle, its force −kx, or +kx when it lies (a force that is not −∇E).
class Tether final : public ForceTerm {
 public:
  Tether(double k, bool lie) : ForceTerm("tether", Level::slow), k_(k), lie_(lie) {}
  double add_forces(const Eigen::Matrix3Xd& x, const Box&, Eigen::Matrix3Xd& f) const override {
    f += (lie_ ? k_ : -k_) * x;
    return 0.5 * k_ * x.squaredNorm();
  }
  bool conserves_momentum() const override { return false; }
  std::string_view style() const override { return "test-tether"; }
  std::string describe() const override { return "½k|x|²"; }
  void define(ParameterRecord& record) const override { (void)record; }

 private:
  double k_;
  bool lie_;
};

// inputs/minimize_chain.toml loaded, not prepared (its [minimize] not yet run).
Scene chain(const std::vector<std::string>& overrides = {}) {
  return load_scene(Deck(test::source_path("inputs/minimize_chain.toml"), overrides));
}

struct Moves {
  std::vector<double> energies;
  double worst_violation = 0.0;
};

// Runs the scene's [minimize] with an observer recording every accepted move's energy (and max |g|).
MinimizeReport observed(Scene& sc, Moves& moves) {
  const StiffBonds* stiff = sc.minimize.rigid ? sc.forces->stiff_bonds() : nullptr;
  std::optional<ConstraintToolbox> toolbox;
  if (stiff) toolbox.emplace(stiff->bonds, sc.state.inv_mass);
  return minimize(*sc.forces, stiff, sc.state, sc.minimize, nullptr, [&](const Eigen::Matrix3Xd& x, double e) {
    moves.energies.push_back(e);
    if (toolbox) moves.worst_violation = std::max(moves.worst_violation, toolbox->max_violation(x));
  });
}

TEST(MinimizeLineSearch, LennardJonesDimerReachesTheMinimumStoppedByFtol) {
  for (const std::string style : {"cg", "sd"})
    for (const double r0 : {1.5, 1.0}) {
      Scene sc = lj_dimer(r0, "style = \"" + style + "\"\nftol = 1e-10");
      std::ostringstream log;
      prepare_scene(sc, log);
      SCOPED_TRACE(style + ": " + log.str());
      ASSERT_TRUE(sc.minimized);
      const MinimizeReport& r = *sc.minimized;
      EXPECT_EQ(r.stopped_by, "ftol");
      EXPECT_LT(r.fnorm, 1e-10);
      EXPECT_NEAR((sc.state.x.col(1) - sc.state.x.col(0)).norm(), std::pow(2.0, 1.0 / 6.0), 1e-9);
      EXPECT_NEAR(r.energy, lj_shifted_minimum(), 1e-12);
      EXPECT_NE(log.str().find("minimize: " + std::string(style == "cg" ? "CG" : "SD") + " stopped by ftol after "),
                std::string::npos);
    }
}

// FIRE, CG and SD from one start reach one minimum: inputs/minimize_chain.toml (four beads, harmonic
// bonds and angles, LJ between the ends: a unique minimum), with its bonds as springs and held
// rigid; and the 30-bead rigid chain (its minimum, the straight chain, has E = 0).
TEST(MinimizeLineSearch, ReachesFiresMinimum) {
  for (const std::string method : {"velocity-verlet", "rattle"}) {
    std::map<std::string, MinimizeReport> r;
    for (const std::string style : {"fire", "cg", "sd"}) {
      Scene sc = chain({"minimize.style=" + style, "integrator.method=" + method});
      ASSERT_EQ(sc.minimize.rigid, method == "rattle");
      r[style] = minimize(*sc.forces, sc.forces->stiff_bonds(), sc.state, sc.minimize);
      SCOPED_TRACE(method + ": " + describe(r[style]));
      EXPECT_EQ(r[style].stopped_by, "ftol");
      if (sc.minimize.rigid) {
        EXPECT_LE(r[style].max_violation, sc.minimize.shake_tolerance);
      }
    }
    EXPECT_LT(r["cg"].energy, -0.16);
    EXPECT_NEAR(r["cg"].energy, r["fire"].energy, 1e-10 * std::abs(r["fire"].energy)) << method;
    EXPECT_NEAR(r["sd"].energy, r["fire"].energy, 1e-10 * std::abs(r["fire"].energy)) << method;
    EXPECT_LT(r["cg"].iterations, r["fire"].iterations) << method;
  }
  std::map<std::string, double> energy;
  for (const std::string style : {"fire", "cg"}) {
    Scene sc = rigid_chain("style = \"" + style + "\"\nftol = 1e-8\nmaxiter = 5000");
    const MinimizeReport r = minimize(*sc.forces, sc.forces->stiff_bonds(), sc.state, sc.minimize);
    EXPECT_EQ(r.stopped_by, "ftol") << describe(r);
    energy[style] = r.energy;
  }
  EXPECT_NEAR(energy["cg"], energy["fire"], 1e-10);
}

// Under rigid bonds every accepted line-search move is on g = 0 to the SHAKE tolerance (the trial
// points too: SHAKE throws otherwise), the energy goes down, and the deck's velocities come back
// tangent in the particles' own metric.
TEST(MinimizeLineSearch, RigidBondsHoldAfterEveryMove) {
  Scene sc = rigid_chain("style = \"cg\"\nftol = 1e-8\nmaxiter = 5000");
  ASSERT_TRUE(sc.minimize.rigid);
  Moves moves;
  const MinimizeReport r = observed(sc, moves);
  EXPECT_EQ(r.stopped_by, "ftol") << describe(r);
  EXPECT_EQ(static_cast<long>(moves.energies.size()), r.iterations);
  EXPECT_LE(moves.worst_violation, sc.minimize.shake_tolerance);
  EXPECT_LE(r.max_violation, sc.minimize.shake_tolerance);
  EXPECT_NE(describe(r).find(", max |g| = "), std::string::npos);
  EXPECT_LT(r.energy, r.initial_energy);
  ConstraintToolbox toolbox(sc.forces->stiff_bonds()->bonds, sc.state.inv_mass);
  Eigen::Matrix3Xd v = sc.state.v;
  toolbox.project_velocity(sc.state.x, v);
  EXPECT_LT((v - sc.state.v).cwiseAbs().maxCoeff(), 1e-12);
  EXPECT_GT(sc.state.v.cwiseAbs().maxCoeff(), 0.1);
}

// An accepted line search never raises the energy beyond its round-off: the backtracking rule asks
// for a decrease, the secant step for E − E0 < 1e-8 (LAMMPS's EMACH), which near the minimum, where
// the energy changes by less than its last bits, lets E wobble by an ulp or two (measured: at most
// 3.3e-16 max(1, |E|), on a few of the last moves). On the chain, rigid and not, the dimer and the
// overlapping builders (soft start).
TEST(MinimizeLineSearch, EnergyNeverIncreasesAcrossAcceptedMoves) {
  std::vector<std::pair<std::string, Scene>> scenes;
  for (const std::string style : {"cg", "sd"}) {
    scenes.emplace_back(style + " chain", chain({"minimize.style=" + style}));
    scenes.emplace_back(style + " rigid chain", rigid_chain("style = \"" + style + "\"\nftol = 1e-8"));
    scenes.emplace_back(style + " dimer", lj_dimer(1.0, "style = \"" + style + "\"\nftol = 1e-10"));
    scenes.emplace_back(style + " overlap", load_scene(Deck(test::source_path("inputs/minimize_overlap.toml"),
                                                            {"minimize.style=" + style, "minimize.maxiter=3000"})));
  }
  for (auto& [name, sc] : scenes) {
    Moves moves;
    const MinimizeReport r = observed(sc, moves);
    SCOPED_TRACE(name + ": " + describe(r));
    ASSERT_FALSE(moves.energies.empty());
    double previous = r.initial_energy;
    long rises = 0;
    double worst_rise = 0.0;
    for (const double e : moves.energies) {
      EXPECT_LE(e - previous, 1e-14 * std::max(1.0, std::abs(e)));
      if (e > previous) ++rises;
      worst_rise = std::max(worst_rise, (e - previous) / std::max(1.0, std::abs(e)));
      previous = e;
    }
    RecordProperty(name + " rises", std::to_string(rises));
    RecordProperty(name + " worst rise", test::exact(worst_rise));
    EXPECT_LE(moves.worst_violation, sc.minimize.shake_tolerance);
  }
}

// The rules by name: etol, maxiter, maxeval; an ftol below round-off is not reached, and what
// stopped it is named instead: maxiter, or a line search's failure ("zero-alpha", "zero-quadratic",
// "zero-force": LAMMPS's "linesearch alpha is zero", "quadratic factors are zero", "forces are
// zero").
TEST(MinimizeLineSearch, EachStopIsReportedByItsRule) {
  {
    Scene sc = lj_dimer(1.5, "style = \"cg\"\nftol = 0\netol = 1e-6");
    Moves moves;
    const MinimizeReport r = observed(sc, moves);
    ASSERT_EQ(r.stopped_by, "etol");
    ASSERT_GE(moves.energies.size(), 2u);
    const double e1 = moves.energies.back(), e0 = moves.energies[moves.energies.size() - 2];
    EXPECT_LT(std::abs(e1 - e0), 1e-6 * 0.5 * (std::abs(e1) + std::abs(e0) + 1e-8));
  }
  {
    Scene sc = chain({"minimize.maxiter=5"});
    const MinimizeReport r = minimize(*sc.forces, nullptr, sc.state, sc.minimize);
    EXPECT_EQ(r.stopped_by, "maxiter");
    EXPECT_EQ(r.iterations, 5);
    EXPECT_NE(describe(r).find("CG stopped by maxiter after 5 iterations"), std::string::npos) << describe(r);
  }
  {
    Scene sc = chain({"minimize.maxeval=20"});
    const MinimizeReport r = minimize(*sc.forces, nullptr, sc.state, sc.minimize);
    EXPECT_EQ(r.stopped_by, "maxeval");
    EXPECT_GE(r.evaluations, 20);
    EXPECT_LT(r.evaluations, 40);  // one line search past the limit at most
  }
  {
    // Below round-off the secant step still moves (as LAMMPS: E − E0 < 1e-8), so an ftol that cannot
    // be reached runs to maxiter, and says so.
    Scene sc = chain({"minimize.ftol=1e-30", "minimize.maxiter=2000"});
    const MinimizeReport r = minimize(*sc.forces, nullptr, sc.state, sc.minimize);
    EXPECT_EQ(r.stopped_by, "maxiter");
    EXPECT_GT(r.fnorm, 1e-30);
    EXPECT_LT(r.fnorm, 1e-10);
  }
  {
    // A tether ½k|x|² whose force is −∇E (or, told to lie, +∇E: downhill by the force, uphill by
    // the energy). Lying: the line search backtracks until the expected decrease 0.4 α f·h is
    // below 1e-8 and stops, "zero-alpha". With k = 1e-20 the slope f·h ~ 1e-40 is below the
    // quadratic line search's 1e-28: "zero-quadratic". Either way back at the start.
    for (const bool lie : {true, false}) {
      ForceField forces(Box{}, 1);
      forces.add(std::make_unique<Tether>(lie ? 1.0 : 1e-20, lie));
      State s{Eigen::Matrix3Xd::Constant(3, 1, 0.5), Eigen::Matrix3Xd::Zero(3, 1), Eigen::VectorXd::Ones(1)};
      MinimizeSettings p;
      p.style = MinimizeStyle::cg;
      p.ftol = 0.0;
      const MinimizeReport r = minimize(forces, nullptr, s, p);
      EXPECT_EQ(r.stopped_by, lie ? "zero-alpha" : "zero-quadratic") << describe(r);
      EXPECT_EQ(r.iterations, 1);
      EXPECT_EQ(r.energy, r.initial_energy);
      EXPECT_EQ(s.x, Eigen::Matrix3Xd::Constant(3, 1, 0.5));
    }
  }
  {
    // Beyond the cutoff the force is 0 exactly: no direction to search.
    Scene sc = lj_dimer(3.0, "style = \"sd\"");
    const MinimizeReport r = minimize(*sc.forces, nullptr, sc.state, sc.minimize);
    EXPECT_EQ(r.stopped_by, "zero-force") << describe(r);
    EXPECT_EQ(r.iterations, 1);
    EXPECT_EQ(r.evaluations, 1);
  }
}

// inputs/minimize_overlap.toml with style = "cg": the soft start's capped force as the search
// direction moves the builders apart, CG converges, the run goes on; stderr and summary.json name
// the style and the rule.
TEST(MinimizeLineSearch, OverlappingBuildersRelaxAndRun) {
  const auto dir = scratch_dir("minimize_overlap_cg");
  const std::string deck = test::source_path("inputs/minimize_overlap.toml");
  const CliResult r =
      cli("run " + deck + " --no-progress --set minimize.style=cg -o " + (dir / "out").string(), "timeout 120 ");
  ASSERT_EQ(r.code, 0) << r.err;
  EXPECT_NE(r.err.find("minimize: CG stopped by ftol after "), std::string::npos) << r.err;
  EXPECT_NE(r.err.find(", max |g| = "), std::string::npos) << r.err;
  const std::string summary = slurp(dir / "out" / "summary.json");
  EXPECT_NE(summary.find("\"minimize\": {\"style\": \"cg\", \"stopped_by\": \"ftol\""), std::string::npos) << summary;
  std::filesystem::remove_all(dir);
}

}  // namespace
}  // namespace stiffmd
