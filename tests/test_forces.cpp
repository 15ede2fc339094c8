// Force terms against central finite differences of their own energy, and Newton's third
// law (docs/design.md §11.8a).
#include <gtest/gtest.h>

#include "engine/scene/whole_molecules.hpp"

#include <random>

#include "forcefields/force_field.hpp"
#include "forcefields/gravity.hpp"
#include "forcefields/stiff_harmonic_bond.hpp"

namespace stiffmd {
namespace {

// Max over all coordinates of |f − (−∂E/∂x)|, relative to max |f|.
double fd_mismatch(const ForceTerm& term, const Eigen::Matrix3Xd& x, const Box& box) {
  Eigen::Matrix3Xd f = Eigen::Matrix3Xd::Zero(3, x.cols()), scratch = f;
  term.add_forces(x, box, f);
  double worst = 0.0;
  const double d = 1e-6;
  for (int i = 0; i < x.cols(); ++i)
    for (int a = 0; a < 3; ++a) {
      Eigen::Matrix3Xd xp = x, xm = x;
      xp(a, i) += d;
      xm(a, i) -= d;
      const double fd = -(term.add_forces(xp, box, scratch) - term.add_forces(xm, box, scratch)) / (2 * d);
      worst = std::max(worst, std::abs(fd - f(a, i)));
    }
  return worst / std::max(1.0, f.cwiseAbs().maxCoeff());
}

Eigen::Matrix3Xd random_positions(int n, double spread, unsigned seed) {
  std::mt19937 rng(seed);
  std::uniform_real_distribution<double> u(-spread, spread);
  Eigen::Matrix3Xd x(3, n);
  for (int i = 0; i < n; ++i)
    for (int a = 0; a < 3; ++a) x(a, i) = u(rng);
  return x;
}

StiffBonds chain_bonds(int n, double eps) {
  StiffBonds sb;
  sb.epsilon = eps;
  for (int i = 0; i + 1 < n; ++i) sb.bonds.push_back({i, i + 1, 0.8 + 0.1 * i, 1.0 + 0.3 * i});
  return sb;
}

TEST(StiffHarmonicBond, ForceIsMinusGradientOfEnergy) {
  const StiffHarmonicBond term("b", Level::fast, chain_bonds(6, 0.1));
  EXPECT_LT(fd_mismatch(term, random_positions(6, 1.0, 1), Box{}), 1e-6);
}

// Positions reach a force term whole (core/state.hpp): a chain wrapped across the x face is made
// whole first, and then a translation of the whole chain by box vectors changes nothing.
TEST(StiffHarmonicBond, ForceIsMinusGradientAcrossPeriodicBoundary) {
  Box box;
  box.periodic = Eigen::Vector3i::Ones();
  box.lengths = Eigen::Vector3d(3.0, 3.5, 4.0);
  Eigen::Matrix3Xd x = random_positions(6, 1.0, 2);
  const Eigen::Matrix3Xd whole = x;
  x(0, 1) += 3.0;  // bonds 0–1 and 1–2 jump across the x boundary
  std::vector<std::pair<int, int>> pairs;
  for (int i = 0; i + 1 < 6; ++i) pairs.emplace_back(i, i + 1);
  ASSERT_FALSE(make_molecules_whole(x, pairs, box));
  EXPECT_LT((x - whole).cwiseAbs().maxCoeff(), 1e-14) << "particle 1 moved back by one box length";
  const StiffHarmonicBond term("b", Level::fast, chain_bonds(6, 0.1));
  EXPECT_LT(fd_mismatch(term, x, box), 1e-6);
  Eigen::Matrix3Xd f0 = Eigen::Matrix3Xd::Zero(3, 6), f1 = f0;
  const double e0 = term.add_forces(x, box, f0);
  x.row(0).array() += 3.0;
  x.row(2).array() -= 8.0;
  const double e1 = term.add_forces(x, box, f1);
  EXPECT_NEAR(e0, e1, 1e-9 * std::abs(e1));
  EXPECT_LT((f0 - f1).cwiseAbs().maxCoeff(), 1e-9);
}

TEST(StiffHarmonicBond, EnergyIsHalfAlphaOverEpsSquaredStretchSquared) {
  StiffBonds sb;
  sb.epsilon = 0.01;
  sb.bonds.push_back({0, 1, 1.0, 2.0});
  const StiffHarmonicBond term("b", Level::fast, sb);
  Eigen::Matrix3Xd x(3, 2);
  x << 0, 1.003, 0, 0, 0, 0;
  Eigen::Matrix3Xd f = Eigen::Matrix3Xd::Zero(3, 2);
  const double e = term.add_forces(x, Box{}, f);
  EXPECT_NEAR(e, 0.5 * (2.0 / 0.01) * (2.0 / 0.01) * 0.003 * 0.003, 1e-12);
  EXPECT_NEAR(f(0, 1), -(2.0 / 0.01) * (2.0 / 0.01) * 0.003, 1e-9);  // pulled back towards 0
}

TEST(StiffHarmonicBond, NewtonsThirdLaw) {
  const StiffHarmonicBond term("b", Level::fast, chain_bonds(8, 0.05));
  Eigen::Matrix3Xd f = Eigen::Matrix3Xd::Zero(3, 8);
  term.add_forces(random_positions(8, 1.5, 3), Box{}, f);
  EXPECT_LT(f.rowwise().sum().cwiseAbs().maxCoeff(), 1e-9 * f.cwiseAbs().maxCoeff());
}

TEST(StiffHarmonicBond, RejectsInvalidParameters) {
  StiffBonds sb = chain_bonds(3, 0.1);
  sb.epsilon = 0.0;
  EXPECT_THROW(StiffHarmonicBond("b", Level::fast, sb), std::invalid_argument);
  sb = chain_bonds(3, 0.1);
  sb.bonds[1].length = 0.0;
  EXPECT_THROW(StiffHarmonicBond("b", Level::fast, sb), std::invalid_argument);
  sb = chain_bonds(3, 0.1);
  sb.bonds[0].j = sb.bonds[0].i;
  EXPECT_THROW(StiffHarmonicBond("b", Level::fast, sb), std::invalid_argument);
}

TEST(Gravity, ForceIsMinusGradientOfEnergyAndFixedParticlesFeelNothing) {
  Eigen::VectorXd inv_mass(4);
  inv_mass << 0.0, 1.0, 0.5, 2.0;
  const Gravity term("g", Level::slow, Eigen::Vector3d(0.3, -1.0, 0.2), inv_mass);
  const Eigen::Matrix3Xd x = random_positions(4, 1.0, 4);
  EXPECT_LT(fd_mismatch(term, x, Box{}), 1e-8);
  Eigen::Matrix3Xd f = Eigen::Matrix3Xd::Zero(3, 4);
  const double e = term.add_forces(x, Box{}, f);
  EXPECT_EQ(f.col(0).norm(), 0.0);
  EXPECT_NEAR(f(1, 2), -2.0, 1e-14);  // m = 2
  double expected = 0.0;
  for (int i = 1; i < 4; ++i) expected -= (1.0 / inv_mass[i]) * Eigen::Vector3d(0.3, -1.0, 0.2).dot(x.col(i));
  EXPECT_NEAR(e, expected, 1e-12);
}

TEST(ForceField, LevelsSumToTotalAndAreCounted) {
  Eigen::VectorXd inv_mass = Eigen::VectorXd::Ones(5);
  ForceField ff(Box{}, 5);
  ff.add(std::make_unique<StiffHarmonicBond>("b", Level::fast, chain_bonds(5, 0.1)));
  ff.add(std::make_unique<Gravity>("g", Level::slow, Eigen::Vector3d(0, -1, 0), inv_mass));
  const Eigen::Matrix3Xd x = random_positions(5, 1.0, 5);
  Eigen::Matrix3Xd fast, slow, all;
  const double ef = ff.compute(x, {Level::fast}, fast);
  const double es = ff.compute(x, {Level::slow}, slow);
  const double ea = ff.compute(x, {Level::fast, Level::slow}, all);
  EXPECT_LT((fast + slow - all).cwiseAbs().maxCoeff(), 1e-12);
  EXPECT_NEAR(ef + es, ea, 1e-12);
  EXPECT_NEAR(ff.energy(x, Level::fast), ef, 1e-12);
  EXPECT_EQ(ff.evaluations(Level::fast), 2);
  EXPECT_EQ(ff.evaluations(Level::slow), 2);
  ASSERT_NE(ff.stiff_bonds(), nullptr);
  EXPECT_EQ(ff.stiff_bonds()->bonds.size(), 4u);
}

}  // namespace
}  // namespace stiffmd
