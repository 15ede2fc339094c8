#include "forcefields/gravity.hpp"

#include <sstream>
#include <stdexcept>

namespace stiffmd {

Gravity::Gravity(std::string name, Level level, Eigen::Vector3d g, Eigen::VectorXd inv_mass)
    : ForceTerm(std::move(name), level), g_(g), mass_(inv_mass.size()) {
  if (!g_.allFinite()) throw std::invalid_argument("g must be finite");
  for (Eigen::Index i = 0; i < inv_mass.size(); ++i) mass_[i] = inv_mass[i] > 0.0 ? 1.0 / inv_mass[i] : 0.0;
}

double Gravity::add_forces(const Eigen::Matrix3Xd& x, const Box&, Eigen::Matrix3Xd& f) const {
  f.noalias() += g_ * mass_.transpose();
  const Eigen::Vector3d first_moment = x * mass_;  // Σ m_i x_i, fixed size: no heap temporary
  return -g_.dot(first_moment);
}

std::string Gravity::describe() const {
  std::ostringstream s;
  s << "uniform field g = (" << g_.x() << ", " << g_.y() << ", " << g_.z() << ")";
  return s.str();
}

}  // namespace stiffmd
