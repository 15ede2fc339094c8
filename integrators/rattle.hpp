// RATTLE (Andersen 1983; HLW §VII.1.4) on the constrained system: the stiff bonds become
// rigid constraints g(x) = 0, and the force is that of every other term,
//
//   v½ = v + ½h M⁻¹(f(x) − G(x)ᵀλ),  x' = x + h v½,  g(x') = 0          (SHAKE)
//   v' = v½ + ½h M⁻¹(f(x') − G(x')ᵀμ),  G(x') v' = 0                    (velocity projection)
//
// With a StiffModes object it integrates the effective dynamics instead (paper eq. EHS):
// the same scheme on U + W(I, X), W = Σ_k I_k ω_k(X), with the actions I taken from the
// initial state — the ε → 0 limit of the stiff system (Rubin–Ungar, Takens, Bornemann).
// Plain RATTLE (W dropped) is the "rigid" limit most engines use, which differs by O(1)
// when the bonds carry vibrational energy.
#pragma once

#include <memory>
#include <string>

#include "integrators/constraints.hpp"
#include "integrators/integrator.hpp"
#include "integrators/modes.hpp"

namespace stiffmd {

class Rattle final : public Integrator {
 public:
  // modes == nullptr: plain RATTLE; otherwise the effective dynamics.
  Rattle(std::string method, ForceField& forces, ConstraintToolbox toolbox, std::unique_ptr<StiffModes> modes);

  // Projects (x, v) M-orthogonally onto {g = 0, G v = 0} (paper eq. ACIV); for the
  // effective dynamics the actions are taken from the state before projection.
  void prepare(State& s, std::ostream& log) override;
  void step(State& s, double h) override;
  void reset() override { valid_ = false; }
  std::string_view method() const override { return method_; }
  // The constraint force at the end of the last step is the velocity projection's impulse over
  // the closing half step: F_c = M (v' − v'_unprojected) / (h/2). Molecules are whole (unwrapped
  // positions) and F_c sums to zero on each, so Σ_i x_i·F_c,i equals the pairwise virial.
  double constraint_virial(const State& s) const override { return (s.x.array() * constraint_force_.array()).sum(); }
  double model_potential(const Eigen::Matrix3Xd& x) override {
    return modes_ ? modes_->correction_force(actions_, x, correction_) : 0.0;
  }

  // The actions, the cached force f(x) with its validity and the constraint force of the last
  // step (for the pressure of the first sample after a restart): m + 1 + 6N words.
  std::vector<double> save_state() const override;
  void load_state(const std::vector<double>& s) override;

  // The actions of the effective dynamics (empty for plain RATTLE).
  const Eigen::VectorXd& actions() const { return actions_; }
  void set_actions(const Eigen::VectorXd& I) { actions_ = I, valid_ = false; }

 private:
  void refresh(const Eigen::Matrix3Xd& x);

  std::string method_;
  ForceField& forces_;
  ConstraintToolbox toolbox_;
  std::unique_ptr<StiffModes> modes_;
  Eigen::VectorXd actions_;
  Eigen::Matrix3Xd f_, correction_, x_old_, v_unprojected_, constraint_force_;
  bool valid_ = false;
};

}  // namespace stiffmd
