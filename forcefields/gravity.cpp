#include "forcefields/gravity.hpp"

#include <sstream>
#include <stdexcept>

namespace stiffmd {

Gravity::Gravity(std::string name, Level level, Eigen::Vector3d g, Eigen::VectorXd inv_mass)
    : ForceTerm(std::move(name), level), g_(g), mass_(inv_mass.size()) {
  if (!g_.allFinite()) throw std::invalid_argument("g must be finite");
  for (Eigen::Index i = 0; i < inv_mass.size(); ++i) mass_[i] = inv_mass[i] > 0.0 ? 1.0 / inv_mass[i] : 0.0;
}

// One plain pass: F_i += m_i g and Σ m_i x_i, in particle order (the Eigen outer product and
// matrix–vector product it replaces cost 5 ns of the pendulum's 60 ns step; the same bits).
// Scalar on purpose: measured, the pendulum's step is 1.77× the hand loop with it and 1.83×
// vectorised (BM_PendulumVsHandWritten, 2 × 3 repetitions each). The likely cause, not proven: f was
// just written element by element (the bond loop), and a 16-byte load of two 8-byte stores cannot
// be store-forwarded.
#if defined(__GNUC__) && !defined(__clang__)
__attribute__((optimize("no-tree-vectorize", "no-tree-slp-vectorize")))
#endif
double
Gravity::add_forces(const Eigen::Matrix3Xd& x, const Box&, Eigen::Matrix3Xd& f) const {
  const double* __restrict xp = x.data();
  const double* __restrict m = mass_.data();
  double* __restrict fp = f.data();
  const double g[3] = {g_.x(), g_.y(), g_.z()};
  double moment[3] = {0.0, 0.0, 0.0};  // Σ m_i x_i
  for (Eigen::Index i = 0, n = x.cols(); i < n; ++i)
    for (int a = 0; a < 3; ++a) {
      fp[3 * i + a] += g[a] * m[i];
      moment[a] += xp[3 * i + a] * m[i];
    }
  return -(g[0] * moment[0] + g[1] * moment[1] + g[2] * moment[2]);
}

#if defined(__GNUC__) && !defined(__clang__)
__attribute__((optimize("no-tree-vectorize", "no-tree-slp-vectorize")))
#endif
void
Gravity::add_forces_only(const Eigen::Matrix3Xd& x, const Box&, Eigen::Matrix3Xd& f) const {
  const double* __restrict m = mass_.data();
  double* __restrict fp = f.data();
  const double g[3] = {g_.x(), g_.y(), g_.z()};
  for (Eigen::Index i = 0, n = x.cols(); i < n; ++i)
    for (int a = 0; a < 3; ++a) fp[3 * i + a] += g[a] * m[i];
}

std::unique_ptr<ForceTerm> Gravity::on_subset(const ParticleSubset& subset, const Box&) const {
  auto out = std::make_unique<Gravity>(name(), level(), g_, Eigen::VectorXd());
  out->mass_.resize(subset.size());
  // The masses the subset carries (a decomposed run's part: its molecules'), as the constructor
  // makes them; without them, this term's of the subset's particles.
  if (subset.inv_mass.size() == subset.global.size())
    for (int k = 0; k < subset.size(); ++k) {
      const double w = subset.inv_mass[static_cast<size_t>(k)];
      out->mass_[k] = w > 0.0 ? 1.0 / w : 0.0;
    }
  else
    for (int k = 0; k < subset.size(); ++k) out->mass_[k] = mass_[subset.global[static_cast<size_t>(k)]];
  return out;
}

std::string Gravity::describe() const {
  std::ostringstream s;
  s << "uniform field g = (" << g_.x() << ", " << g_.y() << ", " << g_.z() << ")";
  return s.str();
}

void Gravity::define(ParameterRecord& record) const {
  record.add("g", {g_.x(), g_.y(), g_.z()});
  record.add("masses", std::span<const double>(mass_.data(), static_cast<std::size_t>(mass_.size())));
}

}  // namespace stiffmd
