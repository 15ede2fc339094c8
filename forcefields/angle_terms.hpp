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
#include <string_view>
#include <vector>

#include "core/topology.hpp"
#include "forcefields/angle_loop.hpp"
#include "forcefields/coefficients.hpp"
#include "forcefields/force_term.hpp"
#include "forcefields/type_claim.hpp"

namespace stiffmd {

// Coefficients of one angle type: k ≥ 0 (energy/rad² for HarmonicAngle, energy for CosineAngle),
// θ₀ in [0, π] (radians).
struct AngleCoeffs {
  double k = 0.0;
  double theta0 = 0.0;
};

// The angle kernels: energy and dE/dθ of one angle.
struct HarmonicAngleKernel {
  static constexpr std::string_view kStyle = "harmonic-angle";
  static void eval(double theta, const AngleCoeffs& p, double& e, double& de_dtheta) {
    const double g = theta - p.theta0;
    e = 0.5 * p.k * g * g;
    de_dtheta = p.k * g;
  }
};

struct CosineAngleKernel {
  static constexpr std::string_view kStyle = "cosine-angle";
  static void eval(double theta, const AngleCoeffs& p, double& e, double& de_dtheta) {
    const double g = theta - p.theta0;
    // 1 − cos g = 2 sin²(g/2): no cancellation near θ₀, where the energy is O(g²).
    const double s = std::sin(0.5 * g);
    e = 2.0 * p.k * s * s;
    de_dtheta = p.k * std::sin(g);
  }
};

// An angle term over a kernel (as PairTerm is over a pair kernel).
template <class K>
class AngleTerm final : public ForceTerm, public TypeClaim {
 public:
  using Params = AngleCoeffs;
  using Kernel = K;

  // Validating constructor: every k ≥ 0 and finite, θ₀ in [0, π], i, j, k ≥ 0 and distinct,
  // 0 ≤ type < types.size(). Angle (core/topology.hpp) is i–j–k, j the vertex; its type
  // indexes `types` (the reader maps the deck's angle types onto this list).
  AngleTerm(std::string name, Level level, std::vector<Angle> angles, std::vector<AngleCoeffs> types);

  double add_forces(const Eigen::Matrix3Xd& x, const Box& box, Eigen::Matrix3Xd& f) const override {
    return accumulate_angle_forces<Kernel>(instances_, x, box, f, partition_);
  }
  double virial(const Eigen::Matrix3Xd& x, const Box& box) const override {
    return accumulate_angle_virial<Kernel>(instances_, x, box);
  }
  // The angles of the subset, in this term's order, with its coefficients.
  std::unique_ptr<ForceTerm> on_subset(const ParticleSubset& subset, const Box&) const override {
    const std::string who = std::string(K::kStyle) + " '" + name() + "'";
    return keeping_claim(std::make_unique<AngleTerm>(
        name(), level(), subset_items(angles_, subset, who, "angle", &Angle::i, &Angle::j, &Angle::k), types_));
  }
  std::string_view style() const override { return Kernel::kStyle; }
  std::string describe() const override;
  // Every type's k and θ₀, then every angle: its particles and its type.
  void define(ParameterRecord& record) const override;

 private:
  std::vector<AngleCoeffs> types_;
  std::vector<Angle> angles_;  // as given, type indexing types_: for define()
  std::vector<AngleInstance<Params>> instances_;
  mutable TuplePartition<3> partition_;  // thread plan of the angle loop
};

using HarmonicAngle = AngleTerm<HarmonicAngleKernel>;
using CosineAngle = AngleTerm<CosineAngleKernel>;

// The members, in the header so that a new kernel needs no explicit instantiation; what does
// not depend on the kernel is in angle_terms.cpp.
namespace angle_detail {
// Checks the coefficients (k ≥ 0, θ₀ in [0, π]) and each angle's indices and type; throws
// std::invalid_argument naming the term.
std::vector<AngleInstance<AngleCoeffs>> angle_instances(std::string_view style, const std::string& name,
                                                        const std::vector<Angle>& angles,
                                                        const std::vector<AngleCoeffs>& types);
std::string describe_angles(std::string_view style, std::size_t n, const std::vector<AngleCoeffs>& types);
void define_angles(ParameterRecord& record, const std::vector<AngleCoeffs>& types, const std::vector<Angle>& angles);
}  // namespace angle_detail

template <class K>
AngleTerm<K>::AngleTerm(std::string name, Level level, std::vector<Angle> angles, std::vector<AngleCoeffs> types)
    : ForceTerm(std::move(name), level),
      types_(std::move(types)),
      angles_(std::move(angles)),
      instances_(angle_detail::angle_instances(K::kStyle, this->name(), angles_, types_)) {}

template <class K>
std::string AngleTerm<K>::describe() const {
  return angle_detail::describe_angles(K::kStyle, instances_.size(), types_);
}

template <class K>
void AngleTerm<K>::define(ParameterRecord& record) const {
  angle_detail::define_angles(record, types_, angles_);
}

}  // namespace stiffmd
