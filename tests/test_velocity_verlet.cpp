// Velocity Verlet on the full stiff system (docs/design.md §11.8c): reversibility, measured order 2
// against a fine-step solution, bounded energy error with the h² scaling.
#include <gtest/gtest.h>

#include <cmath>

#include "engine/observe/observables.hpp"
#include "test_support.hpp"

namespace stiffmd {
namespace {

using test::advance;
using test::pendulum;

TEST(VelocityVerlet, IsTimeReversible) {
  Scene sc = pendulum(0.1, "velocity-verlet", 1e-3, 1.0);
  const Eigen::Matrix3Xd x0 = sc.state.x, v0 = sc.state.v;
  auto integ = make_integrator(sc.integrator, *sc.forces, sc.state.inv_mass);
  advance(sc, 1000, *integ);
  ASSERT_GT((sc.state.x - x0).norm(), 0.1);  // it really moved
  sc.state.v = -sc.state.v;
  integ->reset();  // forces are cached: v changed outside step(), x did not; reset anyway
  advance(sc, 1000, *integ);
  sc.state.v = -sc.state.v;
  EXPECT_LT((sc.state.x - x0).cwiseAbs().maxCoeff(), 1e-9);
  EXPECT_LT((sc.state.v - v0).cwiseAbs().maxCoeff(), 1e-7);
}

// Error at t = 1 against a fine-step solution; the pendulum at ε = 0.1 (fast period ~0.3).
double error_at_t1(double h, const Eigen::Matrix3Xd& reference) {
  Scene sc = pendulum(0.1, "velocity-verlet", h, 1.0);
  advance(sc, std::llround(1.0 / h));
  return (sc.state.x - reference).cwiseAbs().maxCoeff();
}

TEST(VelocityVerlet, ConvergesWithOrderTwo) {
  Scene ref = pendulum(0.1, "velocity-verlet", 1e-5, 1.0);
  advance(ref, 100000);
  const double e1 = error_at_t1(4e-3, ref.state.x);
  const double e2 = error_at_t1(2e-3, ref.state.x);
  const double e3 = error_at_t1(1e-3, ref.state.x);
  const double p12 = std::log2(e1 / e2), p23 = std::log2(e2 / e3);
  RecordProperty("order_4e-3_2e-3", std::to_string(p12));
  RecordProperty("order_2e-3_1e-3", std::to_string(p23));
  EXPECT_NEAR(p12, 2.0, 0.15);
  EXPECT_NEAR(p23, 2.0, 0.15);
}

// max |E(t) − E(0)| / |E(0)| over the first and the second half of t ∈ [0, 10], every step.
std::pair<double, double> relative_energy_error(double h) {
  Scene sc = pendulum(0.1, "velocity-verlet", h, 10.0);
  auto integ = make_integrator(sc.integrator, *sc.forces, sc.state.inv_mass);
  const double e0 = energies(sc.state, *sc.forces).total();
  const long n = std::lround(10.0 / h);
  double first = 0.0, second = 0.0;
  for (long k = 1; k <= n; ++k) {
    integ->step(sc.state, h);
    const double err = std::abs(energies(sc.state, *sc.forces).total() - e0) / std::abs(e0);
    (2 * k <= n ? first : second) = std::max(2 * k <= n ? first : second, err);
  }
  return {first, second};
}

TEST(VelocityVerlet, EnergyErrorIsBoundedWithoutDriftAndScalesLikeHSquared) {
  // h ω/ε ≈ 0.05 at h = 2e-3 (ω/ε ≈ 24): the relative energy error is O((hω/ε)²) ≈ 2e-3.
  const auto [first1, second1] = relative_energy_error(2e-3);
  const auto [first2, second2] = relative_energy_error(1e-3);
  EXPECT_LT(std::max(first1, second1), 1e-3);
  EXPECT_LT(second1, 2.0 * first1) << "energy error grows: drift";
  EXPECT_NEAR(std::log2(std::max(first1, second1) / std::max(first2, second2)), 2.0, 0.3);
}

}  // namespace
}  // namespace stiffmd
