// The run loop's per-step path (engine/run/run.cpp): a step between outputs must leave the
// trajectory the integrator's alone, to the bit (against the hand-written velocity Verlet of
// tools/benchmarks/hand_pendulum.hpp, the floor BM_PendulumRunVsHandWritten measures the run path
// against); the output grids' due steps, found once per output as integers, must be exactly the
// steps at which the grids' own test of the step's time is true; a non-finite state must be found
// at the step it appears in, naming the particle.
#include <gtest/gtest.h>

#include <cmath>
#include <cstdint>
#include <limits>
#include <sstream>
#include <string>
#include <vector>

#include "core/errors.hpp"
#include "engine/io/writers.hpp"
#include "engine/run/run.hpp"
#include "integrators/primitives.hpp"
#include "test_support.hpp"
#include "tools/benchmarks/hand_pendulum.hpp"

namespace stiffmd {
namespace {

const std::vector<std::string> kVerlet = {"integrator.method=\"velocity-verlet\"", "integrator.h=1e-4"};

RunOptions no_files() {
  RunOptions options;  // no output directory, no screen, no progress bar
  options.handle_signals = false;
  return options;
}

// Velocity Verlet through Run (two step_to calls, as the CLI's one or the Python module's
// batches), with the thermo sample (and the monitor) on the deck's grid, every 100 steps, or at an
// interval longer than the run: the same bits as the hand-written loop after 2·10⁵ steps.
TEST(RunLoop, PendulumThroughTheRunEndsOnTheHandWrittenLoopsBits) {
  constexpr std::int64_t kSteps = 200000;
  for (const bool sampled : {false, true}) {
    SCOPED_TRACE(sampled ? "thermo every 100 steps" : "thermo at the start only");
    std::vector<std::string> sets = kVerlet;
    sets.push_back("run.steps=" + std::to_string(kSteps));
    if (!sampled) sets.push_back("output.thermo_interval=1e4");
    Scene sc = test::load("inputs/double_pendulum.toml", sets);
    HandPendulum hand(*sc.forces->stiff_bonds(), sc.state);
    std::ostringstream log;
    stiffmd::Run run(sc, no_files(), log);
    run.step_to(kSteps / 2 + 17);
    run.step_to(kSteps);
    for (std::int64_t k = 0; k < kSteps; ++k) hand.step(sc.integrator.h);
    ASSERT_EQ(sc.state.step, kSteps);
    EXPECT_EQ(sc.state.t, static_cast<double>(kSteps) * sc.integrator.h);
    for (int p = 0; p < 3; ++p)
      for (int a = 0; a < 3; ++a) {
        EXPECT_EQ(sc.state.x(a, p), hand.x(a, p)) << "x of particle " << p << ", axis " << a;
        EXPECT_EQ(sc.state.v(a, p), hand.v(a, p)) << "v of particle " << p << ", axis " << a;
      }
  }
}

// A step far beyond velocity Verlet's stability limit: the state turns non-finite at some step K
// (found by the hand-written loop, the same bits), and the run stops with exit 3's error naming
// step K — not a later one — and stands at step K.
TEST(RunLoop, ABlowUpIsReportedAtTheStepWhereTheStateTurnsNonFinite) {
  Scene sc = test::load("inputs/double_pendulum.toml", {"integrator.method=\"velocity-verlet\"", "integrator.h=0.01",
                                                        "run.steps=100000", "output.thermo_interval=1e4"});
  HandPendulum hand(*sc.forces->stiff_bonds(), sc.state);
  std::int64_t first = 0;
  for (std::int64_t k = 1; k <= 100000 && first == 0; ++k) {
    hand.step(sc.integrator.h);
    for (int p = 0; p < 3; ++p)
      for (int a = 0; a < 3; ++a)
        if (!std::isfinite(hand.x(a, p)) || !std::isfinite(hand.v(a, p))) first = k;
  }
  ASSERT_GT(first, 1) << "the hand-written loop did not blow up";
  std::ostringstream log;
  stiffmd::Run run(sc, no_files(), log);
  try {
    run.step_to(first + 1000);
    ADD_FAILURE() << "no NumericalError";
  } catch (const NumericalError& e) {
    EXPECT_NE(std::string(e.what()).find("step " + std::to_string(first) + " ("), std::string::npos) << e.what();
  }
  EXPECT_EQ(sc.state.step, first);
}

// A small system's check (one block, no threads): a NaN, +∞ or −∞ in any coordinate of x or v
// names the first particle with one, with its step and time; a finite state passes, −0 included.
TEST(RunLoop, FiniteCheckOfASmallStateNamesTheFirstBadParticle) {
  State s;
  s.x = Eigen::Matrix3Xd::Random(3, 5);
  s.v = Eigen::Matrix3Xd::Random(3, 5);
  s.v(2, 4) = -0.0;
  s.inv_mass = Eigen::VectorXd::Ones(5);
  s.step = 7;
  s.t = 0.25;
  EXPECT_NO_THROW(check_finite(s));
  const double bad_values[] = {std::nan(""), std::numeric_limits<double>::infinity(),
                               -std::numeric_limits<double>::infinity()};
  for (const double bad : bad_values)
    for (int p = 0; p < 5; ++p)
      for (int a = 0; a < 3; ++a)
        for (const bool in_v : {false, true}) {
          SCOPED_TRACE(testing::Message() << bad << " in " << (in_v ? "v" : "x") << "(" << a << ", " << p << ")");
          State t = s;
          (in_v ? t.v : t.x)(a, p) = bad;
          if (p < 4) t.x(0, 4) = std::nan("");  // a later one too
          try {
            check_finite(t);
            ADD_FAILURE() << "no NumericalError";
          } catch (const NumericalError& e) {
            EXPECT_NE(std::string(e.what()).find("particle " + std::to_string(p) + " at step 7 (t = 0.25)"),
                      std::string::npos)
                << e.what();
          }
        }
}

// The closing kick's check (kick_checking_finite, integrators/primitives.hpp): v gets the bits of
// kick; true for a finite state (−0 included); false for a NaN, +∞ or −∞ in any coordinate of x or
// of the kicked v; and for a finite state whose sum overflows it may say false (unchecked), which
// the run's own check then passes.
TEST(RunLoop, ClosingKickSaysFiniteOnlyForAFiniteState) {
  const Eigen::Index n = 5;
  Eigen::Matrix3Xd x = Eigen::Matrix3Xd::Random(3, n);
  x(2, 4) = -0.0;
  const Eigen::Matrix3Xd v = Eigen::Matrix3Xd::Random(3, n), f = Eigen::Matrix3Xd::Random(3, n);
  Eigen::VectorXd inv_mass = Eigen::VectorXd::Ones(n);
  inv_mass(1) = 0.0;
  Eigen::Matrix3Xd kicked = v, checked = v;
  kick(kicked, inv_mass, f, 0.01);
  EXPECT_TRUE(kick_checking_finite(checked, x, inv_mass, f, 0.01));
  EXPECT_EQ(checked, kicked);
  const double bad_values[] = {std::nan(""), std::numeric_limits<double>::infinity(),
                               -std::numeric_limits<double>::infinity()};
  for (const double bad : bad_values)
    for (Eigen::Index p = 0; p < n; ++p)
      for (int a = 0; a < 3; ++a)
        for (const bool in_v : {false, true}) {
          SCOPED_TRACE(testing::Message() << bad << " in " << (in_v ? "v" : "x") << "(" << a << ", " << p << ")");
          Eigen::Matrix3Xd xb = x, vb = v;
          (in_v ? vb : xb)(a, p) = bad;
          EXPECT_FALSE(kick_checking_finite(vb, xb, inv_mass, f, 0.01));
        }
  State big;
  big.x = Eigen::Matrix3Xd::Constant(3, n, 1e308);
  big.v = Eigen::Matrix3Xd::Zero(3, n);
  big.inv_mass = inv_mass;
  EXPECT_FALSE(kick_checking_finite(big.v, big.x, inv_mass, Eigen::Matrix3Xd::Zero(3, n), 0.01));
  EXPECT_NO_THROW(check_finite(big));
}

// The steps at which a grid is due, found ahead (IntervalSchedule::next_due_step), are exactly
// those at which its per-step test due(t_k) is true, t_k = t0 + (k − k0) h the run's times: over
// intervals that are and are not multiples of h, a restart's t0 and k0, and a grid served up to a
// time (a restart's cut).
TEST(RunLoop, NextDueStepsAreTheStepsTheGridIsDueAt) {
  struct Case {
    double interval, h, t0;
    std::int64_t k0, start;
    double served;  // served_until (negative: a fresh grid)
  };
  const Case cases[] = {
      {0.01, 1e-4, 0.0, 0, 0, -1.0},         {0.05, 0.015625, 0.0, 0, 0, -1.0},
      {0.1, 0.1, 0.0, 0, 0, -1.0},           {0.3, 0.1, 0.0, 0, 0, -1.0},
      {1e-3, 1e-2, 0.0, 0, 0, -1.0},         {0.7, 0.012, 0.0, 0, 0, -1.0},
      {100.0, 2.0, 0.0, 0, 0, -1.0},         {0.12, 0.012, 0.0, 0, 0, -1.0},
      {0.05, 0.003, 1.234, 411, 411, 1.234}, {1.0 / 3.0, 1.0 / 7.0, 2.0, 14, 14, 2.0 - 1.0 / 7.0},
      {1e4, 1e-4, 0.0, 0, 0, -1.0},
  };
  for (const Case& c : cases) {
    SCOPED_TRACE(testing::Message() << "interval " << c.interval << ", h " << c.h << ", t0 " << c.t0 << ", k0 "
                                    << c.k0);
    const auto time = [&](std::int64_t j) { return c.t0 + static_cast<double>(j - c.k0) * c.h; };
    IntervalSchedule every_step(c.interval), ahead(c.interval);
    if (c.served >= 0.0) {
      every_step.served_until(c.served);
      ahead.served_until(c.served);
    }
    std::int64_t next = ahead.next_due_step(c.start, c.h, time);
    int due_steps = 0;
    for (std::int64_t k = c.start + 1; k <= c.start + 20000; ++k) {
      const bool due = every_step.due(time(k));
      ASSERT_EQ(due, k == next) << "step " << k << ", next due step found " << next;
      if (due) {
        ++due_steps;
        EXPECT_TRUE(ahead.due(time(k)));
        next = ahead.next_due_step(k, c.h, time);
        EXPECT_GT(next, k);
      }
    }
    if (c.interval <= 20000 * c.h / 2) {
      EXPECT_GT(due_steps, 0);
    }
  }
}

}  // namespace
}  // namespace stiffmd
