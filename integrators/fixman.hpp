// Fixman's potential: the correction that makes rigid-bond dynamics sample the stiff-spring
// canonical ensemble in the limit ε → 0 (docs/design.md §5).
//
//   ρ_stiff = ρ_rigid · exp(−β U_F),   U_F(x) = (kT/2) log det A(x),
//   A = K^{1/2} G M⁻¹ Gᵀ K^{1/2} = K^{1/2} S K^{1/2},  K = diag(α_b²),
//
// summed over constraint clusters (find_clusters); = kT Σ_k log ω_k, the canonical average of the
// seed's W = Σ I_k ω_k. A has the sparsity of the bond graph, so the gradient
//   ∂U_F/∂x = (kT/2) Σ_{b,c} (A⁻¹)_{cb} ∂A_{bc}/∂x
// needs A⁻¹ only on that pattern: O(bonds) for open chains (tridiagonal) and rings (cyclic
// tridiagonal), a dense inverse for any other cluster shape.
//
// Nothing allocates after construction; one object must not be used from two threads at once.
#pragma once

#include <Eigen/Core>
#include <memory>
#include <vector>

#include "forcefields/stiff_bond.hpp"

namespace stiffmd {

class ConstraintToolbox;

class FixmanPotential {
 public:
  // How A⁻¹ is formed on each cluster: `fast` uses the chain and ring recurrences where the
  // cluster has that shape (dense elsewhere); `dense` uses the dense inverse everywhere (the
  // reference the tests compare the fast paths with).
  enum class Path { fast, dense };

  // Throws std::invalid_argument for bad bonds / masses: a particle index out of range, a bond
  // joining a particle to itself or two fixed particles, two bonds on the same pair, a length or
  // α that is not finite and > 0, an inverse mass that is not finite and ≥ 0.
  FixmanPotential(std::vector<StiffBond> bonds, Eigen::VectorXd inv_mass, Path path = Path::fast);
  ~FixmanPotential();
  FixmanPotential(FixmanPotential&&) noexcept;
  FixmanPotential& operator=(FixmanPotential&&) noexcept;

  // Writes −∇U_F(x) into f (resized to 3×N if needed, overwritten; zero where no bond acts) and
  // returns U_F(x) (the constant dropped: U_F = (kT/2) Σ_clusters log det A_c).
  // The force is the exact gradient in all coordinates, fixed particles included. Bond vectors are
  // x_i − x_j of the (unwrapped) positions, as in the constraint toolbox.
  // Throws NumericalError (naming the cluster and bond) for a bond of zero or non-finite length, or
  // when S is singular on a cluster (linearly dependent bond directions).
  double force(const Eigen::Matrix3Xd& x, double kT, Eigen::Matrix3Xd& f);
  // The same force added to f (3×N, as x; else std::invalid_argument): f += −∇U_F(x). Returns U_F.
  double add_force(const Eigen::Matrix3Xd& x, double kT, Eigen::Matrix3Xd& f);

  // Read G(x) and the band of S(x)⁻¹ of open chains from `toolbox` (built from the same bonds and
  // inverse masses; it keeps its factors of S for the integrator's velocity projection at the same
  // x) instead of measuring and factoring them here; nullptr: measure and factor here. The force
  // agrees with this object's own path to round-off. Throws std::invalid_argument if the toolbox's
  // clusters are not this potential's. Not with Path::dense, which stays the reference.
  void use_toolbox(ConstraintToolbox* toolbox);

  // Block by block (ConstraintToolbox's molecule blocks, with a toolbox that has them and clusters
  // that share no particle): add_block_force adds −∇U_F of block b's clusters to f (their
  // particles only), value() is U_F of the clusters' last evaluation, summed in cluster order. Every
  // block once at one x gives add_force's bits.
  bool blocks() const;
  void add_block_force(int b, const Eigen::Matrix3Xd& x, double kT, Eigen::Matrix3Xd& f);
  double value(double kT) const;

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

}  // namespace stiffmd
