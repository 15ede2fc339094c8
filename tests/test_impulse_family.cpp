// The seed paper's integrators on its experiment (Lubich & Weiss §2; docs/design.md §3, §7):
// projected and mollified impulse converge like h² + ε to the effective dynamics and keep the
// actions, the plain impulse method does not; the effective dynamics is the ε → 0 limit of
// the stiff system, and plain RATTLE is not.
#include <gtest/gtest.h>

#include <cmath>

#include "integrators/constraints.hpp"
#include "integrators/model_potential.hpp"
#include "integrators/rattle.hpp"
#include "test_support.hpp"

namespace stiffmd {
namespace {

using test::max_errors;
using test::pendulum;
using test::record;

std::vector<std::string> micro(const std::string& dt) {
  return {"integrator.micro_dt=" + dt};
}

TEST(ProjectedImpulse, IsTimeReversible) {
  Scene sc = pendulum(1e-2, "projected-impulse", 0.05, 1.0, micro("eps/50"));
  const Eigen::Matrix3Xd x0 = sc.state.x, v0 = sc.state.v;
  auto integ = make_integrator(sc.integrator, *sc.forces, sc.state.inv_mass);
  for (int k = 0; k < 40; ++k) integ->step(sc.state, 0.05);
  ASSERT_GT((sc.state.x - x0).norm(), 0.1);
  sc.state.v = -sc.state.v;
  for (int k = 0; k < 40; ++k) integ->step(sc.state, 0.05);
  sc.state.v = -sc.state.v;
  EXPECT_LT((sc.state.x - x0).cwiseAbs().maxCoeff(), 1e-9);
  EXPECT_LT((sc.state.v - v0).cwiseAbs().maxCoeff(), 1e-7);
}

// H̄ = ½vᵀMv + U(α(x)) + ε⁻²V(x), the Hamiltonian the mollified impulse method is a splitting
// of: max |H̄(t) − H̄(0)| over the first and second half of [0, 5] at ε = 1e-4.
// The micro steps (velocity Verlet, δ = ε/100) have an energy error of their own, ≈ 5e-4
// here, which floors the h² behaviour; h = 1/4 and 1/8 sit well above it. (At ε = 1e-3 the
// measured order is closer to 1.5 — see the issue note.)
std::pair<double, double> mollified_energy_error(double h) {
  const double t_end = 5.0;
  Scene sc = pendulum(1e-4, "mollified-impulse", h, t_end, micro("eps/100"));
  auto integ = make_integrator(sc.integrator, *sc.forces, sc.state.inv_mass);
  ConstraintToolbox toolbox(sc.forces->stiff_bonds()->bonds, sc.state.inv_mass);
  Eigen::Matrix3Xd X;
  auto modified_energy = [&]() {
    X = sc.state.x;
    toolbox.shake(sc.state.x, X);  // α(x)
    return sc.state.kinetic_energy() + sc.forces->energy(X, Level::slow) + sc.forces->energy(sc.state.x, Level::fast);
  };
  const double e0 = modified_energy();
  const long n = std::lround(t_end / h);
  double first = 0.0, second = 0.0;
  for (long k = 1; k <= n; ++k) {
    integ->step(sc.state, h);
    double& half = 2 * k <= n ? first : second;
    half = std::max(half, std::abs(modified_energy() - e0));
  }
  return {first, second};
}

TEST(MollifiedImpulse, ConservesItsModifiedEnergyToOrderHSquaredWithoutDrift) {
  const auto [first1, second1] = mollified_energy_error(1.0 / 4);
  const auto [first2, second2] = mollified_energy_error(1.0 / 8);
  const double e1 = std::max(first1, second1), e2 = std::max(first2, second2);
  RecordProperty("modified_energy_error", std::to_string(e1) + " " + std::to_string(e2));
  EXPECT_LT(e1, 0.05);
  EXPECT_LT(second1, 2.0 * first1) << "drift";
  EXPECT_LT(second2, 2.0 * first2) << "drift";
  EXPECT_GT(std::log2(e1 / e2), 1.7) << e1 << " " << e2;
}

// Errors of a method at macro step h over t ∈ [0, 2] against the effective dynamics at h/64.
struct Errors {
  double x, p;
  Eigen::VectorXd actions_change;
};

Errors errors_vs_effective(const std::string& method, double h, double eps) {
  Scene ref = pendulum(eps, "effective", h / 64, 2.0);
  const auto reference = record(ref, std::lround(2.0 / (h / 64)));
  Scene sc = pendulum(eps, method, h, 2.0, micro(method == "impulse" ? "eps/200" : "eps/100"));
  StiffModes modes(sc.forces->stiff_bonds()->bonds, sc.state.inv_mass, eps);
  Eigen::VectorXd i0(modes.num_modes()), i1(modes.num_modes());
  modes.actions(sc.state.x, sc.state.v, i0);
  const auto run = record(sc, std::lround(2.0 / h));
  modes.actions(sc.state.x, sc.state.v, i1);
  const auto [ex, ep] = max_errors(run, reference, 64);
  return {ex, ep, (i1 - i0).cwiseAbs()};
}

class ImpulseFamilyConvergence : public ::testing::TestWithParam<std::string> {};

TEST_P(ImpulseFamilyConvergence, ErrorsFallLikeHSquaredAboveTheEpsilonFloor) {
  const double eps = 1e-3;
  const Errors e1 = errors_vs_effective(GetParam(), 1.0, eps);
  const Errors e2 = errors_vs_effective(GetParam(), 0.5, eps);
  const Errors e3 = errors_vs_effective(GetParam(), 0.25, eps);
  const double sx12 = std::log2(e1.x / e2.x), sx23 = std::log2(e2.x / e3.x);
  const double sp12 = std::log2(e1.p / e2.p), sp23 = std::log2(e2.p / e3.p);
  RecordProperty("slope_x", std::to_string(sx12) + " " + std::to_string(sx23));
  RecordProperty("slope_p", std::to_string(sp12) + " " + std::to_string(sp23));
  EXPECT_GE(sx12, 1.8);
  EXPECT_GE(sx23, 1.8);
  EXPECT_GE(sp12, 1.8);
  EXPECT_GE(sp23, 1.8);
  EXPECT_GT(e3.x, 2 * eps) << "h = 1/4 must still be above the O(ε) floor for the slopes to mean h²";
}

TEST_P(ImpulseFamilyConvergence, ActionsStayWithinAFewEpsilon) {
  const double eps = 1e-3;
  const Errors e = errors_vs_effective(GetParam(), 0.5, eps);
  EXPECT_LT(e.actions_change.maxCoeff(), 3 * eps) << e.actions_change.transpose();
}

INSTANTIATE_TEST_SUITE_P(PendulumEps1e3, ImpulseFamilyConvergence,
                         ::testing::Values("projected-impulse", "mollified-impulse"));

TEST(Impulse, LosesTheActions) {
  const double eps = 1e-3;
  const Errors e = errors_vs_effective("impulse", 0.5, eps);
  EXPECT_GT(e.actions_change.maxCoeff(), 30 * eps) << e.actions_change.transpose();
}

// |x − x_VV| at t = 3 for the constrained methods against velocity Verlet on the full stiff
// system with δ = ε/400.
double difference_from_stiff(const std::string& method, double eps) {
  const double delta = eps / 400, h = 1e-3, t = 3.0;
  Scene full = pendulum(eps, "velocity-verlet", delta, t);
  test::advance(full, std::lround(t / delta));
  Scene sc = pendulum(eps, method, h, t);
  record(sc, std::lround(t / h), 1000);
  return (sc.state.x - full.state.x).cwiseAbs().maxCoeff();
}

TEST(Effective, IsTheEpsilonToZeroLimitAndRattleIsNot) {
  const double d2 = difference_from_stiff("effective", 1e-2);
  const double d3 = difference_from_stiff("effective", 1e-3);
  const double rattle = difference_from_stiff("rattle", 1e-3);
  RecordProperty("effective_vs_stiff", std::to_string(d2) + " " + std::to_string(d3));
  RecordProperty("rattle_vs_stiff", std::to_string(rattle));
  EXPECT_GT(d2 / d3, 5.0) << "O(ε): " << d2 << " at ε = 1e-2, " << d3 << " at ε = 1e-3";
  EXPECT_LT(d2 / d3, 20.0) << "O(ε): " << d2 << " at ε = 1e-2, " << d3 << " at ε = 1e-3";
  EXPECT_LT(d3, 5e-3);
  EXPECT_GT(rattle, 0.05) << "dropping the correction potential W must move the solution by O(1)";
  EXPECT_GT(rattle, 20 * d3);
}

TEST(Effective, ProjectsTheInitialDataAndReportsTheActions) {
  Scene sc = pendulum(1e-3, "effective", 0.01, 0.1);
  const auto tr = record(sc, 1);
  EXPECT_NE(tr.log.find("ACIV"), std::string::npos) << tr.log;
  EXPECT_NE(tr.log.find("actions I ="), std::string::npos) << tr.log;
  ConstraintToolbox toolbox(sc.forces->stiff_bonds()->bonds, sc.state.inv_mass);
  EXPECT_LT(toolbox.max_violation(tr.x[0]), 1e-11);
}

// A model potential that counts its evaluations: W = ½ c |x|² (any smooth W will do).
class CountingPotential final : public ModelPotential {
 public:
  explicit CountingPotential(int* calls) : calls_(calls) {}
  double force(const Eigen::Matrix3Xd& x, Eigen::Matrix3Xd& f) override {
    ++*calls_;
    f = -kC * x;
    return 0.5 * kC * x.squaredNorm();
  }
  static constexpr double kC = 0.1;

 private:
  int* calls_;
};

// The model potential (W of the effective dynamics, U_F of fixman) is evaluated once per step, by
// the closing force, and the thermo row reads that value at the state the step left; before the
// first step and after reset() it is computed afresh.
TEST(Rattle, TheThermoRowReusesTheStepsModelPotential) {
  Scene sc = pendulum(1e-3, "rattle", 0.01, 0.1);
  int calls = 0;
  Rattle r("effective", *sc.forces, ConstraintToolbox(sc.forces->stiff_bonds()->bonds, sc.state.inv_mass),
           std::make_unique<CountingPotential>(&calls));
  std::ostringstream log;
  r.prepare(sc.state, log);
  EXPECT_EQ(r.model_potential(sc.state.x), 0.5 * CountingPotential::kC * sc.state.x.squaredNorm());
  EXPECT_EQ(calls, 1);
  for (int k = 0; k < 3; ++k) r.step(sc.state, 0.01);
  EXPECT_EQ(calls, 1 + 1 + 3);  // the first step's opening force, then one closing force per step
  EXPECT_EQ(r.model_potential(sc.state.x), 0.5 * CountingPotential::kC * sc.state.x.squaredNorm());
  EXPECT_EQ(calls, 5) << "the thermo row must reuse the step's value";
  r.reset();
  r.model_potential(sc.state.x);
  EXPECT_EQ(calls, 6);
}

}  // namespace
}  // namespace stiffmd
