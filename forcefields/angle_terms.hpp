// Angle terms on triplets (i, j, k), j the vertex, through the shared loop in angle_loop.hpp.
// θ in radians; parameters per angle type.
//   HarmonicAngle: E = ½ k (θ − θ₀)².  LAMMPS angle_style harmonic writes E = K (θ − θ₀)², so
//                  K_LAMMPS = k/2 (and LAMMPS's angle_coeff takes θ₀ in degrees).
//   CosineAngle:   E = k [1 − cos(θ − θ₀)].  θ₀ = π gives LAMMPS's angle_style cosine,
//                  E = K (1 + cos θ), with K_LAMMPS = k; near θ₀ it is ½ k (θ − θ₀)², the same
//                  curvature as HarmonicAngle with the same k.
#pragma once

#include <cmath>
#include <string>
#include <vector>

#include "engine/topology.hpp"
#include "forcefields/angle_loop.hpp"
#include "forcefields/force_term.hpp"

namespace stiffmd {

// Coefficients of one angle type: k ≥ 0 (energy/rad² for HarmonicAngle, energy for CosineAngle),
// θ₀ in [0, π] (radians).
struct AngleCoeffs {
  double k = 0.0;
  double theta0 = 0.0;
};

class HarmonicAngle final : public ForceTerm {
 public:
  // Validating constructor: every k ≥ 0 and finite, θ₀ in [0, π], i, j, k ≥ 0 and distinct,
  // 0 ≤ type < types.size(). Angle (engine/topology.hpp) is i–j–k, j the vertex; its type
  // indexes `types` (the reader maps the deck's angle types onto this list).
  HarmonicAngle(std::string name, Level level, std::vector<Angle> angles, std::vector<AngleCoeffs> types);

  double add_forces(const Eigen::Matrix3Xd& x, const Box& box, Eigen::Matrix3Xd& f) const override;
  double virial(const Eigen::Matrix3Xd& x, const Box& box) const override;
  std::string_view style() const override { return "harmonic-angle"; }
  std::string describe() const override;

  using Params = AngleCoeffs;
  struct Kernel {
    static void eval(double theta, const Params& p, double& e, double& de_dtheta) {
      const double g = theta - p.theta0;
      e = 0.5 * p.k * g * g;
      de_dtheta = p.k * g;
    }
  };

 private:
  std::vector<AngleCoeffs> types_;
  std::vector<AngleInstance<Params>> instances_;
};

class CosineAngle final : public ForceTerm {
 public:
  // Validating constructor: as HarmonicAngle's.
  CosineAngle(std::string name, Level level, std::vector<Angle> angles, std::vector<AngleCoeffs> types);

  double add_forces(const Eigen::Matrix3Xd& x, const Box& box, Eigen::Matrix3Xd& f) const override;
  double virial(const Eigen::Matrix3Xd& x, const Box& box) const override;
  std::string_view style() const override { return "cosine-angle"; }
  std::string describe() const override;

  using Params = AngleCoeffs;
  struct Kernel {
    static void eval(double theta, const Params& p, double& e, double& de_dtheta) {
      const double g = theta - p.theta0;
      // 1 − cos g = 2 sin²(g/2): no cancellation near θ₀, where the energy is O(g²).
      const double s = std::sin(0.5 * g);
      e = 2.0 * p.k * s * s;
      de_dtheta = p.k * std::sin(g);
    }
  };

 private:
  std::vector<AngleCoeffs> types_;
  std::vector<AngleInstance<Params>> instances_;
};

}  // namespace stiffmd
