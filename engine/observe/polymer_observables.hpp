// Observables for polymer scenes: kinetic temperature, virial pressure, mean radius of
// gyration and end-to-end distance per molecule, and bond-length / bond-angle histograms.
#pragma once

#include <string>
#include <vector>

#include "engine/core/state.hpp"
#include "engine/core/topology.hpp"
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

// Molecules with at least two particles: particle lists in index order.
class Molecules {
 public:
  Molecules(const Topology& topology, const Eigen::VectorXd& inv_mass, const Eigen::VectorXd& mass);
  bool empty() const { return members_.empty(); }
  // Mean over molecules of the mass-weighted radius of gyration and of |x_last − x_first|
  // (the end-to-end distance of a linear chain). Positions are unwrapped, so molecules are whole.
  void measure(const Eigen::Matrix3Xd& x, double& rg, double& end_to_end) const;

 private:
  std::vector<std::vector<int>> members_;
  Eigen::VectorXd mass_;
};

// Writes DIR/histograms.csv: quantity,bin_low,bin_high,count for bond lengths (every bond) and
// bond angles in degrees (the topology's angles, or every pair of bonds sharing a particle).
void write_histograms(const std::string& path, const Eigen::Matrix3Xd& x, const Box& box, const Topology& topology,
                      int bins = 100);

}  // namespace stiffmd
