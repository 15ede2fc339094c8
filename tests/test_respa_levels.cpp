// N-level r-RESPA as data (docs/design.md §3): the deck's [[integrator.levels]], innermost
// first with LAMMPS's loop factors, become the stages of MultipleTimeStepping. One level is
// velocity Verlet, two named levels are today's impulse family, bit for bit; three levels are
// time-reversible and second order; the method's kick on every level slower than the stiff one
// keeps the actions, which the plain kick and a kick projected on the outermost level alone lose;
// a level's own kick (kick = "plain" under a mollified outermost level) is the one it applies;
// under Langevin the O steps of a macro step span h exactly once; a restart continues bit for bit.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <sstream>

#include "cli_support.hpp"
#include "engine/deck/deck.hpp"
#include "engine/run/checkpoint.hpp"
#include "engine/scene/scene.hpp"
#include "integrators/constraints.hpp"
#include "integrators/modes.hpp"
#include "integrators/multiple_time_stepping.hpp"
#include "test_support.hpp"

namespace stiffmd {
namespace {

// A free trimer on stiff bonds (ℓ = 1, ε), a harmonic bend (k = 5, θ₀ = 120°) and, slowest, a
// tether on bead 0 and gravity; bond vibrations thermalised at T = 0.5. `levels` is the text of
// the [integrator] table after method and h; links/bend/rest name each term's level.
struct Trimer {
  std::string method = "impulse";
  double eps = 1e-3, h = 0.1;
  std::string levels;  // [[integrator.levels]] rows, or micro_steps = n
  std::string links = "fast", bend = "slow", rest = "slow";
  std::string extra;  // more tables ([thermostat])
};

// kick_b, kick_a: the angles' and the pair level's `kick` key (none when empty).
std::string three_levels(int na, int nb, const std::string& kick_b = "", const std::string& kick_a = "") {
  const auto kick = [](const std::string& k) { return k.empty() ? std::string() : "kick = \"" + k + "\"\n"; };
  return "[[integrator.levels]]\nname = \"bonds\"\n[[integrator.levels]]\nname = \"angles\"\nsubsteps = " +
         std::to_string(nb) + "\n" + kick(kick_b) +
         "[[integrator.levels]]\nname = \"pair\"\nsubsteps = " + std::to_string(na) + "\n" + kick(kick_a);
}

Trimer three_level_trimer(const std::string& method, double eps, double h, int na, int nb,
                          const std::string& kick_b = "", const std::string& kick_a = "") {
  return {method, eps, h, three_levels(na, nb, kick_b, kick_a), "bonds", "angles", "pair", ""};
}

Scene load_trimer(const Trimer& t) {
  std::ostringstream d;
  d << "[types.bead]\nmass = 1.0\n"
    << "[[build]]\nstyle = \"linear-chains\"\ntype = \"bead\"\nchains = 1\nbeads = 3\nbond_length = 1.0\n"
    << "bond_type = \"link\"\nangle_type = \"bend\"\nmin_distance = 0.9\nseed = 7\n"
    << "[forces.links]\nstyle = \"stiff-harmonic\"\nlevel = \"" << t.links << "\"\nepsilon = " << test::exact(t.eps)
    << "\nbond_types.link = { length = 1.0, alpha = 1.0 }\n"
    << "[forces.bending]\nstyle = \"harmonic-angle\"\nlevel = \"" << t.bend
    << "\"\nangle_types.bend = { k = 5.0, theta0 = 120 }\n"
    << "[forces.anchor]\nstyle = \"harmonic-tether\"\nlevel = \"" << t.rest
    << "\"\nparticles = [0]\ncenter = [0, 0, 0]\nk = 1.0\n"
    << "[forces.gravity]\nstyle = \"gravity\"\nlevel = \"" << t.rest << "\"\ng = [0, 0, -1]\n"
    << "[prepare]\nproject = true\nvibrational_temperature = 0.5\n"
    << "[run]\nt_end = 10\n"
    << t.extra << "\n"
    << "[integrator]\nmethod = \"" << t.method << "\"\nh = " << test::exact(t.h) << "\n"
    << t.levels;
  const Deck deck(Deck::Text{"trimer.toml", d.str()}, {});
  Scene sc = load_scene(deck);
  std::ostringstream log;
  prepare_scene(sc, log);
  return sc;
}

// x and v after n macro steps of the scene's own integrator.
State run(Scene& sc, int n) {
  auto integ = make_integrator(sc.integrator, *sc.forces, sc.state.inv_mass);
  std::ostringstream log;
  integ->prepare(sc.state, log);
  for (int k = 0; k < n; ++k) {
    integ->step(sc.state, sc.integrator.h);
    ++sc.state.step;
  }
  return sc.state;
}

bool identical(const State& a, const State& b) {
  return (a.x.array() == b.x.array()).all() && (a.v.array() == b.v.array()).all();
}

TEST(RespaLevels, OneLevelIsVelocityVerletBitForBit) {
  Trimer vv{"velocity-verlet", 0.1, 2e-3, "", "fast", "slow", "slow", ""};
  Scene ref_scene = load_trimer(vv);
  const State ref = run(ref_scene, 200);
  for (const std::string method : {"impulse", "projected-impulse", "mollified-impulse"}) {
    Trimer one{method, 0.1, 2e-3, "[[integrator.levels]]\nname = \"all\"\n", "all", "all", "all", ""};
    Scene sc = load_trimer(one);
    EXPECT_TRUE(identical(run(sc, 200), ref)) << method;
  }
  // velocity Verlet on named levels steps them all together: their substeps do not apply.
  Scene sc = load_trimer(three_level_trimer("velocity-verlet", 0.1, 2e-3, 2, 5));
  EXPECT_TRUE(identical(run(sc, 200), ref));
}

class TwoLevels : public ::testing::TestWithParam<std::string> {};

// The same deck written the old way (level = "fast" / "slow", micro_steps) and the new way
// (two named levels, the outer one with substeps): the same trajectory to the last bit, also
// under Langevin (the O step in the middle of the micro steps).
TEST_P(TwoLevels, AreTheImpulseMethodBitForBit) {
  for (const std::string& thermostat :
       {std::string(), std::string("[thermostat]\nstyle = \"langevin\"\ntemperature = 0.3\ndamp = 0.5\nseed = 3\n")}) {
    Trimer old_way{GetParam(), 1e-3, 0.02, "micro_steps = 250\n", "fast", "slow", "slow", thermostat};
    Trimer new_way{
        GetParam(), 1e-3,
        0.02,       "[[integrator.levels]]\nname = \"bonds\"\n[[integrator.levels]]\nname = \"rest\"\nsubsteps = 250\n",
        "bonds",    "rest",
        "rest",     thermostat};
    Scene a = load_trimer(old_way), b = load_trimer(new_way);
    EXPECT_EQ(a.integrator.micro_steps, b.integrator.micro_steps);
    const Eigen::Matrix3Xd x0 = a.state.x;
    const State sa = run(a, 60), sb = run(b, 60);
    ASSERT_GT((sa.x - x0).norm(), 0.01);
    EXPECT_TRUE(identical(sa, sb)) << (thermostat.empty() ? "NVE" : "Langevin");
    EXPECT_EQ(a.forces->evaluations(a.forces->outermost()), b.forces->evaluations(b.forces->outermost()));
    EXPECT_EQ(a.forces->evaluations(a.forces->innermost()), b.forces->evaluations(b.forces->innermost()));
  }
}

INSTANTIATE_TEST_SUITE_P(ImpulseFamily, TwoLevels,
                         ::testing::Values("impulse", "projected-impulse", "mollified-impulse"),
                         test::method_test_name);

class ThreeLevels : public ::testing::TestWithParam<std::string> {};

// Forward 40 macro steps, flip the velocities, 40 back: the start again, to round-off.
TEST_P(ThreeLevels, AreTimeReversible) {
  Scene sc = load_trimer(three_level_trimer(GetParam(), 1e-2, 0.05, 5, 50));
  auto integ = make_integrator(sc.integrator, *sc.forces, sc.state.inv_mass);
  const Eigen::Matrix3Xd x0 = sc.state.x, v0 = sc.state.v;
  for (int k = 0; k < 40; ++k) integ->step(sc.state, 0.05);
  ASSERT_GT((sc.state.x - x0).norm(), 0.1);
  sc.state.v = -sc.state.v;
  for (int k = 0; k < 40; ++k) integ->step(sc.state, 0.05);
  sc.state.v = -sc.state.v;
  EXPECT_LT((sc.state.x - x0).cwiseAbs().maxCoeff(), 1e-10);
  EXPECT_LT((sc.state.v - v0).cwiseAbs().maxCoeff(), 1e-8);
}

// On a smooth system (ε = 0.1: the bonds' period 2πε/ω ≈ 0.4 is resolved by every level's
// step) the global error at t = 1 falls by 4 when h halves with the loop factors fixed: second
// order, like each of the nested Verlet splittings. The plain kick is a splitting of the full
// system, so its reference is velocity Verlet at δ = 1e-5 (measured errors 3.0e-3, 7.6e-4,
// 1.9e-4); the projected and mollified kicks change the equations (P(x)f, α′ᵀf(α)), so theirs is
// the same method at h/8 = 1.25e-3.
TEST_P(ThreeLevels, AreSecondOrder) {
  const double t_end = 1.0;
  const bool plain = GetParam() == "impulse";
  const double h_ref = plain ? 1e-5 : 1.25e-3;
  Scene ref_scene = load_trimer(plain ? Trimer{"velocity-verlet", 0.1, h_ref, "", "fast", "slow", "slow", ""}
                                      : three_level_trimer(GetParam(), 0.1, h_ref, 2, 4));
  const State ref = run(ref_scene, static_cast<int>(std::lround(t_end / h_ref)));
  std::vector<double> err;
  for (const double h : {0.04, 0.02, 0.01}) {
    Scene sc = load_trimer(three_level_trimer(GetParam(), 0.1, h, 2, 4));
    const State s = run(sc, static_cast<int>(std::lround(t_end / h)));
    err.push_back(std::max((s.x - ref.x).cwiseAbs().maxCoeff(), (s.v - ref.v).cwiseAbs().maxCoeff()));
  }
  RecordProperty("errors", std::to_string(err[0]) + " " + std::to_string(err[1]) + " " + std::to_string(err[2]));
  EXPECT_NEAR(std::log2(err[0] / err[1]), 2.0, 0.2) << err[0] << " " << err[1];
  EXPECT_NEAR(std::log2(err[1] / err[2]), 2.0, 0.2) << err[1] << " " << err[2];
  EXPECT_GT(err[2], 1e-9) << "above round-off, so the ratio means h²";
}

INSTANTIATE_TEST_SUITE_P(Methods, ThreeLevels, ::testing::Values("impulse", "projected-impulse", "mollified-impulse"),
                         test::method_test_name);

// max over the macro steps of |sort I(t) − sort I(0)|∞ (sorted: the two modes' labels follow the
// frequencies, not the modes, and the exact dynamics swaps them while keeping both actions).
double action_change(Scene& sc, Integrator& integ, int n) {
  StiffModes modes(sc.forces->stiff_bonds()->bonds, sc.state.inv_mass, sc.forces->stiff_bonds()->epsilon);
  Eigen::VectorXd i0(modes.num_modes()), i(modes.num_modes());
  modes.actions(sc.state.x, sc.state.v, i0);
  std::sort(i0.begin(), i0.end());
  double change = 0.0;
  for (int k = 0; k < n; ++k) {
    integ.step(sc.state, sc.integrator.h);
    modes.actions(sc.state.x, sc.state.v, i);
    std::sort(i.begin(), i.end());
    change = std::max(change, (i - i0).cwiseAbs().maxCoeff());
  }
  return change;
}

// ε = 1e-3, h = 0.1 (tether, gravity), the bend every 0.02, the bonds every 2e-5, t ∈ [0, 5]:
// actions I ≈ (0.15, 0.34). Velocity Verlet on the full system (δ = 2e-5) keeps them within 0.011
// (measured); the projected and mollified kicks on both slower levels within 0.008; the plain
// kick changes them by 0.76, and projecting the outermost kick alone (the bend's level kick =
// "plain": kicked plainly every 0.02, i.e. every ≈ 5 periods of the bonds) by 0.15, 20 times the
// rule's change. A level's kick may be plain only where its step resolves the stiff period.
TEST(RespaLevels, TheKickOnEverySlowerLevelKeepsTheActions) {
  const int n = 50, na = 5, nb = 1000;
  auto change_of = [&](const std::string& method, const std::string& kick_b) {
    Scene sc = load_trimer(three_level_trimer(method, 1e-3, 0.1, na, nb, kick_b));
    auto integ = make_integrator(sc.integrator, *sc.forces, sc.state.inv_mass);
    return action_change(sc, *integ, n);
  };
  const double projected = change_of("projected-impulse", ""), mollified = change_of("mollified-impulse", "");
  const double plain = change_of("impulse", "");
  const double outer_only = change_of("projected-impulse", "plain");
  RecordProperty("action_change", "projected " + std::to_string(projected) + " mollified " + std::to_string(mollified) +
                                      " plain " + std::to_string(plain) + " outermost-only " +
                                      std::to_string(outer_only));
  EXPECT_LT(projected, 0.015);
  EXPECT_LT(mollified, 0.015);
  EXPECT_GT(plain, 0.3);
  EXPECT_GT(outer_only, 0.1);
}

// A level whose kick names the method's own is the method's run to the last bit: the key changes
// nothing unless it changes the kick.
TEST(RespaLevels, ALevelKickOfTheMethodsOwnIsTheSameRun) {
  for (const auto& [method, kick] : {std::pair<std::string, std::string>{"impulse", "plain"},
                                     {"projected-impulse", "projected"},
                                     {"mollified-impulse", "mollified"}}) {
    Scene ref_scene = load_trimer(three_level_trimer(method, 1e-2, 0.05, 5, 50));
    const Eigen::Matrix3Xd x0 = ref_scene.state.x;
    const State ref = run(ref_scene, 20);
    ASSERT_GT((ref.x - x0).norm(), 0.01);
    for (const auto& [kick_b, kick_a] : {std::pair<std::string, std::string>{kick, ""}, {"", kick}, {kick, kick}}) {
      Scene sc = load_trimer(three_level_trimer(method, 1e-2, 0.05, 5, 50, kick_b, kick_a));
      EXPECT_TRUE(identical(run(sc, 20), ref)) << method << ": angles kick '" << kick_b << "', pair kick '" << kick_a;
    }
  }
}

// mollified-impulse with the angles' level kick = "plain": after each macro step the integrator's
// cached kick forces (the forces its next opening kicks apply, carried_state().columns, outermost
// stage first) are, at the current x, the outermost level's terms mollified alone,
// α′(x)ᵀ f_pair(α(x)), the angles' level's plain force f_angles(x), and the bonds' plain force;
// the pressure's constraint virial is the outermost kick's removed virial alone,
// −Σ x·(f_pair(α) − α′ᵀ f_pair(α)). Each differs from what the other kick would give.
TEST(RespaLevels, EachLevelKicksWithItsOwnKick) {
  Scene sc = load_trimer(three_level_trimer("mollified-impulse", 1e-2, 0.05, 5, 50, "plain"));
  auto integ = make_integrator(sc.integrator, *sc.forces, sc.state.inv_mass);
  ConstraintToolbox toolbox(sc.forces->stiff_bonds()->bonds, sc.state.inv_mass);
  const int n = sc.state.size();
  Eigen::Matrix3Xd X(3, n), f_at_X(3, n), mollified(3, n), plain_pair(3, n), plain_angles(3, n), bonds(3, n);
  Eigen::Matrix3Xd projected_angles(3, n);
  for (int step = 1; step <= 5; ++step) {
    integ->step(sc.state, sc.integrator.h);
    ++sc.state.step;
    const Eigen::Matrix3Xd& x = sc.state.x;
    toolbox.mollified_force(
        x,
        [&](const Eigen::Matrix3Xd& at, Eigen::Matrix3Xd& f) {
          sc.forces->compute(at, {Level{2}}, f);
          f_at_X = f;
        },
        X, mollified);
    sc.forces->compute(x, {Level{2}}, plain_pair);
    sc.forces->compute(x, {Level{1}}, plain_angles);
    sc.forces->compute(x, {Level{0}}, bonds);
    projected_angles = plain_angles;
    toolbox.project_force(x, projected_angles);
    const CarriedState c = integ->carried_state();
    ASSERT_EQ(c.columns.size(), 3u);
    EXPECT_TRUE((c.columns[0].array() == mollified.array()).all()) << "step " << step;
    EXPECT_TRUE((c.columns[1].array() == plain_angles.array()).all()) << "step " << step;
    EXPECT_TRUE((c.columns[2].array() == bonds.array()).all()) << "step " << step;
    // What the other kick would have applied differs: the test tells the kicks apart.
    EXPECT_GT((mollified - plain_pair).norm(), 1e-3 * plain_pair.norm());
    EXPECT_GT((projected_angles - plain_angles).norm(), 1e-3 * plain_angles.norm());
    const double removed = (x.array() * (f_at_X - mollified).array()).sum();
    EXPECT_NEAR(integ->constraint_virial(sc.state), -removed, 1e-12 * std::abs(removed));
    EXPECT_GT(std::abs(removed), 1e-8);
  }
}

// Free particles (zero forces on three levels) under Langevin friction at kT = 0: every O step
// multiplies v by e^{−γΔ}, so v(nh) = e^{−γnh} v(0) exactly when the O steps of a macro step
// (one per step of the middle level, in the middle of its run of innermost steps) span h once.
TEST(RespaLevels, LangevinOStepsSpanTheMacroStepOnce) {
  std::ostringstream d;
  d << "[types.a]\nmass = 2.0\n";
  for (int i = 0; i < 4; ++i) d << "[[particles]]\nposition = [" << i << ", 0, 0]\nvelocity = [1, " << i << ", -0.5]\n";
  d << "[forces.g0]\nstyle = \"gravity\"\nlevel = \"inner\"\ng = [0, 0, 0]\n"
    << "[forces.g1]\nstyle = \"gravity\"\nlevel = \"middle\"\ng = [0, 0, 0]\n"
    << "[forces.g2]\nstyle = \"gravity\"\nlevel = \"outer\"\ng = [0, 0, 0]\n"
    << "[thermostat]\nstyle = \"langevin\"\ntemperature = 0\nfriction = 0.7\nseed = 1\n"
    << "[run]\nt_end = 1\n"
    << "[integrator]\nmethod = \"impulse\"\nh = 0.1\n"
    << "[[integrator.levels]]\nname = \"inner\"\n[[integrator.levels]]\nname = \"middle\"\nsubsteps = 3\n"
    << "[[integrator.levels]]\nname = \"outer\"\nsubsteps = 4\n";
  const Deck deck(Deck::Text{"free.toml", d.str()}, {});
  Scene sc = load_scene(deck);
  const Eigen::Matrix3Xd v0 = sc.state.v;
  ASSERT_GT(v0.norm(), 1.0);
  run(sc, 10);
  const Eigen::Matrix3Xd expected = std::exp(-0.7 * 10 * 0.1) * v0;
  EXPECT_LT((sc.state.v - expected).cwiseAbs().maxCoeff(), 1e-13);
}

// `stiffmd check` prints the levels outermost first: each one's step, loop factor and terms.
TEST(RespaLevels, CheckPrintsTheLevelStructure) {
  const auto r = test::cli("check " + test::source_path("inputs/respa_chains.toml"));
  ASSERT_EQ(r.code, 0) << r.err;
  for (const char* line :
       {"levels:      3, innermost first in the deck; r-RESPA, outermost first, mollified-impulse:\n",
        "  pair: step 0.01, 2 steps of angles each, kick mollified; terms: excluded_volume\n",
        "  angles: step 0.005, 25 steps of bonds each, kick mollified; terms: bending\n",
        "  bonds: step 0.0002, kick plain; terms: bonds\n", "50 micro steps (micro_dt = 0.0002)"})
    EXPECT_NE(r.out.find(line), std::string::npos) << line << "\n" << r.out;
  // A level's own kick replaces the method's on that level alone.
  const std::string d =
      describe_settings(load_trimer(three_level_trimer("projected-impulse", 1e-2, 0.05, 5, 50, "plain")));
  for (const char* line : {"  pair: step 0.05, 5 steps of angles each, kick projected; terms: anchor gravity\n",
                           "  angles: step 0.01, 50 steps of bonds each, kick plain; terms: bending\n",
                           "  bonds: step 0.0002, kick plain; terms: links\n"})
    EXPECT_NE(d.find(line), std::string::npos) << line << "\n" << d;
}

// inputs/respa_chains.toml (three levels, mollified kicks, Langevin): 10 steps in one run and
// 5 + 5 across a restart end in the same state, cached kick forces and thermo file, bit for bit.
TEST(RespaLevels, ARestartContinuesBitForBit) {
  namespace fs = std::filesystem;
  const std::string deck = test::source_path("inputs/respa_chains.toml");
  const std::string common = " --no-progress --set prepare.relax_steps=100 --set output.thermo_interval=0.01";
  const fs::path d = test::scratch_dir("respa_restart");
  ASSERT_EQ(test::cli("run " + deck + " -o " + (d / "whole").string() + common + " --set run.t_end=0.1").code, 0);
  ASSERT_EQ(test::cli("run " + deck + " -o " + (d / "parts").string() + common + " --set run.t_end=0.05").code, 0);
  const auto r = test::cli("run " + deck + " -o " + (d / "parts").string() + common +
                           " --set run.t_end=0.1 --restart " + (d / "parts" / "checkpoint.bin").string());
  ASSERT_EQ(r.code, 0) << r.err;
  const Checkpoint a = read_checkpoint((d / "whole" / "checkpoint.bin").string());
  const Checkpoint b = read_checkpoint((d / "parts" / "checkpoint.bin").string());
  EXPECT_EQ(a.state.step, 10);
  EXPECT_EQ(a.state.step, b.state.step);
  EXPECT_TRUE((a.state.x.array() == b.state.x.array()).all()) << "positions differ";
  EXPECT_TRUE((a.state.v.array() == b.state.v.array()).all()) << "velocities differ";
  EXPECT_EQ(a.integrator_state, b.integrator_state);
  EXPECT_EQ(test::slurp(d / "whole" / "thermo.csv"), test::slurp(d / "parts" / "thermo.csv"));
  // Every level's force evaluations, counted across the restart as in one run: the first force,
  // then one per step of the level (10 pair steps of 2 angle steps of 25 bond steps).
  const std::string counts = "\"level_evaluations\": {\"bonds\": 501, \"angles\": 21, \"pair\": 11}";
  EXPECT_NE(test::slurp(d / "whole" / "summary.json").find(counts), std::string::npos);
  EXPECT_NE(test::slurp(d / "parts" / "summary.json").find(counts), std::string::npos);
  fs::remove_all(d);
}

// The bundled deck of the per-level kick (inputs/peptide_mts.toml, tools/mts_electrostatics.py
// --write-deck): three levels, PPPM alone on the outermost with the method's mollified kick, the
// bonded level plainly kicked, the stiff X–H bonds innermost; `check` prints each level's kick.
TEST(RespaLevels, ThePeptideDeckKicksOnlyThePppmLevelMollified) {
  const Scene sc = test::load("inputs/peptide_mts.toml");
  ASSERT_EQ(sc.integrator.method, "mollified-impulse");
  ASSERT_EQ(sc.integrator.levels.size(), 3u);
  EXPECT_FALSE(sc.integrator.levels[0].kick.has_value());
  EXPECT_EQ(sc.integrator.levels[1].kick, Kick::plain);
  EXPECT_FALSE(sc.integrator.levels[2].kick.has_value());
  for (const auto& term : sc.forces->terms()) {
    if (term->style() == "pppm") {
      EXPECT_EQ(term->level().index, 2);
    }
  }
  // Its stiff bonds are chosen by mass (masses = [1.008]): those of peptide.toml's bond types.
  const Scene rigid = test::load("inputs/peptide.toml");
  ASSERT_NE(sc.forces->stiff_bonds(), nullptr);
  EXPECT_EQ(sc.forces->stiff_bonds()->bonds.size(), rigid.forces->stiff_bonds()->bonds.size() - 640);  // no water angle
  const test::CliResult r = test::cli("check " + test::source_path("inputs/peptide_mts.toml"));
  ASSERT_EQ(r.code, 0) << r.err;
  EXPECT_NE(r.out.find("kick plain"), std::string::npos) << r.out;
  EXPECT_NE(r.out.find("kick mollified"), std::string::npos) << r.out;
}

}  // namespace
}  // namespace stiffmd
