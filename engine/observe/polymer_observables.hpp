// Observables for polymer scenes: kinetic temperature, virial pressure, mean radius of gyration
// and size (chains: end-to-end distance; rings: diameter) per molecule, and bond-length /
// bond-angle histograms.
#pragma once

#include <string>
#include <vector>

#include "core/state.hpp"
#include "core/topology.hpp"
#include "forcefields/force_field.hpp"

namespace stiffmd {

// Kinetic temperature 2K / dof (k_B = 1).
inline double temperature(const State& s, int dof) {
  return dof > 0 ? 2.0 * s.kinetic_energy() / dof : 0.0;
}

// Degrees of freedom: 3 per mobile particle, less 3 for the conserved total momentum when no
// particle is fixed and no external field acts, less one per rigid constraint.
int degrees_of_freedom(const State& s, bool momentum_conserved, int constraints);

// P = (2K + W) / (3V) with W = Σ r_ij·f_ij over every term (virial theorem); the caller adds the
// rigid-constraint forces' virial for RATTLE and the effective dynamics (Thermo::sample).
// kinetic: the K of the kinetic term (Thermo: the integrator's estimate); < 0: the state's.
double pressure(const State& s, const ForceField& forces, double volume, double kinetic = -1.0);

// Molecules with at least two particles, each with the shape of its own bond graph: a linear chain
// (a path: two ends), a ring (a cycle: every bead has two bonded neighbours) or neither (branched,
// as a star, or not one connected graph).
class Molecules {
 public:
  Molecules(const Topology& topology, const Eigen::VectorXd& inv_mass, const Eigen::VectorXd& mass);
  bool empty() const { return molecules_.empty(); }
  // Whether some molecule is a linear chain or a ring, the shapes with a size R below.
  bool has_end_to_end() const { return num_sized_ > 0; }
  // rg: the mean over molecules of the mass-weighted radius of gyration.
  // end_to_end: the mean over linear chains and rings of their size R, as tools/analyze.py defines
  // it: a linear chain's end-to-end distance |x_end − x_start|; a ring's root-mean-square diameter
  // R = √(⟨|x_{p(k+⌊N/2⌋)} − x_{p(k)}|²⟩ over k), p the N beads in bond order (a ring's ends meet).
  // Branched molecules have no end-to-end distance and are left out (0 when none is sized).
  // Positions are unwrapped, so molecules are whole.
  void measure(const Eigen::Matrix3Xd& x, double& rg, double& end_to_end) const;
  // The sums behind the means (over the molecules, over the sized ones) and their counts: the
  // means of several processes' molecules together (Thermo::sums).
  void sum(const Eigen::Matrix3Xd& x, double& rg_sum, double& end_to_end_sum) const;
  int count() const { return static_cast<int>(molecules_.size()); }
  int sized() const { return num_sized_; }

 private:
  enum class Shape { linear, ring, other };
  struct Molecule {
    std::vector<int> members;  // index order
    Shape shape = Shape::other;
    std::vector<int> path;  // linear: the two ends (lower index first); ring: the beads in bond order
  };
  std::vector<Molecule> molecules_;
  int num_sized_ = 0;  // linear chains and rings
  Eigen::VectorXd mass_;
};

}  // namespace stiffmd
