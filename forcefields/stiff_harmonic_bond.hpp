// Stiff harmonic bond, the constraint-defining fast part ε⁻²V (docs/design.md §1):
//   E_b = ½ (α_b/ε)² (|x_i − x_j| − ℓ_b)².
#pragma once

#include <string>
#include <vector>

#include "forcefields/bond_loop.hpp"
#include "forcefields/force_term.hpp"
#include "forcefields/stiff_bond_rule.hpp"

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
  // The rule that made this term's bonds from the system's topology (StiffBondRule): with it, a
  // term on a particle subset makes its bonds from the subset's topology by the same rule, and
  // never reads this term's list. Empty (a term made from its bonds alone): it cuts its list.
  void set_rule(StiffBondRule rule) { rule_ = std::move(rule); }
  const StiffBondRule& rule() const { return rule_; }
  // The stiff bonds of the subset, in this term's order (the constraint clusters' order), same ε
  // and rule. With a rule: the rule on the subset's topology (the system's restricted to the
  // subset, in its order: the term's bonds on the subset in the term's order), unless an item of
  // that topology reaches outside the subset or has a type the rule does not know (a subset that
  // cuts a molecule, or a topology that is not the system's); then, and without a rule, this
  // term's list cut to the subset, which names what it refuses.
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
  StiffBondRule rule_;
  std::vector<BondInstance<Params>> instances_;
  mutable BondPartition partition_;  // thread plan of the bond loop
  // The micro steps' blocks of whole molecules (kick_drift_forces)
  mutable MicroStepPlan<Params> plan_;
};

}  // namespace stiffmd
