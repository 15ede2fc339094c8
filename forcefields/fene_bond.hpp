// FENE bond with an optional WCA core, as LAMMPS's bond_style fene (same K, R0, epsilon, sigma,
// no factor differences):
//   E(r) = −½ K R₀² ln(1 − (r/R₀)²)                        (finite extensibility, r < R₀)
//        + 4ε[(σ/r)¹² − (σ/r)⁶] + ε   for r < 2^{1/6} σ     (WCA repulsion; ε = 0 disables it)
// Not constraint-defining: it runs through the shared bond loop (bond_loop.hpp) like any soft bond.
// A bond with r ≥ R₀ has no energy: this is a numerical failure (NumericalError naming the bond),
// where LAMMPS warns "FENE bond too long" and clamps the log argument — a silent change of the
// potential that we prefer to refuse. So is r = 0 (coincident particles, where the direction of
// the force is undefined).
#pragma once

#include <cmath>
#include <string>
#include <vector>

#include "engine/topology.hpp"
#include "forcefields/bond_loop.hpp"
#include "forcefields/force_term.hpp"

namespace stiffmd {

// Coefficients of one FENE bond type (LAMMPS bond_coeff order): K ≥ 0 (energy/length²),
// R0 > 0 (length), epsilon ≥ 0 (energy), sigma (length; > 0 when epsilon > 0).
struct FeneCoeffs {
  double K = 0.0;
  double R0 = 0.0;
  double epsilon = 0.0;
  double sigma = 0.0;
};

class FeneBond final : public ForceTerm {
 public:
  // Validating constructor: per type K ≥ 0, R0 > 0, epsilon ≥ 0, sigma > 0 where epsilon > 0,
  // all finite; per bond i, j ≥ 0, i ≠ j, 0 ≤ type < types.size(). Bond::type indexes `types`.
  FeneBond(std::string name, Level level, std::vector<Bond> bonds, std::vector<FeneCoeffs> types);

  double add_forces(const Eigen::Matrix3Xd& x, const Box& box, Eigen::Matrix3Xd& f) const override;
  double virial(const Eigen::Matrix3Xd& x, const Box& box) const override;
  std::string_view style() const override { return "fene"; }
  std::string describe() const override;

  // Per-bond constants, precomputed from FeneCoeffs so the kernel does no divisions by parameters.
  struct Params {
    double K;
    double R0;
    double inv_R0_sq;     // 1/R₀²
    double half_K_R0_sq;  // ½ K R₀²
    double epsilon;
    double sigma_sq;    // σ²
    double wca_cut_sq;  // (2^{1/6} σ)², 0 when ε = 0
  };
  struct Kernel {
    static void eval(double r, const Params& p, double& e, double& de_dr) {
      const double r_sq = r * r;
      const double stretch = r_sq * p.inv_R0_sq;  // (r/R₀)²
      if (!(r > 0.0 && stretch < 1.0)) out_of_range(r, p.R0);
      // log1p keeps ln(1 − (r/R₀)²) accurate for short bonds, where it is ≈ −(r/R₀)².
      e = -p.half_K_R0_sq * std::log1p(-stretch);
      de_dr = p.K * r / (1.0 - stretch);
      if (r_sq < p.wca_cut_sq) {
        const double s2 = p.sigma_sq / r_sq;
        const double s6 = s2 * s2 * s2;  // (σ/r)⁶
        e += 4.0 * p.epsilon * (s6 * s6 - s6) + p.epsilon;
        de_dr -= 24.0 * p.epsilon * (2.0 * s6 * s6 - s6) / r;
      }
    }
    // Thrown from the kernel, which does not know the bond; FeneBond rethrows naming it.
    [[noreturn]] static void out_of_range(double r, double R0);
  };

 private:
  // Finds the bond the kernel refused and throws NumericalError naming its particles and r.
  [[noreturn]] void throw_out_of_range(const Eigen::Matrix3Xd& x, const Box& box) const;

  std::vector<FeneCoeffs> types_;
  std::vector<BondInstance<Params>> instances_;
  mutable BondPartition partition_;  // thread plan of the bond loop
};

}  // namespace stiffmd
