// The dense and sparse back ends of the constraint toolbox's cluster solvers
// (integrators/constraint_solvers.hpp), for the clusters that are not open chains.
#include "integrators/constraint_solvers.hpp"

#include <Eigen/Cholesky>
#include <Eigen/LU>
#include <Eigen/SparseCholesky>
#include <Eigen/SparseCore>
#include <Eigen/SparseLU>
#include <algorithm>
#include <array>
#include <cmath>
#include <cstddef>
#include <memory>
#include <vector>

namespace stiffmd::constraint_detail {
namespace {

// Dense clusters of any shape (rings, stars, the pendulum when not a chain ...) above
// kMaxSmallBonds bonds. Every object is sized here, so compute() and solve() reuse the storage.
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

// Clusters of n ≤ kMaxSmallBonds bonds (water's triangle, X–H stars, short rings): DenseSolver's
// algorithms with n fixed at compile time, so that the loops unroll and nothing goes through
// Eigen's dynamic-size machinery (blocking dispatch, gemv calls, permutation objects), which
// costs several times the arithmetic at these sizes. Every operation is the one Eigen 3.4's
// dynamic LLT / PartialPivLU and triangular solves perform at n ≤ 16 (their unblocked paths), in
// the same order, so without FMA contraction (the default build) the factors and solutions are
// the general solver's bit for bit:
//   LLT, column k:  L_kk = √(K_kk − Σ_{j<k} L_kj²),  L_ik = (K_ik − Σ_{j<k} L_ij L_kj) / L_kk  (i > k),
//                   each Σ summed from j = 0 up; fails when the radicand is ≤ 0 (Eigen's info());
//   LU, column k:   pivot = the first row i ≥ k of largest |K_ik|, swapped into row k (unless the
//                   column is all zero), L_ik = K_ik / U_kk, then K_ij −= L_ik U_kj (i, j > k);
//   solves:         L y = b column-wise (y_i /= L_ii, then b_s −= y_i L_si for s > i), Lᵀ x = y
//                   row-wise (x_i = (y_i − Σ_{s>i} L_si x_s) / L_ii), U x = y column-wise from the
//                   bottom; a zero entry skips its division and update, as Eigen's does.
template <int N>
class SmallDenseSolver final : public ClusterSolver {
 public:
  explicit SmallDenseSolver(const std::vector<Coupling>& couplings) {
    for (const Coupling& c : couplings) slot_.push_back(c.row + N * c.col);
  }

  bool factorize(const Eigen::VectorXd& values, bool symmetric) override {
    double* a = a_.data();  // column-major: a[i + N j] = K(i, j)
    a_.fill(0.0);
    const int* slot = slot_.data();
    for (std::size_t k = 0, m = slot_.size(); k < m; ++k) a[slot[k]] += values[k];
    double scale = 0.0;
    for (int k = 0; k < N * N; ++k) scale = std::max(scale, std::abs(a[k]));  // the exact max: order-free
    symmetric_ = symmetric;
    return symmetric ? factorize_llt(a, scale) : factorize_lu(a, scale);
  }

  void solve(const Eigen::VectorXd& rhs, Eigen::VectorXd& sol) override {
    const double* a = a_.data();
    double* x = sol.data();
    if (symmetric_) {
      for (int i = 0; i < N; ++i) x[i] = rhs[i];
      for (int i = 0; i < N; ++i) {  // L y = b
        if (x[i] == 0.0) continue;
        x[i] /= a[i + N * i];
        for (int s = i + 1; s < N; ++s) x[s] -= x[i] * a[s + N * i];
      }
      for (int i = N - 1; i >= 0; --i) {  // Lᵀ x = y
        if (i + 1 < N) {
          double sum = a[(i + 1) + N * i] * x[i + 1];
          for (int s = i + 2; s < N; ++s) sum += a[s + N * i] * x[s];
          x[i] -= sum;
        }
        if (x[i] != 0.0) x[i] /= a[i + N * i];
      }
      return;
    }
    for (int i = 0; i < N; ++i) x[i] = rhs[i];
    for (int k = 0; k < N; ++k) std::swap(x[k], x[swap_[k]]);  // P b
    for (int i = 0; i < N; ++i) {                              // L y = P b, L unit lower
      if (x[i] == 0.0) continue;
      for (int s = i + 1; s < N; ++s) x[s] -= x[i] * a[s + N * i];
    }
    for (int i = N - 1; i >= 0; --i) {  // U x = y
      if (x[i] == 0.0) continue;
      x[i] /= a[i + N * i];
      for (int s = 0; s < i; ++s) x[s] -= x[i] * a[s + N * i];
    }
  }

 private:
  bool factorize_llt(double* a, double scale) {
    for (int k = 0; k < N; ++k) {
      double x = a[k + N * k];
      if (k > 0) {
        double norm = a[k] * a[k];
        for (int j = 1; j < k; ++j) norm += a[k + N * j] * a[k + N * j];
        x -= norm;
      }
      if (x <= 0.0) return false;  // not positive definite (NaN goes on, as in Eigen, to the pivot check)
      x = std::sqrt(x);
      a[k + N * k] = x;
      for (int i = k + 1; i < N; ++i) {
        if (k > 0) {
          double dot = a[i] * a[k];
          for (int j = 1; j < k; ++j) dot += a[i + N * j] * a[k + N * j];
          a[i + N * k] -= dot;
        }
        a[i + N * k] /= x;
      }
    }
    // The pivots of LLT are L_kk².
    Eigen::Matrix<double, N, 1> pivots;
    for (int k = 0; k < N; ++k) pivots[k] = a[k + N * k] * a[k + N * k];
    return pivots_regular(pivots, scale);
  }

  bool factorize_lu(double* a, double scale) {
    for (int k = 0; k < N; ++k) {
      int pivot = k;
      double biggest = std::abs(a[k + N * k]);
      for (int i = k + 1; i < N; ++i)
        if (std::abs(a[i + N * k]) > biggest) {
          biggest = std::abs(a[i + N * k]);
          pivot = i;
        }
      swap_[k] = pivot;
      if (biggest != 0.0) {
        if (pivot != k)
          for (int j = 0; j < N; ++j) std::swap(a[k + N * j], a[pivot + N * j]);
        for (int i = k + 1; i < N; ++i) a[i + N * k] /= a[k + N * k];
      }
      for (int j = k + 1; j < N; ++j)
        for (int i = k + 1; i < N; ++i) a[i + N * j] -= a[i + N * k] * a[k + N * j];
    }
    Eigen::Matrix<double, N, 1> pivots;
    for (int k = 0; k < N; ++k) pivots[k] = a[k + N * k];
    return pivots_regular(pivots, scale);
  }

  std::array<double, N * N> a_{};  // K, then its factors (L below and on the diagonal, or L\U)
  std::array<int, N> swap_{};      // LU: row k was swapped with row swap_[k] ≥ k
  std::vector<int> slot_;          // index into a_ for each coupling
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
  switch (n) {
    case 1:
      return std::make_unique<SmallDenseSolver<1>>(couplings);
    case 2:
      return std::make_unique<SmallDenseSolver<2>>(couplings);
    case 3:
      return std::make_unique<SmallDenseSolver<3>>(couplings);
    case 4:
      return std::make_unique<SmallDenseSolver<4>>(couplings);
    default:
      return make_general_dense_solver(n, couplings);
  }
}

std::unique_ptr<ClusterSolver> make_general_dense_solver(int n, const std::vector<Coupling>& couplings) {
  return std::make_unique<DenseSolver>(n, couplings);
}

std::unique_ptr<ClusterSolver> make_sparse_solver(int n, const std::vector<Coupling>& couplings) {
  return std::make_unique<SparseSolver>(n, couplings);
}

}  // namespace stiffmd::constraint_detail
