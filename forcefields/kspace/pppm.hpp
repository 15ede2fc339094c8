// `pppm`: the reciprocal-space part of Ewald summation on a mesh, particle–particle
// particle–mesh (Hockney & Eastwood 1988) as LAMMPS's kspace_style pppm does it with ik
// differentiation. The same energy, forces and virial as EwaldSum (ewald_sum.hpp), approximated:
//
//  1. charge assignment: each charge spread over P³ mesh points with the order-P Hockney–Eastwood
//     weights W_P (the cardinal B-spline of order P, the P-fold convolution of the unit box with
//     itself, centred on the charge), ρ_m = Σ_i q_i W_P(m − s_i) with s_i the particle's position
//     in mesh units;
//  2. ρ̂(k) = Σ_m ρ_m e^{−ik·r_m} by a real-to-complex FFT (FFTW3);
//  3. the optimal influence function for ik differentiation (Hockney & Eastwood; LAMMPS's
//     compute_gf_ik), with k_m = k + 2π m/h the aliases and U(k) = Π_a (sin(k_a h_a/2)/(k_a h_a/2))^P
//     the assignment function's transform,
//        G(k) = (4π/k²) Σ_m (k·k_m / k_m²) U²(k_m) e^{−k_m²/4g²} / [Σ_m U²(k_m)]²,
//     the numerator's aliases summed over |m_a| ≤ ⌊g L_a/(π n_a) (−ln 10⁻⁷)^{1/4}⌋ (LAMMPS's
//     count), the denominator in closed form, Σ_m U²(k_m) = Π_a Σ_{l<P} b_l sin^{2l}(k_a h_a/2);
//  4. E = (C/2V) Σ_{k≠0} G(k)|ρ̂(k)|², W_ab = Σ_k E_k (δ_ab − 2 k_a k_b (1/k² + 1/(4g²))) (the
//     Ewald form with G for A, as LAMMPS), self and background terms as EwaldSum's;
//  5. the field E_a(r_m) = (C/V) Σ_k (−i k_a) G(k) ρ̂(k) e^{ik·r_m} by three complex-to-real
//     FFTs (the derivative zeroed at each axis's Nyquist index, as LAMMPS's real part of a
//     complex transform does), interpolated back with the same weights: F_i = q_i Σ_m W_P E(r_m).
// ik-differentiated forces are not exactly −∇E of this energy (they agree to the method's
// accuracy), and the net force is not exactly zero.
//
// FFTW plans are made once, at construction (FFTW_ESTIMATE: the same plan, so the same bits, every
// time), under a lock since FFTW's planner is not thread-safe; an evaluation allocates nothing. The
// influence function is computed again when the box's edges change (a barostat). Serial: no
// threads (the spreading and the FFTs are one thread's; a threaded version needs per-thread meshes
// summed in order to stay deterministic).
//
// On several processes (a Communicator, on_subset): a replicated mesh. Each rank spreads its own
// charges over the whole mesh, the ranks sum the mesh (and Σq, Σq²), every rank does the same
// FFTs and interpolates the forces on its own particles. A distributed mesh (each rank a slab of
// the FFT) is not done: the mesh's sum costs one all-reduce of the whole mesh per evaluation.
// Every rank then has the whole energy and virial from the whole mesh, and returns 1/size of each:
// the shares add up to the whole system's (on one process they are the energy and virial).
#pragma once

#include <memory>
#include <string>
#include <vector>

#include "core/communicator.hpp"
#include "forcefields/force_term.hpp"
#include "forcefields/kspace/ewald_parameters.hpp"

namespace stiffmd {

// The weights of the order-P assignment (1 ≤ P ≤ 7) of a point at s (in mesh units, any real) to
// the P mesh points first, first + 1, …, first + P − 1 (not folded into the mesh): w[j] = W_P(s −
// first − j), Σ_j w[j] = 1. Returns first.
int assignment_weights(double s, int order, double* w);

class ParticleParticleParticleMesh final : public ForceTerm {
 public:
  // As EwaldSum's; throws std::invalid_argument for g ≤ 0, a mesh size < 1 or > 4096, an order
  // outside 1 … 7, qqrd2e ≤ 0, a non-finite charge or a box that is not fully periodic.
  ParticleParticleParticleMesh(std::string name, Level level, std::vector<double> charges,
                               const MeshParameters& parameters, double qqrd2e, const Box& box,
                               const Communicator* comm = nullptr);
  ~ParticleParticleParticleMesh() override;

  double add_forces(const Eigen::Matrix3Xd& x, const Box& box, Eigen::Matrix3Xd& f) const override;
  double virial(const Eigen::Matrix3Xd& x, const Box& box) const override;
  Sums energy_and_virial(const Eigen::Matrix3Xd& x, const Box& box, Eigen::Matrix3Xd& scratch) const override;
  void add_forces_and_virial_diagonal(const Eigen::Matrix3Xd& x, const Box& box, Eigen::Matrix3Xd& f,
                                      ExactDiagonal& w) const override;
  bool conserves_momentum() const override { return true; }
  bool uses_charges() const override { return true; }
  Phase phase() const override { return Phase::kspace; }
  std::unique_ptr<ForceTerm> on_subset(const ParticleSubset& subset, const Box& box) const override;
  std::string_view style() const override { return "pppm"; }
  std::string describe() const override;
  void define(ParameterRecord& record) const override;

  void set_processes(const Communicator* comm) override { comm_ = comm; }
  const MeshParameters& parameters() const { return parameters_; }
  const std::vector<double>& charges() const { return charges_; }

 private:
  struct Result {
    double energy = 0.0;
    double w[3] = {0.0, 0.0, 0.0};
  };
  Result evaluate(const Eigen::Matrix3Xd& x, const Box& box, Eigen::Matrix3Xd* f) const;
  void influence_function(const Box& box) const;

  std::vector<double> charges_;
  MeshParameters parameters_;
  double qqrd2e_;
  const Communicator* comm_;
  std::vector<double> aliasing_;  // b_l: Σ_m U²(k_m) = Π_a Σ_l b_l sin^{2l}(k_a h_a/2)
  struct Fftw;                    // the plans and the FFTW-allocated meshes
  std::unique_ptr<Fftw> fft_;
  // Per mode of the half spectrum (nz × ny × (nx/2 + 1)): G(k) and the virial factors
  // 1 − 2 k_a² (1/k² + 1/(4g²)); per axis the wavenumbers 2π p/L_a; for the box edges they were
  // computed at.
  mutable std::vector<double> green_, virial_factor_, wavenumber_[3];
  mutable Eigen::Vector3d green_lengths_ = Eigen::Vector3d::Zero();
  // Per particle and axis: its P mesh points (as offsets into the mesh) and weights (scratch).
  mutable std::vector<std::size_t> offset_;
  mutable std::vector<double> weight_;
};

}  // namespace stiffmd
