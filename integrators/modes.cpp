// Frequencies, actions and correction potential of the effective dynamics
// (design.md §3; Lubich & Weiss eqs. (CH), (actions), (separated), (nonresonant)).
#include "integrators/eigen_dense.hpp"  // first: see the header

#include <algorithm>
#include <cmath>
#include <limits>
#include <stdexcept>
#include <string>
#include <utility>
#include "integrators/modes.hpp"

#include "engine/errors.hpp"
#include "integrators/constraints.hpp"

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

  void check_positions(const Eigen::Matrix3Xd& x) const {
    if (x.cols() != inv_mass.size())
      throw std::invalid_argument("StiffModes: x has " + std::to_string(x.cols()) + " particles, expected " +
                                  std::to_string(inv_mass.size()));
  }

  // Bond geometry and A = K^{1/2} S K^{1/2} of cluster c at x, then its eigen-decomposition
  // (design.md §3). S_bc = Σ_p m_p⁻¹ (s_b(p) u_b)·(s_c(p) u_c) over the particles p the two
  // bonds share, s_b(i) = +1, s_b(j) = −1: the rows of G carry +u_b at i and −u_b at j.
  void decompose(const Cluster& c, const Eigen::Matrix3Xd& x, bool vectors) {
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
    A.resize(nb, nb);
    for (int b = 0; b < nb; ++b) {
      const double ab = bonds[c.bonds[b]].alpha;
      // u_b·u_b = 1 exactly; using it avoids a rounding asymmetry on the diagonal.
      A(b, b) = ab * ab * (c.im[c.li[b]] + c.im[c.lj[b]]);
      for (int e = 0; e < b; ++e) {
        double s = 0.0;
        if (c.li[b] == c.li[e]) s += c.im[c.li[b]];
        if (c.li[b] == c.lj[e]) s -= c.im[c.li[b]];
        if (c.lj[b] == c.li[e]) s -= c.im[c.lj[b]];
        if (c.lj[b] == c.lj[e]) s += c.im[c.lj[b]];
        const double v = (s == 0.0) ? 0.0 : ab * bonds[c.bonds[e]].alpha * s * u.col(b).dot(u.col(e));
        A(b, e) = v;
        A(e, b) = v;
      }
    }
    solver.compute(A, vectors ? Eigen::ComputeEigenvectors : Eigen::EigenvaluesOnly);
    if (solver.info() != Eigen::Success)
      throw NumericalError("StiffModes: eigen-decomposition of cluster " + std::to_string(c.index) + " (" +
                           std::to_string(nb) + " bonds) did not converge");
  }

  // λ_k of the last decomposition, after the check that 1/λ_k is meaningful.
  double positive_eigenvalue(const Cluster& c, int k) const {
    const auto& lam = solver.eigenvalues();
    const double lk = lam[k];
    if (!(lk > kZeroEigenvalue * lam[lam.size() - 1]))
      throw NumericalError("StiffModes: mode " + std::to_string(k) + " of cluster " + std::to_string(c.index) +
                           " has eigenvalue " + std::to_string(lk) +
                           " (zero frequency): its constraints are (nearly) redundant here");
    return lk;
  }
};

StiffModes::StiffModes(std::vector<StiffBond> bonds, Eigen::VectorXd inv_mass, double epsilon, int max_cluster_bonds)
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
  int max_nb = 0, max_np = 0;
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
    c.particles = fc.particles;
    for (int p : c.particles) c.im.push_back(d.inv_mass[p]);
    auto local = [&](int p) {
      return static_cast<int>(std::lower_bound(c.particles.begin(), c.particles.end(), p) - c.particles.begin());
    };
    for (int b : c.bonds) {
      c.li.push_back(local(d.bonds[b].i));
      c.lj.push_back(local(d.bonds[b].j));
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
  for (const Impl::Cluster& c : d.clusters) {
    d.decompose(c, x, false);
    const auto& lam = d.solver.eigenvalues();
    // A is SPD only up to rounding where constraints are redundant; report ω = 0 there.
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
  for (const Impl::Cluster& c : d.clusters) {
    d.decompose(c, x, true);
    const int nb = static_cast<int>(c.bonds.size());
    // Linearised normal motion (design.md §3): ζ = g(x) obeys ζ̈ ≈ G ẍ = −ε⁻² S K ζ, so
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
  double W = 0.0;
  for (const Impl::Cluster& c : d.clusters) {
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
      // ∇λ_k = 2 Σ_b √K_b q_kb ∇²g_b w_k, w_k = M⁻¹ Gᵀ K^{1/2} q_k (design.md §3).
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

StiffModes::Validity StiffModes::validity(const Eigen::Matrix3Xd& x) {
  Impl& d = *impl_;
  d.check_positions(x);
  Validity out{kInf, kInf};
  for (const Impl::Cluster& c : d.clusters) {
    d.decompose(c, x, false);
    const auto& lam = d.solver.eigenvalues();
    const int nb = static_cast<int>(lam.size());
    // ω is ascending (the solver sorts λ), so the smallest gap is between neighbours and
    // the nearest ω_l to a target is found by bisection. d.z holds ω here as scratch.
    d.z.resize(nb);
    for (int k = 0; k < nb; ++k) d.z[k] = std::sqrt(std::max(lam[k], 0.0));
    const double* om = d.z.data();
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
  return out;
}

}  // namespace stiffmd
