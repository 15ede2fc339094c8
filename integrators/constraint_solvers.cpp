// The dense and sparse back ends of the constraint toolbox's cluster solvers
// (integrators/constraint_solvers.hpp), for the clusters that are not open chains.
#include "integrators/constraint_solvers.hpp"

#include <Eigen/Cholesky>
#include <Eigen/LU>
#include <Eigen/SparseCholesky>
#include <Eigen/SparseCore>
#include <Eigen/SparseLU>
#include <algorithm>
#include <cstddef>
#include <memory>
#include <vector>

namespace stiffmd::constraint_detail {
namespace {

// Small clusters of any shape (rings, stars, the pendulum when not a chain ...). Every object
// is sized here, so compute() and solve() reuse the storage.
class DenseSolver final : public ClusterSolver {
 public:
  DenseSolver(int n, const std::vector<Coupling>& couplings) : k_(n, n), llt_(n), lu_(n), couplings_(couplings) {}

  bool factorize(const Eigen::VectorXd& values, bool symmetric) override {
    k_.setZero();
    for (size_t k = 0; k < couplings_.size(); ++k) k_(couplings_[k].row, couplings_[k].col) += values[k];
    const double scale = k_.cwiseAbs().maxCoeff();
    symmetric_ = symmetric;
    if (symmetric_) {
      llt_.compute(k_);
      // LLT pivots are L_ii²; a tiny one means S is singular even if LLT "succeeded".
      return llt_.info() == Eigen::Success && pivots_regular(llt_.matrixLLT().diagonal().cwiseAbs2(), scale);
    }
    lu_.compute(k_);
    return pivots_regular(lu_.matrixLU().diagonal(), scale);
  }

  void solve(const Eigen::VectorXd& rhs, Eigen::VectorXd& sol) override {
    if (symmetric_) {
      sol = rhs;
      llt_.solveInPlace(sol);
    } else {
      sol = lu_.solve(rhs);  // into a distinct vector: in-place would allocate a permutation mask
    }
  }

 private:
  Eigen::MatrixXd k_;
  Eigen::LLT<Eigen::MatrixXd> llt_;
  Eigen::PartialPivLU<Eigen::MatrixXd> lu_;
  std::vector<Coupling> couplings_;
  bool symmetric_ = true;
};

// Large clusters that are not chains (big rings, branched polymers): fill-reducing sparse
// factorizations with the symbolic analysis done once. These may allocate inside factorize().
class SparseSolver final : public ClusterSolver {
 public:
  SparseSolver(int n, const std::vector<Coupling>& couplings) : k_(n, n) {
    std::vector<Eigen::Triplet<double>> pattern;
    for (const Coupling& c : couplings) pattern.emplace_back(c.row, c.col, 1.0);
    k_.setFromTriplets(pattern.begin(), pattern.end());
    k_.makeCompressed();
    for (const Coupling& c : couplings) slot_.push_back(&k_.coeffRef(c.row, c.col) - k_.valuePtr());
    ldlt_.analyzePattern(k_);
    lu_.analyzePattern(k_);
  }

  bool factorize(const Eigen::VectorXd& values, bool symmetric) override {
    std::fill(k_.valuePtr(), k_.valuePtr() + k_.nonZeros(), 0.0);
    for (size_t k = 0; k < slot_.size(); ++k) k_.valuePtr()[slot_[k]] += values[k];
    const double scale = Eigen::Map<const Eigen::VectorXd>(k_.valuePtr(), k_.nonZeros()).cwiseAbs().maxCoeff();
    symmetric_ = symmetric;
    if (symmetric_) {
      ldlt_.factorize(k_);
      return ldlt_.info() == Eigen::Success && pivots_regular(ldlt_.vectorD(), scale);
    }
    lu_.factorize(k_);
    return lu_.info() == Eigen::Success;
  }

  void solve(const Eigen::VectorXd& rhs, Eigen::VectorXd& sol) override {
    if (symmetric_)
      sol = ldlt_.solve(rhs);
    else
      sol = lu_.solve(rhs);
  }

 private:
  Eigen::SparseMatrix<double> k_;
  Eigen::SimplicialLDLT<Eigen::SparseMatrix<double>> ldlt_;
  Eigen::SparseLU<Eigen::SparseMatrix<double>> lu_;
  std::vector<std::ptrdiff_t> slot_;  // index into k_'s values for each coupling
  bool symmetric_ = true;
};

}  // namespace

std::unique_ptr<ClusterSolver> make_dense_solver(int n, const std::vector<Coupling>& couplings) {
  return std::make_unique<DenseSolver>(n, couplings);
}

std::unique_ptr<ClusterSolver> make_sparse_solver(int n, const std::vector<Coupling>& couplings) {
  return std::make_unique<SparseSolver>(n, couplings);
}

}  // namespace stiffmd::constraint_detail
