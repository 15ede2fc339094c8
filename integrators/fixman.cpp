// Fixman's potential U_F = (kT/2) log det A and its force (docs/design.md §5).
//
// log det A = log det S + Σ_b log α_b², so the gradient needs only S = G M⁻¹ Gᵀ:
//   ∂U_F/∂x = (kT/2) tr(S⁻¹ ∂S/∂x).
// S_bb = 1/m_i + 1/m_j does not depend on x; an off-diagonal entry of a pair of bonds b, c
// sharing a mobile particle p is S_bc = w_bc u_b·u_c with w_bc = s_b(p) s_c(p)/m_p (s_b(i) = +1,
// s_b(j) = −1: G's rows carry +u_b at i, −u_b at j). With ∂u_b/∂x_i = −∂u_b/∂x_j = P_b/r_b,
// P_b = I − u_b u_bᵀ, the force on bond b's ends is
//   f_i = −h_b, f_j = +h_b,  h_b = P_b t_b / r_b,  t_b = kT Σ_c Z_bc w_bc u_c,  Z = S⁻¹,
// summed over the bonds c coupled to b: only Z on the pattern of S is needed.
#include "integrators/eigen_dense.hpp"  // first: see the header

#include "integrators/fixman.hpp"

#include <algorithm>
#include <cmath>
#include <limits>
#include <map>
#include <stdexcept>
#include <string>
#include <utility>

#include "core/errors.hpp"
#include "core/parallel.hpp"
#include "integrators/constraints.hpp"

namespace stiffmd {
namespace {

// A pivot this small relative to the largest diagonal entry of S means the bond directions are
// (numerically) linearly dependent: log det S → −∞ and the force blows up.
constexpr double kSingularPivot = 1e-13;

// Two bonds k < l (local indices) coupled through a shared mobile particle: S_kl = weight u_k·u_l.
struct Pair {
  int k;
  int l;
  double weight;
};

// The shared rules of a set of stiff bonds (forcefields/stiff_bond.hpp).
void validate(const std::vector<StiffBond>& bonds, const Eigen::VectorXd& inv_mass) {
  if (const auto problem = find_stiff_bond_problem(bonds, &inv_mass))
    throw std::invalid_argument("FixmanPotential: " + problem->what);
}

// Band of the inverse of an SPD tridiagonal matrix (diagonal d[0..n), off-diagonal e[0..n−1)) by
// its LDLᵀ factorization: D_0 = d_0, l_k = e_k/D_k, D_{k+1} = d_{k+1} − l_k e_k. Since Lᵀ Z =
// D⁻¹ L⁻¹ is lower triangular with diagonal D⁻¹, its (k, k+1) and (k, k) entries give the backward
// recurrences Z_{k,k+1} = −l_k Z_{k+1,k+1}, Z_kk = 1/D_k − l_k Z_{k,k+1} (all terms of Z_kk ≥ 0:
// no cancellation). Writes D into pivot, l into factor, Z_kk into z_diag, Z_{k,k+1} into z_off.
// Returns false if a pivot is ≤ kSingularPivot·scale.
bool tridiagonal_inverse_band(int n, const double* d, const double* e, double scale, double* pivot, double* factor,
                              double* z_diag, double* z_off) {
  pivot[0] = d[0];
  for (int k = 0; k + 1 < n; ++k) {
    if (!(pivot[k] > kSingularPivot * scale)) return false;
    factor[k] = e[k] / pivot[k];
    pivot[k + 1] = d[k + 1] - factor[k] * e[k];
  }
  if (!(pivot[n - 1] > kSingularPivot * scale)) return false;
  z_diag[n - 1] = 1.0 / pivot[n - 1];
  for (int k = n - 2; k >= 0; --k) {
    z_off[k] = -factor[k] * z_diag[k + 1];
    z_diag[k] = 1.0 / pivot[k] - factor[k] * z_off[k];
  }
  return true;
}

// Σ_k log p_k of positive pivots with one logarithm per ~100 factors instead of one each: the
// product is taken as it goes and its logarithm banked whenever it leaves [2^−500, 2^500]. A
// pivot lies in (kSingularPivot · scale, scale] (S_kk = 1/m_i + 1/m_j bounds it above, and
// factorize rejects smaller), so no product overflows before it is banked unless the masses are
// beyond 1e±150.
double sum_of_logs(const double* pivot, int n) {
  constexpr double kHigh = 0x1p500, kLow = 0x1p-500;
  double banked = 0.0, product = 1.0;
  for (int k = 0; k < n; ++k) {
    product *= pivot[k];
    if (!(product < kHigh && product > kLow)) {
      banked += std::log(product);
      product = 1.0;
    }
  }
  return banked + std::log(product);
}

struct Cluster {
  int index = 0;  // position in find_clusters order, for messages
  ClusterShape shape = ClusterShape::other;
  std::vector<int> bonds;   // local → global bond index (path order for chains and rings)
  std::vector<Pair> pairs;  // chain: pair k = (k, k+1); ring: the same, then (0, n−1); other: any order
  double log_alpha2 = 0.0;  // Σ_b log α_b², the constant that turns log det S into log det A
  double log_det = 0.0;     // log det S at the last evaluation
  // Scratch, sized in the constructor.
  Eigen::VectorXd diag;    // S_kk = 1/m_i + 1/m_j
  Eigen::VectorXd value;   // S on each pair
  Eigen::VectorXd z_pair;  // Z = S⁻¹ on each pair
  // Open chains, at the last evaluation: Z_{k,k+1} (the toolbox's band or z_pair) and the frame
  // u_b, r_b it was formed in (the toolbox's kept one or this object's measure).
  const double* z_chain = nullptr;
  const Eigen::Matrix3Xd* u_chain = nullptr;
  const Eigen::VectorXd* r_chain = nullptr;
  Eigen::VectorXd pivot, factor, z_diag, z_off, border, y;  // chains and rings
  Eigen::MatrixXd S, Z;                                     // other shapes (and Path::dense)
  Eigen::LLT<Eigen::MatrixXd> llt;
  Eigen::VectorXd column;
};

}  // namespace

struct FixmanPotential::Impl {
  std::vector<StiffBond> bonds;
  Eigen::VectorXd inv_mass;
  std::vector<Cluster> clusters;
  std::vector<std::int64_t> bonds_before;  // bonds in clusters 0 … c − 1; size clusters + 1
  bool clusters_share_particles = false;   // through a fixed particle: scatter serially
  Eigen::Matrix3Xd u;                      // u_b, by global bond index
  Eigen::VectorXd r;                       // r_b = |x_i − x_j|
  Eigen::Matrix3Xd h;                      // h_b = P_b t_b / r_b: force −h_b on i, +h_b on j
  Path path = Path::fast;
  ConstraintToolbox* toolbox = nullptr;  // use_toolbox: G and the factors of S on open chains

  Impl(std::vector<StiffBond> bonds_in, Eigen::VectorXd inv_mass_in, Path path);
  void measure(const Cluster& c, const Eigen::Matrix3Xd& x);
  void inverse_on_pattern(Cluster& c) const;
  // Z on the pattern and log det S of cluster c at x: from the toolbox's factors for open chains
  // (use_toolbox), else measured and inverted here; for open chains also sets z_chain and its frame.
  void inverse(Cluster& c, const Eigen::Matrix3Xd& x);
  // Rings and other shapes: h_b for each bond (gradient), added to the ends (scatter).
  void gradient(Cluster& c, double kT);
  void scatter(const Cluster& c, Eigen::Matrix3Xd& f) const;
  // Open chains: the same terms in one walk along the chain, added to f as they are formed.
  void chain_force(const Cluster& c, double kT, Eigen::Matrix3Xd& f) const;
  void add_cluster_force(Cluster& c, double kT, Eigen::Matrix3Xd& f);
  // Adds −∇U_F(x) to f, returns U_F (force's work, without its clearing of f).
  double add_force(const Eigen::Matrix3Xd& x, double kT, Eigen::Matrix3Xd& f);

  // Runs f(c) for every cluster, in contiguous blocks of about equal bond count on the OpenMP
  // threads (as the constraint toolbox does); each cluster writes only its own bonds' scratch.
  template <class F>
  void for_each_cluster(F&& f) {
    const int nc = static_cast<int>(clusters.size());
    const int parts = std::min(threads_for(static_cast<std::int64_t>(bonds.size())), nc);
    if (parts <= 1) {
      run_as_one_part(nc > 1 ? static_cast<std::int64_t>(bonds.size()) : 0, [&] {
        for (int c = 0; c < nc; ++c) f(c);
      });
      return;
    }
    run_parts(parts, [&](int part) {
      auto first = [&](int v) {
        return static_cast<int>(
            std::lower_bound(bonds_before.begin(), bonds_before.end() - 1, block_begin(bonds_before.back(), parts, v)) -
            bonds_before.begin());
      };
      const int end = part + 1 == parts ? nc : first(part + 1);
      for (int c = first(part); c < end; ++c) f(c);
    });
  }
};

FixmanPotential::Impl::Impl(std::vector<StiffBond> bonds_in, Eigen::VectorXd inv_mass_in, Path path)
    : bonds(std::move(bonds_in)), inv_mass(std::move(inv_mass_in)), path(path) {
  validate(bonds, inv_mass);
  const int m = static_cast<int>(bonds.size());
  u = Eigen::Matrix3Xd::Zero(3, m);
  r = Eigen::VectorXd::Zero(m);
  h = Eigen::Matrix3Xd::Zero(3, m);
  const std::vector<ConstraintCluster> found = find_clusters(bonds, inv_mass);
  bonds_before.assign(1, 0);
  std::vector<int> owner(inv_mass.size(), -1);
  for (int ci = 0; ci < static_cast<int>(found.size()); ++ci) {
    Cluster c;
    c.index = ci;
    ClusterPath cp = cluster_path(found[ci], bonds, inv_mass);
    if (path == Path::dense) cp = {ClusterShape::other, found[ci].bonds};
    c.shape = cp.shape;
    c.bonds = std::move(cp.bonds);
    const int n = static_cast<int>(c.bonds.size());
    // The couplings: for each mobile particle, every pair of its bonds.
    const BondsAtParticles at = bonds_at_mobile_particles(c.bonds, bonds, inv_mass);  // (local bond, sign)
    std::map<std::pair<int, int>, double> weight;
    for (const auto& [p, list] : at)
      for (size_t a = 0; a < list.size(); ++a)
        for (size_t b = a + 1; b < list.size(); ++b) {
          const auto [k, sk] = list[a];
          const auto [l, sl] = list[b];
          weight[{std::min(k, l), std::max(k, l)}] += sk * sl * inv_mass[p];
        }
    c.pairs.resize(weight.size());
    int next = 0;
    for (const auto& [kl, w] : weight) {
      int slot = next++;
      if (c.shape != ClusterShape::other) slot = kl.second == kl.first + 1 ? kl.first : n - 1;  // ring corner last
      c.pairs[slot] = {kl.first, kl.second, w};
    }
    c.diag.resize(n);
    for (int k = 0; k < n; ++k) {
      const StiffBond& b = bonds[c.bonds[k]];
      c.diag[k] = inv_mass[b.i] + inv_mass[b.j];
      c.log_alpha2 += 2.0 * std::log(b.alpha);
    }
    const int np = static_cast<int>(c.pairs.size());
    c.value = c.z_pair = Eigen::VectorXd::Zero(np);
    if (c.shape == ClusterShape::other) {
      c.S = c.Z = Eigen::MatrixXd::Zero(n, n);
      c.llt = Eigen::LLT<Eigen::MatrixXd>(n);
      c.column = Eigen::VectorXd::Zero(n);
    } else {
      c.pivot = c.factor = c.z_diag = c.z_off = c.border = c.y = Eigen::VectorXd::Zero(n);
    }
    bonds_before.push_back(bonds_before.back() + n);
    for (int p : found[ci].particles) {
      if (owner[p] >= 0 && owner[p] != ci) clusters_share_particles = true;
      owner[p] = ci;
    }
    clusters.push_back(std::move(c));
  }
}

// u_b and r_b of the cluster's bonds; G does not exist where a bond has no direction.
void FixmanPotential::Impl::measure(const Cluster& c, const Eigen::Matrix3Xd& x) {
  for (int b : c.bonds) {
    const Eigen::Vector3d d = x.col(bonds[b].i) - x.col(bonds[b].j);
    const double rb = d.norm();
    if (!(rb > 0.0) || !std::isfinite(rb))
      throw NumericalError("Fixman potential: cluster " + std::to_string(c.index) + ", " + describe_bond(b, bonds[b]) +
                           (rb == 0.0 ? " has zero length" : " has a non-finite length"));
    r[b] = rb;
    u.col(b) = d / rb;
  }
}

// log det S and Z = S⁻¹ on the pairs of cluster c, from c.value.
void FixmanPotential::Impl::inverse_on_pattern(Cluster& c) const {
  const int n = static_cast<int>(c.bonds.size());
  const double scale = c.diag.maxCoeff();
  auto singular = [&]() {
    throw NumericalError("Fixman potential: cluster " + std::to_string(c.index) +
                         ": S = G M⁻¹ Gᵀ is singular (the bond directions are linearly dependent)");
  };
  if (c.shape == ClusterShape::chain) {
    if (!tridiagonal_inverse_band(n, c.diag.data(), c.value.data(), scale, c.pivot.data(), c.factor.data(),
                                  c.z_diag.data(), c.z_off.data()))
      singular();
    c.log_det = sum_of_logs(c.pivot.data(), n);
    for (int k = 0; k + 1 < n; ++k) c.z_pair[k] = c.z_off[k];
    return;
  }
  if (c.shape == ClusterShape::ring) {
    // Bordered solve: S = [[T, b], [bᵀ, d]] with T the tridiagonal leading (n−1)-block and
    // b = S_{0,n−1} e_0 + S_{n−2,n−1} e_{n−2}. With y = T⁻¹ b and the Schur complement
    // s = d − bᵀy > 0: S⁻¹ = [[T⁻¹ + y yᵀ/s, −y/s], [−yᵀ/s, 1/s]], det S = det T · s.
    const int t = n - 1;
    if (!tridiagonal_inverse_band(t, c.diag.data(), c.value.data(), scale, c.pivot.data(), c.factor.data(),
                                  c.z_diag.data(), c.z_off.data()))
      singular();
    double* b = c.border.data();
    double* y = c.y.data();
    std::fill(b, b + t, 0.0);
    b[0] += c.value[n - 1];
    b[t - 1] += c.value[n - 2];
    y[0] = b[0];  // L z = b, D w = z, Lᵀ y = w
    for (int k = 0; k + 1 < t; ++k) y[k + 1] = b[k + 1] - c.factor[k] * y[k];
    for (int k = 0; k < t; ++k) y[k] /= c.pivot[k];
    for (int k = t - 2; k >= 0; --k) y[k] -= c.factor[k] * y[k + 1];
    double s = c.diag[n - 1];
    for (int k = 0; k < t; ++k) s -= b[k] * y[k];
    if (!(s > kSingularPivot * scale)) singular();
    c.log_det = std::log(s) + sum_of_logs(c.pivot.data(), t);
    for (int k = 0; k + 1 < t; ++k) c.z_pair[k] = c.z_off[k] + y[k] * y[k + 1] / s;
    c.z_pair[n - 2] = -y[t - 1] / s;
    c.z_pair[n - 1] = -y[0] / s;
    return;
  }
  // Any other shape: dense Cholesky and the full inverse, column by column.
  c.S.setZero();
  c.S.diagonal() = c.diag;
  for (int p = 0; p < static_cast<int>(c.pairs.size()); ++p) {
    c.S(c.pairs[p].k, c.pairs[p].l) = c.value[p];
    c.S(c.pairs[p].l, c.pairs[p].k) = c.value[p];
  }
  c.llt.compute(c.S);
  if (c.llt.info() != Eigen::Success) singular();
  c.log_det = 0.0;
  for (int k = 0; k < n; ++k) {
    const double lkk = c.llt.matrixLLT()(k, k);
    if (!(lkk * lkk > kSingularPivot * scale)) singular();
    c.log_det += 2.0 * std::log(lkk);
  }
  for (int k = 0; k < n; ++k) {
    c.column.setZero();
    c.column[k] = 1.0;
    c.llt.solveInPlace(c.column);
    c.Z.col(k) = c.column;
  }
  for (int p = 0; p < static_cast<int>(c.pairs.size()); ++p) c.z_pair[p] = c.Z(c.pairs[p].k, c.pairs[p].l);
}

// h_b = P_b t_b / r_b, t_b = kT Σ_c Z_bc w_bc u_c (the header comment), into h.
void FixmanPotential::Impl::gradient(Cluster& c, double kT) {
  for (int b : c.bonds) h.col(b).setZero();
  for (int p = 0; p < static_cast<int>(c.pairs.size()); ++p) {
    const int bk = c.bonds[c.pairs[p].k], bl = c.bonds[c.pairs[p].l];
    const double gamma = kT * c.z_pair[p] * c.pairs[p].weight;
    h.col(bk) += gamma * u.col(bl);  // t_b, projected below
    h.col(bl) += gamma * u.col(bk);
  }
  for (int b : c.bonds) {
    const Eigen::Vector3d t = h.col(b);
    h.col(b) = (t - u.col(b) * u.col(b).dot(t)) / r[b];
  }
}

void FixmanPotential::Impl::inverse(Cluster& c, const Eigen::Matrix3Xd& x) {
  if (toolbox && c.shape == ClusterShape::chain) {
    // A chain's pairs are (k, k + 1) in order: Z on them is the band's off-diagonal. log det S =
    // −Σ log(1/pivot) (banked as for the pivots).
    const ConstraintToolbox::ChainInverseBand band = toolbox->chain_inverse_band(c.index);
    c.log_det = -sum_of_logs(band.inverse_pivots, band.n);
    c.z_chain = band.z_off;
    c.u_chain = &toolbox->kept_directions();
    c.r_chain = &toolbox->kept_lengths();
    return;
  }
  measure(c, x);
  for (int p = 0; p < static_cast<int>(c.pairs.size()); ++p)
    c.value[p] = c.pairs[p].weight * u.col(c.bonds[c.pairs[p].k]).dot(u.col(c.bonds[c.pairs[p].l]));
  inverse_on_pattern(c);
  c.z_chain = c.z_pair.data();
  c.u_chain = &u;
  c.r_chain = &r;
}

void FixmanPotential::Impl::add_cluster_force(Cluster& c, double kT, Eigen::Matrix3Xd& f) {
  if (c.shape == ClusterShape::chain) {
    chain_force(c, kT, f);
  } else {
    gradient(c, kT);
    scatter(c, f);
  }
}

// h_k = P_k t_k / r_k with t_k = kT (Z_{k−1,k} w_{k−1,k} u_{k−1} + Z_{k,k+1} w_{k,k+1} u_{k+1}) (the
// file's top comment), added to bond k's ends as it is formed: one pass over the chain's bonds, no
// h stored. Each particle receives its bonds' terms in bond order, as scatter adds them. Z and the
// frame are those inverse() left (z_chain, u_chain, r_chain).
void FixmanPotential::Impl::chain_force(const Cluster& c, double kT, Eigen::Matrix3Xd& f) const {
  const int n = static_cast<int>(c.bonds.size());
  const int* bond = c.bonds.data();
  const double* z_off = c.z_chain;
  const double* u = c.u_chain->data();
  const double* r = c.r_chain->data();
  double* out = f.data();
  double before = 0.0;  // γ_{k−1} = kT Z_{k−1,k} w_{k−1,k}; 0 at the first bond
  for (int k = 0; k < n; ++k) {
    const double* uk = u + 3 * bond[k];
    double tx = 0.0, ty = 0.0, tz = 0.0;
    if (k > 0) {
      const double* up = u + 3 * bond[k - 1];
      tx = before * up[0];
      ty = before * up[1];
      tz = before * up[2];
    }
    if (k + 1 < n) {
      const double gamma = kT * z_off[k] * c.pairs[k].weight;
      const double* un = u + 3 * bond[k + 1];
      tx += gamma * un[0];
      ty += gamma * un[1];
      tz += gamma * un[2];
      before = gamma;
    }
    const double along = uk[0] * tx + uk[1] * ty + uk[2] * tz;
    const double inv_r = 1.0 / r[bond[k]];
    const double hx = (tx - uk[0] * along) * inv_r, hy = (ty - uk[1] * along) * inv_r,
                 hz = (tz - uk[2] * along) * inv_r;
    double* fi = out + 3 * bonds[bond[k]].i;
    double* fj = out + 3 * bonds[bond[k]].j;
    fi[0] -= hx;
    fi[1] -= hy;
    fi[2] -= hz;
    fj[0] += hx;
    fj[1] += hy;
    fj[2] += hz;
  }
}

void FixmanPotential::Impl::scatter(const Cluster& c, Eigen::Matrix3Xd& f) const {
  for (int b : c.bonds) {
    f.col(bonds[b].i) -= h.col(b);
    f.col(bonds[b].j) += h.col(b);
  }
}

void FixmanPotential::use_toolbox(ConstraintToolbox* toolbox) {
  Impl& d = *impl_;
  if (toolbox && d.path == Path::dense)
    throw std::invalid_argument("FixmanPotential: the dense path is the reference; it does not use a toolbox");
  if (toolbox) {
    // The same bonds in the same clusters, each in the same order (find_clusters, cluster_path).
    bool same = toolbox->bonds().size() == d.bonds.size() && toolbox->clusters().size() == d.clusters.size();
    for (std::size_t b = 0; same && b < d.bonds.size(); ++b) {
      const StiffBond &p = toolbox->bonds()[b], &q = d.bonds[b];
      same = p.i == q.i && p.j == q.j && p.length == q.length;
    }
    for (const Cluster& c : d.clusters)
      if (same && c.shape == ClusterShape::chain) same = toolbox->cluster_bonds(c.index) == c.bonds;
    if (!same) throw std::invalid_argument("FixmanPotential: the constraint toolbox is built from other bonds");
  }
  d.toolbox = toolbox;
}

bool FixmanPotential::blocks() const {
  return impl_->toolbox && impl_->toolbox->blocks_available() && !impl_->clusters_share_particles;
}

// add_force's work on the clusters of block b: the toolbox's factors and bands there, then each
// cluster's inverse and force, as for_each_cluster gives them.
void FixmanPotential::add_block_force(int b, const Eigen::Matrix3Xd& x, double kT, Eigen::Matrix3Xd& f) {
  Impl& d = *impl_;
  d.toolbox->inverse_bands_block(b, x);
  for (int c = d.toolbox->block_cluster_begin(b), end = d.toolbox->block_cluster_end(b); c < end; ++c) {
    Cluster& cluster = d.clusters[c];
    d.inverse(cluster, x);
    d.add_cluster_force(cluster, kT, f);
  }
}

double FixmanPotential::value(double kT) const {
  double log_det = 0.0;
  for (const Cluster& c : impl_->clusters) log_det += c.log_det + c.log_alpha2;
  return 0.5 * kT * log_det;
}

FixmanPotential::FixmanPotential(std::vector<StiffBond> bonds, Eigen::VectorXd inv_mass, Path path)
    : impl_(std::make_unique<Impl>(std::move(bonds), std::move(inv_mass), path)) {}
FixmanPotential::~FixmanPotential() = default;
FixmanPotential::FixmanPotential(FixmanPotential&&) noexcept = default;
FixmanPotential& FixmanPotential::operator=(FixmanPotential&&) noexcept = default;

double FixmanPotential::force(const Eigen::Matrix3Xd& x, double kT, Eigen::Matrix3Xd& f) {
  Impl& d = *impl_;
  if (x.cols() != d.inv_mass.size())
    throw std::invalid_argument("FixmanPotential::force: x has " + std::to_string(x.cols()) + " particles, expected " +
                                std::to_string(d.inv_mass.size()));
  if (f.cols() != x.cols()) f.resize(3, x.cols());
  f.setZero();
  return d.add_force(x, kT, f);
}

double FixmanPotential::add_force(const Eigen::Matrix3Xd& x, double kT, Eigen::Matrix3Xd& f) {
  Impl& d = *impl_;
  if (x.cols() != d.inv_mass.size() || f.cols() != x.cols())
    throw std::invalid_argument("FixmanPotential::add_force: x has " + std::to_string(x.cols()) + " and f " +
                                std::to_string(f.cols()) + " particles, expected " + std::to_string(d.inv_mass.size()));
  return d.add_force(x, kT, f);
}

double FixmanPotential::Impl::add_force(const Eigen::Matrix3Xd& x, double kT, Eigen::Matrix3Xd& f) {
  // The toolbox's factors of S at x and the band of S⁻¹, open chains of one length in lockstep
  // (one chain's sweep is latency-bound): inverse() below then finds them.
  if (toolbox) toolbox->inverse_bands(x);
  for_each_cluster([&](int ci) {
    Cluster& c = clusters[ci];
    inverse(c, x);
    if (!clusters_share_particles) add_cluster_force(c, kT, f);  // each cluster owns its particles
  });
  double log_det = 0.0;
  for (Cluster& c : clusters) {
    if (clusters_share_particles) add_cluster_force(c, kT, f);  // a shared fixed particle: in cluster order
    log_det += c.log_det + c.log_alpha2;
  }
  return 0.5 * kT * log_det;
}

}  // namespace stiffmd
