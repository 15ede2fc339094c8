// The per-cluster linear solvers of the constraint toolbox (integrators/constraints.hpp): they
// factorize and solve with K(a, b) = G(a) M⁻¹ G(b)ᵀ on one connected cluster of stiff bonds, the
// matrix of every toolbox operation (S = K(x, x) of the projections, SHAKE's and the mollifier's
// Newton matrices J = K(y, x_ref) and Jᵀ = K(x, X)). Private to the toolbox's sources.
//
// Three back ends, chosen once per cluster when the toolbox is built (integrators/constraints.cpp):
//   open chains          S: twisted tridiagonal factorization without pivoting (SPD, ChainLdlt);
//                        J: tridiagonal LU with partial pivoting (LAPACK gttrf); O(bonds) each;
//   small other clusters dense LLT (S) / LU with partial pivoting (J), no heap traffic: fixed-size
//                        code up to kMaxSmallBonds bonds, Eigen's dynamic-size ones above;
//   large other clusters sparse SimplicialLDLT (S) / SparseLU (J), pattern analysed once
//                        (the dense and sparse ones in integrators/constraint_solvers.cpp).
#pragma once

#include <Eigen/Core>
#include <algorithm>
#include <cmath>
#include <cstddef>
#include <memory>
#include <stdexcept>
#include <utility>
#include <vector>

namespace stiffmd::constraint_detail {

// A pivot this small relative to the largest entry of K means G is (numerically) rank
// deficient on the cluster, e.g. a collinear triangle; the solve would return garbage.
constexpr double kSingularPivot = 1e-13;

// One term of K(a, b) = G(a) M⁻¹ G(b)ᵀ on a cluster:
//   K(row, col) += sign · m_p⁻¹ · u_row(a)·u_col(b),
// for each mobile particle p shared by local bonds row and col (row == col: the diagonal,
// S_bb = 1/m_i + 1/m_j). sign = ±1 from G's rows: +u_b at i, −u_b at j.
struct Coupling {
  int row;
  int col;
  int particle;
  double sign;
  int row_bond = 0;  // the bond indices of row and col (cluster order → bond list)
  int col_bond = 0;
};

// Factorizes and solves with K on one cluster. K is handed over entrywise in coupling order:
// K(couplings[k].row, couplings[k].col) += values[k].
class ClusterSolver {
 public:
  virtual ~ClusterSolver() = default;
  // symmetric promises K = S (SPD). Returns false when K is numerically singular.
  virtual bool factorize(const Eigen::VectorXd& values, bool symmetric) = 0;
  // sol = K⁻¹ rhs (sol and rhs pre-sized, distinct).
  virtual void solve(const Eigen::VectorXd& rhs, Eigen::VectorXd& sol) = 0;
};

// Templated on the expression so that checking the pivots never materializes a temporary.
template <typename Pivots>
bool pivots_regular(const Eigen::MatrixBase<Pivots>& pivots, double scale) {
  return pivots.allFinite() && pivots.cwiseAbs().minCoeff() > kSingularPivot * scale;
}

// Open chains in chain order: K is tridiagonal (bond k shares particles only with bonds k ± 1).
// S itself never needs a row swap (each Schur complement is ≥ the next sub-diagonal entry,
// 1/m_shared), but J far from the manifold (SHAKE from a distant start, the mollifier of a badly
// stretched state) does.
class TridiagonalSolver final : public ClusterSolver {
 public:
  TridiagonalSolver(int n, const std::vector<Coupling>& couplings)
      : n_(n), bands_(3 * n - 2), du2_(std::max(n - 2, 0)), inv_pivot_(n), swapped_(n) {
    for (const Coupling& c : couplings) slot_.push_back(slot_of(c));
  }

  bool factorize(const Eigen::VectorXd& values, bool /*symmetric*/) override {
    bands_.setZero();
    const int* slot = slot_.data();
    for (std::size_t k = 0, m = slot_.size(); k < m; ++k) bands_[slot[k]] += values[k];
    return factorize_bands();
  }

  // The three bands of K, to be filled by the caller before factorize_bands(): sub[k] =
  // K(k+1, k), diagonal[k] = K(k, k), super[k] = K(k, k+1).
  double* sub() { return bands_.data(); }
  double* diagonal() { return bands_.data() + n_ - 1; }
  double* super() { return bands_.data() + 2 * n_ - 1; }

  bool factorize_bands() {
    const double scale = bands_.cwiseAbs().maxCoeff();
    double* dl = sub();
    double* d = diagonal();
    double* du = super();
    du2_.setZero();
    // Gaussian elimination with partial pivoting; a row swap fills the second super-diagonal.
    for (int i = 0; i < n_ - 1; ++i) {
      swapped_[i] = std::abs(d[i]) < std::abs(dl[i]);
      if (!swapped_[i]) {
        if (d[i] != 0.0) {
          dl[i] /= d[i];
          d[i + 1] -= dl[i] * du[i];
        }
      } else {
        const double factor = d[i] / dl[i];
        d[i] = dl[i];
        dl[i] = factor;
        const double upper = du[i];
        du[i] = d[i + 1];
        d[i + 1] = upper - factor * d[i + 1];
        if (i < n_ - 2) {
          du2_[i] = du[i + 1];
          du[i + 1] = -factor * du[i + 1];
        }
      }
    }
    if (!pivots_regular(Eigen::Map<const Eigen::VectorXd>(d, n_), scale)) return false;
    inv_pivot_ = Eigen::Map<const Eigen::VectorXd>(d, n_).cwiseInverse();  // solve multiplies
    return true;
  }

  void solve(const Eigen::VectorXd& rhs, Eigen::VectorXd& sol) override {
    const double* dl = sub();
    const double* du = super();
    sol = rhs;
    for (int i = 0; i < n_ - 1; ++i) {  // L (with the row swaps)
      if (swapped_[i]) std::swap(sol[i], sol[i + 1]);
      sol[i + 1] -= dl[i] * sol[i];
    }
    for (int i = n_ - 1; i >= 0; --i) {  // U
      double s = sol[i];
      if (i + 1 < n_) s -= du[i] * sol[i + 1];
      if (i + 2 < n_) s -= du2_[i] * sol[i + 2];
      sol[i] = s * inv_pivot_[i];
    }
  }

 private:
  // bands_ = [sub (n−1) | diagonal (n) | super (n−1)], the LAPACK gttrf layout.
  int slot_of(const Coupling& c) const {
    if (c.col == c.row - 1) return c.col;
    if (c.col == c.row) return n_ - 1 + c.row;
    if (c.col == c.row + 1) return 2 * n_ - 1 + c.row;
    throw std::logic_error("chain cluster is not tridiagonal");
  }
  int n_;
  Eigen::VectorXd bands_;
  Eigen::VectorXd du2_;
  Eigen::VectorXd inv_pivot_;  // 1 / U's diagonal
  std::vector<char> swapped_;
  std::vector<int> slot_;  // index into bands_ for each coupling
};

// S = G M⁻¹ Gᵀ of an open chain, SPD and tridiagonal, without pivoting (no row swap is ever
// needed: each Schur complement exceeds the next sub-diagonal entry, see above), as a twisted
// factorization: L D Lᵀ from the first bond down to the middle p = n/2 and U D Uᵀ from the last
// bond up to it (Parlett & Dhillon, Linear Algebra Appl. 309 (2000) 121),
//   top     D_0 = S_00,          l_k = S_{k,k+1} / D_k,      D_{k+1} = S_{k+1,k+1} − l_k S_{k,k+1}  (k < p)
//   bottom  D_{n−1} = S_{n−1,n−1}, u_k = S_{k,k+1} / D_{k+1},  D_k = S_kk − u_k S_{k,k+1}          (k ≥ p)
//   twist   γ_p = D⁺_p + D⁻_p − S_pp.
// Each recurrence is a chain of dependent divisions (latency-bound, one at a time); the two are
// independent, so running them in one loop overlaps them, as it does the two halves of each sweep.
class ChainLdlt {
 public:
  explicit ChainLdlt(int n) : n_(n), p_(n / 2), diagonal_(n), off_(std::max(n - 1, 0)), inv_pivot_(n) {}

  // The bands of S, to be filled before factorize(): diagonal[k] = S_kk, off[k] = S_{k,k+1}.
  double* diagonal() { return diagonal_.data(); }
  double* off() { return off_.data(); }

  // In place (off[k] becomes l_k or u_k); false when a pivot is ≤ kSingularPivot × the largest
  // diagonal entry. D⁺ runs down from the top to the twist p, D⁻ up from the bottom, and
  // γ_p = D⁺_p + D⁻_p − d_p joins them (factorize_group, one chain).
  bool factorize() {
    ChainLdlt* self = this;
    bool regular = false;
    factorize_group<1>(&self, &regular);
    return regular;
  }

  // The band of Z = S⁻¹ from the factors, without a division: Z_pp = 1/γ_p, then outwards from
  // the twist by the recurrences of the top and bottom factorizations (Lᵀ Z = D⁻¹ L⁻¹ above it,
  // its mirror below): Z_{k,k+1} = −l_k Z_{k+1,k+1}, Z_kk = 1/D⁺_k + l_k² Z_{k+1,k+1} for k < p;
  // Z_{k−1,k} = −u_{k−1} Z_{k−1,k−1}, Z_kk = 1/D⁻_k + u_{k−1}² Z_{k−1,k−1} for k > p. z_diag has n
  // entries, z_off n − 1 (Z_{k,k+1}).
  // For K chains of one length in lockstep (each chain's recurrence is a dependent multiply–subtract
  // chain, as in factorize_group; each gets the operations it gets alone, K = 1).
  template <int K>
  static void inverse_band_group(const ChainLdlt* const* c, double* const* z_diag, double* const* z_off) {
    const int n = c[0]->n_, p = c[0]->p_;
    const double* m[K];
    const double* inv[K];
    for (int j = 0; j < K; ++j) {
      m[j] = c[j]->off_.data();
      inv[j] = c[j]->inv_pivot_.data();
      z_diag[j][p] = inv[j][p];
    }
    for (int k = p - 1; k >= 0; --k)
      for (int j = 0; j < K; ++j) {
        z_off[j][k] = -m[j][k] * z_diag[j][k + 1];
        z_diag[j][k] = inv[j][k] - m[j][k] * z_off[j][k];
      }
    for (int k = p + 1; k < n; ++k)
      for (int j = 0; j < K; ++j) {
        z_off[j][k - 1] = -m[j][k - 1] * z_diag[j][k - 1];
        z_diag[j][k] = inv[j][k] - m[j][k - 1] * z_off[j][k - 1];
      }
  }
  // 1/D⁺_k (k < p), 1/γ_p, 1/D⁻_k (k > p): det S = 1 / Π of these.
  const double* inverse_pivots() const { return inv_pivot_.data(); }
  int size() const { return n_; }

  // K chains of one length in lockstep: their recurrences interleaved, so that the dependent
  // multiply–subtract (and division) chains of different chains overlap — one chain's sweep is
  // latency-bound. Each chain gets exactly the operations of its own factorize() / solve(), in
  // the same order: the same bits. regular[j]: as factorize()'s return.
  template <int K>
  static void factorize_group(ChainLdlt* const* c, bool* regular) {
    const int n = c[0]->n_, p = c[0]->p_;
    const int top_steps = p, bottom_steps = n - 1 - p;
    const double* d[K];
    double* e[K];
    double* inv[K];
    double tiny[K], top[K], bottom[K];
    for (int j = 0; j < K; ++j) {
      d[j] = c[j]->diagonal_.data();
      e[j] = c[j]->off_.data();
      inv[j] = c[j]->inv_pivot_.data();
      tiny[j] = kSingularPivot * c[j]->diagonal_.cwiseAbs().maxCoeff();
      top[j] = d[j][0];
      bottom[j] = d[j][n - 1];
      regular[j] = true;
    }
    for (int t = 0; t < std::max(top_steps, bottom_steps); ++t) {
      if (t < top_steps)
        for (int j = 0; j < K; ++j) {
          regular[j] &= top[j] > tiny[j];
          inv[j][t] = 1.0 / top[j];
          const double l = e[j][t] * inv[j][t];
          top[j] = d[j][t + 1] - l * e[j][t];
          e[j][t] = l;
        }
      if (t < bottom_steps) {
        const int k = n - 2 - t;
        for (int j = 0; j < K; ++j) {
          regular[j] &= bottom[j] > tiny[j];
          inv[j][k + 1] = 1.0 / bottom[j];
          const double u = e[j][k] * inv[j][k + 1];
          bottom[j] = d[j][k] - u * e[j][k];
          e[j][k] = u;
        }
      }
    }
    for (int j = 0; j < K; ++j) {
      const double gamma = top[j] + bottom[j] - d[j][p];
      regular[j] &= gamma > tiny[j];  // false for NaN too
      inv[j][p] = 1.0 / gamma;
    }
  }

  template <int K>
  static void solve_group(const ChainLdlt* const* c, const double* const* rhs, double* const* sol) {
    const int n = c[0]->n_, p = c[0]->p_;
    const int top_steps = p, bottom_steps = n - 1 - p, steps = std::max(top_steps, bottom_steps);
    const double* m[K];
    const double* inv[K];
    double z[K], w[K], b_twist[K];
    for (int j = 0; j < K; ++j) {
      m[j] = c[j]->off_.data();
      inv[j] = c[j]->inv_pivot_.data();
      b_twist[j] = rhs[j][p];
      z[j] = rhs[j][0];
      w[j] = rhs[j][n - 1];
      sol[j][0] = z[j];
      sol[j][n - 1] = w[j];
    }
    for (int t = 0; t < steps; ++t) {
      if (t < top_steps)
        for (int j = 0; j < K; ++j) {
          z[j] = rhs[j][t + 1] - m[j][t] * z[j];
          sol[j][t + 1] = z[j];
        }
      if (t < bottom_steps) {
        const int k = n - 2 - t;
        for (int j = 0; j < K; ++j) {
          w[j] = rhs[j][k] - m[j][k] * w[j];
          sol[j][k] = w[j];
        }
      }
    }
    double up[K], down[K];
    for (int j = 0; j < K; ++j) {
      const double x_twist = (z[j] + w[j] - b_twist[j]) * inv[j][p];
      sol[j][p] = x_twist;
      up[j] = down[j] = x_twist;
    }
    for (int t = 0; t < steps; ++t) {
      if (t < top_steps) {
        const int k = p - 1 - t;
        for (int j = 0; j < K; ++j) {
          up[j] = sol[j][k] * inv[j][k] - m[j][k] * up[j];
          sol[j][k] = up[j];
        }
      }
      if (t < bottom_steps) {
        const int k = p + 1 + t;
        for (int j = 0; j < K; ++j) {
          down[j] = sol[j][k] * inv[j][k] - m[j][k - 1] * down[j];
          sol[j][k] = down[j];
        }
      }
    }
  }

  // sol = S⁻¹ rhs: L z = b from the top and U w = b from the bottom to the twist, then the back
  // substitution outwards from it (solve_group, one chain). sol must not alias rhs: with n odd the
  // top sweep writes sol[p] in the same round as the bottom sweep reads rhs[p] (every caller
  // passes the cluster's distinct rhs and sol).
  void solve(const double* rhs, double* sol) const {
    const ChainLdlt* self = this;
    solve_group<1>(&self, &rhs, &sol);
  }

 private:
  int n_;
  int p_;                      // the twist
  Eigen::VectorXd diagonal_;   // S_kk
  Eigen::VectorXd off_;        // S_{k,k+1}, then l_k (k < p) or u_k (k ≥ p)
  Eigen::VectorXd inv_pivot_;  // 1 / D⁺_k (k < p), 1 / γ_p, 1 / D⁻_k (k > p)
};

// The back ends of the clusters that are not open chains (integrators/constraint_solvers.cpp): n
// bonds, K's pattern given by the couplings.
// make_dense_solver: fixed-size code for n ≤ kMaxSmallBonds, else the general dense solver
// (Eigen's dynamic-size LLT / PartialPivLU), which the small one reproduces bit for bit.
constexpr int kMaxSmallBonds = 4;
std::unique_ptr<ClusterSolver> make_dense_solver(int n, const std::vector<Coupling>& couplings);
std::unique_ptr<ClusterSolver> make_general_dense_solver(int n, const std::vector<Coupling>& couplings);
std::unique_ptr<ClusterSolver> make_sparse_solver(int n, const std::vector<Coupling>& couplings);

}  // namespace stiffmd::constraint_detail
