// Maxwell–Boltzmann velocities of a part of the system, the same for a particle whichever part
// holds it: its three normals are keyed by its global index (counter-based, as the Langevin noise:
// integrators/thermostat.hpp), and the two corrections that need the whole system — the
// centre-of-mass velocity removed, the kinetic energy set to the temperature exactly — use sums
// whose value does not depend on the order of their terms (SignedExactSum, core/exact_sum.hpp),
// added over the ranks. So the velocities are the same bits on any number of ranks, and on one,
// for any partition of the particles: what a rank that holds only its part needs (docs/parallel.md,
// "What a rank holds"). They are not the velocities of [velocities] on one process
// (core/portable_random.hpp: one random stream over the particles in order), which every deck's
// bits depend on.
#pragma once

#include <Eigen/Core>
#include <cstdint>
#include <span>

#include "core/communicator.hpp"

namespace stiffmd {

// v_i = √(k_BT m_i⁻¹) z_i, z_i the normals of particle_noise(key(seed), global[i]); fixed particles
// (inverse mass 0) at rest; then, over the mobile particles of every rank, twice: v −= Σ m v / Σ m;
// last v ×= √(dof k_BT / Σ m v²) with dof = 3 (mobile particles) − 3 (all zero when dof ≤ 0 or
// kT = 0). `ranks` (may be null: one process) adds the sums over the ranks (collective).
// kT < 0 or non-finite, or an inverse mass that is negative or non-finite: std::invalid_argument.
Eigen::Matrix3Xd maxwell_boltzmann_by_particle(const Eigen::VectorXd& inv_mass, std::span<const int> global, double kT,
                                               std::uint64_t seed, const Communicator* ranks);

}  // namespace stiffmd
