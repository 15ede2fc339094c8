// The constraint toolbox (design.md §2; Lubich & Weiss §2.2–2.3).
//
// Every operation reduces to solves with K(a, b) = G(a) M⁻¹ G(b)ᵀ on one cluster:
//   S(x) = K(x, x)        (SPD)  force and velocity projections;
//   J    = K(y, x_ref)           Newton matrix of SHAKE / the mollifier α;
//   Jᵀ   = K(x, X)               step 2 of the mollified force.
// K has the sparsity of S, so one pattern per cluster (the "couplings") serves all three; a
// non-symmetric K is simply assembled with its arguments swapped instead of solving with Kᵀ.
//
// Three back ends, chosen once per cluster in the constructor:
//   open chains          S: twisted tridiagonal factorization without pivoting (SPD, ChainLdlt);
//                        J: tridiagonal LU with partial pivoting (LAPACK gttrf); O(bonds) each;
//   small other clusters dense LLT (S) / PartialPivLU (J), pre-sized, no heap traffic;
//   large other clusters sparse SimplicialLDLT (S) / SparseLU (J), pattern analysed once.
// Clusters are solved in parallel on the OpenMP threads (Impl::for_each_cluster).
//
// S(x) is measured and factored once per configuration (issue 14: a constrained BAOAB step asks
// for it up to five times at three positions). The toolbox keeps the last configuration it was
// handed, bit for bit, with G there and S's factors; an operation at the same x reuses them. What
// is kept is a function of x alone, so a run restarted without the cache computes the same bits.
// SHAKE near its reference iterates with that S(x_ref) (the chord, SHAKE's own quasi-Newton, no
// factorization) and falls back to full Newton on J when it contracts too slowly.
#include "integrators/constraints.hpp"

#include <Eigen/Cholesky>
#include <Eigen/LU>
#include <Eigen/SparseCholesky>
#include <Eigen/SparseCore>
#include <Eigen/SparseLU>
#include <algorithm>
#include <array>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <exception>
#include <limits>
#include <map>
#include <stdexcept>
#include <string>
#include <type_traits>
#include <utility>

#include "engine/core/errors.hpp"
#include "engine/core/parallel.hpp"

namespace stiffmd {
namespace {

// u_a · v_b for the columns a of u and b of v (3 × n arrays, column-major): the couplings of S and J.
inline double column_dot(const double* u, int a, const double* v, int b) {
  const double* p = u + 3 * a;
  const double* q = v + 3 * b;
  return p[0] * q[0] + p[1] * q[1] + p[2] * q[2];
}

// Clusters that are not open chains and have more bonds than this use sparse factorizations.
// Measured on rings (mollified force, -O2): dense wins below ~40 bonds, sparse above, and
// only the dense path is allocation-free.
constexpr int kMaxDenseBonds = 40;

// A pivot this small relative to the largest entry of K means G is (numerically) rank
// deficient on the cluster, e.g. a collinear triangle; the solve would return garbage.
constexpr double kSingularPivot = 1e-13;

// Open chains of one length whose solves run in lockstep (Impl::for_each_group): enough
// independent recurrences to hide the latency of each chain's multiply–subtract and division.
constexpr int kChainGroup = 4;

// Calls f(std::integral_constant<int, k>()) for a group of 1 ≤ k ≤ kChainGroup chains (the
// lockstep templates take the group size as a template argument); nothing for k = 0.
template <class F>
void for_group_size(int k, F&& f) {
  static_assert(kChainGroup == 4, "one case per group size");
  switch (k) {
    case 0:
      return;
    case 1:
      f(std::integral_constant<int, 1>());
      return;
    case 2:
      f(std::integral_constant<int, 2>());
      return;
    case 3:
      f(std::integral_constant<int, 3>());
      return;
    default:
      f(std::integral_constant<int, 4>());
      return;
  }
}

// SHAKE iterations allowed inside mollified_force, whose API has no max_iter.
constexpr int kMollifierMaxIter = 50;

// SHAKE starts with chord iterations on S(x_ref) when every |h_b(y)| ≤ this × ℓ_b (h ≈ g near the
// manifold, Impl::chain_gap; a drift of one step: |g| ~ (h|v_rel|)²/(2ℓ), 1e-4 ℓ typical on the
// stiff melt), and switches to Newton on J = G(y) M⁻¹ G(x_ref)ᵀ as soon as an iteration reduces
// the largest residual by less than kChordContraction. The chord's rate is about |G(y) − G(x_ref)|
// (the bonds' rotation since x_ref): ≈ 0.01 for a melt's step. The start bound was 1e-2 ℓ: a
// full drift of h = 0.02 (fixman's OBABO step) on data.chain puts the fastest pair of some chains
// past it ((0.02 · 8)²/2 ≈ 0.013), and those chains then took Newton from the start (a measure,
// a factorization of J and a solve per iteration): OBABO was 3 % faster than BAOAB per step with
// 1e-2 and is 13 % faster with 5e-2 (medians of 5 interleaved runs each). The chords still
// contract there (the contraction test guards the rest).
constexpr double kChordStart = 5e-2;
constexpr double kChordContraction = 0.25;

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

// Unit vectors and lengths of all bonds at one configuration: the rows of G are ±u_b.
struct BondFrame {
  Eigen::Matrix3Xd u;
  Eigen::VectorXd length;
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

// Open chains in chain order: K is tridiagonal (design.md §2). S itself never needs a row
// swap (each Schur complement is ≥ the next sub-diagonal entry, 1/m_shared), but J far from
// the manifold (SHAKE from a distant start, the mollifier of a badly stretched state) does.
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

std::vector<Coupling> couplings_of(const std::vector<int>& order, const std::vector<StiffBond>& bonds,
                                   const Eigen::VectorXd& inv_mass) {
  std::vector<Coupling> couplings;
  for (const auto& [particle, list] : bonds_at_mobile_particles(order, bonds, inv_mass))
    for (const auto& [row, row_sign] : list)
      for (const auto& [col, col_sign] : list)
        couplings.push_back({row, col, particle, row_sign * col_sign, order[row], order[col]});
  return couplings;
}

std::string format_g(double value) {
  char buffer[32];
  std::snprintf(buffer, sizeof buffer, "%.1e", value);
  return buffer;
}

// The shared rules (forcefields/stiff_bond.hpp): the toolbox needs every one of them, S being
// singular otherwise (a bond between fixed particles, a duplicated row, unrealisable lengths).
void validate(const std::vector<StiffBond>& bonds, const Eigen::VectorXd& inv_mass) {
  if (const auto problem = find_stiff_bond_problem(bonds, &inv_mass)) throw InputError(problem->what);
}

void require_columns(const Eigen::Matrix3Xd& a, Eigen::Index n, const char* what) {
  if (a.cols() != n)
    throw std::invalid_argument(std::string(what) + ": expected " + std::to_string(n) + " particles, got " +
                                std::to_string(a.cols()));
}

// Per-cluster data: the solve order of its bonds, the pattern of K, the solver and scratch.
struct ClusterData {
  std::vector<int> bonds;           // position in K → bond index (chain order for chains)
  std::vector<Coupling> couplings;  // the pattern of K, shared by S, J and Jᵀ
  std::unique_ptr<ClusterSolver> solver;
  Eigen::VectorXd values;  // K entries, one per coupling
  // Open chains assemble K's bands directly: K(k,k) = diag_w[k] u_k(a)·u_k(b) and
  // K(k,k+1), K(k+1,k) = off_w[k] u_k(a)·u_{k+1}(b), u_{k+1}(a)·u_k(b) (the couplings summed).
  TridiagonalSolver* chain = nullptr;  // = solver, for chains (J)
  std::unique_ptr<ChainLdlt> spd;      // chains: S
  Eigen::VectorXd diag_w, off_w;
  Eigen::VectorXd rhs, sol;
  Eigen::VectorXd lambda;           // SHAKE multipliers, accumulated over Newton steps
  Eigen::VectorXd half_inv_length;  // 1 / (2ℓ_b), local order: SHAKE's chord residual (Impl::chain_gap)
  // Open chains, for SHAKE's chord (Impl::chain_gap, Impl::chain_displace): the particles along
  // the chain, path[k] and path[k + 1] the ends of local bond k (n + 1 of them), their inverse
  // masses, ℓ_k², and σ_k u_k at the kept configuration (σ_k = +1 when bond k's i is path[k],
  // −1 when it is path[k + 1]: σ_k u_k points from path[k + 1] to path[k]).
  std::vector<int> path;
  Eigen::VectorXd path_inv_mass, length2, orientation;
  Eigen::Matrix3Xd e_kept;
  // What is known at the toolbox's kept configuration (Impl::keep): G there (in at_kept) and
  // S's factors (spd for chains, else solver until SHAKE's Newton factors J in it).
  bool frame_kept = false;
  bool s_factored = false;
  std::int64_t factorizations = 0;  // of S and of SHAKE's and the mollifier's J, for tests
  // Open chains, for Fixman's potential: the band of S⁻¹ at the kept configuration (z_diag is the
  // recurrence's own, z_off what chain_inverse_band hands out), formed from
  // the factors of S of factorization number band_at (current while s_factored and no
  // factorization came since: Impl::band_current).
  Eigen::VectorXd z_diag, z_off;
  std::int64_t band_at = -1;
};

// −h_k = (ℓ_k² − |d_k|²) / (2ℓ_k) of an open chain's bonds, fed the particles along its path in
// order (particle path[k] closes bond k − 1): SHAKE's chord residual (Impl::chain_gap,
// Impl::chain_displace). result(): max |h|, NaN when a length is not finite.
struct PathGap {
  const double* length2;
  const double* half_inv_length;
  double* minus_h;
  double px = 0.0, py = 0.0, pz = 0.0;  // the previous particle
  double worst = 0.0;
  bool finite = true;

  PathGap(const ClusterData& d, double* out)
      : length2(d.length2.data()), half_inv_length(d.half_inv_length.data()), minus_h(out) {}
  void operator()(int k, double x, double y, double z) {
    if (k > 0) {
      const double dx = px - x, dy = py - y, dz = pz - z;
      const double r2 = dx * dx + dy * dy + dz * dz;
      minus_h[k - 1] = (length2[k - 1] - r2) * half_inv_length[k - 1];
      worst = std::max(worst, std::abs(minus_h[k - 1]));
      finite &= r2 <= std::numeric_limits<double>::max();  // false for ∞ and NaN
    }
    px = x;
    py = y;
    pz = z;
  }
  double result() const { return finite ? worst : std::numeric_limits<double>::quiet_NaN(); }
};

// a += sign · M⁻¹Gᵀ coef (kMassWeighted) or sign · Gᵀ coef on an open chain, with G at the kept
// configuration, walking its path so that each particle is read and written once:
// a_p += s_p (σ_k u_k coef_k − σ_{k−1} u_{k−1} coef_{k−1}) for p = path[k] (no term past either
// end), s_p = sign · m_p⁻¹ or sign; then visit(k, a_p) with the particle's new value. If b is
// given, also b_p += b_sign (…) at the mobile particles (m_p⁻¹ > 0) in the same pass.
template <bool kMassWeighted, class Visit>
void walk_chain(const ClusterData& d, double* a, const double* coef, double sign, Visit&& visit, double* b = nullptr,
                double b_sign = 0.0) {
  const int n = static_cast<int>(d.bonds.size());
  const int* path = d.path.data();
  const double* w = d.path_inv_mass.data();
  const double* e = d.e_kept.data();
  double ex = 0.0, ey = 0.0, ez = 0.0;  // σ_{k−1} u_{k−1} coef_{k−1}
  for (int k = 0; k <= n; ++k) {
    double fx = 0.0, fy = 0.0, fz = 0.0;  // σ_k u_k coef_k
    if (k < n) {
      fx = e[3 * k] * coef[k];
      fy = e[3 * k + 1] * coef[k];
      fz = e[3 * k + 2] * coef[k];
    }
    double* q = a + 3 * path[k];
    const double s = kMassWeighted ? sign * w[k] : sign;
    q[0] += s * (fx - ex);
    q[1] += s * (fy - ey);
    q[2] += s * (fz - ez);
    visit(k, q[0], q[1], q[2]);
    if (b != nullptr && w[k] > 0.0) {  // not at a fixed particle, which clusters may share
      double* r = b + 3 * path[k];
      r[0] += b_sign * (fx - ex);
      r[1] += b_sign * (fy - ey);
      r[2] += b_sign * (fz - ez);
    }
    ex = fx;
    ey = fy;
    ez = fz;
  }
}

}  // namespace

struct ConstraintToolbox::Impl {
  Impl(std::vector<StiffBond> bonds_in, Eigen::VectorXd inv_mass_in);

  int num_particles() const { return static_cast<int>(inv_mass.size()); }

  // An open chain's −h_b(y) = (ℓ_b² − |d_b|²) / (2ℓ_b) into minus_h (local order), along its path
  // (contiguous particles on a melt read in order); max |h_b| returned, NaN when a length is not
  // finite. h = 0 is the manifold g = 0 and h_b = g_b (1 + g_b / (2ℓ_b)): SHAKE's chord iterates
  // on it without a square root or a division per bond.
  double chain_gap(int c, const Eigen::Matrix3Xd& y, double* minus_h) const;
  // An open chain's chord update and its new residual in one pass along the path: λ += δ,
  // y += M⁻¹G(x_ref)ᵀδ (each particle once: y_p += m_p⁻¹(σ_k u_k δ_k − σ_{k−1} u_{k−1} δ_{k−1}) for
  // p = path[k]), then −h(y) into minus_h as soon as both ends of a bond have moved; returns max |h|
  // (NaN when a length is not finite).
  double chain_displace(int c, Eigen::Matrix3Xd& y, const double* delta, double* minus_h);
  // minus_g (size of the cluster, local order), if given, receives −g_b(x); returns max_b |g_b(x)| then.
  double measure(int c, const Eigen::Matrix3Xd& x, BondFrame& frame, const char* what, int iteration = -1,
                 double* minus_g = nullptr);
  void factorize(int c, const BondFrame& rows, const BondFrame& cols, bool symmetric, const char* what);
  void set_path(ClusterData& d) const;  // open chains, at construction
  // Makes x the kept configuration (a copy), forgetting G and S of the last one unless x is it, bit
  // for bit. Serial; before the clusters' loop.
  void keep(const Eigen::Matrix3Xd& x);
  void copy_configuration(const Eigen::Matrix3Xd& x);  // kept_x = x, on the threads
  // G and the factors of S at the kept configuration on cluster c, computed if not known yet.
  void factor_kept_s(int c, const char* what);
  void chain_s_bands(int c, const char* what);
  void chain_s_factored(int c, bool regular, const char* what);
  void solve_chains(const int* cs, int k);
  // sol = S⁻¹ rhs at the kept configuration (after factor_kept_s).
  void solve_kept_s(int c);
  [[noreturn]] void singular(int c, bool symmetric, const char* what) const;
  Eigen::Vector3d inv_mass_difference(int b, const Eigen::Matrix3Xd& w) const;
  // mobile_only: nothing at fixed particles (a velocity projection's constraint force: their v stays).
  void add_constraint_force(int c, const BondFrame& frame, const Eigen::VectorXd& coef, double sign,
                            Eigen::Matrix3Xd& f, bool mobile_only = false) const;
  void add_constraint_displacement(int c, const BondFrame& frame, const Eigen::VectorXd& coef, double sign,
                                   Eigen::Matrix3Xd& y) const;

  template <bool kForce>
  void chain_project_rhs(int c, const Eigen::Matrix3Xd& a);
  // With force (velocity only): force −= rate · Gᵀμ at the mobile particles as well.
  template <bool kForce>
  void chain_project_update(int c, Eigen::Matrix3Xd& a, Eigen::Matrix3Xd* force = nullptr, double rate = 0.0);
  void project_force_cluster(int c, Eigen::Matrix3Xd& f);
  void project_velocity_cluster(int c, Eigen::Matrix3Xd& v, Eigen::Matrix3Xd* force, double rate);
  // SHAKE on one cluster, as a sequence of iterations (shake_group interleaves several).
  struct ShakeState {
    int c = 0;
    int iteration = 0;
    bool chord = false;  // chord steps on S(x_ref); false: Newton on J
    double previous = std::numeric_limits<double>::infinity();
    double chord_residual = 0.0;  // max |h| of the last chord update, with −h in rhs
    bool have_chord_residual = false;
  };
  enum class ShakeNext { converged, chord_solve, newton_done };
  void shake_start(ShakeState& st, int c);
  // One iteration up to the chord's solve: converged; chord_solve (−h or −g in rhs: solve S(x_ref)
  // into sol, then shake_chord_update); or a Newton step done. Throws NumericalError.
  ShakeNext shake_iterate(ShakeState& st, Eigen::Matrix3Xd& y, double tol, int max_iter);
  void shake_chord_update(ShakeState& st, Eigen::Matrix3Xd& y);
  void shake_cluster(int c, Eigen::Matrix3Xd& y, double tol, int max_iter);
  void mollify_cluster(int c, Eigen::Matrix3Xd& f);

  // Runs f(c) for every cluster c. Clusters are independent solves touching their own bonds'
  // scratch and their own particles, so they run on the OpenMP threads in contiguous blocks of
  // about equal bond count (parallel.hpp) — unless a fixed particle is shared by two clusters:
  // both add its reaction force, and that sum must stay in cluster order. A NumericalError is
  // rethrown for the first failing cluster in cluster order, as in a serial loop.
  template <class F>
  void for_each_cluster(F&& f) {
    const int nc = static_cast<int>(data.size());
    const int parts = clusters_share_particles ? 1 : std::min(threads_for(static_cast<std::int64_t>(bonds.size())), nc);
    if (parts <= 1) {
      run_as_one_part(serial_everywhere() ? 0 : static_cast<std::int64_t>(bonds.size()), [&] {
        for (int c = 0; c < nc; ++c) f(c);
      });
      return;
    }
    run_parts(parts, [&](int u) {
      const int end = u + 1 == parts ? nc : first_cluster_of_block(parts, u + 1);
      for (int c = first_cluster_of_block(parts, u); c < end; ++c) f(c);
    });
  }
  // One block at any thread count: run_as_one_part must not count it as parallel work.
  bool serial_everywhere() const { return clusters_share_particles || data.size() <= 1; }
  // The first cluster of block v of `parts` (blocks of about equal bond count).
  int first_cluster_of_block(int parts, int v) const {
    return static_cast<int>(
        std::lower_bound(bonds_before.begin(), bonds_before.end() - 1, block_begin(bonds_before.back(), parts, v)) -
        bonds_before.begin());
  }

  // Runs f(first, count) over the clusters in groups: up to kChainGroup consecutive open chains of
  // one length (their solves run in lockstep: ChainLdlt::solve_group), any other cluster alone; on
  // the threads in the blocks of for_each_cluster, groups never crossing a block. Each cluster gets
  // the operations it would get alone, so the result does not depend on the grouping (nor on the
  // thread count); a NumericalError is rethrown for the first failing cluster in cluster order.
  template <class F>
  void for_each_group(F&& f) {
    const int nc = static_cast<int>(data.size());
    auto run_block = [&](int begin, int end) {
      for (int c = begin; c < end;) {
        int count = 1;
        if (data[c].spd)
          while (count < kChainGroup && c + count < end && data[c + count].spd &&
                 data[c + count].bonds.size() == data[c].bonds.size())
            ++count;
        f(c, count);
        c += count;
      }
    };
    const int parts = clusters_share_particles ? 1 : std::min(threads_for(static_cast<std::int64_t>(bonds.size())), nc);
    if (parts <= 1) {
      run_as_one_part(serial_everywhere() ? 0 : static_cast<std::int64_t>(bonds.size()), [&] { run_block(0, nc); });
      return;
    }
    run_parts(parts, [&](int u) {
      run_block(first_cluster_of_block(parts, u), u + 1 == parts ? nc : first_cluster_of_block(parts, u + 1));
    });
  }
  // Factorizes S at the kept configuration for the chains first … first + count − 1 that are not
  // factored yet, in lockstep (factor_kept_s for each, with one factorization pass).
  void factor_kept_group(int first, int count, const char* what);
  // Factors S (factor_kept_group) and forms the band of S⁻¹ for the open chains first … first +
  // count − 1 (of one length) where it is not current, in lockstep.
  void chain_inverse_band_group(int first, int count);
  bool band_current(const ClusterData& d) const { return d.s_factored && d.band_at == d.factorizations; }
  // SHAKE on a group of clusters (shake_group below: their chord solves in lockstep).
  void shake_group(int first, int count, Eigen::Matrix3Xd& y, double tol, int max_iter);
  template <bool kForce>
  void project_group(int first, int count, Eigen::Matrix3Xd& a, Eigen::Matrix3Xd* force = nullptr, double rate = 0.0);

  std::vector<StiffBond> bonds;
  Eigen::VectorXd inv_mass;
  std::vector<ConstraintCluster> clusters;
  std::vector<ClusterData> data;           // parallel to clusters
  std::vector<std::int64_t> bonds_before;  // bonds in clusters 0 … c − 1; size clusters + 1
  bool clusters_share_particles = false;   // through a fixed particle
  Eigen::Matrix3Xd kept_x;                 // the kept configuration (x_ref of SHAKE, x of P(x))
  bool kept = false;
  BondFrame at_kept;           // G at kept_x, for the clusters with frame_kept
  BondFrame at_cur;            // G at y (or X = α(x))
  Eigen::Matrix3Xd curvature;  // per bond: λ_b A_b ((M⁻¹r)_i − (M⁻¹r)_j), mollified force step 4
};

ConstraintToolbox::Impl::Impl(std::vector<StiffBond> bonds_in, Eigen::VectorXd inv_mass_in)
    : bonds(std::move(bonds_in)), inv_mass(std::move(inv_mass_in)) {
  validate(bonds, inv_mass);
  clusters = find_clusters(bonds, inv_mass);
  const int m = static_cast<int>(bonds.size());
  at_kept = {Eigen::Matrix3Xd::Zero(3, m), Eigen::VectorXd::Zero(m)};
  at_cur = at_kept;
  curvature = Eigen::Matrix3Xd::Zero(3, m);
  for (const ConstraintCluster& cluster : clusters) {
    ClusterData d;
    // Open chains in path order, so that K is tridiagonal; any other cluster as found.
    ClusterPath path = cluster_path(cluster, bonds, inv_mass);
    const bool chain = path.shape == ClusterShape::chain;
    d.bonds = chain ? std::move(path.bonds) : cluster.bonds;
    d.couplings = couplings_of(d.bonds, bonds, inv_mass);
    const int n = static_cast<int>(d.bonds.size());
    if (chain) {
      auto tri = std::make_unique<TridiagonalSolver>(n, d.couplings);
      d.chain = tri.get();
      d.solver = std::move(tri);
      d.spd = std::make_unique<ChainLdlt>(n);
      d.z_diag = Eigen::VectorXd::Zero(n);
      d.z_off = Eigen::VectorXd::Zero(std::max(n - 1, 0));
      d.diag_w = Eigen::VectorXd::Zero(n);
      d.off_w = Eigen::VectorXd::Zero(std::max(n - 1, 0));
      for (const Coupling& cp : d.couplings) {
        if (cp.row == cp.col) d.diag_w[cp.row] += cp.sign * inv_mass[cp.particle];
        if (cp.col == cp.row + 1) d.off_w[cp.row] += cp.sign * inv_mass[cp.particle];
      }
      d.couplings = {};  // chains assemble from diag_w, off_w: 160 bytes per bond less to keep
    } else if (n <= kMaxDenseBonds)
      d.solver = std::make_unique<DenseSolver>(n, d.couplings);
    else
      d.solver = std::make_unique<SparseSolver>(n, d.couplings);
    d.values = Eigen::VectorXd::Zero(static_cast<Eigen::Index>(d.couplings.size()));
    d.rhs = d.sol = d.lambda = Eigen::VectorXd::Zero(n);
    d.half_inv_length.resize(n);
    for (int k = 0; k < n; ++k) d.half_inv_length[k] = 0.5 / bonds[d.bonds[k]].length;
    if (chain) set_path(d);
    data.push_back(std::move(d));
  }
  bonds_before.assign(1, 0);
  std::vector<int> owner(inv_mass.size(), -1);
  for (int c = 0; c < static_cast<int>(clusters.size()); ++c) {
    bonds_before.push_back(bonds_before.back() + static_cast<std::int64_t>(clusters[c].bonds.size()));
    for (int p : clusters[c].particles) {
      if (owner[p] >= 0 && owner[p] != c) clusters_share_particles = true;
      owner[p] = c;
    }
  }
}

// The particles along an open chain (ClusterData::path): consecutive bonds of the path order share
// a mobile particle, path[k + 1]; path[0] and path[n] are the far ends of the first and last bond.
void ConstraintToolbox::Impl::set_path(ClusterData& d) const {
  const int n = static_cast<int>(d.bonds.size());
  auto shared = [&](const StiffBond& a, const StiffBond& b) {  // the mobile particle of both
    for (const int p : {a.i, a.j})
      if (inv_mass[p] > 0.0 && (p == b.i || p == b.j)) return p;
    throw std::logic_error("constraint toolbox: consecutive bonds of a chain share no mobile particle");
  };
  auto other_end = [](const StiffBond& b, int p) { return b.i == p ? b.j : b.i; };
  d.path.assign(static_cast<std::size_t>(n) + 1, 0);
  const StiffBond& first = bonds[d.bonds[0]];
  if (n == 1) {
    d.path = {first.i, first.j};
  } else {
    for (int k = 0; k + 1 < n; ++k) d.path[k + 1] = shared(bonds[d.bonds[k]], bonds[d.bonds[k + 1]]);
    d.path[0] = other_end(first, d.path[1]);
    d.path[n] = other_end(bonds[d.bonds[n - 1]], d.path[n - 1]);
  }
  d.path_inv_mass.resize(n + 1);
  d.length2.resize(n);
  d.orientation.resize(n);
  d.e_kept = Eigen::Matrix3Xd::Zero(3, n);
  for (int q = 0; q <= n; ++q) d.path_inv_mass[q] = inv_mass[d.path[q]];
  for (int k = 0; k < n; ++k) {
    const StiffBond& b = bonds[d.bonds[k]];
    d.length2[k] = b.length * b.length;
    d.orientation[k] = b.i == d.path[k] ? 1.0 : -1.0;
    if (!(b.i == d.path[k] && b.j == d.path[k + 1]) && !(b.j == d.path[k] && b.i == d.path[k + 1]))
      throw std::logic_error("constraint toolbox: a chain's bond does not join consecutive particles of its path");
  }
}

// Unit vectors u_b and lengths of cluster c's bonds at x. G(x) does not exist where a bond
// has zero length, so that is an error, as is any non-finite coordinate.
double ConstraintToolbox::Impl::measure(int c, const Eigen::Matrix3Xd& x, BondFrame& frame, const char* what,
                                        int iteration, double* minus_g) {
  // One pass without branches (u = d / |d| for every bond; SHAKE's residual in the same pass),
  // then the check: called several times per macro step by SHAKE and the mollifier, so it is
  // kept tight.
  double* u = frame.u.data();
  double* len = frame.length.data();
  const StiffBond* bond = bonds.data();
  const std::vector<int>& order = data[c].bonds;
  const int n = static_cast<int>(order.size());
  bool ok = true;
  double worst = 0.0;
  for (int k = 0; k < n; ++k) {
    const int b = order[k];
    const Eigen::Vector3d d = bond_vector(x, bond[b].i, bond[b].j);
    const double dx = d[0], dy = d[1], dz = d[2];
    const double length = std::sqrt(dx * dx + dy * dy + dz * dz);
    const double inv = 1.0 / length;
    u[3 * b] = dx * inv;
    u[3 * b + 1] = dy * inv;
    u[3 * b + 2] = dz * inv;
    len[b] = length;
    ok &= length > 0.0 && length <= std::numeric_limits<double>::max();  // false for 0, ∞, NaN
    if (minus_g != nullptr) {                                            // loop-invariant: the compiler splits the loop
      minus_g[k] = bond[b].length - length;
      worst = std::max(worst, std::abs(minus_g[k]));
    }
  }
  if (ok) return worst;
  for (const int b : data[c].bonds) {
    const double length = len[b];
    if (length > 0.0 && std::isfinite(length)) continue;
    std::string where = std::string(what) + " failed in cluster " + std::to_string(c);
    if (iteration >= 0) where += " at iteration " + std::to_string(iteration);
    throw NumericalError(where + ": " + describe_bond(b, bonds[b]) +
                         (length == 0.0 ? " has zero length" : " has a non-finite length"));
  }
  return worst;
}

double ConstraintToolbox::Impl::chain_gap(int c, const Eigen::Matrix3Xd& y, double* minus_h) const {
  const ClusterData& d = data[c];
  const int* path = d.path.data();
  const double* yp = y.data();
  PathGap gap(d, minus_h);
  for (int k = 0, n = static_cast<int>(d.bonds.size()); k <= n; ++k) {
    const double* q = yp + 3 * path[k];
    gap(k, q[0], q[1], q[2]);
  }
  return gap.result();
}

double ConstraintToolbox::Impl::chain_displace(int c, Eigen::Matrix3Xd& y, const double* delta, double* minus_h) {
  ClusterData& d = data[c];
  d.lambda += Eigen::Map<const Eigen::VectorXd>(delta, d.lambda.size());
  PathGap gap(d, minus_h);
  walk_chain<true>(d, y.data(), delta, 1.0, gap);
  return gap.result();
}

// Factorizes K = G(rows) M⁻¹ G(cols)ᵀ on cluster c (see Coupling).
void ConstraintToolbox::Impl::factorize(int c, const BondFrame& rows, const BondFrame& cols, bool symmetric,
                                        const char* what) {
  ClusterData& d = data[c];
  const double* ur = rows.u.data();
  const double* uc = cols.u.data();
  auto dot = [&](int a, int b) { return column_dot(ur, a, uc, b); };
  if (d.chain) {
    const int n = static_cast<int>(d.bonds.size());
    const int* bond = d.bonds.data();
    double* sub = d.chain->sub();
    double* diagonal = d.chain->diagonal();
    double* super = d.chain->super();
    for (int k = 0; k < n; ++k) diagonal[k] = d.diag_w[k] * dot(bond[k], bond[k]);
    for (int k = 0; k + 1 < n; ++k) {
      super[k] = d.off_w[k] * dot(bond[k], bond[k + 1]);
      sub[k] = d.off_w[k] * dot(bond[k + 1], bond[k]);
    }
    if (!d.chain->factorize_bands()) singular(c, symmetric, what);
    return;
  }
  const double* w = inv_mass.data();
  double* values = d.values.data();
  const Coupling* cp = d.couplings.data();
  for (std::size_t k = 0, n = d.couplings.size(); k < n; ++k) {
    values[k] = cp[k].sign * w[cp[k].particle] * column_dot(ur, cp[k].row_bond, uc, cp[k].col_bond);
  }
  if (!d.solver->factorize(d.values, symmetric)) singular(c, symmetric, what);
}

void ConstraintToolbox::Impl::keep(const Eigen::Matrix3Xd& x) {
  if (kept && kept_x.cols() == x.cols()) {
    // Bit for bit, in the particle blocks of the threads (a hit reads all of x).
    const int parts = threads_for(x.cols());
    std::array<char, kMaxParts> same{};
    run_parts(parts, [&](int u) {
      const std::int64_t b = block_begin(x.cols(), parts, u), e = block_begin(x.cols(), parts, u + 1);
      same[u] = std::memcmp(kept_x.data() + 3 * b, x.data() + 3 * b, sizeof(double) * 3 * (e - b)) == 0;
    });
    if (std::all_of(same.begin(), same.begin() + parts, [](char s) { return s != 0; })) return;
  }
  copy_configuration(x);
  for (ClusterData& d : data) d.frame_kept = d.s_factored = false;
}

void ConstraintToolbox::Impl::copy_configuration(const Eigen::Matrix3Xd& x) {
  if (kept_x.cols() != x.cols()) kept_x.resize(3, x.cols());  // once
  parallel_blocks(x.cols(), threads_for(x.cols()),
                  [&](std::int64_t b, std::int64_t e) { kept_x.middleCols(b, e - b) = x.middleCols(b, e - b); });
  kept = true;
}

// An open chain's bands of S at the kept configuration (measured first if need be), and σ_k u_k
// along the path (SHAKE's chord, the projections: used once S is factored) in the same pass: one
// walk over the chain's directions instead of two.
void ConstraintToolbox::Impl::chain_s_bands(int c, const char* what) {
  ClusterData& d = data[c];
  if (!d.frame_kept) {
    measure(c, kept_x, at_kept, what);
    d.frame_kept = true;
  }
  const double* u = at_kept.u.data();
  const int n = static_cast<int>(d.bonds.size());
  const int* bond = d.bonds.data();
  double* diagonal = d.spd->diagonal();
  double* off = d.spd->off();
  double* e = d.e_kept.data();
  const double* sigma = d.orientation.data();
  for (int k = 0; k < n; ++k) {
    const double* uk = u + 3 * bond[k];
    diagonal[k] = d.diag_w[k] * column_dot(u, bond[k], u, bond[k]);
    if (k + 1 < n) off[k] = d.off_w[k] * column_dot(u, bond[k], u, bond[k + 1]);
    e[3 * k] = sigma[k] * uk[0];
    e[3 * k + 1] = sigma[k] * uk[1];
    e[3 * k + 2] = sigma[k] * uk[2];
  }
}

// After an open chain's factorization (chain_s_bands wrote σ_k u_k).
void ConstraintToolbox::Impl::chain_s_factored(int c, bool regular, const char* what) {
  ClusterData& d = data[c];
  if (!regular) singular(c, true, what);
  d.s_factored = true;
  ++d.factorizations;
}

void ConstraintToolbox::Impl::factor_kept_s(int c, const char* what) {
  ClusterData& d = data[c];
  if (!d.frame_kept) {
    measure(c, kept_x, at_kept, what);
    d.frame_kept = true;
  }
  if (d.s_factored) return;
  if (d.spd) {
    chain_s_bands(c, what);
    chain_s_factored(c, d.spd->factorize(), what);
    return;
  }
  factorize(c, at_kept, at_kept, true, what);
  d.s_factored = true;
  ++d.factorizations;
}

void ConstraintToolbox::Impl::factor_kept_group(int first, int count, const char* what) {
  int todo[kChainGroup];
  int k = 0;
  // A bond of zero or non-finite length is reported as alone: after the clusters before it are
  // factored (one of them may be singular: that is then the error).
  std::exception_ptr failed;
  for (int c = first; c < first + count && !failed; ++c) {
    if (data[c].s_factored) continue;
    try {
      chain_s_bands(c, what);
      todo[k++] = c;
    } catch (const NumericalError&) {
      failed = std::current_exception();
    }
  }
  ChainLdlt* chain[kChainGroup];
  bool regular[kChainGroup];
  for (int j = 0; j < k; ++j) chain[j] = data[todo[j]].spd.get();
  for_group_size(k, [&](auto size) { ChainLdlt::factorize_group<decltype(size)::value>(chain, regular); });
  for (int j = 0; j < k; ++j) chain_s_factored(todo[j], regular[j], what);  // the first singular one throws
  if (failed) std::rethrow_exception(failed);
}

// sol = S⁻¹ rhs for the given open chains (of one length) in lockstep.
void ConstraintToolbox::Impl::solve_chains(const int* cs, int k) {
  const ChainLdlt* chain[kChainGroup];
  const double* rhs[kChainGroup];
  double* sol[kChainGroup];
  for (int j = 0; j < k; ++j) {
    chain[j] = data[cs[j]].spd.get();
    rhs[j] = data[cs[j]].rhs.data();
    sol[j] = data[cs[j]].sol.data();
  }
  for_group_size(k, [&](auto size) { ChainLdlt::solve_group<decltype(size)::value>(chain, rhs, sol); });
}

void ConstraintToolbox::Impl::solve_kept_s(int c) {
  ClusterData& d = data[c];
  if (d.spd)
    d.spd->solve(d.rhs.data(), d.sol.data());
  else
    d.solver->solve(d.rhs, d.sol);
}

void ConstraintToolbox::Impl::singular(int c, bool symmetric, const char* what) const {
  throw NumericalError(std::string(what) + " failed in cluster " + std::to_string(c) +
                       (symmetric ? ": S = G M⁻¹ Gᵀ is singular (the bond directions are linearly dependent)"
                                  : ": the Newton matrix G(y) M⁻¹ G(x_ref)ᵀ is singular (too far from the reference)"));
}

// (M⁻¹w)_i − (M⁻¹w)_j for bond b: with u_b this is row b of G M⁻¹ w.
Eigen::Vector3d ConstraintToolbox::Impl::inv_mass_difference(int b, const Eigen::Matrix3Xd& w) const {
  return inv_mass[bonds[b].i] * w.col(bonds[b].i) - inv_mass[bonds[b].j] * w.col(bonds[b].j);
}

// f += sign · Gᵀ coef. Fixed particles receive their share too unless mobile_only: it is the
// reaction force there, and keeping the full Gᵀ makes P an exact projection.
void ConstraintToolbox::Impl::add_constraint_force(int c, const BondFrame& frame, const Eigen::VectorXd& coef,
                                                   double sign, Eigen::Matrix3Xd& f, bool mobile_only) const {
  const ClusterData& d = data[c];
  for (int k = 0; k < static_cast<int>(d.bonds.size()); ++k) {
    const int b = d.bonds[k];
    const Eigen::Vector3d force = sign * coef[k] * frame.u.col(b);
    if (!mobile_only || inv_mass[bonds[b].i] > 0.0) f.col(bonds[b].i) += force;
    if (!mobile_only || inv_mass[bonds[b].j] > 0.0) f.col(bonds[b].j) -= force;
  }
}

// y += sign · M⁻¹ Gᵀ coef: the motion the constraint force causes (none at fixed particles).
void ConstraintToolbox::Impl::add_constraint_displacement(int c, const BondFrame& frame, const Eigen::VectorXd& coef,
                                                          double sign, Eigen::Matrix3Xd& y) const {
  const ClusterData& d = data[c];
  for (int k = 0; k < static_cast<int>(d.bonds.size()); ++k) {
    const int b = d.bonds[k];
    const Eigen::Vector3d step = sign * coef[k] * frame.u.col(b);
    y.col(bonds[b].i) += inv_mass[bonds[b].i] * step;
    y.col(bonds[b].j) -= inv_mass[bonds[b].j] * step;
  }
}

// An open chain's projection along its path (after factor_kept_s): rhs = G M⁻¹ f (kForce) or
// G v, rhs_k = σ_k u_k · (a at path[k] − a at path[k + 1]) with a = M⁻¹f or v; S μ = rhs; then,
// walking the path, a_p −= c_p (σ_k u_k μ_k − σ_{k−1} u_{k−1} μ_{k−1}) for p = path[k], c_p = 1
// for a force (f − Gᵀμ) and m_p⁻¹ for a velocity (v − M⁻¹Gᵀμ). Each particle is read once per
// pass, in path order, instead of through the bond records.
template <bool kForce>
void ConstraintToolbox::Impl::chain_project_rhs(int c, const Eigen::Matrix3Xd& a) {
  ClusterData& d = data[c];
  const int n = static_cast<int>(d.bonds.size());
  const int* path = d.path.data();
  const double* w = d.path_inv_mass.data();
  const double* e = d.e_kept.data();
  const double* ap = a.data();
  double* rhs = d.rhs.data();
  const double* p = ap + 3 * path[0];
  const double wp = kForce ? w[0] : 1.0;
  double px = wp * p[0], py = wp * p[1], pz = wp * p[2];
  for (int k = 0; k < n; ++k) {
    const double* q = ap + 3 * path[k + 1];
    const double wq = kForce ? w[k + 1] : 1.0;
    const double qx = wq * q[0], qy = wq * q[1], qz = wq * q[2];
    rhs[k] = e[3 * k] * (px - qx) + e[3 * k + 1] * (py - qy) + e[3 * k + 2] * (pz - qz);
    px = qx;
    py = qy;
    pz = qz;
  }
}

// a −= Gᵀμ (force) or M⁻¹Gᵀμ (velocity), μ in sol; force −= rate · Gᵀμ if given.
template <bool kForce>
void ConstraintToolbox::Impl::chain_project_update(int c, Eigen::Matrix3Xd& a, Eigen::Matrix3Xd* force, double rate) {
  walk_chain<!kForce>(
      data[c], a.data(), data[c].sol.data(), -1.0, [](int, double, double, double) {},
      force != nullptr ? force->data() : nullptr, -rate);
}

// A group of clusters (for_each_group): open chains project in lockstep (a group of one alone),
// any other cluster through project_force_cluster / project_velocity_cluster.
template <bool kForce>
void ConstraintToolbox::Impl::project_group(int first, int count, Eigen::Matrix3Xd& a, Eigen::Matrix3Xd* force,
                                            double rate) {
  if (!data[first].spd) {
    if (kForce)
      project_force_cluster(first, a);
    else
      project_velocity_cluster(first, a, force, rate);
    return;
  }
  factor_kept_group(first, count, kForce ? "force projection" : "velocity projection");
  int cs[kChainGroup];
  for (int j = 0; j < count; ++j) {
    cs[j] = first + j;
    chain_project_rhs<kForce>(cs[j], a);
  }
  solve_chains(cs, count);
  for (int j = 0; j < count; ++j) chain_project_update<kForce>(cs[j], a, force, rate);
}

// P(x) f = f − Gᵀλ, S λ = G M⁻¹ f (paper eq. (proj)), on a cluster that is not an open chain
// (those go through project_group).
void ConstraintToolbox::Impl::project_force_cluster(int c, Eigen::Matrix3Xd& f) {
  ClusterData& d = data[c];
  factor_kept_s(c, "force projection");
  for (int k = 0; k < d.rhs.size(); ++k) d.rhs[k] = at_kept.u.col(d.bonds[k]).dot(inv_mass_difference(d.bonds[k], f));
  solve_kept_s(c);
  add_constraint_force(c, at_kept, d.sol, -1.0, f);
}

// RATTLE's velocity step: the M-orthogonal projection of v onto the tangent space G v = 0 (not an
// open chain: those go through project_group).
void ConstraintToolbox::Impl::project_velocity_cluster(int c, Eigen::Matrix3Xd& v, Eigen::Matrix3Xd* force,
                                                       double rate) {
  ClusterData& d = data[c];
  factor_kept_s(c, "velocity projection");
  for (int k = 0; k < d.rhs.size(); ++k) {
    const StiffBond& bond = bonds[d.bonds[k]];
    d.rhs[k] = at_kept.u.col(d.bonds[k]).dot(v.col(bond.i) - v.col(bond.j));
  }
  solve_kept_s(c);
  add_constraint_displacement(c, at_kept, d.sol, -1.0, v);
  if (force != nullptr) add_constraint_force(c, at_kept, d.sol, -rate, *force, true);  // −rate Gᵀμ
}

// y = y0 + M⁻¹G(x_ref)ᵀλ with g(y) = 0 (paper eq. (ProMol) when y0 = x_ref), x_ref the kept
// configuration: g(y + M⁻¹G(x_ref)ᵀδ) ≈ g(y) + J δ with J = G(y) M⁻¹ G(x_ref)ᵀ. Open chains near
// x_ref take chord steps S(x_ref) δ = −g(y) (SHAKE's quasi-Newton: S is J at y = x_ref, and its
// factors are usually kept from the velocity projection that ended the last step); otherwise, or
// as soon as the chord contracts slowly, full Newton on J (quadratic convergence, and λ accurate
// enough for the mollified force's H_λ).
void ConstraintToolbox::Impl::shake_start(ShakeState& st, int c) {
  ClusterData& d = data[c];
  if (!d.frame_kept) {
    measure(c, kept_x, at_kept, "SHAKE (reference configuration)");
    d.frame_kept = true;
  }
  st = ShakeState{};
  st.c = c;
  st.chord = d.spd != nullptr;
  d.lambda.setZero();
}

ConstraintToolbox::Impl::ShakeNext ConstraintToolbox::Impl::shake_iterate(ShakeState& st, Eigen::Matrix3Xd& y,
                                                                          double tol, int max_iter) {
  const int c = st.c;
  ClusterData& d = data[c];
  const int n = static_cast<int>(d.bonds.size());
  const int* bond = d.bonds.data();
  const int iteration = st.iteration;
  // The chord needs only the residual, −h(y) (gap: no square root; after a chord update it was
  // computed in the update's pass); G(y), a full measure with rhs = −g(y), only to confirm
  // convergence (it is then kept for the velocity projection), for a Newton step, or to name a
  // bond whose length is not finite.
  double residual = !st.chord ? 0.0 : st.have_chord_residual ? st.chord_residual : chain_gap(c, y, d.rhs.data());
  st.have_chord_residual = false;
  bool measured = false;
  auto measure_y = [&] {
    residual = measure(c, y, at_cur, "SHAKE", iteration, d.rhs.data());
    measured = true;
  };
  if (!st.chord || !(residual > tol)) {  // Newton, converged by h, or not finite
    measure_y();
    if (residual <= tol) return ShakeNext::converged;
  }
  if (iteration == max_iter) {
    if (!measured) measure_y();  // report g, not h
    int worst = 0;
    d.rhs.cwiseAbs().maxCoeff(&worst);
    const int b = bond[worst];
    throw NumericalError("SHAKE did not converge in cluster " + std::to_string(c) + " after " +
                         std::to_string(max_iter) + " iterations: worst " + describe_bond(b, bonds[b]) +
                         ", |g| = " + format_g(residual));
  }
  if (iteration == 0 && st.chord)
    for (int k = 0; k < n; ++k) st.chord &= std::abs(d.rhs[k]) <= kChordStart * bonds[bond[k]].length;
  st.chord &= !(residual > kChordContraction * st.previous);  // false for NaN too
  st.previous = residual;
  if (!st.chord && !measured) measure_y();  // Newton from here: J needs G(y)
  if (st.chord) return ShakeNext::chord_solve;
  factorize(c, at_cur, at_kept, false, "SHAKE");
  ++d.factorizations;
  if (!d.spd) d.s_factored = false;  // J took S's place in the solver
  d.solver->solve(d.rhs, d.sol);
  d.lambda += d.sol;
  add_constraint_displacement(c, at_kept, d.sol, +1.0, y);
  ++st.iteration;
  return ShakeNext::newton_done;
}

// After S(x_ref) δ = −h(y) (or −g(y) after a full measure) into sol: in one pass along the
// chain, λ += δ, y += M⁻¹G(x_ref)ᵀδ and the new −h(y).
void ConstraintToolbox::Impl::shake_chord_update(ShakeState& st, Eigen::Matrix3Xd& y) {
  ClusterData& d = data[st.c];
  st.chord_residual = chain_displace(st.c, y, d.sol.data(), d.rhs.data());
  st.have_chord_residual = true;
  ++st.iteration;
}

// y = y0 + M⁻¹G(x_ref)ᵀλ with g(y) = 0 (paper eq. (ProMol) when y0 = x_ref), x_ref the kept
// configuration: g(y + M⁻¹G(x_ref)ᵀδ) ≈ g(y) + J δ with J = G(y) M⁻¹ G(x_ref)ᵀ. Open chains near
// x_ref take chord steps S(x_ref) δ = −g(y) (SHAKE's quasi-Newton: S is J at y = x_ref, and its
// factors are usually kept from the velocity projection that ended the last step); otherwise, or
// as soon as the chord contracts slowly, full Newton on J (quadratic convergence, and λ accurate
// enough for the mollified force's H_λ).
void ConstraintToolbox::Impl::shake_cluster(int c, Eigen::Matrix3Xd& y, double tol, int max_iter) {
  shake_group(c, 1, y, tol, max_iter);
}

// SHAKE on each cluster of a group (for_each_group: open chains of one length, or any cluster
// alone), the chord solves of the group in lockstep. Each cluster goes through its own iterations
// exactly as alone; a failure is held until the group is done and the first failing cluster's
// rethrown.
void ConstraintToolbox::Impl::shake_group(int first, int count, Eigen::Matrix3Xd& y, double tol, int max_iter) {
  ShakeState st[kChainGroup];
  bool active[kChainGroup];
  std::exception_ptr error[kChainGroup];
  auto guard = [&](int j, auto&& work) {
    try {
      work();
    } catch (const NumericalError&) {
      error[j] = std::current_exception();
      active[j] = false;
    }
  };
  for (int j = 0; j < count; ++j) {
    active[j] = true;
    guard(j, [&] { shake_start(st[j], first + j); });
  }
  for (;;) {
    int solving[kChainGroup], cs[kChainGroup];
    int k = 0;
    for (int j = 0; j < count; ++j) {
      if (!active[j]) continue;
      guard(j, [&] {
        const ShakeNext next = shake_iterate(st[j], y, tol, max_iter);
        if (next == ShakeNext::converged) active[j] = false;
        if (next != ShakeNext::chord_solve) return;
        factor_kept_s(first + j, "SHAKE (reference configuration)");
        solving[k] = j;
        cs[k++] = first + j;
      });
    }
    if (k == 0 && std::none_of(active, active + count, [](bool a) { return a; })) break;
    solve_chains(cs, k);
    for (int q = 0; q < k; ++q) shake_chord_update(st[solving[q]], y);
  }
  for (int j = 0; j < count; ++j)
    if (error[j]) std::rethrow_exception(error[j]);
}

// Steps 2–4 of the mollified force (design.md §2), from α′(x) = (I − M⁻¹G(x)ᵀJ⁻¹G(X))(I + M⁻¹H_λ),
// which follows by differentiating X = x + M⁻¹G(x)ᵀλ(x), g(X) = 0. On entry f = f_slow(X) and
// data[c].lambda holds the multipliers of X = α(x).
void ConstraintToolbox::Impl::mollify_cluster(int c, Eigen::Matrix3Xd& f) {
  ClusterData& d = data[c];
  // G(x) and G(X) are in at_kept and at_cur: shake_cluster measured x as its reference and
  // X = α(x) in its last, converged iteration (mollified_force calls the two in turn, and
  // f_slow does not touch the toolbox).
  // Step 2: Jᵀμ = G(x) M⁻¹ f, Jᵀ = G(x) M⁻¹ G(X)ᵀ.
  factorize(c, at_kept, at_cur, false, "mollified force");
  ++d.factorizations;
  if (!d.spd) d.s_factored = false;  // Jᵀ took S's place in the solver
  for (int k = 0; k < d.rhs.size(); ++k) d.rhs[k] = at_kept.u.col(d.bonds[k]).dot(inv_mass_difference(d.bonds[k], f));
  d.solver->solve(d.rhs, d.sol);
  // Step 3: r = f − G(X)ᵀμ.
  add_constraint_force(c, at_cur, d.sol, -1.0, f);
  // Step 4: F̄ = r + H_λ M⁻¹ r. ∇²g_b acts on (x_i, x_j) as [[A, −A], [−A, A]],
  // A = (I − u uᵀ)/|x_i − x_j| at x (the derivative of u_b(x)). All of r is needed before
  // any of it is overwritten, hence the per-bond buffer.
  for (int k = 0; k < d.rhs.size(); ++k) {
    const int b = d.bonds[k];
    const Eigen::Vector3d w = inv_mass_difference(b, f);
    const Eigen::Vector3d u = at_kept.u.col(b);
    curvature.col(b) = d.lambda[k] * (w - u * u.dot(w)) / at_kept.length[b];
  }
  for (int b : d.bonds) {
    f.col(bonds[b].i) += curvature.col(b);
    f.col(bonds[b].j) -= curvature.col(b);
  }
}

ConstraintToolbox::ConstraintToolbox(std::vector<StiffBond> bonds, Eigen::VectorXd inv_mass)
    : impl_(std::make_unique<Impl>(std::move(bonds), std::move(inv_mass))) {}
ConstraintToolbox::~ConstraintToolbox() = default;
ConstraintToolbox::ConstraintToolbox(ConstraintToolbox&&) noexcept = default;
ConstraintToolbox& ConstraintToolbox::operator=(ConstraintToolbox&&) noexcept = default;

const std::vector<StiffBond>& ConstraintToolbox::bonds() const {
  return impl_->bonds;
}
const std::vector<ConstraintCluster>& ConstraintToolbox::clusters() const {
  return impl_->clusters;
}
int ConstraintToolbox::num_bonds() const {
  return static_cast<int>(impl_->bonds.size());
}
void ConstraintToolbox::keep(const Eigen::Matrix3Xd& x) {
  require_columns(x, impl_->num_particles(), "keep");
  impl_->keep(x);
}

void ConstraintToolbox::Impl::chain_inverse_band_group(int first, int count) {
  factor_kept_group(first, count, "Fixman potential");
  const ChainLdlt* chain[kChainGroup];
  double* z_diag[kChainGroup];
  double* z_off[kChainGroup];
  int k = 0;
  for (int c = first; c < first + count; ++c) {
    ClusterData& d = data[c];
    if (band_current(d)) continue;
    chain[k] = d.spd.get();
    z_diag[k] = d.z_diag.data();
    z_off[k++] = d.z_off.data();
    d.band_at = d.factorizations;
  }
  for_group_size(k, [&](auto size) { ChainLdlt::inverse_band_group<decltype(size)::value>(chain, z_diag, z_off); });
}

void ConstraintToolbox::inverse_bands(const Eigen::Matrix3Xd& x) {
  require_columns(x, impl_->num_particles(), "inverse_bands");
  Impl& d = *impl_;
  d.keep(x);
  d.for_each_group([&](int c, int count) {
    if (d.data[c].spd) d.chain_inverse_band_group(c, count);
  });
}

ConstraintToolbox::ChainInverseBand ConstraintToolbox::chain_inverse_band(int c) {
  ClusterData& d = impl_->data.at(static_cast<std::size_t>(c));
  if (!d.spd) return {};
  impl_->chain_inverse_band_group(c, 1);
  return {d.z_off.data(), d.spd->inverse_pivots(), static_cast<int>(d.bonds.size())};
}

const std::vector<int>& ConstraintToolbox::cluster_bonds(int c) const {
  return impl_->data.at(static_cast<std::size_t>(c)).bonds;
}

const Eigen::Matrix3Xd& ConstraintToolbox::kept_directions() const {
  return impl_->at_kept.u;
}
const Eigen::VectorXd& ConstraintToolbox::kept_lengths() const {
  return impl_->at_kept.length;
}

std::int64_t ConstraintToolbox::factorizations() const {
  std::int64_t total = 0;
  for (const ClusterData& d : impl_->data) total += d.factorizations;
  return total;
}

void ConstraintToolbox::constraint_values(const Eigen::Matrix3Xd& x, Eigen::Ref<Eigen::VectorXd> g) const {
  require_columns(x, impl_->num_particles(), "constraint_values");
  for (int b = 0; b < num_bonds(); ++b) g[b] = constraint_value(impl_->bonds[b], x);
}

double ConstraintToolbox::max_violation(const Eigen::Matrix3Xd& x) const {
  require_columns(x, impl_->num_particles(), "max_violation");
  return stiffmd::max_violation(impl_->bonds, x);
}

void ConstraintToolbox::project_force(const Eigen::Matrix3Xd& x, Eigen::Matrix3Xd& f) {
  require_columns(x, impl_->num_particles(), "project_force");
  require_columns(f, impl_->num_particles(), "project_force");
  impl_->keep(x);
  impl_->for_each_group([&](int c, int count) { impl_->project_group<true>(c, count, f); });
}

void ConstraintToolbox::project_velocity(const Eigen::Matrix3Xd& x, Eigen::Matrix3Xd& v, Eigen::Matrix3Xd* force,
                                         double rate) {
  require_columns(x, impl_->num_particles(), "project_velocity");
  require_columns(v, impl_->num_particles(), "project_velocity");
  if (force != nullptr) require_columns(*force, impl_->num_particles(), "project_velocity (force)");
  impl_->keep(x);
  impl_->for_each_group([&](int c, int count) { impl_->project_group<false>(c, count, v, force, rate); });
}

void ConstraintToolbox::shake(const Eigen::Matrix3Xd& x_ref, Eigen::Matrix3Xd& y, Eigen::VectorXd* lambda, double tol,
                              int max_iter) {
  require_columns(x_ref, impl_->num_particles(), "shake");
  require_columns(y, impl_->num_particles(), "shake");
  Impl& d = *impl_;
  d.keep(x_ref);  // a copy: y may be x_ref itself
  d.for_each_group([&](int c, int count) { d.shake_group(c, count, y, tol, max_iter); });
  // Every cluster's last measure was of the converged y: keep y with G there, for the velocity
  // projection that follows in RATTLE (S at y is factored when first asked for).
  d.copy_configuration(y);
  std::swap(d.at_kept, d.at_cur);
  for (ClusterData& c : d.data) {
    c.frame_kept = true;
    c.s_factored = false;
  }
  if (lambda == nullptr) return;
  lambda->resize(num_bonds());  // a no-op when the caller keeps the vector
  for (const ClusterData& c : d.data)
    for (int k = 0; k < c.lambda.size(); ++k) (*lambda)[c.bonds[k]] = c.lambda[k];
}

void ConstraintToolbox::mollified_force(const Eigen::Matrix3Xd& x, const ForceFunction& f_slow, Eigen::Matrix3Xd& X,
                                        Eigen::Matrix3Xd& out, double tol) {
  require_columns(x, impl_->num_particles(), "mollified_force");
  // Step 1: X = α(x), the M-orthogonal projection of x onto g = 0 (paper eq. (ProMol)).
  impl_->keep(x);
  X.resize(3, x.cols());  // no allocation once sized
  parallel_blocks(x.cols(), threads_for(x.cols()),
                  [&](std::int64_t b, std::int64_t e) { X.middleCols(b, e - b) = x.middleCols(b, e - b); });
  impl_->for_each_cluster([&](int c) { impl_->shake_cluster(c, X, tol, kMollifierMaxIter); });
  out.resize(3, x.cols());
  f_slow(X, out);
  require_columns(out, impl_->num_particles(), "mollified_force (f_slow output)");
  impl_->for_each_cluster([&](int c) { impl_->mollify_cluster(c, out); });
}

BondsAtParticles bonds_at_mobile_particles(const std::vector<int>& order, const std::vector<StiffBond>& bonds,
                                           const Eigen::VectorXd& inv_mass) {
  BondsAtParticles at;
  for (int r = 0; r < static_cast<int>(order.size()); ++r) {
    const StiffBond& b = bonds[order[r]];
    if (inv_mass[b.i] > 0.0) at[b.i].emplace_back(r, +1.0);
    if (inv_mass[b.j] > 0.0) at[b.j].emplace_back(r, -1.0);
  }
  return at;
}

}  // namespace stiffmd
