// Deck loading (docs/design.md §8): variables and expressions, --set overrides, strictness.
#include <gtest/gtest.h>

#include <cmath>
#include <filesystem>
#include <fstream>

#include "engine/core/errors.hpp"
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

}  // namespace
}  // namespace stiffmd
