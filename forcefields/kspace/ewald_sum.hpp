// `ewald`: the reciprocal-space part of Ewald summation (Ewald 1921), summed exactly over the
// k-vectors of EwaldParameters (LAMMPS kspace_style ewald). With C = qqrd2e, V the volume and the
// structure factor S(k) = Σ_j q_j e^{ik·r_j} over every particle of the system,
//   E = (C / 2V) Σ_{k≠0} A(k) |S(k)|² − C g/√π Σ q_j² − C π (Σ q_j)² / (2 V g²),
//   A(k) = (4π/k²) e^{−k²/4g²},
// the second term the self energy and the third the neutralising background's (zero for a
// neutral system; with it the total Ewald energy of a charged system does not depend on g). The
// real-space pairs C q_i q_j erfc(g r)/r and the exclusion corrections are the pair styles'.
//   F_i = (C/V) q_i Σ_{k≠0} A(k) k Im[S(k)* e^{ik·r_i}],
//   W_ab = Σ_{k≠0} E_k (δ_ab − 2 k_a k_b (1/k² + 1/(4g²))) + δ_ab E_background,
// with E_k = (C/2V) A(k)|S(k)|²: W_aa = −L_a ∂E/∂L_a at fixed scaled coordinates, the pair
// virial's Σ r_a f_a (virial() is its trace). Only half of the k-vectors are visited (k and −k
// give the same terms).
//
// Positions may lie anywhere (unwrapped): each is folded into the box before its phases
// e^{i 2π n x/L} are formed. Fully periodic orthorhombic boxes only.
//
// On several processes (a Communicator, on_subset): each rank holds some of the particles; the
// ranks sum their S(k) (and Σq) so that every rank forms the whole system's S, and each computes
// the forces on its own particles. Each rank's energy is its particles' share
//   E_i = (C/2V) Σ_{k≠0} A(k) q_i Re[S(k)* e^{ik·r_i}] − C g q_i²/√π − C π Q q_i / (2 V g²)
// (½ q_i φ(r_i) with the self and background terms split per particle; Q the system's charge),
// and its virial the same per-particle split of W: the ranks' shares add up to the whole
// system's energy and virial; on one process they are the energy and virial. Serial (no threads).
#pragma once

#include <complex>
#include <memory>
#include <string>
#include <vector>

#include "core/communicator.hpp"
#include "forcefields/force_term.hpp"
#include "forcefields/kspace/ewald_parameters.hpp"

namespace stiffmd {

class EwaldSum final : public ForceTerm {
 public:
  // charges: per particle (of this process, when `comm` spans several); `box` must be periodic on
  // every axis: its edges fix the set of k-vectors (EwaldParameters). comm: null for one process.
  // Throws std::invalid_argument for g ≤ 0, a kmax < 1, qqrd2e ≤ 0, a non-finite charge or a box
  // that is not fully periodic.
  EwaldSum(std::string name, Level level, std::vector<double> charges, const EwaldParameters& parameters, double qqrd2e,
           const Box& box, const Communicator* comm = nullptr);

  double add_forces(const Eigen::Matrix3Xd& x, const Box& box, Eigen::Matrix3Xd& f) const override;
  double virial(const Eigen::Matrix3Xd& x, const Box& box) const override;
  Sums energy_and_virial(const Eigen::Matrix3Xd& x, const Box& box, Eigen::Matrix3Xd& scratch) const override;
  void add_forces_and_virial_diagonal(const Eigen::Matrix3Xd& x, const Box& box, Eigen::Matrix3Xd& f,
                                      ExactDiagonal& w) const override;
  bool conserves_momentum() const override { return true; }
  std::unique_ptr<ForceTerm> on_subset(const ParticleSubset& subset, const Box& box) const override;
  std::string_view style() const override { return "ewald"; }
  std::string describe() const override;
  void define(ParameterRecord& record) const override;

  // The processes the structure factors are summed over (null: one process). Every rank's term
  // must then be evaluated at the same points (each evaluation is one collective sum).
  void set_communicator(const Communicator* comm) { comm_ = comm; }
  const EwaldParameters& parameters() const { return parameters_; }
  const std::vector<double>& charges() const { return charges_; }
  // The k-vectors summed over (half of them: one of each ±k pair).
  int kvectors() const { return static_cast<int>(index_.size()); }

 private:
  struct Result {
    double energy = 0.0;
    double w[3] = {0.0, 0.0, 0.0};
  };
  // Energy and virial diagonal (this process's shares); the forces into f when it is not null.
  Result evaluate(const Eigen::Matrix3Xd& x, const Box& box, Eigen::Matrix3Xd* f) const;

  std::vector<double> charges_;
  EwaldParameters parameters_;
  double qqrd2e_;
  const Communicator* comm_;
  std::vector<Eigen::Vector3i> index_;  // the integer k-vectors, one per ±k pair
  // Scratch, sized at construction: per particle its phases e^{i 2π n x_a / L_a} for n = 0 … kmax[a]
  // (three rows), the summed structure factors (Re, Im; then Σq), each k's particle sum, and
  // each k's vector and A(k) at the evaluation's box.
  mutable std::vector<std::complex<double>> phase_[3];
  mutable std::vector<double> s_;
  mutable std::vector<double> p_;
  mutable std::vector<double> coef_;
};

}  // namespace stiffmd
