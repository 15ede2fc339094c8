// Frequencies, actions and the correction potential of the effective dynamics
// (docs/design.md §4 "Frequencies and actions"; Lubich & Weiss eq. (CH), (actions),
// (separated), (nonresonant)).
//
// The stiff part ε⁻² V, V = ½ Σ_b α_b² g_b(x)², vibrates in m normal modes. Near the
// constraint manifold the bond coordinates z = K^{1/2} g obey z̈ = −ε⁻² A z with
//   A = K^{1/2} S K^{1/2},  S = G M⁻¹ Gᵀ,  K = diag(α_b²),
// so the (unscaled) frequencies are ω_k = √λ_k(A) and the physical ones ω_k/ε. These are
// exactly the square roots of the nonzero eigenvalues of the pencil λM − ∇²V on the
// manifold named in paper eq. (CH), since there ∇²V = Gᵀ K G.
//
// S is block-diagonal over constraint clusters (find_clusters), so everything here is
// done per cluster with an eigen-decomposition (tridiagonal for open chains, dense for other
// shapes); clusters larger than a limit are
// skipped (their modes are simply absent from every output).
//
// Mode order in every output vector: clusters in the order of find_clusters (ordered by
// their first bond), and within a cluster ascending frequency.
//
// Nothing here allocates after construction (one shared scratch, sized for the largest
// included cluster); the methods are therefore non-const and one object must not be
// used from two threads at once.
#pragma once

#include <Eigen/Core>
#include <memory>
#include <vector>

#include "forcefields/stiff_bond.hpp"

namespace stiffmd {

class StiffModes {
 public:
  // Hard upper bound on max_cluster_bonds. The dense matrices live in Eigen types with
  // this compile-time maximum size: that is what keeps SelfAdjointEigenSolver from
  // heap-allocating a Householder workspace on every call (Eigen 3.4 does so for fully
  // dynamic matrices when eigenvectors are requested). Clusters this large have frequency
  // bands so dense that the separation condition (separated) fails anyway.
  static constexpr int kMaxDenseBonds = 128;

  // bonds, inverse masses (0 = fixed), ε. Clusters with more than max_cluster_bonds bonds
  // are skipped and counted. Throws InputError for ε ≤ 0, bonds that break the rules of
  // find_stiff_bond_problem (forcefields/stiff_bond.hpp; among them a bond whose two ends are
  // both fixed: it has no vibrational mode), or max_cluster_bonds outside [1, kMaxDenseBonds].
  //
  // Open chains (S tridiagonal in chain order) are decomposed on the tridiagonal A itself
  // (eigenvalues by LAPACK dsterf, eigenvectors by twisted factorizations; molecules of one or two
  // bonds in closed form), O(bonds²) per chain and in parallel over chains; every other cluster by
  // a dense eigen-solver. Solver::dense
  // forces the dense path everywhere (the tests' reference).
  enum class Solver { fast, dense };
  StiffModes(std::vector<StiffBond> bonds, Eigen::VectorXd inv_mass, double epsilon, int max_cluster_bonds = 64,
             Solver solver = Solver::fast);
  ~StiffModes();
  StiffModes(StiffModes&&) noexcept;
  StiffModes& operator=(StiffModes&&) noexcept;

  // Total number of modes over the included clusters (= number of bonds in them).
  int num_modes() const;
  // Number of clusters left out because they have more than max_cluster_bonds bonds.
  int num_skipped_clusters() const;
  double epsilon() const;

  // ω_k(x), unscaled (the physical frequency is ω_k/ε), into omega (size num_modes()).
  // A non-positive eigenvalue (redundant constraints at x) is reported as ω_k = 0.
  void frequencies(const Eigen::Matrix3Xd& x, Eigen::Ref<Eigen::VectorXd> omega);

  // Actions I_k(x, v) = E_k/ω_k into I (size num_modes()), with the modal energy
  //   E_k = ½ ẇ_k²/λ_k + ½ ε⁻² w_k²,  w = Qᵀ K^{1/2} g(x),  ẇ = Qᵀ K^{1/2} G v
  // (docs/design.md §4). This is paper eq. (actions): I_k = (q_{1,k}² + p_{1,k}²)/(2ε), i.e. the
  // harmonic action E_k/(ω_k/ε) divided by ε, so that W = Σ I_k ω_k is the vibrational
  // energy and I = O(1) under the energy bound (EBound).
  // Throws NumericalError if a mode of an included cluster has (numerically) zero frequency.
  void actions(const Eigen::Matrix3Xd& x, const Eigen::Matrix3Xd& v, Eigen::Ref<Eigen::VectorXd> I);

  // Correction potential W(I, x) = Σ_k I_k ω_k(x) of paper eq. (CH) and its force −∇W
  // into f (resized to 3 × N if needed, overwritten; zero on particles of no included
  // cluster). Returns W. The force is the exact gradient of W as a function of all
  // coordinates, fixed particles included (an integrator multiplies it by their zero
  // inverse mass). Where two frequencies with different actions coincide W is not
  // differentiable; validity() is the guard against that.
  // Throws NumericalError if a mode with I_k ≠ 0 has (numerically) zero frequency.
  double correction_force(const Eigen::VectorXd& I, const Eigen::Matrix3Xd& x, Eigen::Matrix3Xd& f);

  // Validity monitor for the effective dynamics (paper eqs. (separated), (nonresonant)),
  // evaluated within each included cluster (modes of different clusters couple only
  // through the slow potential) and minimised over clusters:
  //   min_gap        = min_{j≠k} |ω_j − ω_k|,
  //   min_resonance  = min_{j,k,l, signs} |ω_j ± ω_k ± ω_l|  over all index triples, repeats
  //                    included as in the paper: j = k gives |2ω_j − ω_l| (1:2 resonance)
  //                    and ω_l itself (a mode must not become slow).
  // +infinity where there is nothing to compare (no modes; a one-mode cluster has no gap).
  // Compare with √ε: below it the limit dynamics is not determined (Takens chaos).
  struct Validity {
    double min_gap;
    double min_resonance;
  };
  Validity validity(const Eigen::Matrix3Xd& x);

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

}  // namespace stiffmd
