// Observables computed from a state: the thermo row (design.md §3; issue 2's columns).
#pragma once

#include <string>
#include <vector>

#include "engine/state.hpp"
#include "forcefields/force_field.hpp"

namespace stiffmd {

struct Energies {
  double kinetic = 0.0;
  double slow = 0.0;   // U(x): every slow-level term
  double stiff = 0.0;  // ε⁻²V(x) and anything else integrated on the fast level
  double total() const { return kinetic + slow + stiff; }
};

Energies energies(const State& s, const ForceField& forces);

// max_b |g_b(x)| = max_b | |x_i − x_j| − ℓ_b | over the constraint-defining bonds (0 if none).
double max_constraint_violation(const Eigen::Matrix3Xd& x, const Box& box, const StiffBonds* stiff);

// One row of thermo output: named columns, fixed for a run.
class Thermo {
 public:
  Thermo(const ForceField& forces);
  const std::vector<std::string>& columns() const { return columns_; }
  // Values for the current state; energy_drift is relative to the first call's total energy.
  const std::vector<double>& sample(const State& s);
  double initial_energy() const { return e0_; }

 private:
  const ForceField& forces_;
  std::vector<std::string> columns_;
  std::vector<double> values_;
  bool have_e0_ = false;
  double e0_ = 0.0;
};

}  // namespace stiffmd
