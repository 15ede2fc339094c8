// Constant pressure by stochastic cell rescaling (C-rescale: Bernetti & Bussi, J. Chem. Phys. 153,
// 114107 (2020)), on molecules: the box and the molecules' centres of mass are scaled together,
// each molecule moved rigidly, so that stiff springs and rigid bonds are untouched and the pressure
// that drives the cell is the molecular one, in which every intramolecular force drops out
// (docs/design.md, "Constant pressure"). The cell moves between macro steps, every `interval` of
// them, around any method: never inside the micro steps of the impulse family.
#pragma once

#include <Eigen/Core>
#include <cstdint>
#include <memory>
#include <string_view>
#include <vector>

#include "core/state.hpp"
#include "forcefields/force_field.hpp"

namespace stiffmd {

class Communicator;
class Integrator;

struct BarostatSettings {
  // Which box lengths move together: all three (isotropic), x with y and z alone
  // (semi-isotropic), or each alone (anisotropic).
  enum class Coupling { isotropic, semi_isotropic, anisotropic };
  bool on = false;
  Coupling coupling = Coupling::isotropic;
  Eigen::Vector3d pressure = Eigen::Vector3d::Zero();  // P₀ per axis (equal within a coupled group)
  double tau = 0.0;                                    // τ_p, the relaxation time of the volume
  double compressibility = 0.0;                        // β_T, an estimate: with τ_p, the volume's mobility
  int interval = 10;                                   // macro steps per cell move (GROMACS's nstpcouple)
  double temperature = 0.0;                            // kT, the thermostat's
  std::uint64_t seed = 1;
  // The molecule of each particle (bonded_molecules, core/topology.hpp): what moves rigidly.
  std::vector<int> molecule;
  // A decomposed run's part (docs/parallel.md): the sums over molecules are added over
  // `processes` (null: this process holds the whole system).
  const Communicator* processes = nullptr;
};

// The molecular pressure tensor's diagonal: P_aa = (2 K_a + W_aa) / V, K_a = Σ_I ½ M_I V_{I,a}² the
// kinetic energy of the molecules' centres of mass along a, and W_aa = Σ_I R_{I,a} F_{I,a} the
// molecular virial, formed as the pair virial Σ_pairs d_a f_a less Σ_i δ_{i,a} f_{i,a} (δ_i = x_i −
// R_I: whole molecules make both periodic-safe). Only the pair terms enter: the bonded terms,
// stiff springs and constraint forces act within molecules, and their share is zero identically.
class MolecularPressure {
 public:
  MolecularPressure(std::vector<int> molecule, const Eigen::VectorXd& inv_mass,
                    const Communicator* processes = nullptr);
  // The centres of mass R_I and their velocities V_I at s (centres(), velocities()).
  void locate(const State& s);
  // 2K_a + W_aa, summed over every process (no division by V); locate() first. `scratch` takes the
  // pair forces.
  Eigen::Vector3d virial_and_kinetic(const State& s, const ForceField& forces, Eigen::Matrix3Xd& scratch);
  // P_aa at s (locate included).
  Eigen::Vector3d pressure(const State& s, const ForceField& forces, Eigen::Matrix3Xd& scratch);
  const Eigen::Matrix3Xd& centres() const { return centre_; }
  const Eigen::Matrix3Xd& velocities() const { return velocity_; }
  const std::vector<int>& molecule() const { return molecule_; }
  int molecules() const { return static_cast<int>(molecule_mass_.size()); }

 private:
  std::vector<int> molecule_;
  Eigen::VectorXd inv_mass_, molecule_mass_;
  Eigen::Matrix3Xd centre_, velocity_;
  const Communicator* processes_;
};

// One cell move of the C-rescale equation over dt, per coupled group g of k axes (docs/design.md,
// "Constant pressure"; Itô, the volume's measure dV):
//   Δε_g = k β_T (P_g − P₀)/(3τ_p) dt + √(2 k kT β_T dt / (3 V τ_p)) ξ_g,   ε_g = Σ_{a∈g} log L_a,
// P_g the mean of the group's P_aa; each axis of the group scales by μ_a = exp(Δε_g / k).
// Isotropic (k = 3) this is Bernetti & Bussi's dε = β_T (P − P₀)/τ_p dt + √(2 kT β_T/(V τ_p)) dW
// for ε = log V. ξ from (seed, step): the same on every process.
Eigen::Vector3d cell_scaling(const BarostatSettings& b, const Eigen::Vector3d& p, double volume, double dt,
                             std::int64_t step);

// Wraps `inner` so that after every `interval`-th macro step the cell moves (cell_scaling) and
// every molecule with it: x_i += (μ − 1)∘(R_I − o), v_i −= (1 − 1/μ)∘V_I, L ← μ∘L (o the box's
// origin, fixed). The box is set on `forces` (every later evaluation and the neighbour lists
// follow it) and the inner method forgets its cached forces. The box is the checkpoint's own
// (engine/run/checkpoint.hpp), not the method's: its words are the inner method's. Throws NumericalError when the box
// shrinks below twice the longest pair cutoff plus skin.
std::unique_ptr<Integrator> with_cell_rescaling(std::unique_ptr<Integrator> inner, const BarostatSettings& settings,
                                                ForceField& forces, const Eigen::VectorXd& inv_mass);

std::string_view coupling_name(BarostatSettings::Coupling c);

}  // namespace stiffmd
