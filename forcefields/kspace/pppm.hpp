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
// time), under a lock since FFTW's planner is not thread-safe; an evaluation allocates nothing (on
// several processes, see below: the buffers of the planes a rank's particles touch may grow). The
// influence function is computed again when the box's edges change (a barostat). Serial: no
// threads (the spreading and the FFTs are one thread's; a threaded version needs per-thread meshes
// summed in order to stay deterministic).
//
// On several processes (a Communicator of size > 1, set_processes; the term on a rank's particles,
// on_subset): a distributed mesh, slabs along z. Rank r owns the planes z ∈ [r n_z/N, (r+1) n_z/N)
// for the forward transform and the columns (the (k_x, k_y) modes of the 2D half spectrum,
// numbered k_y (n_x/2 + 1) + k_x) c ∈ [r M/N, (r+1) M/N), M = n_y (n_x/2 + 1), for the solve.
//   - Spreading: each rank spreads its particles' charges into its window, the smallest circular
//     range of planes holding every plane its charged particles touch (possibly wrapping through
//     z = 0), the ranks' windows known to all by one sum of 2N integers; each window plane goes to
//     its owner (one exchange), which adds the ranks' contributions in rank order (the same bits
//     for a given rank count, however the ranks' particles move in their windows).
//   - Forward: 2D real-to-complex FFTs of the owned planes (fftw_plan_many_dft_r2c), a transpose
//     (one exchange with a fixed plan) after which each rank holds whole z columns of its modes,
//     1D complex FFTs along z. The energy and virial over the rank's own modes, then one sum of six
//     numbers over the ranks (with Σq and Σq²).
//   - Backward, forces only: (−i k_a) G ρ̂ for the three components on the own modes, 1D inverse
//     FFTs, the transpose back (one exchange), 2D complex-to-real FFTs of the owned planes, and each
//     window plane's field sent back to the ranks whose windows hold it (one exchange); each rank
//     interpolates its own particles' forces from its window, as one process does from the mesh.
// A mesh with fewer planes (or columns) than ranks works: those ranks own none and send nothing.
// Serial FFTW plus the Communicator's exchange_known, not fftw3-mpi: fftw3-mpi needs the MPI_Comm
// (Communicator::native()), so it would bring MPI calls into forcefields/ (the engine calls MPI in
// engine/run/processes.cpp only), could not run on tests/fake_processes.hpp's ranks (threads of
// one process, no MPI) nor in a build without MPI, and its own transposes are the same all-to-all.
// Per rank, in doubles (mesh = n_x n_y n_z): about 12 mesh/N for its planes (charges, then the
// three field components), their 2D spectra, its columns (ρ̂ and the three fields), G and the
// virial factors on its modes; 8 mesh/N (N − 1)/N for the transposes' buffers (its own block is
// copied); 4 per point of the window's planes other ranks own (charges out, field back), 1 per
// point of those it owns (its charges: its field is read where the inverse FFT left it), and 4 per
// point of the planes other ranks' windows hold of its own (charges in, field out). One process:
// 8 mesh. No part holds the whole mesh: a part's buffers are made when it is given its processes
// (set_processes; on_subset builds no mesh). The window's buffers grow when a rank's charges
// touch more planes than they ever did (its first evaluation, then rarely: the one allocation an
// evaluation may make; capacity is never given back; a part built again after a migration starts
// empty, as its plans and G are made again). An evaluation is 4 exchanges and 2 sums
// (without forces 2 and 2): to each other owner of its window's planes, the transpose to each
// rank whose columns meet its planes (up to N − 1), and with forces the transpose back and the
// field (three times the charges' bytes) to the ranks whose windows hold its planes; the sums of
// 2N integers (the windows) and 6 doubles. traffic() reports the last evaluation's. Each
// exchange is a synchronisation, against the replicated mesh's one all-reduce: on few ranks and
// small meshes the replicated mesh was quicker (docs/electrostatics.md, "What it costs, measured").
// Every rank has the whole energy and virial after the sum and returns 1/size of each, so that the
// shares add up to the whole system's (on one process they are the energy and virial). On one
// process (no Communicator, or one rank) the mesh is whole and transformed by one 3D plan: the
// bits of the term before the distributed mesh; on N ranks the sums' order differs (round-off).
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

  // One process (null, or one rank): the whole mesh; more: this rank's slab (built here).
  void set_processes(const Communicator* comm) override;
  // The mesh, its plans and G, made again (the same plans, so the same bits) when next evaluated.
  void release_buffers() const override;
  const MeshParameters& parameters() const { return parameters_; }
  const std::vector<double>& charges() const { return charges_; }

  // What this rank's last evaluation sent (on several processes): messages and bytes of its
  // exchanges to the other ranks (what it keeps is copied), the reductions, and the window's
  // buffers that had to grow (allocations).
  struct Traffic {
    long messages = 0, bytes = 0, reductions = 0, growths = 0;
    int window_planes = 0;  // the planes this rank's charges touch, as one circular range
  };
  const Traffic& traffic() const { return traffic_; }

 private:
  struct Result {
    double energy = 0.0;
    double w[3] = {0.0, 0.0, 0.0};
  };
  struct Deferred {};  // on_subset: no mesh until set_processes (or the first evaluation)
  ParticleParticleParticleMesh(Deferred, std::string name, Level level, std::vector<double> charges,
                               const MeshParameters& parameters, double qqrd2e, const Box& box,
                               const Communicator* comm);
  Result evaluate(const Eigen::Matrix3Xd& x, const Box& box, Eigen::Matrix3Xd* f) const;
  Result evaluate_slabs(const Eigen::Matrix3Xd& x, const Box& box, Eigen::Matrix3Xd* f) const;
  void build_mesh() const;
  void influence_function(const Box& box) const;

  std::vector<double> charges_;
  MeshParameters parameters_;
  double qqrd2e_;
  const Communicator* comm_;
  std::vector<double> aliasing_;  // b_l: Σ_m U²(k_m) = Π_a Σ_l b_l sin^{2l}(k_a h_a/2)
  mutable Box box_;               // the box of the last influence function (at first the construction's)
  struct Fftw;                    // one process: the plans and the FFTW-allocated whole mesh
  struct Slabs;                   // several: this rank's planes and columns, plans, exchange buffers
  mutable std::unique_ptr<Fftw> fft_;
  mutable std::unique_ptr<Slabs> slabs_;
  // Per mode of the half spectrum this process solves (one process: nz × ny × (nx/2 + 1), mode
  // (iz ny + iy)(nx/2 + 1) + ix; several: its columns, mode c_local nz + iz): G(k) and the virial
  // factors 1 − 2 k_a² (1/k² + 1/(4g²)); per axis the wavenumbers 2π p/L_a; for the box edges they
  // were computed at.
  mutable std::vector<double> green_, virial_factor_, wavenumber_[3];
  mutable Eigen::Vector3d green_lengths_ = Eigen::Vector3d::Zero();
  // Per particle and axis: its P mesh points (as offsets into the mesh; several processes: z as the
  // plane's index in the window) and weights (scratch).
  mutable std::vector<std::size_t> offset_;
  mutable std::vector<double> weight_;
  mutable Traffic traffic_;
};

}  // namespace stiffmd
