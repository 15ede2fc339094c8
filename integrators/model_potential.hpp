// The potential a constrained method adds to U on the manifold g = 0 (docs/design.md §4, §5): a
// strategy of Rattle, so that one RATTLE step serves
//   rattle     no model potential (the rigid limit);
//   effective  W(I, x) = Σ_k I_k ω_k(x) at the actions I of the initial state (paper eq. (CH));
//   fixman     U_F(x) = (kT/2) log det(K^{1/2} G M⁻¹ Gᵀ K^{1/2}), the canonical average of W
//              (docs/design.md §5): with a thermostat at kT, the ε → 0 limit of the stiff ensemble.
#pragma once

#include <Eigen/Core>
#include <ostream>
#include <stdexcept>
#include <string>
#include <vector>

#include "core/state.hpp"
#include "integrators/fixman.hpp"
#include "integrators/modes.hpp"

namespace stiffmd {

class ModelPotential {
 public:
  virtual ~ModelPotential() = default;
  // f = −∇W(x) (overwritten), returns W(x).
  virtual double force(const Eigen::Matrix3Xd& x, Eigen::Matrix3Xd& f) = 0;
  // f += −∇W(x) (f is 3×N), returns W(x); scratch (3×N) may be overwritten. By default force()
  // into scratch, then a pass adding it; a potential that can add in place overrides it.
  virtual double add_force(const Eigen::Matrix3Xd& x, Eigen::Matrix3Xd& f, Eigen::Matrix3Xd& scratch) {
    const double value = force(x, scratch);
    f += scratch;
    return value;
  }
  // Once, before the first step of a fresh run, on the state before its projection.
  virtual void prepare(const State&, std::ostream&) {}
  // The integrator's constraint toolbox, which a potential may read G(x) and S(x)'s factors from
  // (FixmanCorrection); called once by the integrator that owns both.
  virtual void attach(ConstraintToolbox&) {}
  // Block by block (the constrained step in molecule blocks, integrators/rattle.hpp): whether the
  // potential can add its force one molecule block of the attached toolbox at a time
  // (add_block_force, every block once at one x, then blocked_value() for W there), with the bits
  // of add_force.
  virtual bool blocks() const { return false; }
  virtual void add_block_force(int, const Eigen::Matrix3Xd&, Eigen::Matrix3Xd&) {}
  virtual double blocked_value() const { return 0.0; }
  // What the potential carries beyond (x, v), for checkpoints.
  virtual std::vector<double> save_state() const { return {}; }
  // The constants among its state (Integrator::invariants): all of it, for the effective correction.
  virtual std::vector<double> invariants() const { return save_state(); }
  virtual void set_invariants(const std::vector<double>& w) { load_state(w); }
  virtual void load_state(const std::vector<double>& s) {
    if (!s.empty()) throw std::invalid_argument("this integrator carries no state, the checkpoint has some");
  }
};

// The effective dynamics' correction W(I, x) = Σ_k I_k ω_k(x), the actions taken from the
// initial state (paper eq. (actions)) and kept fixed: they are adiabatic invariants.
class EffectiveCorrection final : public ModelPotential {
 public:
  explicit EffectiveCorrection(StiffModes modes)
      : modes_(std::move(modes)), actions_(Eigen::VectorXd::Zero(modes_.num_modes())) {}
  double force(const Eigen::Matrix3Xd& x, Eigen::Matrix3Xd& f) override {
    return modes_.correction_force(actions_, x, f);
  }
  void prepare(const State& s, std::ostream& log) override {
    modes_.actions(s.x, s.v, actions_);
    log << "effective dynamics: actions I =";
    for (Eigen::Index k = 0; k < actions_.size(); ++k) log << ' ' << actions_[k];
    log << "\n";
  }
  std::vector<double> save_state() const override { return {actions_.data(), actions_.data() + actions_.size()}; }
  void load_state(const std::vector<double>& s) override {
    if (static_cast<Eigen::Index>(s.size()) != actions_.size())
      throw std::invalid_argument("the checkpoint holds " + std::to_string(s.size()) + " actions, this scene has " +
                                  std::to_string(actions_.size()) + " modes");
    actions_ = Eigen::Map<const Eigen::VectorXd>(s.data(), actions_.size());
  }

 private:
  StiffModes modes_;
  Eigen::VectorXd actions_;
};

// Fixman's potential U_F(x) = (kT/2) log det(K^{1/2} G M⁻¹ Gᵀ K^{1/2}) (docs/design.md §5): with it
// and a thermostat at kT, RATTLE's rigid-bond ensemble becomes the stiff-spring one,
// ρ_stiff = ρ_rigid exp(−β U_F). It carries no state: kT is the thermostat's.
class FixmanCorrection final : public ModelPotential {
 public:
  FixmanCorrection(FixmanPotential potential, double kT) : potential_(std::move(potential)), kT_(kT) {}
  double force(const Eigen::Matrix3Xd& x, Eigen::Matrix3Xd& f) override { return potential_.force(x, kT_, f); }
  double add_force(const Eigen::Matrix3Xd& x, Eigen::Matrix3Xd& f, Eigen::Matrix3Xd&) override {
    return potential_.add_force(x, kT_, f);
  }
  // At x_{n+1} the integrator's velocity projection has just measured and factored S there.
  void attach(ConstraintToolbox& toolbox) override { potential_.use_toolbox(&toolbox); }
  bool blocks() const override { return potential_.blocks(); }
  void add_block_force(int b, const Eigen::Matrix3Xd& x, Eigen::Matrix3Xd& f) override {
    potential_.add_block_force(b, x, kT_, f);
  }
  double blocked_value() const override { return potential_.value(kT_); }

 private:
  FixmanPotential potential_;
  double kT_;
};

}  // namespace stiffmd
