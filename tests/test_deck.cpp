// Deck loading (docs/design.md §8): variables and expressions, --set overrides, strictness.
#include <gtest/gtest.h>

#include <cmath>
#include <filesystem>
#include <fstream>

#include "core/errors.hpp"
#include "test_support.hpp"

namespace stiffmd {
namespace {

namespace fs = std::filesystem;

// Writes a deck to a temporary file and returns its path.
std::string write_deck(const std::string& name, const std::string& text) {
  const fs::path p = fs::temp_directory_path() / ("stiffmd_deck_" + name + "_" + std::to_string(::getpid()) + ".toml");
  std::ofstream(p) << text;
  return p.string();
}

const char* kMinimal = R"(
[variables]
a = "2*b"        # refers to a variable defined later
b = 0.25
[types.bead]
mass = "4*b"
[[particles]]
position = [0, 0, "a + pi"]
velocity = ["-b", 0, 0]
[integrator]
method = "velocity-verlet"
h = "b/100"
[run]
t_end = 1
)";

TEST(Deck, VariablesAndExpressionsInNumericFields) {
  const Deck deck(write_deck("minimal", kMinimal), {});
  EXPECT_DOUBLE_EQ(deck.variables().at("a"), 0.5);
  const Scene sc = load_scene(deck);
  EXPECT_DOUBLE_EQ(sc.state.inv_mass[0], 1.0);
  EXPECT_DOUBLE_EQ(sc.state.x(2, 0), 0.5 + M_PI);
  EXPECT_DOUBLE_EQ(sc.state.v(0, 0), -0.25);
  EXPECT_DOUBLE_EQ(sc.integrator.h, 0.0025);
  EXPECT_EQ(sc.num_steps(), 400);
  EXPECT_EQ(sc.forces->terms().size(), 0u);  // the deck names no force term: none is built
  EXPECT_EQ(sc.types[0].element, "C");       // bead types get a valid element by default
}

TEST(Deck, SetOverridesVariablesValuesAndStrings) {
  const Scene sc = test::load("inputs/double_pendulum.toml",
                              {"variables.eps=1e-4", "integrator.method=impulse", "integrator.micro_dt=eps/100",
                               "integrator.h=0.01", "run.t_end=2", "particles.2.velocity=[0.5, 0, 0]"});
  EXPECT_DOUBLE_EQ(sc.state.x(1, 2), 5e-4);  // 5ε with the overridden ε
  EXPECT_EQ(sc.integrator.method, "impulse");
  EXPECT_EQ(sc.integrator.micro_steps, 10000);
  EXPECT_DOUBLE_EQ(sc.run.t_end, 2.0);
  EXPECT_DOUBLE_EQ(sc.state.v(0, 2), 0.5);
  ASSERT_NE(sc.forces->stiff_bonds(), nullptr);
  EXPECT_DOUBLE_EQ(sc.forces->stiff_bonds()->epsilon, 1e-4);
}

TEST(Deck, PendulumIsTheSeedExample) {
  const Scene sc = test::load("inputs/double_pendulum.toml");
  const double eps = 1e-3;
  EXPECT_EQ(sc.state.size(), 3);
  EXPECT_EQ(sc.state.inv_mass[0], 0.0);  // the pivot is fixed
  EXPECT_EQ(sc.state.inv_mass[1], 1.0);
  EXPECT_EQ(sc.state.inv_mass[2], 1.0);
  EXPECT_TRUE(sc.state.x.col(0).isZero());
  EXPECT_DOUBLE_EQ(sc.state.x(0, 1), std::sqrt(0.5));
  EXPECT_DOUBLE_EQ(sc.state.x(1, 1), -std::sqrt(0.5));
  EXPECT_DOUBLE_EQ(sc.state.x(0, 2), std::sqrt(2.0));
  EXPECT_DOUBLE_EQ(sc.state.x(1, 2), 5 * eps);
  EXPECT_TRUE(sc.state.v.isZero());
  EXPECT_DOUBLE_EQ(sc.run.t_end, 10.0);
  const StiffBonds* sb = sc.forces->stiff_bonds();
  ASSERT_NE(sb, nullptr);
  EXPECT_DOUBLE_EQ(sb->epsilon, eps);
  ASSERT_EQ(sb->bonds.size(), 2u);
  for (const auto& b : sb->bonds) {
    EXPECT_DOUBLE_EQ(b.length, 1.0);
    EXPECT_DOUBLE_EQ(b.alpha, 1.0);
  }
  // U = y1 + y2: the gravity term's energy at x(0).
  EXPECT_NEAR(sc.forces->energy(sc.state.x, Level::slow), -std::sqrt(0.5) + 5 * eps, 1e-15);
}

TEST(Deck, ErrorsNameTheFileLineAndKey) {
  const std::string path = write_deck("bad_mass", std::string(kMinimal) + "\n");
  try {
    const Deck deck(path, {"types.bead.mass=-2"});
    load_scene(deck);
    FAIL() << "no error";
  } catch (const InputError& e) {
    EXPECT_EQ(std::string(e.what()),
              "--set types.bead.mass: types.bead.mass: expected a mass > 0 (use fixed = true on a particle to pin it)");
  }
  std::string text = kMinimal;
  text.replace(text.find("h = \"b/100\""), 11, "h = \"b/0\"");
  try {
    const Deck deck(write_deck("bad_h", text), {});
    load_scene(deck);
    FAIL() << "no error";
  } catch (const InputError& e) {
    const std::string m = e.what();
    EXPECT_NE(m.find(".toml:12: integrator.h: expression \"b/0\" evaluates to inf"), std::string::npos) << m;
  }
}

// [parallel] balance: recut by default when the load is uneven (docs/parallel.md, "Load balance");
// a value that is not a mode, or a threshold below 1, refused at its key.
TEST(Deck, ParallelBalanceTakesAModeAndAThreshold) {
  const std::string path = write_deck("balance", std::string(kMinimal) + "\n");
  const Scene plain = load_scene(Deck(path, {}));
  EXPECT_EQ(plain.parallel.balance.when, BalanceSettings::When::dynamic);
  EXPECT_EQ(plain.parallel.balance.threshold, 1.1);
  const Scene start = load_scene(Deck(path, {"parallel.balance=\"start\"", "parallel.balance_threshold=1.25"}));
  EXPECT_EQ(start.parallel.balance.when, BalanceSettings::When::start);
  EXPECT_EQ(start.parallel.balance.threshold, 1.25);
  EXPECT_EQ(load_scene(Deck(path, {"parallel.balance=\"off\""})).parallel.balance.when, BalanceSettings::When::off);
  for (const auto& [set, key] : {std::pair{"parallel.balance=\"sometimes\"", "parallel.balance"},
                                 std::pair{"parallel.balance=1", "parallel.balance"},
                                 std::pair{"parallel.balance_threshold=0.9", "parallel.balance_threshold"}}) {
    try {
      load_scene(Deck(path, {set}));
      FAIL() << set << ": no error";
    } catch (const InputError& e) {
      EXPECT_NE(std::string(e.what()).find(std::string(key) + ": "), std::string::npos) << e.what();
    }
  }
}

// A per-pair override ([[forces.NAME.pair]]) inherits what it does not set from the term: a zero
// global epsilon stays zero when the override sets only sigma (it used to become 1).
TEST(Deck, PairOverrideInheritsTheTermsParameters) {
  for (const double eps : {0.0, 2.0}) {
    const std::string text = R"(
[types.A]
mass = 1
[types.B]
mass = 1
[[particles]]
type = "A"
position = [0, 0, 0]
[[particles]]
type = "B"
position = [1.1, 0, 0]
[forces.pairs]
style = "lj"
epsilon = )" + std::to_string(eps) +
                             R"(
sigma = 1.0
cutoff = 2.5
[[forces.pairs.pair]]
types = ["A", "B"]
sigma = 1.2
[integrator]
method = "velocity-verlet"
h = 0.01
[run]
t_end = 0.1
)";
    const Deck deck(write_deck("pair_override", text), {});
    const Scene sc = load_scene(deck);
    // 4ε[(σ/r)¹² − (σ/r)⁶] cut and shifted at rc, with ε the term's and σ the override's.
    const auto lj = [&](double r) { return 4 * eps * (std::pow(1.2 / r, 12) - std::pow(1.2 / r, 6)); };
    EXPECT_NEAR(sc.forces->energy(sc.state.x, Level::slow), lj(1.1) - lj(2.5), 1e-12) << "epsilon = " << eps;
  }
}

TEST(Deck, UnknownKeysListWhatIsExpected) {
  std::string text = std::string(kMinimal) + "[output]\nxyz_intervall = 0.1\n";
  try {
    const Deck deck(write_deck("typo", text), {});
    load_scene(deck);
    FAIL() << "no error";
  } catch (const InputError& e) {
    const std::string m = e.what();
    EXPECT_NE(m.find("output.xyz_intervall: unknown key; did you mean 'xyz_interval'? (expected one of:"),
              std::string::npos)
        << m;
    EXPECT_NE(m.find(", xyz_interval,"), std::string::npos) << m;  // asked for with has(): listed too
  }
}

// "Did you mean" looks among the keys the table takes. A key the deck file sets is not offered for
// another key of the file (both were written on purpose: a key of another style, copied), but it
// is for a key given with --set, which is how a set key is changed.
TEST(Deck, DidYouMeanOffersAKeyTheDeckSetsToASet) {
  const auto error = [](const std::string& deck, const std::vector<std::string>& set) {
    try {
      const Deck d(deck, set);
      load_scene(d);
    } catch (const InputError& e) {
      return std::string(e.what());
    }
    return std::string("no error");
  };
  const std::string trimers = test::source_path("inputs/nvt_trimers.toml");  // sets output.thermo_interval
  std::string m = error(trimers, {"output.thermo_intervall=1"});
  EXPECT_EQ(m.rfind("--set output.thermo_intervall: output.thermo_intervall: unknown key; did you mean "
                    "'thermo_interval'? (expected one of:",
                    0),
            0u)
      << m;
  m = error(trimers, {"output.xyz_intervall=1"});  // a key the deck does not set, as before
  EXPECT_NE(m.find("did you mean 'xyz_interval'?"), std::string::npos) << m;
  m = error(
      write_deck("typo_beside_key", std::string(kMinimal) + "[output]\nxyz_interval = 0.1\nxyz_intervall = 0.1\n"), {});
  EXPECT_NE(m.find("output.xyz_intervall: unknown key (expected one of:"), std::string::npos) << m;
}

// An error a --set causes names the --set, wherever the check that finds it stands: at a key whose
// expression uses an overridden variable, at a key checked against an overridden one (t_end
// against h), at a table that holds an overridden key, at a key that collides with an overridden
// one, or at the deck for a type an overridden builder key names.
TEST(Deck, AnErrorCausedByASetNamesTheSet) {
  const std::string trimers = test::source_path("inputs/nvt_trimers.toml");
  const auto error = [&](const std::vector<std::string>& set) {
    try {
      const Deck d(trimers, set);
      load_scene(d);
    } catch (const InputError& e) {
      return std::string(e.what());
    }
    return std::string("no error");
  };
  EXPECT_EQ(error({"variables.eps=0"}),
            trimers + ":40 (with --set variables.eps): forces.bonds.epsilon: expected a number > 0, got 0");
  EXPECT_EQ(error({"integrator.h=0.07"})
                .rfind(trimers + ":55 (with --set integrator.h): run.t_end: t_end = 100 is "
                                 "1428.57142857 macro steps of integrator.h = 0.07",
                       0),
            0u)
      << error({"integrator.h=0.07"});
  EXPECT_EQ(error({"output.xyz=thermo.csv"}),
            trimers +
                " (with --set output.xyz): output.thermo: \"thermo.csv\" is also output.xyz; expected a file "
                "of its own");
  EXPECT_EQ(error({"build.0.bond_type=c"}),
            trimers +
                ":1 (with --set build.0.bond_type): deck: bond type 'c' is not defined by any force term (add "
                "[forces.NAME.bond_types.c])");
  // A FENE bond stretched beyond an overridden R0 is refused at the term's bond_types, the table
  // that holds the override.
  const std::string fene = write_deck("fene_r0", R"([types.bead]
mass = 1.0
[[particles]]
position = [0, 0, 0]
[[particles]]
position = [1, 0, 0]
[[bonds]]
particles = [0, 1]
type = "b"
[forces.chain]
style = "fene"
bond_types.b = { K = 30.0, R0 = 1.5, epsilon = 1.0, sigma = 1.0 }
[integrator]
method = "velocity-verlet"
h = 0.001
[run]
t_end = 0.01
)");
  try {
    const Deck d(fene, {"forces.chain.bond_types.b.R0=0.5"});
    load_scene(d);
    FAIL() << "no error";
  } catch (const InputError& e) {
    EXPECT_EQ(std::string(e.what()).rfind(
                  fene + ":12 (with --set forces.chain.bond_types.b.R0): forces.chain.bond_types: ", 0),
              0u)
        << e.what();
  }
  // A variable of the file that refers to an overridden one is named through it.
  const std::string chained =
      write_deck("chained_variable", std::string(kMinimal) + "[forces.g]\nstyle = \"gravity\"\ng = [0, 0, \"a\"]\n");
  try {
    const Deck d(chained, {"variables.b=1e200"});
    load_scene(d);
    FAIL() << "no error";
  } catch (const InputError& e) {
    EXPECT_NE(std::string(e.what()).find("(with --set variables.b)"), std::string::npos) << e.what();
  }
}

}  // namespace
}  // namespace stiffmd
