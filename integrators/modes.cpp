// Frequencies, actions and correction potential of the effective dynamics
// (docs/design.md §4; Lubich & Weiss eqs. (CH), (actions), (separated), (nonresonant)).
#include "integrators/eigen_dense.hpp"  // first: see the header

#include <algorithm>
#include <cmath>
#include <limits>
#include <stdexcept>
#include <string>
#include <utility>
#include "integrators/modes.hpp"

#include "core/errors.hpp"
#include "core/parallel.hpp"
#include "integrators/constraints.hpp"

// LAPACK: the eigenvalues of a symmetric tridiagonal matrix, ascending, by the Pal–Walker–Kahan
// root-free QR (O(n²), no eigenvectors). On 99-bond chains this plus the O(n)-per-vector twisted
// factorizations below beat MRRR (dstemr) with vectors, which spends most of its time refining.
extern "C" void dsterf_(const int* n, double* d, double* e, int* info);

namespace stiffmd {

namespace {

// Compile-time maximum size: keeps every Eigen temporary of the eigen-solver off the heap.
using DenseMatrix = Eigen::Matrix<double, Eigen::Dynamic, Eigen::Dynamic, Eigen::ColMajor, StiffModes::kMaxDenseBonds,
                                  StiffModes::kMaxDenseBonds>;
using DenseVector = Eigen::Matrix<double, Eigen::Dynamic, 1, Eigen::ColMajor, StiffModes::kMaxDenseBonds, 1>;

constexpr double kInf = std::numeric_limits<double>::infinity();

// An eigenvalue this small relative to the largest of its cluster means the constraint
// rows are (nearly) linearly dependent at x: the mode has no oscillation to speak of and
// 1/λ_k, 1/ω_k would blow up.
constexpr double kZeroEigenvalue = 1e-12;

}  // namespace

struct StiffModes::Impl {
  struct Cluster {
    int index = 0;               // position in find_clusters order, for messages
    int first_mode = 0;          // offset of this cluster's modes in the output vectors
    std::vector<int> bonds;      // global bond indices
    std::vector<int> particles;  // global particle index of each local particle
    std::vector<double> im;      // inverse mass of each local particle
    std::vector<int> li, lj;     // local particle index of each bond's ends
    // The couplings of S on this cluster, the toolbox's (bonds_at_mobile_particles: every pair of
    // bonds at one mobile particle p): S_be = w u_b·u_e, w = s_b(p) s_e(p)/m_p, local b > e.
    struct Coupling {
      int b, e;
      double w;
    };
    std::vector<Coupling> couplings;
    // Open chains: bonds in chain order, A tridiagonal with A(b, b+1) = off_w[b] α_b α_{b+1} u_b·u_{b+1},
    // off_w[b] the coupling of bonds b and b+1 (the one mobile particle they share).
    bool chain = false;
    std::vector<double> off_w;
  };

  // Scratch of one thread for the chain path, sized for the longest chain.
  struct ChainWorkspace {
    Eigen::Matrix3Xd u;
    Eigen::VectorXd r, diag, off, lambda, scratch, z, zdot, w, wdot, coef;
    Eigen::VectorXd q;  // the eigenvectors, n × n column-major in the first n² entries
    // Pivots of T − λ_k I from the top (forward) and the bottom (backward), stored as 1/D at
    // [b·n + k] so that the recurrences run over all k at once (independent, vectorisable).
    Eigen::VectorXd inv_forward, inv_backward, twist;
    std::vector<int> twist_index;
  };

  std::vector<StiffBond> bonds;
  Eigen::VectorXd inv_mass;
  double epsilon = 1.0;
  std::vector<Cluster> clusters;
  int num_modes = 0;
  int num_skipped = 0;

  // Shared scratch, sized in the constructor for the largest included cluster.
  Eigen::Matrix3Xd u;  // unit bond vectors u_b = (x_i − x_j)/r_b
  Eigen::VectorXd r;   // bond lengths r_b = |x_i − x_j|
  DenseMatrix A;
  Eigen::SelfAdjointEigenSolver<DenseMatrix> solver;
  DenseVector z, zdot, w, wdot;
  Eigen::Matrix3Xd wk;  // w_k = M⁻¹ Gᵀ K^{1/2} q_k on the cluster's local particles

  // The chain path: chain clusters (indices into clusters) split over the threads in blocks of
  // about equal bond count, one workspace per thread; per-bond and per-cluster results are
  // combined afterwards in cluster order, so nothing depends on the thread count.
  std::vector<int> chains;
  std::vector<std::int64_t> chain_bonds_before;  // bonds in chains 0 … k − 1
  std::vector<ChainWorkspace> workspaces;
  Eigen::Matrix3Xd h;             // per bond: ∂W/∂x_i (= −∂W/∂x_j) from its cluster's chain path
  std::vector<double> cluster_W;  // W of each cluster (chain path)
  std::vector<Validity> cluster_validity;

  void check_positions(const Eigen::Matrix3Xd& x) const {
    if (x.cols() != inv_mass.size())
      throw std::invalid_argument("StiffModes: x has " + std::to_string(x.cols()) + " particles, expected " +
                                  std::to_string(inv_mass.size()));
  }

  // Bond geometry and A = K^{1/2} S K^{1/2} of cluster c at x, then its eigen-decomposition
  // (docs/design.md §4). S_bc = Σ_p m_p⁻¹ (s_b(p) u_b)·(s_c(p) u_c) over the particles p the two
  // bonds share, s_b(i) = +1, s_b(j) = −1: the rows of G carry +u_b at i and −u_b at j.
  // u_b, r_b of every bond of cluster c at x, by local bond index.
  void measure(const Cluster& c, const Eigen::Matrix3Xd& x, Eigen::Matrix3Xd& u, Eigen::VectorXd& r) const {
    const int nb = static_cast<int>(c.bonds.size());
    for (int b = 0; b < nb; ++b) {
      const StiffBond& bond = bonds[c.bonds[b]];
      const Eigen::Vector3d d = bond_vector(x, bond.i, bond.j);
      const double rb = d.norm();
      if (!(rb > 0.0) || !std::isfinite(rb))
        throw NumericalError("StiffModes: bond " + std::to_string(c.bonds[b]) + " (particles " +
                             std::to_string(bond.i) + ", " + std::to_string(bond.j) + ") of cluster " +
                             std::to_string(c.index) + " has length " + std::to_string(rb) + ": no bond direction");
      r[b] = rb;
      u.col(b) = d / rb;
    }
  }

  void decompose(const Cluster& c, const Eigen::Matrix3Xd& x, bool vectors) {
    const int nb = static_cast<int>(c.bonds.size());
    measure(c, x, u, r);
    A.setZero(nb, nb);
    for (int b = 0; b < nb; ++b) {
      const double ab = bonds[c.bonds[b]].alpha;
      // u_b·u_b = 1 exactly; using it avoids a rounding asymmetry on the diagonal.
      A(b, b) = ab * ab * (c.im[c.li[b]] + c.im[c.lj[b]]);
    }
    for (const Cluster::Coupling& k : c.couplings) {
      const double v = bonds[c.bonds[k.b]].alpha * bonds[c.bonds[k.e]].alpha * k.w * u.col(k.b).dot(u.col(k.e));
      A(k.b, k.e) = v;
      A(k.e, k.b) = v;
    }
    solver.compute(A, vectors ? Eigen::ComputeEigenvectors : Eigen::EigenvaluesOnly);
    if (solver.info() != Eigen::Success)
      throw NumericalError("StiffModes: eigen-decomposition of cluster " + std::to_string(c.index) + " (" +
                           std::to_string(nb) + " bonds) did not converge");
  }

  // λ_k of the last decomposition, after the check that 1/λ_k is meaningful.
  double positive_eigenvalue(const Cluster& c, int k) const { return positive_eigenvalue(c, k, solver.eigenvalues()); }
  double positive_eigenvalue(const Cluster& c, int k, const Eigen::Ref<const Eigen::VectorXd>& lam) const {
    const double lk = lam[k];
    if (!(lk > kZeroEigenvalue * lam[lam.size() - 1]))
      throw NumericalError("StiffModes: mode " + std::to_string(k) + " of cluster " + std::to_string(c.index) +
                           " has eigenvalue " + std::to_string(lk) +
                           " (zero frequency): its constraints are (nearly) redundant here");
    return lk;
  }

  // The tridiagonal A of chain c at x (docs/design.md §4; A_bb = α_b² (1/m_i + 1/m_j) since u_b·u_b = 1),
  // then its eigenvalues (ascending, in ws.lambda) and, if asked, its eigenvectors (ws.q).
  void decompose_chain(const Cluster& c, const Eigen::Matrix3Xd& x, bool vectors, ChainWorkspace& ws) const {
    int n = static_cast<int>(c.bonds.size());
    measure(c, x, ws.u, ws.r);
    for (int b = 0; b < n; ++b) {
      const double ab = bonds[c.bonds[b]].alpha;
      ws.diag[b] = ab * ab * (c.im[c.li[b]] + c.im[c.lj[b]]);
      if (b + 1 < n) ws.off[b] = ab * bonds[c.bonds[b + 1]].alpha * c.off_w[b] * ws.u.col(b).dot(ws.u.col(b + 1));
    }
    if (n <= 2) {  // molecules of one or two bonds: closed forms, no LAPACK call
      small_chain(n, ws);
      return;
    }
    ws.lambda.head(n) = ws.diag.head(n);
    ws.scratch.head(n) = ws.off.head(n);
    int info = 0;
    dsterf_(&n, ws.lambda.data(), ws.scratch.data(), &info);
    if (info != 0)
      throw NumericalError("StiffModes: eigenvalues of chain cluster " + std::to_string(c.index) + " (" +
                           std::to_string(n) + " bonds) did not converge (LAPACK dsterf info " + std::to_string(info) +
                           ")");
    if (vectors) chain_eigenvectors(n, ws);
  }

  // Eigenpairs of a chain of one or two bonds in closed form (eigenvectors always: they are free).
  // 2 × 2: λ± = (a + b)/2 ± √(((a − b)/2)² + e²), the smaller one as det/λ₊ (no cancellation, as
  // LAPACK dlae2); the eigenvector of λ₊ from whichever row of A − λ₊ is the better conditioned.
  static void small_chain(int n, ChainWorkspace& ws) {
    if (n == 1) {
      ws.lambda[0] = ws.diag[0];
      ws.q[0] = 1.0;
      return;
    }
    const double a = ws.diag[0], b = ws.diag[1], e = ws.off[0];
    // sqrt rather than std::hypot (whose overflow guards cost more than the rest of the 2 × 2):
    // the entries are α²/m-sized, nowhere near overflow.
    const double half = 0.5 * (a - b), hyp = std::sqrt(half * half + e * e), big = 0.5 * (a + b) + hyp;  // a, b > 0
    ws.lambda[0] = (a / big) * b - (e / big) * e;
    ws.lambda[1] = big;
    double v0 = e, v1 = big - a;             // (A − λ₊) v = 0 from the first row …
    if (std::abs(big - b) > std::abs(v1)) {  // … or from the second
      v0 = big - b;
      v1 = e;
    }
    const double norm = std::sqrt(v0 * v0 + v1 * v1);
    if (norm == 0.0) {  // e = 0 and a = b: any orthonormal basis
      v0 = 0.0;
      v1 = 1.0;
    } else {
      v0 /= norm;
      v1 /= norm;
    }
    ws.q[0] = -v1;  // column 0: the eigenvector of λ₋, orthogonal to that of λ₊ (column 1)
    ws.q[1] = v0;
    ws.q[2] = v0;
    ws.q[3] = v1;
  }

  // Eigenvectors of the tridiagonal T (diagonal ws.diag, off-diagonal ws.off) for its eigenvalues
  // ws.lambda by twisted factorizations (Parlett & Dhillon; the core of MRRR, LAPACK dlar1v):
  // with the pivots D⁺_b of T − λ = L D⁺ Lᵀ from the top, D⁻_b of U D⁻ Uᵀ from the bottom and
  // γ_b = D⁺_b + D⁻_b − (T_bb − λ), the twist index r = argmin |γ_b| gives q_r = 1,
  // q_b = −(e_b/D⁺_b) q_{b+1} above r and q_{b+1} = −(e_b/D⁻_{b+1}) q_b below; O(n) per vector.
  // Accurate to O(nε/relative gap), as the dense solver; orthogonal to the same order.
  static void chain_eigenvectors(int n, ChainWorkspace& ws) {
    const double* d = ws.diag.data();
    const double* e = ws.off.data();
    const double* lam = ws.lambda.data();
    double* fw = ws.inv_forward.data();
    double* bw = ws.inv_backward.data();
    double* twist = ws.twist.data();
    // A zero pivot (λ exactly at an eigenvalue of a leading block) is replaced by a tiny one of
    // either sign, as LAPACK's pivmin: the twisted vector stays finite and exact to rounding.
    double emax = 0.0;
    for (int b = 0; b + 1 < n; ++b) emax = std::max(emax, std::abs(e[b]));
    const double pivmin = std::numeric_limits<double>::min() * std::max(1.0, emax * emax);
    auto safe = [pivmin](double D) { return std::abs(D) < pivmin ? -pivmin : D; };
#pragma omp simd
    for (int k = 0; k < n; ++k) fw[k] = 1.0 / safe(d[0] - lam[k]);
    for (int b = 1; b < n; ++b) {
      const double e2 = e[b - 1] * e[b - 1];
      const double* prev = fw + (b - 1) * n;
      double* cur = fw + b * n;
#pragma omp simd
      for (int k = 0; k < n; ++k) cur[k] = 1.0 / safe(d[b] - lam[k] - e2 * prev[k]);
    }
#pragma omp simd
    for (int k = 0; k < n; ++k) bw[(n - 1) * n + k] = 1.0 / safe(d[n - 1] - lam[k]);
    for (int b = n - 2; b >= 0; --b) {
      const double e2 = e[b] * e[b];
      const double* next = bw + (b + 1) * n;
      double* cur = bw + b * n;
#pragma omp simd
      for (int k = 0; k < n; ++k) cur[k] = 1.0 / safe(d[b] - lam[k] - e2 * next[k]);
    }
    // γ_b = D⁺_b + D⁻_b − (T_bb − λ) = (T_bb − λ) − e_{b−1}²/D⁺_{b−1} − e_b²/D⁻_{b+1}.
    int* r = ws.twist_index.data();
    for (int k = 0; k < n; ++k) {
      twist[k] = std::numeric_limits<double>::infinity();
      r[k] = 0;
    }
    for (int b = 0; b < n; ++b) {
      const double up = b > 0 ? e[b - 1] * e[b - 1] : 0.0, down = b + 1 < n ? e[b] * e[b] : 0.0;
      const double* above = fw + (b > 0 ? b - 1 : 0) * n;
      const double* below = bw + (b + 1 < n ? b + 1 : b) * n;
      for (int k = 0; k < n; ++k) {
        const double g = std::abs(d[b] - lam[k] - up * above[k] - down * below[k]);
        if (g < twist[k]) {
          twist[k] = g;
          r[k] = b;
        }
      }
    }
    for (int k = 0; k < n; ++k) {
      double* q = ws.q.data() + static_cast<std::ptrdiff_t>(k) * n;
      q[r[k]] = 1.0;
      double norm2 = 1.0;
      for (int b = r[k] - 1; b >= 0; --b) {
        q[b] = -e[b] * fw[b * n + k] * q[b + 1];
        norm2 += q[b] * q[b];
      }
      for (int b = r[k]; b + 1 < n; ++b) {
        q[b + 1] = -e[b] * bw[(b + 1) * n + k] * q[b];
        norm2 += q[b + 1] * q[b + 1];
      }
      const double scale = 1.0 / std::sqrt(norm2);
      for (int b = 0; b < n; ++b) q[b] *= scale;
    }
  }

  // Runs f(c, workspace) for every chain cluster c on the threads (see `chains`).
  template <class F>
  void for_each_chain(F&& f) {
    const int nc = static_cast<int>(chains.size());
    const int parts = std::min({threads_for(chain_bonds_before.back()), nc, static_cast<int>(workspaces.size())});
    if (parts <= 1) {
      run_as_one_part(nc > 1 ? chain_bonds_before.back() : 0, [&] {
        for (int k = 0; k < nc; ++k) f(clusters[chains[k]], workspaces[0]);
      });
      return;
    }
    run_parts(parts, [&](int part) {
      auto first = [&](int v) {
        return static_cast<int>(std::lower_bound(chain_bonds_before.begin(), chain_bonds_before.end() - 1,
                                                 block_begin(chain_bonds_before.back(), parts, v)) -
                                chain_bonds_before.begin());
      };
      const int end = part + 1 == parts ? nc : first(part + 1);
      for (int k = first(part); k < end; ++k) f(clusters[chains[k]], workspaces[part]);
    });
  }
};

StiffModes::StiffModes(std::vector<StiffBond> bonds, Eigen::VectorXd inv_mass, double epsilon, int max_cluster_bonds,
                       Solver solver)
    : impl_(std::make_unique<Impl>()) {
  Impl& d = *impl_;
  if (!(epsilon > 0.0) || !std::isfinite(epsilon))
    throw InputError("StiffModes: epsilon must be positive and finite, got " + std::to_string(epsilon));
  if (max_cluster_bonds < 1 || max_cluster_bonds > kMaxDenseBonds)
    throw InputError("StiffModes: max_cluster_bonds must be in [1, " + std::to_string(kMaxDenseBonds) + "], got " +
                     std::to_string(max_cluster_bonds));
  // The shared rules (forcefields/stiff_bond.hpp); among them, a bond between two fixed
  // particles has no vibrational mode.
  if (const auto problem = find_stiff_bond_problem(bonds, &inv_mass)) throw InputError("StiffModes: " + problem->what);

  d.bonds = std::move(bonds);
  d.inv_mass = std::move(inv_mass);
  d.epsilon = epsilon;

  const std::vector<ConstraintCluster> found = find_clusters(d.bonds, d.inv_mass);
  int max_nb = 0, max_np = 0, max_chain = 0;
  for (size_t ci = 0; ci < found.size(); ++ci) {
    const ConstraintCluster& fc = found[ci];
    const int nb = static_cast<int>(fc.bonds.size());
    if (nb > max_cluster_bonds) {
      ++d.num_skipped;
      continue;
    }
    Impl::Cluster c;
    c.index = static_cast<int>(ci);
    c.first_mode = d.num_modes;
    c.bonds = fc.bonds;
    if (solver == Solver::fast) {
      ClusterPath path = cluster_path(fc, d.bonds, d.inv_mass);
      c.chain = path.shape == ClusterShape::chain;
      if (c.chain) c.bonds = std::move(path.bonds);
    }
    c.particles = fc.particles;
    for (int p : c.particles) c.im.push_back(d.inv_mass[p]);
    auto local = [&](int p) {
      return static_cast<int>(std::lower_bound(c.particles.begin(), c.particles.end(), p) - c.particles.begin());
    };
    for (int b : c.bonds) {
      c.li.push_back(local(d.bonds[b].i));
      c.lj.push_back(local(d.bonds[b].j));
    }
    for (const auto& [p, at] : bonds_at_mobile_particles(c.bonds, d.bonds, d.inv_mass))
      for (size_t k = 0; k < at.size(); ++k)
        for (size_t l = 0; l < k; ++l) {
          const int b = std::max(at[k].first, at[l].first), e = std::min(at[k].first, at[l].first);
          c.couplings.push_back({b, e, at[k].second * at[l].second * d.inv_mass[p]});
        }
    if (c.chain) {  // chain order: bond b+1 is coupled to b, through the one mobile particle they share
      c.off_w.assign(nb > 0 ? nb - 1 : 0, 0.0);
      for (const Impl::Cluster::Coupling& k : c.couplings)
        if (k.b == k.e + 1) c.off_w[k.e] = k.w;
    }
    if (c.chain) {
      d.chains.push_back(static_cast<int>(d.clusters.size()));
      max_chain = std::max(max_chain, nb);
    }
    d.num_modes += nb;
    max_nb = std::max(max_nb, nb);
    max_np = std::max(max_np, static_cast<int>(c.particles.size()));
    d.clusters.push_back(std::move(c));
  }

  d.u.resize(3, max_nb);
  d.r.resize(max_nb);
  d.A.resize(max_nb, max_nb);
  d.z.resize(max_nb);
  d.zdot.resize(max_nb);
  d.w.resize(max_nb);
  d.wdot.resize(max_nb);
  d.wk.resize(3, max_np);

  d.chain_bonds_before.assign(1, 0);
  for (int k : d.chains)
    d.chain_bonds_before.push_back(d.chain_bonds_before.back() + static_cast<std::int64_t>(d.clusters[k].bonds.size()));
  // One workspace per thread (at most kMaxParts); more threads later simply share the parts.
  d.workspaces.resize(d.chains.empty() ? 0 : static_cast<size_t>(std::clamp(max_threads(), 1, kMaxParts)));
  for (Impl::ChainWorkspace& ws : d.workspaces) {
    const int n = max_chain;
    ws.u.resize(3, n);
    ws.r = ws.diag = ws.off = ws.lambda = ws.scratch = ws.z = ws.zdot = ws.w = ws.wdot = ws.coef = ws.twist =
        Eigen::VectorXd::Zero(n);
    ws.q = ws.inv_forward = ws.inv_backward = Eigen::VectorXd::Zero(static_cast<Eigen::Index>(n) * n);
    ws.twist_index.assign(static_cast<size_t>(n), 0);
  }
  d.h = Eigen::Matrix3Xd::Zero(3, static_cast<Eigen::Index>(d.bonds.size()));
  d.cluster_W.assign(found.size(), 0.0);
  d.cluster_validity.assign(found.size(), Validity{kInf, kInf});
}

StiffModes::~StiffModes() = default;
StiffModes::StiffModes(StiffModes&&) noexcept = default;
StiffModes& StiffModes::operator=(StiffModes&&) noexcept = default;

int StiffModes::num_modes() const {
  return impl_->num_modes;
}
int StiffModes::num_skipped_clusters() const {
  return impl_->num_skipped;
}
double StiffModes::epsilon() const {
  return impl_->epsilon;
}

void StiffModes::frequencies(const Eigen::Matrix3Xd& x, Eigen::Ref<Eigen::VectorXd> omega) {
  Impl& d = *impl_;
  d.check_positions(x);
  if (omega.size() != d.num_modes)
    throw std::invalid_argument("StiffModes::frequencies: omega has size " + std::to_string(omega.size()) +
                                ", expected " + std::to_string(d.num_modes));
  // A is SPD only up to rounding where constraints are redundant; report ω = 0 there.
  d.for_each_chain([&](const Impl::Cluster& c, Impl::ChainWorkspace& ws) {
    d.decompose_chain(c, x, false, ws);
    for (int k = 0; k < static_cast<int>(c.bonds.size()); ++k)
      omega[c.first_mode + k] = std::sqrt(std::max(ws.lambda[k], 0.0));
  });
  for (const Impl::Cluster& c : d.clusters) {
    if (c.chain) continue;
    d.decompose(c, x, false);
    const auto& lam = d.solver.eigenvalues();
    for (int k = 0; k < lam.size(); ++k) omega[c.first_mode + k] = std::sqrt(std::max(lam[k], 0.0));
  }
}

void StiffModes::actions(const Eigen::Matrix3Xd& x, const Eigen::Matrix3Xd& v, Eigen::Ref<Eigen::VectorXd> I) {
  Impl& d = *impl_;
  d.check_positions(x);
  if (v.cols() != x.cols())
    throw std::invalid_argument("StiffModes::actions: v has " + std::to_string(v.cols()) + " particles, expected " +
                                std::to_string(x.cols()));
  if (I.size() != d.num_modes)
    throw std::invalid_argument("StiffModes::actions: I has size " + std::to_string(I.size()) + ", expected " +
                                std::to_string(d.num_modes));
  const double inv_eps2 = 1.0 / (d.epsilon * d.epsilon);
  // The chain path: the same formulas as below with the tridiagonal decomposition.
  d.for_each_chain([&](const Impl::Cluster& c, Impl::ChainWorkspace& ws) {
    d.decompose_chain(c, x, true, ws);
    const int nb = static_cast<int>(c.bonds.size());
    for (int b = 0; b < nb; ++b) {
      const StiffBond& bond = d.bonds[c.bonds[b]];
      ws.z[b] = bond.alpha * (ws.r[b] - bond.length);
      ws.zdot[b] = bond.alpha * ws.u.col(b).dot(v.col(bond.i) - v.col(bond.j));
    }
    const Eigen::Map<const Eigen::MatrixXd> Q(ws.q.data(), nb, nb);
    ws.w.head(nb).noalias() = Q.transpose() * ws.z.head(nb);
    ws.wdot.head(nb).noalias() = Q.transpose() * ws.zdot.head(nb);
    for (int k = 0; k < nb; ++k) {
      const double lk = d.positive_eigenvalue(c, k, ws.lambda.head(nb));
      const double energy = 0.5 * ws.wdot[k] * ws.wdot[k] / lk + 0.5 * inv_eps2 * ws.w[k] * ws.w[k];
      I[c.first_mode + k] = energy / std::sqrt(lk);
    }
  });
  for (const Impl::Cluster& c : d.clusters) {
    if (c.chain) continue;
    d.decompose(c, x, true);
    const int nb = static_cast<int>(c.bonds.size());
    // Linearised normal motion (docs/design.md §4): ζ = g(x) obeys ζ̈ ≈ G ẍ = −ε⁻² S K ζ, so
    // z = K^{1/2} ζ obeys z̈ = −ε⁻² A z and decouples in the eigenbasis of A. The normal
    // kinetic energy ½ ζ̇ᵀ S⁻¹ ζ̇ = ½ żᵀ A⁻¹ ż splits into ½ ẇ_k²/λ_k; the potential
    // ε⁻² V = ½ ε⁻² |z|² into ½ ε⁻² w_k².
    d.z.resize(nb);
    d.zdot.resize(nb);
    for (int b = 0; b < nb; ++b) {
      const StiffBond& bond = d.bonds[c.bonds[b]];
      d.z[b] = bond.alpha * (d.r[b] - bond.length);
      d.zdot[b] = bond.alpha * d.u.col(b).dot(v.col(bond.i) - v.col(bond.j));
    }
    d.w.noalias() = d.solver.eigenvectors().transpose() * d.z;
    d.wdot.noalias() = d.solver.eigenvectors().transpose() * d.zdot;
    for (int k = 0; k < nb; ++k) {
      const double lk = d.positive_eigenvalue(c, k);
      const double energy = 0.5 * d.wdot[k] * d.wdot[k] / lk + 0.5 * inv_eps2 * d.w[k] * d.w[k];
      // Paper eq. (actions): energy over the unscaled frequency (= harmonic action / ε).
      I[c.first_mode + k] = energy / std::sqrt(lk);
    }
  }
}

double StiffModes::correction_force(const Eigen::VectorXd& I, const Eigen::Matrix3Xd& x, Eigen::Matrix3Xd& f) {
  Impl& d = *impl_;
  d.check_positions(x);
  if (I.size() != d.num_modes)
    throw std::invalid_argument("StiffModes::correction_force: I has size " + std::to_string(I.size()) + ", expected " +
                                std::to_string(d.num_modes));
  if (f.cols() != x.cols()) f.resize(3, x.cols());
  f.setZero();
  // The chain path. A_bb is constant, so ∂λ_k = q_kᵀ ∂A q_k = 2 Σ_b q_kb q_k,b+1 ∂A_{b,b+1} touches
  // only A's off-diagonal, A_{b,b+1} = α_b α_{b+1} w_b u_b·u_{b+1} (w_b = off_w). Summed over the
  // modes first, ∇W = Σ_k (I_k/2ω_k) ∇λ_k = Σ_b γ_b ∇(u_b·u_{b+1}) with
  //   γ_b = α_b α_{b+1} w_b Σ_k (I_k/ω_k) q_kb q_k,b+1,
  // and ∂(u_b·u_c)/∂x_i(b) = P_b u_c / r_b, P_b = I − u_b u_bᵀ: O(bonds²) per chain for the
  // coefficients, O(bonds) for the force, instead of O(bonds) per mode.
  d.for_each_chain([&](const Impl::Cluster& c, Impl::ChainWorkspace& ws) {
    d.decompose_chain(c, x, true, ws);
    const int nb = static_cast<int>(c.bonds.size());
    const Eigen::Map<const Eigen::MatrixXd> Q(ws.q.data(), nb, nb);
    double W_c = 0.0;
    ws.coef.head(nb).setZero();
    for (int k = 0; k < nb; ++k) {
      const double Ik = I[c.first_mode + k];
      if (Ik == 0.0) continue;  // a zero action contributes nothing, even at ω_k = 0
      const double omega = std::sqrt(d.positive_eigenvalue(c, k, ws.lambda.head(nb)));
      W_c += Ik * omega;
      const double s = Ik / omega;
      const double* q = Q.col(k).data();
      for (int b = 0; b + 1 < nb; ++b) ws.coef[b] += s * q[b] * q[b + 1];
    }
    d.cluster_W[c.index] = W_c;
    for (int b = 0; b < nb; ++b) d.h.col(c.bonds[b]).setZero();  // t_b = Σ_c γ_bc u_c, then P_b t_b / r_b
    for (int b = 0; b + 1 < nb; ++b) {
      const double gamma = ws.coef[b] * d.bonds[c.bonds[b]].alpha * d.bonds[c.bonds[b + 1]].alpha * c.off_w[b];
      d.h.col(c.bonds[b]) += gamma * ws.u.col(b + 1);
      d.h.col(c.bonds[b + 1]) += gamma * ws.u.col(b);
    }
    for (int b = 0; b < nb; ++b) {
      const Eigen::Vector3d t = d.h.col(c.bonds[b]);
      d.h.col(c.bonds[b]) = (t - ws.u.col(b) * ws.u.col(b).dot(t)) / ws.r[b];
    }
  });
  double W = 0.0;
  for (const Impl::Cluster& c : d.clusters) {
    if (c.chain) {  // in cluster order: a fixed particle may be shared with another cluster
      W += d.cluster_W[c.index];
      for (int b : c.bonds) {
        f.col(d.bonds[b].i) -= d.h.col(b);
        f.col(d.bonds[b].j) += d.h.col(b);
      }
      continue;
    }
    d.decompose(c, x, true);
    const int nb = static_cast<int>(c.bonds.size());
    const int np = static_cast<int>(c.particles.size());
    const auto& Q = d.solver.eigenvectors();
    for (int k = 0; k < nb; ++k) {
      const double Ik = I[c.first_mode + k];
      if (Ik == 0.0) continue;  // a zero action contributes nothing, even at ω_k = 0
      const double omega = std::sqrt(d.positive_eigenvalue(c, k));
      W += Ik * omega;
      // Perturbation theory on A q_k = λ_k q_k with |q_k| = 1: dλ_k = q_kᵀ dA q_k
      // = 2 (K^{1/2} q_k)ᵀ dG M⁻¹ Gᵀ K^{1/2} q_k, and row b of dG is (∇²g_b dx)ᵀ, hence
      // ∇λ_k = 2 Σ_b √K_b q_kb ∇²g_b w_k, w_k = M⁻¹ Gᵀ K^{1/2} q_k (docs/design.md §4).
      d.wk.leftCols(np).setZero();
      for (int b = 0; b < nb; ++b) {
        const double s = d.bonds[c.bonds[b]].alpha * Q(b, k);
        d.wk.col(c.li[b]) += (s * c.im[c.li[b]]) * d.u.col(b);
        d.wk.col(c.lj[b]) -= (s * c.im[c.lj[b]]) * d.u.col(b);
      }
      // −∇(I_k ω_k) = −I_k ∇λ_k / (2 ω_k) = −(I_k/ω_k) Σ_b √K_b q_kb ∇²g_b w_k, with ∇²g_b
      // acting on (x_i, x_j) as [[A_b, −A_b], [−A_b, A_b]], A_b = (I − u_b u_bᵀ)/r_b.
      const double scale = Ik / omega;
      for (int b = 0; b < nb; ++b) {
        const StiffBond& bond = d.bonds[c.bonds[b]];
        const double coef = scale * bond.alpha * Q(b, k);
        if (coef == 0.0) continue;
        const Eigen::Vector3d diff = d.wk.col(c.li[b]) - d.wk.col(c.lj[b]);
        const Eigen::Vector3d ub = d.u.col(b);
        const Eigen::Vector3d h = (coef / d.r[b]) * (diff - ub * ub.dot(diff));
        f.col(bond.i) -= h;
        f.col(bond.j) += h;
      }
    }
  }
  return W;
}

namespace {

// Gaps and resonances of one cluster's ascending frequencies om[0..nb), folded into out.
void scan_validity(const double* om, int nb, StiffModes::Validity& out) {
  // ω is ascending (the solvers sort λ), so the smallest gap is between neighbours and
  // the nearest ω_l to a target is found by bisection.
  for (int k = 1; k < nb; ++k) out.min_gap = std::min(out.min_gap, om[k] - om[k - 1]);
  // Up to an overall sign every |ω_j ± ω_k ± ω_l| is either ω_j + ω_k + ω_l (≥ 3 ω_min)
  // or |ω_a + ω_b − ω_c| for some (a ≤ b, c); the latter with c = a gives ω_b ≥ ω_min,
  // which the scan below includes, so the scan alone attains the minimum.
  for (int a = 0; a < nb; ++a) {
    for (int b = a; b < nb; ++b) {
      const double target = om[a] + om[b];
      const double* it = std::lower_bound(om, om + nb, target);
      if (it != om + nb) out.min_resonance = std::min(out.min_resonance, *it - target);
      if (it != om) out.min_resonance = std::min(out.min_resonance, target - *(it - 1));
    }
  }
}

}  // namespace

StiffModes::Validity StiffModes::validity(const Eigen::Matrix3Xd& x) {
  Impl& d = *impl_;
  d.check_positions(x);
  Validity out{kInf, kInf};
  d.for_each_chain([&](const Impl::Cluster& c, Impl::ChainWorkspace& ws) {
    d.decompose_chain(c, x, false, ws);
    const int nb = static_cast<int>(c.bonds.size());
    for (int k = 0; k < nb; ++k) ws.z[k] = std::sqrt(std::max(ws.lambda[k], 0.0));
    d.cluster_validity[c.index] = Validity{kInf, kInf};
    scan_validity(ws.z.data(), nb, d.cluster_validity[c.index]);
  });
  for (const Impl::Cluster& c : d.clusters) {
    if (c.chain) {
      out.min_gap = std::min(out.min_gap, d.cluster_validity[c.index].min_gap);
      out.min_resonance = std::min(out.min_resonance, d.cluster_validity[c.index].min_resonance);
      continue;
    }
    d.decompose(c, x, false);
    const auto& lam = d.solver.eigenvalues();
    const int nb = static_cast<int>(lam.size());
    d.z.resize(nb);  // ω, as scratch
    for (int k = 0; k < nb; ++k) d.z[k] = std::sqrt(std::max(lam[k], 0.0));
    scan_validity(d.z.data(), nb, out);
  }
  return out;
}

}  // namespace stiffmd
