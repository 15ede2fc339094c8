#include "integrators/rattle.hpp"

#include <sstream>

#include "integrators/primitives.hpp"

namespace stiffmd {

Rattle::Rattle(std::string method, ForceField& forces, ConstraintToolbox toolbox, std::unique_ptr<StiffModes> modes)
    : method_(std::move(method)),
      forces_(forces),
      toolbox_(std::move(toolbox)),
      modes_(std::move(modes)),
      f_(Eigen::Matrix3Xd::Zero(3, forces.num_particles())),
      correction_(f_),
      x_old_(f_),
      v_unprojected_(f_),
      constraint_force_(f_) {
  if (modes_) actions_ = Eigen::VectorXd::Zero(modes_->num_modes());
}

void Rattle::prepare(State& s, std::ostream& log) {
  if (modes_) modes_->actions(s.x, s.v, actions_);
  const Eigen::Matrix3Xd x0 = s.x, v0 = s.v;
  const double g0 = toolbox_.max_violation(s.x);
  toolbox_.shake(s.x, s.x);             // X0 = x0 + M⁻¹G(x0)ᵀλ, g(X0) = 0
  toolbox_.project_velocity(s.x, s.v);  // Y0 = P(X0) y0
  valid_ = false;
  std::ostringstream m;
  m << method_ << ": initial data projected onto the constraint manifold (paper eq. ACIV): max |g| " << g0 << " -> "
    << toolbox_.max_violation(s.x) << ", max |dx| = " << (s.x - x0).cwiseAbs().maxCoeff()
    << ", max |dv| = " << (s.v - v0).cwiseAbs().maxCoeff();
  if (modes_) {
    m << "; actions I =";
    for (Eigen::Index k = 0; k < actions_.size(); ++k) m << ' ' << actions_[k];
  }
  log << m.str() << "\n";
}

void Rattle::refresh(const Eigen::Matrix3Xd& x) {
  forces_.compute_unconstrained(x, f_);
  if (modes_) {
    modes_->correction_force(actions_, x, correction_);  // −∇W(I, x)
    f_ += correction_;
  }
  valid_ = true;
}

void Rattle::step(State& s, double h) {
  if (!valid_) refresh(s.x);
  kick(s.v, s.inv_mass, f_, 0.5 * h);
  x_old_ = s.x;
  drift(s.x, s.v, h);
  toolbox_.shake(x_old_, s.x);  // x' = x + h v½ + M⁻¹G(x)ᵀλ with g(x') = 0
  s.v = (s.x - x_old_) / h;     // v½ including the constraint impulse
  refresh(s.x);
  kick(s.v, s.inv_mass, f_, 0.5 * h);
  v_unprojected_ = s.v;
  toolbox_.project_velocity(s.x, s.v);  // G(x') v' = 0
  // F_c = M Δv / (h/2); fixed particles (inverse mass 0) have Δv = 0 and get no force.
  for (int i = 0; i < s.size(); ++i)
    constraint_force_.col(i) = s.inv_mass[i] > 0.0
                                   ? ((s.v.col(i) - v_unprojected_.col(i)) * (2.0 / (h * s.inv_mass[i]))).eval()
                                   : Eigen::Vector3d::Zero().eval();
}

std::vector<double> Rattle::save_state() const {
  std::vector<double> w(actions_.data(), actions_.data() + actions_.size());
  w.push_back(valid_ ? 1.0 : 0.0);
  w.insert(w.end(), f_.data(), f_.data() + f_.size());
  w.insert(w.end(), constraint_force_.data(), constraint_force_.data() + constraint_force_.size());
  return w;
}

void Rattle::load_state(const std::vector<double>& w) {
  const Eigen::Index m = actions_.size(), n3 = f_.size();
  if (static_cast<Eigen::Index>(w.size()) != m + 1 + 2 * n3)
    throw std::invalid_argument("the checkpoint holds " + std::to_string(w.size()) + " words of " + method_ +
                                " state, this scene needs " + std::to_string(m + 1 + 2 * n3) + " (" +
                                std::to_string(m) + " actions, forces of " + std::to_string(n3 / 3) + " particles)");
  actions_ = Eigen::Map<const Eigen::VectorXd>(w.data(), m);
  valid_ = w[m] != 0.0;
  f_ = Eigen::Map<const Eigen::Matrix3Xd>(w.data() + m + 1, 3, f_.cols());
  constraint_force_ = Eigen::Map<const Eigen::Matrix3Xd>(w.data() + m + 1 + n3, 3, f_.cols());
}

}  // namespace stiffmd
