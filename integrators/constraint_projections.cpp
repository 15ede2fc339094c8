// The constraint toolbox's projections (integrators/constraints.hpp) at the kept configuration x:
// the force projection P(x) f = f − Gᵀλ, S λ = G M⁻¹ f (paper eq. (proj)), and RATTLE's velocity
// projection v ← v − M⁻¹Gᵀμ, S μ = G v; open chains walk their path, in lockstep groups.
#include "integrators/constraint_toolbox_impl.hpp"

#include "core/errors.hpp"
#include "core/timing.hpp"

namespace stiffmd {
using namespace constraint_detail;  // the toolbox's private types (constraint_toolbox_impl.hpp)

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

// S μ = G v on cluster c (not an open chain), at the kept configuration: μ in its `sol`.
void ConstraintToolbox::Impl::solve_velocity_normal(int c, const Eigen::Matrix3Xd& v) {
  ClusterData& d = data[c];
  factor_kept_s(c, "velocity projection");
  for (int k = 0; k < d.rhs.size(); ++k) {
    const StiffBond& bond = bonds[d.bonds[k]];
    d.rhs[k] = at_kept.u.col(d.bonds[k]).dot(v.col(bond.i) - v.col(bond.j));
  }
  solve_kept_s(c);
}

// RATTLE's velocity step: the M-orthogonal projection of v onto the tangent space G v = 0 (not an
// open chain: those go through project_group).
void ConstraintToolbox::Impl::project_velocity_cluster(int c, Eigen::Matrix3Xd& v, Eigen::Matrix3Xd* force,
                                                       double rate) {
  ClusterData& d = data[c];
  solve_velocity_normal(c, v);
  add_constraint_displacement(c, at_kept, d.sol, -1.0, v);
  if (force != nullptr) add_constraint_force(c, at_kept, d.sol, -rate, *force, true);  // −rate Gᵀμ
}

// The velocity projection's right-hand side G v and its solve S μ = G v, without the update:
// ½ μᵀ S μ = ½ (Gv)ᵀ μ is the kinetic energy the update would remove (K(v − M⁻¹Gᵀμ) =
// K(v) − vᵀGᵀμ + ½ μᵀ G M⁻¹ Gᵀ μ, fixed particles at rest).
void ConstraintToolbox::Impl::normal_energy_group(int first, int count, const Eigen::Matrix3Xd& v) {
  if (!data[first].spd) {
    ClusterData& d = data[first];
    solve_velocity_normal(first, v);
    d.normal_energy = 0.5 * d.rhs.dot(d.sol);
    return;
  }
  factor_kept_group(first, count, "velocity projection");
  int cs[kChainGroup];
  for (int j = 0; j < count; ++j) {
    cs[j] = first + j;
    chain_project_rhs<false>(cs[j], v);
  }
  solve_chains(cs, count);
  for (int j = 0; j < count; ++j) data[cs[j]].normal_energy = 0.5 * data[cs[j]].rhs.dot(data[cs[j]].sol);
}

double ConstraintToolbox::normal_kinetic_energy(const Eigen::Matrix3Xd& x, const Eigen::Matrix3Xd& v) {
  const ScopedPhase phase(Phase::constraints);
  require_columns(x, impl_->num_particles(), "normal_kinetic_energy");
  require_columns(v, impl_->num_particles(), "normal_kinetic_energy");
  impl_->keep(x);
  impl_->for_each_group([&](int c, int count) { impl_->normal_energy_group(c, count, v); });
  double sum = 0.0;
  for (const ClusterData& d : impl_->data) sum += d.normal_energy;
  return sum;
}

void ConstraintToolbox::project_force(const Eigen::Matrix3Xd& x, Eigen::Matrix3Xd& f) {
  const ScopedPhase phase(Phase::constraints);
  require_columns(x, impl_->num_particles(), "project_force");
  require_columns(f, impl_->num_particles(), "project_force");
  impl_->keep(x);
  impl_->for_each_group([&](int c, int count) { impl_->project_group<true>(c, count, f); });
}

void ConstraintToolbox::project_velocity(const Eigen::Matrix3Xd& x, Eigen::Matrix3Xd& v, Eigen::Matrix3Xd* force,
                                         double rate) {
  const ScopedPhase phase(Phase::constraints);
  require_columns(x, impl_->num_particles(), "project_velocity");
  require_columns(v, impl_->num_particles(), "project_velocity");
  if (force != nullptr) require_columns(*force, impl_->num_particles(), "project_velocity (force)");
  impl_->keep(x);
  impl_->for_each_group([&](int c, int count) { impl_->project_group<false>(c, count, v, force, rate); });
}

// project_velocity and normal_kinetic_energy's terms on block b (constraints.hpp).
void ConstraintToolbox::project_velocity_block(int b, const Eigen::Matrix3Xd& x, Eigen::Matrix3Xd& v,
                                               Eigen::Matrix3Xd* force, double rate) {
  Impl& d = *impl_;
  const Impl::Block& k = d.blocks[b];
  d.keep_block(k, x);
  d.run_groups(k.cluster_begin, k.cluster_end,
               [&](int c, int count) { d.project_group<false>(c, count, v, force, rate); });
}

void ConstraintToolbox::normal_energy_block(int b, const Eigen::Matrix3Xd& x, const Eigen::Matrix3Xd& v) {
  Impl& d = *impl_;
  const Impl::Block& k = d.blocks[b];
  d.keep_block(k, x);
  d.run_groups(k.cluster_begin, k.cluster_end, [&](int c, int count) { d.normal_energy_group(c, count, v); });
}

}  // namespace stiffmd
