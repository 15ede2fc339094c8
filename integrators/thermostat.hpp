// The canonical ensemble (docs/design.md §5): Langevin dynamics inside every method, and the
// stochastic velocity rescaling thermostat of Bussi, Donadio & Parrinello (J. Chem. Phys. 126,
// 014101 (2007)) around any of them.
//
// Noise is counter-based: the Gaussian for (seed, step, substep, particle, component) is a hash
// of those integers (splitmix64) turned into a normal by the ziggurat method (integrators/
// ziggurat.hpp; Box–Muller for the few normals of the velocity rescaling). It does not depend on the
// thread partition or on any generator state, so a run is bit-for-bit reproducible for a seed
// and a thread count, and a restart from a checkpoint continues the same noise: the only state
// is State::step, which the checkpoint holds and the run loop advances.
#pragma once

#include <Eigen/Core>
#include <cmath>
#include <cstdint>
#include <memory>
#include <optional>
#include <string_view>
#include <vector>

#include "core/state.hpp"
#include "integrators/ziggurat.hpp"

namespace stiffmd {

class Communicator;
class ForceField;
class Integrator;

struct ThermostatSettings {
  enum class Style { none, langevin, csvr };
  // Where Langevin's friction and noise enter the step: baoab (an exact O step between the drifts),
  // lammps (a friction and noise force added to the outermost kick force, as LAMMPS's fix nve +
  // fix langevin do inside velocity Verlet; LangevinForce below), or obabo (an exact O step of ½h
  // before and after the Hamiltonian step, Bussi & Parrinello 2007; for the constrained methods
  // one SHAKE per step instead of BAOAB's two: integrators/rattle.hpp).
  enum class Splitting { baoab, lammps, obabo };
  Style style = Style::none;
  Splitting splitting = Splitting::baoab;
  double temperature = 0.0;  // kT (k_B = 1)
  // Langevin: friction γ_i per particle (1/time; LAMMPS's damp = 1/γ, scaled per type).
  Eigen::VectorXd friction;
  double tau = 0.0;  // csvr: relaxation time of the kinetic energy
  std::uint64_t seed = 1;
  // A decomposed run's part of the system (docs/parallel.md): the noise of local particle i is
  // that of particle particle_id[i] of the whole system (empty: i itself), so a trajectory does
  // not depend on how the particles are distributed; csvr's kinetic energy is summed over
  // `processes` (null: this process holds the whole system) and its degrees of freedom are
  // `degrees_of_freedom` when > 0 (the whole system's), else counted from the particles.
  std::vector<std::int64_t> particle_id;
  const Communicator* processes = nullptr;
  int degrees_of_freedom = 0;
  bool on() const { return style != Style::none; }
};

std::string_view thermostat_style_name(ThermostatSettings::Style style);

// Degrees of freedom of the kinetic energy (k_B T = 2K/dof): 3 per mobile particle, less 3 when
// the total momentum is conserved (no fixed particle, every term conserves it, and no Langevin
// noise: its random forces do not sum to zero), less one per rigid constraint.
int degrees_of_freedom(const Eigen::VectorXd& inv_mass, bool momentum_conserved, int rigid_constraints);
bool momentum_conserved(const ForceField& forces, const Eigen::VectorXd& inv_mass, const ThermostatSettings& t);

// The constrained O step v ← P(c v + σξ), c = e^{−γh}, keeps the Maxwell law on the tangent space,
// covariance kT P M⁻¹, only when c is one number on each cluster of stiff bonds: then
// c² kT PM⁻¹ + (1 − c²) kT PM⁻¹ Pᵀ = kT PM⁻¹ (PM⁻¹ = M⁻¹Pᵀ, P² = P). With c varying inside a cluster
// the projection mixes the particles' rates and the stationary temperature falls below kT
// (rigid trimers, masses 1, 1/4, 1, the middle bead's γ four times the ends': T = 0.985 kT). Two mobile particles of
// one cluster with different frictions, the first such pair in particle order; none when every cluster has one.
struct UnevenFriction {
  int a = -1, b = -1;        // particles, a < b, friction[a] != friction[b]
  std::vector<int> cluster;  // the cluster's particles, ascending
};
struct ConstraintCluster;
std::optional<UnevenFriction> uneven_friction_in_cluster(const std::vector<ConstraintCluster>& clusters,
                                                         const Eigen::VectorXd& inv_mass,
                                                         const Eigen::VectorXd& friction);

// Counter-based noise: splitmix64's finaliser (Steele, Lea & Flood 2014) applied to a key made
// of the counters. Consecutive inputs give independent-looking outputs (BigCrush-clean).
inline std::uint64_t mix64(std::uint64_t z) {
  z = (z ^ (z >> 30)) * 0xbf58476d1ce4e5b9ULL;
  z = (z ^ (z >> 27)) * 0x94d049bb133111ebULL;
  return z ^ (z >> 31);
}
constexpr std::uint64_t kGolden = 0x9e3779b97f4a7c15ULL;

// The key of one (seed, step, substep): the start of a splitmix64 stream whose j-th value is
// mix64(key + (j+1)·golden).
inline std::uint64_t noise_key(std::uint64_t seed, std::int64_t step, std::uint64_t substep) {
  return mix64(mix64(mix64(seed + kGolden) + static_cast<std::uint64_t>(step) * kGolden) + substep * kGolden);
}
inline std::uint64_t noise_word(std::uint64_t key, std::uint64_t j) {
  return mix64(key + (j + 1) * kGolden);
}

// Two independent standard normals from one 64-bit word (two 32-bit uniforms, Box–Muller). The
// uniforms are (k + ½)/2³², never 0, so the tails stop at √(−2 log 2⁻³³) ≈ 6.8σ.
inline void normal_pair(std::uint64_t word, double& z0, double& z1) {
  constexpr double kScale = 1.0 / 4294967296.0;
  const double u1 = (static_cast<double>(word >> 32) + 0.5) * kScale;
  const double u2 = (static_cast<double>(word & 0xffffffffULL) + 0.5) * kScale;
  const double r = std::sqrt(-2.0 * std::log(u1)), phi = 6.283185307179586 * u2;
  z0 = r * std::cos(phi);
  z1 = r * std::sin(phi);
}

// The three normals of particle i for (seed, step, substep): from words 3i, 3i + 1, 3i + 2 of
// the stream, by the ziggurat (three hashes and, in 99.3 % of the draws, a table lookup and a
// multiply each: Box–Muller's logarithm, square root, sine and cosine per pair were 15 % of a
// Langevin step of the thermal stiff limit and 45 % of velocity Verlet's on a melt).
inline Eigen::Vector3d particle_noise(std::uint64_t key, std::int64_t i, const ZigguratTable& t = ziggurat_table()) {
  const std::uint64_t j = 3 * static_cast<std::uint64_t>(i);
  return {ziggurat_normal(noise_word(key, j), t), ziggurat_normal(noise_word(key, j + 1), t),
          ziggurat_normal(noise_word(key, j + 2), t)};
}

// ½vᵀMv before and after a thermostat's change of the velocities: after − before is the heat
// it put into the system (docs/design.md §5, the conserved energy).
struct KineticChange {
  double before = 0.0, after = 0.0;
  double heat() const { return after - before; }
};

// Σ of per-particle terms over the mobile particles (inverse mass > 0) with the bits of
// parallel_sum(n, parts, …) over them (core/parallel.hpp), when the terms are formed block by block
// (the constrained step in molecule blocks, integrators/rattle.cpp), on threads whose blocks are
// not parallel_sum's: with one part a running sum in particle order (the blocks taken in order by
// one thread), with several each term kept and the parts' sums formed by total().
class ParticleSum {
 public:
  void start(std::int64_t n, int parts) {
    parts_ = parts;
    n_ = n;
    running_ = 0.0;
    if (parts_ > 1 && static_cast<std::int64_t>(terms_.size()) != n) terms_.assign(static_cast<std::size_t>(n), 0.0);
  }
  // The term of mobile particle i (a fixed one's is never added).
  void add(std::int64_t i, double term) {
    if (parts_ > 1)
      terms_[static_cast<std::size_t>(i)] = term;
    else
      running_ += term;
  }
  double total(const Eigen::VectorXd& inv_mass) const;

 private:
  int parts_ = 1;
  std::int64_t n_ = 0;
  double running_ = 0.0;
  std::vector<double> terms_;
};

// The Ornstein–Uhlenbeck part "O" of a Langevin splitting, solved exactly over dt:
//   v_i ← c_i v_i + √((1 − c_i²) kT / m_i) ξ_i,   c_i = exp(−γ_i dt),   ξ_i ~ N(0, I₃).
// Fixed particles (inverse mass 0) stay at rest. Parallel over particle blocks; the noise of a
// particle does not depend on the block it falls in.
class LangevinNoise {
 public:
  LangevinNoise(const ThermostatSettings& settings, const Eigen::VectorXd& inv_mass);
  // O step of length dt at macro step `step`, sub-step `substep` of that step.
  void apply(Eigen::Matrix3Xd& v, double dt, std::int64_t step, std::uint64_t substep) {
    o_step<false>(v, dt, step, substep);
  }
  // The same, returning ½ vᵀ M v before and after it, formed in the same pass (each summed as
  // kinetic_energy in integrators/primitives.hpp: the same bits).
  KineticChange apply_and_measure(Eigen::Matrix3Xd& v, double dt, std::int64_t step, std::uint64_t substep) {
    return o_step<true>(v, dt, step, substep);
  }
  // kick_drift(x, v, inv_mass, f, dt_kick, half_drift) (integrators/primitives.hpp), then
  // apply_and_measure(v, dt, step, substep), then drift(x, v, half_drift), in one pass over the
  // particles, run by run (thermostat.cpp): each particle's x and v are read and written once
  // instead of three times. The same bits as the three passes (the same expressions on each
  // particle, the same sums in the same order).
  KineticChange kick_drift_o_drift(Eigen::Matrix3Xd& x, Eigen::Matrix3Xd& v, const Eigen::VectorXd& inv_mass,
                                   const Eigen::Matrix3Xd& f, double dt_kick, double half_drift, double dt,
                                   std::int64_t step, std::uint64_t substep);
  // The O step of apply over dt on particles first … last − 1 only, each velocity with apply's
  // bits, after set_step(dt) (serial: the coefficients). Ranges on distinct threads may run at once.
  // before and after, if given, receive ½ m|v|² of each mobile particle of the range before and
  // after the change (apply_and_measure's terms).
  void set_step(double dt) {
    if (dt != dt_) coefficients(dt);
  }
  void apply_range(Eigen::Matrix3Xd& v, std::int64_t step, std::uint64_t substep, std::int64_t first, std::int64_t last,
                   ParticleSum* before, ParticleSum* after) const;
  double temperature() const { return kT_; }
  const Eigen::VectorXd& friction() const { return friction_; }  // γ_i per particle
  const Eigen::VectorXd& inv_mass() const { return inv_mass_; }

 private:
  void coefficients(double dt);  // c_i and σ_i for dt (recomputed only when dt changes)
  template <bool kMeasure>
  KineticChange o_step(Eigen::Matrix3Xd& v, double dt, std::int64_t step, std::uint64_t substep) {
    return o_pass<kMeasure, false>(nullptr, v, nullptr, nullptr, 0.0, 0.0, dt, step, substep);
  }
  // With kDrift, the kick and the half drifts around it (kick_drift_o_drift).
  template <bool kMeasure, bool kDrift>
  KineticChange o_pass(Eigen::Matrix3Xd* x, Eigen::Matrix3Xd& v, const Eigen::VectorXd* inv_mass,
                       const Eigen::Matrix3Xd* f, double dt_kick, double half_drift, double dt, std::int64_t step,
                       std::uint64_t substep);
  double kT_;
  std::uint64_t seed_;
  std::vector<std::int64_t> id_;  // ThermostatSettings::particle_id
  Eigen::VectorXd friction_, inv_mass_, c_, sigma_;
  double dt_ = -1.0;
};

// Langevin dynamics as a force (LAMMPS's fix langevin, Schneider & Stoll, Phys. Rev. B 17, 1302
// (1978)), added to the outermost kick force where that force is computed, i.e. after the half kick
// and the drift of velocity Verlet (after the micro steps for the impulse family):
//   f_i += −γ_i m_i v_i + √(24 γ_i m_i kT / h) (u_i − ½),   u_i uniform on (0, 1)³ per component,
// v_i the velocities at that moment. The uniform noise has the variance 2γ m kT / h of the
// Gaussian one (LAMMPS's choice: cheaper, and the sum over the steps of a relaxation time is
// Gaussian anyway). The force serves the closing half kick of this step and the opening one of
// the next, so it is part of the cached kick force (and of the checkpoint). Fixed particles
// (inverse mass 0) get nothing. Noise from (seed, step, substep, particle) as LangevinNoise's.
class LangevinForce {
 public:
  LangevinForce(const ThermostatSettings& settings, const Eigen::VectorXd& inv_mass);
  // Adds the friction and noise force for velocities v over a step h to f, and writes it into
  // `part` (what of f is the thermostat's: its kicks' heat, kick_heat).
  void add(const Eigen::Matrix3Xd& v, double h, std::int64_t step, std::uint64_t substep, Eigen::Matrix3Xd& f,
           Eigen::Matrix3Xd& part) const;
  // The heat of the Langevin part f_L of a kick by dt: its impulse b = dt M⁻¹f_L taken as a jump
  // of its own at the on-step velocity v, before the opening kick's conservative part
  // (K(v + b) − K(v) = Σ m b·v + ½ m|b|²) or, `closing`, after the closing kick's (K(v) − K(v − b)
  // = Σ m b·v − ½ m|b|², v the kicked velocity). Between the two the Hamiltonian step is velocity
  // Verlet's, whole (multiple_time_stepping.cpp). Summed in particle blocks (parallel_sum).
  double kick_heat(const Eigen::Matrix3Xd& v, const Eigen::Matrix3Xd& part, double dt, bool closing) const;

 private:
  double kT_;
  std::uint64_t seed_;
  std::vector<std::int64_t> id_;  // ThermostatSettings::particle_id
  Eigen::VectorXd friction_, inv_mass_;
};

// Builds the stochastic velocity rescaling wrapper around `inner` (Bussi et al. 2007, eq. (A7)):
// after each macro step the kinetic energy K is replaced by K' drawn from the exact solution of
//   dK = (K̄ − K) dt/τ + 2 √(K K̄ / N_f) dW/√τ,   K̄ = N_f kT / 2,
// over dt = h, by rescaling every velocity by one factor α = √(K'/K). A global thermostat: it
// changes each velocity only by a common factor per step and leaves the dynamics between steps
// untouched, the least disturbance of the dynamics for a canonical K distribution. N_f = dof.
std::unique_ptr<Integrator> with_velocity_rescaling(std::unique_ptr<Integrator> inner,
                                                    const ThermostatSettings& settings, int dof);

// The factor α² = K'/K of one rescaling step (Bussi et al., eq. (A7)), from the noise of
// (seed, step): exposed for the test of its distribution.
double rescaling_factor_squared(double kinetic, double target_kinetic, int dof, double c, std::uint64_t seed,
                                std::int64_t step, double* r1 = nullptr);

}  // namespace stiffmd
