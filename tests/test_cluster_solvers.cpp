// The per-cluster dense solvers of the constraint toolbox (integrators/constraint_solvers.hpp):
// the fixed-size solver of clusters of up to kMaxSmallBonds bonds against the general dense one
// (Eigen's dynamic-size LLT / PartialPivLU) on random K of every small size.
#include <gtest/gtest.h>

#include <Eigen/Dense>
#include <cmath>
#include <memory>
#include <random>
#include <vector>

#include "integrators/constraint_solvers.hpp"

namespace stiffmd::constraint_detail {
namespace {

// A dense n × n pattern, one coupling per entry, plus a second term on the diagonal (as the
// diagonal S_bb = 1/m_i + 1/m_j has), so that the assembly's sums are exercised too.
std::vector<Coupling> dense_pattern(int n) {
  std::vector<Coupling> couplings;
  for (int col = 0; col < n; ++col)
    for (int row = 0; row < n; ++row) couplings.push_back({row, col, 0, 1.0});
  for (int b = 0; b < n; ++b) couplings.push_back({b, b, 0, 1.0});
  return couplings;
}

// The coupling values that assemble K (the diagonal split into two terms).
Eigen::VectorXd values_of(const Eigen::MatrixXd& k) {
  const int n = static_cast<int>(k.rows());
  Eigen::VectorXd values(n * n + n);
  for (int col = 0; col < n; ++col)
    for (int row = 0; row < n; ++row) values[row + n * col] = row == col ? 0.25 * k(row, col) : k(row, col);
  for (int b = 0; b < n; ++b) values[n * n + b] = 0.75 * k(b, b);
  return values;
}

struct Solved {
  bool regular;
  Eigen::VectorXd sol;
};

Solved solve_with(ClusterSolver& solver, const Eigen::MatrixXd& k, bool symmetric, const Eigen::VectorXd& rhs) {
  Solved s{solver.factorize(values_of(k), symmetric), Eigen::VectorXd::Zero(rhs.size())};
  if (s.regular) solver.solve(rhs, s.sol);
  return s;
}

// Each size: random SPD K = A Aᵀ + n·1 (S) and random non-symmetric K with entries of both signs
// (J far from the manifold, so that partial pivoting swaps rows): the small solver's solution is
// the general one's to round-off, relative to its norm.
TEST(ClusterSolvers, SmallSolverMatchesTheGeneralDenseSolver) {
  std::mt19937_64 rng(20);
  std::uniform_real_distribution<double> uniform(-1.0, 1.0);
  for (int n = 1; n <= kMaxSmallBonds; ++n) {
    const std::vector<Coupling> pattern = dense_pattern(n);
    auto small = make_dense_solver(n, pattern);
    auto general = make_general_dense_solver(n, pattern);
    for (int trial = 0; trial < 200; ++trial) {
      const Eigen::MatrixXd a = Eigen::MatrixXd::NullaryExpr(n, n, [&] { return uniform(rng); });
      const Eigen::VectorXd rhs = Eigen::VectorXd::NullaryExpr(n, [&] { return uniform(rng); });
      const bool symmetric = trial % 2 == 0;
      const Eigen::MatrixXd k =
          symmetric ? Eigen::MatrixXd(a * a.transpose() + n * Eigen::MatrixXd::Identity(n, n)) : a;
      const Solved expected = solve_with(*general, k, symmetric, rhs);
      const Solved got = solve_with(*small, k, symmetric, rhs);
      ASSERT_EQ(got.regular, expected.regular) << "n = " << n << ", trial " << trial;
      if (!expected.regular) continue;
      EXPECT_LE((got.sol - expected.sol).norm(), 1e-13 * expected.sol.norm()) << "n = " << n << ", trial " << trial;
      // The same operations in the same order: without FMA contraction, the same bits.
#if !defined(__FMA__)
      EXPECT_EQ(got.sol, expected.sol) << "n = " << n << ", trial " << trial;
#endif
    }
  }
}

// Singular K (a repeated row and column, as a collinear triangle's S has; a zero matrix; a NaN):
// the small solver reports them exactly as the general one does.
TEST(ClusterSolvers, SmallSolverFlagsASingularKAsTheGeneralOneDoes) {
  std::mt19937_64 rng(21);
  std::uniform_real_distribution<double> uniform(-1.0, 1.0);
  for (int n = 1; n <= kMaxSmallBonds; ++n) {
    const std::vector<Coupling> pattern = dense_pattern(n);
    auto small = make_dense_solver(n, pattern);
    auto general = make_general_dense_solver(n, pattern);
    const Eigen::VectorXd rhs = Eigen::VectorXd::Ones(n);
    for (const bool symmetric : {true, false}) {
      std::vector<Eigen::MatrixXd> singular{Eigen::MatrixXd::Zero(n, n)};
      Eigen::MatrixXd with_nan = Eigen::MatrixXd::Identity(n, n);
      with_nan(n - 1, n - 1) = std::nan("");
      singular.push_back(with_nan);
      if (n >= 2) {
        // Rank n − 1: the last bond's row of G is the first's.
        Eigen::MatrixXd g = Eigen::MatrixXd::NullaryExpr(n, 3 * n, [&] { return uniform(rng); });
        g.row(n - 1) = g.row(0);
        singular.push_back(
            symmetric ? Eigen::MatrixXd(g * g.transpose())
                      : Eigen::MatrixXd(g * Eigen::MatrixXd::NullaryExpr(3 * n, n, [&] { return uniform(rng); })));
      }
      for (const Eigen::MatrixXd& k : singular) {
        const Solved expected = solve_with(*general, k, symmetric, rhs);
        EXPECT_FALSE(expected.regular) << "n = " << n << "\n" << k;
        EXPECT_EQ(solve_with(*small, k, symmetric, rhs).regular, expected.regular) << "n = " << n << "\n" << k;
      }
    }
  }
}

}  // namespace
}  // namespace stiffmd::constraint_detail
