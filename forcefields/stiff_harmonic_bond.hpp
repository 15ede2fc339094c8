// Stiff harmonic bond, the constraint-defining fast part ε⁻²V (docs/design.md §1):
//   E_b = ½ (α_b/ε)² (|x_i − x_j| − ℓ_b)².
#pragma once

#include <string>
#include <vector>

#include "forcefields/bond_loop.hpp"
#include "forcefields/force_term.hpp"

namespace stiffmd {

class StiffHarmonicBond final : public ForceTerm, public FusedMicroStep {
 public:
  // Validating constructor: ε > 0 and the rules of find_stiff_bond_problem (stiff_bond.hpp) that
  // need no masses (i ≠ j, ℓ_b > 0, α_b > 0, one bond per pair, realisable lengths).
  StiffHarmonicBond(std::string name, Level level, StiffBonds bonds);

  double add_forces(const Eigen::Matrix3Xd& x, const Box& box, Eigen::Matrix3Xd& f) const override;
  double virial(const Eigen::Matrix3Xd& x, const Box& box) const override {
    return accumulate_bond_virial<Kernel>(instances_, x, box);
  }
  // The stiff bonds of the subset, in this term's order (the constraint clusters' order), same ε.
  std::unique_ptr<ForceTerm> on_subset(const ParticleSubset& subset, const Box& box) const override;
  std::string_view style() const override { return "stiff-harmonic"; }
  std::string describe() const override;
  void define(ParameterRecord& record) const override;  // ε and every bond's particles, ℓ_b and α_b
  const StiffBonds* stiff_bonds() const override { return &bonds_; }
  const FusedMicroStep* fused_micro_step() const override { return this; }
  void kick_drift_forces(Eigen::Matrix3Xd& x, Eigen::Matrix3Xd& v, const Eigen::VectorXd& inv_mass, Eigen::Matrix3Xd& f,
                         double first_kick, double dt_kick, double dt, int steps) const override {
    fused_kick_drift_bond_forces<Kernel>(instances_, x, v, inv_mass, f, first_kick, dt_kick, dt, steps, plan_);
  }

  struct Params {
    double length;
    double k;  // (α/ε)²
  };
  struct Kernel {
    static void eval(double r, const Params& p, double& e, double& de_dr) {
      const double g = r - p.length;
      e = 0.5 * p.k * g * g;
      de_dr = p.k * g;
    }
  };

 private:
  StiffBonds bonds_;
  std::vector<BondInstance<Params>> instances_;
  mutable BondPartition partition_;  // thread plan of the bond loop
  // The micro steps' blocks of whole molecules (kick_drift_forces)
  mutable MicroStepPlan<Params> plan_;
};

}  // namespace stiffmd
