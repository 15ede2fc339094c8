// The constraint toolbox (Lubich & Weiss §2.2–2.3): building it, and its accessors.
//
// Every operation reduces to solves with K(a, b) = G(a) M⁻¹ G(b)ᵀ on one cluster:
//   S(x) = K(x, x)        (SPD)  force and velocity projections;
//   J    = K(y, x_ref)           Newton matrix of SHAKE / the mollifier α;
//   Jᵀ   = K(x, X)               step 2 of the mollified force.
// K has the sparsity of S, so one pattern per cluster (the "couplings") serves all three; a
// non-symmetric K is simply assembled with its arguments swapped instead of solving with Kᵀ.
//
// Three back ends, chosen once per cluster in the constructor below (integrators/constraint_solvers.hpp:
// open chains tridiagonal, small other clusters dense, large ones sparse). Clusters are solved in
// parallel on the OpenMP threads (Impl::for_each_cluster). The toolbox's work by file:
// integrators/constraint_toolbox_impl.hpp.
//
// S(x) is measured and factored once per configuration: a constrained BAOAB step asks for it up
// to five times, at three positions. The toolbox keeps the last configuration it was
// handed, bit for bit, with G there and S's factors; an operation at the same x reuses them. What
// is kept is a function of x alone, so a run restarted without the cache computes the same bits.
// SHAKE near its reference iterates with that S(x_ref) (the chord, SHAKE's own quasi-Newton, no
// factorization) and falls back to full Newton on J when it contracts too slowly.
#include "integrators/constraints.hpp"

#include <algorithm>
#include <cstdint>
#include <memory>
#include <stdexcept>
#include <utility>
#include <vector>

#include "core/errors.hpp"
#include "integrators/constraint_toolbox_impl.hpp"

namespace stiffmd {
using namespace constraint_detail;  // the toolbox's private types (constraint_toolbox_impl.hpp)
namespace {

// Clusters that are not open chains and have more bonds than this use sparse factorizations.
// Measured on rings (mollified force, -O2): dense wins below ~40 bonds, sparse above, and
// only the dense path is allocation-free.
constexpr int kMaxDenseBonds = 40;

std::vector<Coupling> couplings_of(const std::vector<int>& order, const std::vector<StiffBond>& bonds,
                                   const Eigen::VectorXd& inv_mass) {
  std::vector<Coupling> couplings;
  for (const auto& [particle, list] : bonds_at_mobile_particles(order, bonds, inv_mass))
    for (const auto& [row, row_sign] : list)
      for (const auto& [col, col_sign] : list)
        couplings.push_back({row, col, particle, row_sign * col_sign, order[row], order[col]});
  return couplings;
}

// The shared rules (forcefields/stiff_bond.hpp): the toolbox needs every one of them, S being
// singular otherwise (a bond between fixed particles, a duplicated row, unrealisable lengths).
void validate(const std::vector<StiffBond>& bonds, const Eigen::VectorXd& inv_mass) {
  if (const auto problem = find_stiff_bond_problem(bonds, &inv_mass)) throw InputError(problem->what);
}

}  // namespace

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
      d.solver = make_dense_solver(n, d.couplings);
    else
      d.solver = make_sparse_solver(n, d.couplings);
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
  plan_blocks();
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

const std::vector<int>& ConstraintToolbox::cluster_bonds(int c) const {
  return impl_->data.at(static_cast<std::size_t>(c)).bonds;
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

}  // namespace stiffmd
