// The constraint toolbox (Lubich & Weiss §2.2–2.3).
//
// Built from the stiff bonds of a scene. Every operation uses the sparse SPD matrix
//   S(x) = G M⁻¹ Gᵀ,  G = g′(x) (one row per bond: +u_b at i, −u_b at j),
// which is block-diagonal over connected constraint clusters; each cluster is solved on
// its own (O(bonds) for chains), clusters are independent. Particles with inverse mass
// 0 (fixed) contribute nothing to S.
//
// Nothing here allocates after construction: scratch space is sized once.
#pragma once

#include <Eigen/Core>
#include <cstdint>
#include <functional>
#include <memory>
#include <vector>

#include "forcefields/stiff_bond.hpp"
#include "integrators/clusters.hpp"

namespace stiffmd {

// Slow force evaluated at a configuration: out = f(x) (f = −∇U), overwriting out.
using ForceFunction = std::function<void(const Eigen::Matrix3Xd& x, Eigen::Matrix3Xd& out)>;

class ConstraintToolbox {
 public:
  ConstraintToolbox(std::vector<StiffBond> bonds, Eigen::VectorXd inv_mass);
  ~ConstraintToolbox();
  ConstraintToolbox(ConstraintToolbox&&) noexcept;
  ConstraintToolbox& operator=(ConstraintToolbox&&) noexcept;

  const std::vector<StiffBond>& bonds() const;
  const std::vector<ConstraintCluster>& clusters() const;
  int num_bonds() const;
  // Cluster matrices factored so far (S, and the Newton matrices of SHAKE and the mollifier). S(x)
  // is measured and factored once per configuration: the toolbox keeps the last x it was handed
  // (compared bit for bit) with G(x) and S(x)'s factors, and SHAKE leaves its converged y kept.
  std::int64_t factorizations() const;

  // For Fixman's potential (integrators/fixman.cpp), which reads G(x) and the band of S(x)⁻¹ from
  // here instead of measuring and factoring again. inverse_bands(x) keeps x (as any call does)
  // and, on every open chain, measures and factors S there unless that is done (SHAKE and the
  // projections share the factors) and forms the band of S⁻¹ — chains of one length in lockstep,
  // each with the operations it gets alone. chain_inverse_band(c) then returns, for open chain c,
  // the off-diagonal of the band (z_off: n − 1 entries Z_{k,k+1}, in the cluster's bond order,
  // cluster_bonds — all U_F's gradient needs) and the inverse pivots of S's factorization (n
  // entries, det S = 1 / their product), forming them first if they are not current at the kept configuration; all null
  // when c is not an open chain. Valid until the next call that moves or refactors the kept
  // configuration. Distinct clusters may be served from distinct threads at once. kept_directions
  // and kept_lengths hold u_b and |d_b| at the kept configuration for every bond of a cluster
  // measured since keep. Both throw NumericalError as the factorization does.
  struct ChainInverseBand {
    const double* z_off = nullptr;
    const double* inverse_pivots = nullptr;
    int n = 0;
  };
  void keep(const Eigen::Matrix3Xd& x);
  void inverse_bands(const Eigen::Matrix3Xd& x);
  ChainInverseBand chain_inverse_band(int c);
  const std::vector<int>& cluster_bonds(int c) const;  // local → global bond (path order on chains)
  const Eigen::Matrix3Xd& kept_directions() const;
  const Eigen::VectorXd& kept_lengths() const;

  // g_b(x) = |x_i − x_j| − ℓ_b for every bond, into g (size m).
  void constraint_values(const Eigen::Matrix3Xd& x, Eigen::Ref<Eigen::VectorXd> g) const;
  // max_b |g_b(x)|
  double max_violation(const Eigen::Matrix3Xd& x) const;

  // Force projection, in place:  f ← P(x) f = f − Gᵀλ,  S λ = G M⁻¹ f   (paper eq. (proj)).
  // Afterwards G M⁻¹ f = 0.
  void project_force(const Eigen::Matrix3Xd& x, Eigen::Matrix3Xd& f);

  // RATTLE velocity projection, in place:  v ← v − M⁻¹Gᵀμ,  S μ = G v.  Afterwards G v = 0.
  // force, if given, gets −rate · Gᵀμ added at the mobile particles: M Δv · rate, the constraint
  // force of the impulse spread over a time 1/rate (nothing at fixed particles, whose v stays).
  void project_velocity(const Eigen::Matrix3Xd& x, Eigen::Matrix3Xd& v, Eigen::Matrix3Xd* force = nullptr,
                        double rate = 0.0);

  // ½ (Gv)ᵀ S⁻¹ (Gv) = K(v) − K(P(x)v), S μ = G v at x: the kinetic energy of v's part normal to
  // the manifold, which the velocity projection removes (P is M-orthogonal), without changing v.
  // Summed over the clusters in cluster order: the same bits on any thread count.
  double normal_kinetic_energy(const Eigen::Matrix3Xd& x, const Eigen::Matrix3Xd& v);

  // SHAKE position projection, in place: y ← y + M⁻¹ G(x_ref)ᵀ λ with g(y) = 0, by Newton on
  // λ (J = G(y) M⁻¹ G(x_ref)ᵀ, per cluster; open chains near x_ref first by chord steps on
  // S(x_ref), falling back to Newton when they contract slowly). With x_ref = y this is the mollifier α(x) of
  // paper eq. (ProMol). Converged when max_b |g_b| ≤ tol. Throws NumericalError naming the
  // cluster, the worst bond and the iteration count when it does not converge in max_iter.
  // lambda (size m) receives the multipliers if non-null. multiplier_tol > 0 is LAMMPS's fix
  // shake tolerance as well: a cluster also stops at the first iterate whose update changed no
  // multiplier in LAMMPS's scaling (λ_b / |d_b(x_ref)|, a mass) by more than multiplier_tol —
  // the update applied, as LAMMPS applies its last one (docs/decks.md, shake_tolerance).
  void shake(const Eigen::Matrix3Xd& x_ref, Eigen::Matrix3Xd& y, Eigen::VectorXd* lambda = nullptr, double tol = 1e-12,
             int max_iter = 50, double multiplier_tol = 0.0);

  // Molecule blocks: the constrained step of integrators/rattle.cpp taken block by block
  // (docs/performance.md, "The constrained step in molecule blocks"). A block is a range of
  // particles holding whole clusters (at least block_particles() of them, about 120 bytes a
  // particle of x, v, f and the step's copies plus the clusters' scratch: L2), its clusters a range
  // of the cluster order; every operation of a step that acts cluster by cluster runs for one
  // block before the next, while the block is in cache. Available when every cluster's particles
  // lie in one block (clusters numbered along the particles, as every engine's data numbers its
  // molecules) and no two clusters share a particle; each cluster gets the operations of the
  // whole-system calls, so the same bits. A range of clusters numbered out of order or spanning
  // the system makes one large block: correct, streamed like the whole-system calls.
  bool blocks_available() const;
  std::int64_t block_particles() const;
  void set_block_particles(std::int64_t n);  // the minimum (tests: small blocks); rebuilds the plan
  int num_blocks() const;
  std::int64_t block_first(int b) const;  // particles block_first(b) … block_last(b) − 1
  std::int64_t block_last(int b) const;
  // Runs f(b) for every block on `parts` threads (contiguous runs of blocks of about equal
  // particle count; parts ≤ 1: one part, in block order). Each block touches only its own
  // particles and clusters. An exception ends its part; the first one in part order is rethrown.
  void for_each_block(int parts, const std::function<void(int)>& f);
  // The whole-system operations on block b (its particles of x_ref, y, x, v, force and its
  // clusters only): shake(x_ref, y, nullptr, tol, max_iter, multiplier_tol), project_velocity,
  // and normal_kinetic_energy's per-cluster terms, which normal_energy_sum() then adds in cluster
  // order as normal_kinetic_energy does. The kept configuration is kept block by block: a block
  // whose particles differ from it bit for bit forgets its clusters' G and factors only.
  void shake_block(int b, const Eigen::Matrix3Xd& x_ref, Eigen::Matrix3Xd& y, double tol, int max_iter,
                   double multiplier_tol);
  void project_velocity_block(int b, const Eigen::Matrix3Xd& x, Eigen::Matrix3Xd& v, Eigen::Matrix3Xd* force = nullptr,
                              double rate = 0.0);
  void normal_energy_block(int b, const Eigen::Matrix3Xd& x, const Eigen::Matrix3Xd& v);
  double normal_energy_sum() const;
  // inverse_bands on block b's clusters (x's particles of the block), and the block's clusters
  // begin … end − 1 (Fixman's potential block by block, integrators/fixman.hpp).
  void inverse_bands_block(int b, const Eigen::Matrix3Xd& x);
  int block_cluster_begin(int b) const;
  int block_cluster_end(int b) const;
  // Before a pass of block operations on a configuration of n particles (serial): sizes the kept
  // configuration if nothing is kept yet.
  void begin_blocks();

  // Exact mollified force F̄(x) = α′(x)ᵀ f(α(x)), in four steps:
  //   X = α(x), f = f_slow(X); solve Jᵀμ = G(x) M⁻¹ f, J = G(X) M⁻¹ G(x)ᵀ;
  //   r = f − G(X)ᵀμ;  F̄ = r + H_λ M⁻¹ r,  H_λ = Σ_b λ_b ∇²g_b(x).
  // X receives α(x); out receives F̄. f_slow is called exactly once.
  void mollified_force(const Eigen::Matrix3Xd& x, const ForceFunction& f_slow, Eigen::Matrix3Xd& X,
                       Eigen::Matrix3Xd& out, double tol = 1e-12);

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

}  // namespace stiffmd
