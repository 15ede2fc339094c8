// Uniform external field (gravity): E = −Σ_i m_i g·x_i, F_i = m_i g. Fixed particles
// (inverse mass 0) feel no field: they are held in place and carry no energy.
#pragma once

#include <Eigen/Core>
#include <string>

#include "forcefields/force_term.hpp"

namespace stiffmd {

class Gravity final : public ForceTerm {
 public:
  bool conserves_momentum() const override { return false; }  // an external field
  Gravity(std::string name, Level level, Eigen::Vector3d g, Eigen::VectorXd inv_mass);

  double add_forces(const Eigen::Matrix3Xd& x, const Box& box, Eigen::Matrix3Xd& f) const override;
  // The same forces without Σ m_i x_i (half of add_forces's arithmetic).
  void add_forces_only(const Eigen::Matrix3Xd& x, const Box& box, Eigen::Matrix3Xd& f) const override;
  // The field on the subset's particles, with their masses.
  std::unique_ptr<ForceTerm> on_subset(const ParticleSubset& subset, const Box& box) const override;
  std::string_view style() const override { return "gravity"; }
  std::string describe() const override;
  void define(ParameterRecord& record) const override;  // g and the masses it multiplies

 private:
  Eigen::Vector3d g_;
  Eigen::VectorXd mass_;  // m_i, 0 for fixed particles
};

}  // namespace stiffmd
