// Bond-potential kernels for BondTerm (bond_term.hpp), as pair_potentials.hpp is for PairTerm:
// a kernel is a small value type, the loop over bonds (bond_loop.hpp) is written once. Each
// kernel supplies
//   Coeffs                  the per-bond-type coefficients a user gives (with units);
//   Params                  constants derived from them for the inner loop;
//   kStyle                  the style name (as in a deck);
//   validate(c)             throws std::invalid_argument naming the bad coefficient
//                           (coefficients.hpp);
//   params(c)               the derived constants;
//   eval(r, p, e, dE_dr)    the energy and its derivative at bond length r > 0. A kernel defined
//                           only on part of r > 0 (FENE) throws NumericalError outside it; the
//                           term then names the bond;
//   eval_sq(r², p, e, g)    optional: the energy and g = (1/r) dE/dr from r² alone, branch-free,
//                           with e NaN outside the domain (the bond loop then needs no square
//                           root, vectorises the kernel and tests the energy; FENE);
//   describe(s, c)          the coefficients, for `stiffmd check`;
//   define(record, c)       every coefficient, exactly (parameter_record.hpp), for the scene
//                           fingerprint of checkpoints.
#pragma once

#include <algorithm>
#include <cmath>
#include <limits>
#include <ostream>
#include <sstream>
#include <string_view>

#include "core/errors.hpp"
#include "core/log_one_minus.hpp"
#include "forcefields/coefficients.hpp"
#include "forcefields/parameter_record.hpp"

namespace stiffmd {

// `fene` (LAMMPS bond_style fene: same K, R0, epsilon, sigma, no factor differences):
//   E(r) = −½ K R₀² ln(1 − (r/R₀)²)                        (finite extensibility, r < R₀)
//        + 4ε[(σ/r)¹² − (σ/r)⁶] + ε   for r < 2^{1/6} σ     (WCA repulsion; ε = 0 disables it)
// A bond with r ≥ R₀ has no energy: a numerical failure (NumericalError naming the bond), where
// LAMMPS warns "FENE bond too long" and clamps the log argument — a silent change of the
// potential that we prefer to refuse. So is r = 0 (the force direction is undefined).
struct Fene {
  struct Coeffs {
    double K = 0.0;        // stiffness, energy/length²
    double R0 = 0.0;       // maximum extension, length
    double epsilon = 0.0;  // WCA core depth, energy (0: no core)
    double sigma = 1.0;    // WCA core diameter, length
  };
  // Precomputed so that the kernel does no divisions by parameters.
  struct Params {
    double K;
    double R0;
    double inv_R0_sq;     // 1/R₀²
    double half_K_R0_sq;  // ½ K R₀²
    double epsilon;
    double sigma_sq;  // σ²
  };
  static constexpr std::string_view kStyle = "fene";

  static void validate(const Coeffs& c) {
    require(c.K, kStiffness, "K");
    require(c.R0, kLength, "R0");
    require(c.epsilon, kEnergy, "epsilon");
    if (c.epsilon > 0.0) require(c.sigma, kLength, "sigma (with epsilon > 0)");
  }
  static Params params(const Coeffs& c) {
    return {c.K, c.R0, 1.0 / (c.R0 * c.R0), 0.5 * c.K * c.R0 * c.R0, c.epsilon, c.sigma * c.sigma};
  }
  // The kernel in r² (bond_loop.hpp: a kernel may offer eval_sq), with no square root and no
  // branch, so that the bond loop vectorises it: E and g = (1/r) dE/dr,
  //   g = K/(1 − (r/R₀)²) − 24ε[2(σ/r)¹² − (σ/r)⁶]/r²   (the core's part for r < 2^{1/6} σ).
  // Outside the domain, 0 < r² < R₀², e is NaN (and g meaningless). Always inlined: a call keeps
  // the loop scalar.
  [[gnu::always_inline]] static void eval_sq(double r_sq, const Params& p, double& e, double& g) {
    double u = 0.0;
    eval_sq_split(r_sq, p, e, u, g);
    // log_one_minus is ln(1 − (r/R₀)²) to an ulp also for short bonds, where it is ≈ −(r/R₀)².
    e += log_weight(p) * log_one_minus(r_sq * p.inv_R0_sq);
  }
  // The same with the logarithm apart: E = e_rest + log_weight(p) ln u, u = 1 − (r/R₀)² (rounded),
  // so that a loop over bonds of one type can add their logarithms as the logarithm of their
  // product, one ln for many bonds (bond_loop.hpp, block_forces).
  static double log_weight(const Params& p) { return -p.half_K_R0_sq; }
  [[gnu::always_inline]] static void eval_sq_split(double r_sq, const Params& p, double& e_rest, double& u, double& g) {
    const double stretch = r_sq * p.inv_R0_sq;  // (r/R₀)²
    u = 1.0 - stretch;
    // One division for both reciprocals: 1/(1 − (r/R₀)²) = r² q and 1/r² = u q.
    const double q = 1.0 / (r_sq * u);
    const double inv_r_sq = u * q;
    // The core: 4ε[(σ/r)¹² − (σ/r)⁶] + ε = ε (2(σ/r)⁶ − 1)², and r < 2^{1/6} σ is 2(σ/r)⁶ > 1; so the
    // core is ε m² with m = max(2(σ/r)⁶ − 1, 0), and its g = −24ε m (σ/r)⁶/r², continuous at the
    // cutoff — no branch, and no cancellation near it.
    const double s2 = p.sigma_sq * inv_r_sq;
    const double s6 = s2 * s2 * s2;  // (σ/r)⁶
    const double m = std::max(2.0 * s6 - 1.0, 0.0);
    g = p.K * (r_sq * q) - 24.0 * p.epsilon * m * s6 * inv_r_sq;
    // Outside the domain (r = 0, r ≥ R₀, NaN) the energy is NaN: the loop tests its sum.
    e_rest = p.epsilon * m * m + ((r_sq > 0.0) & (stretch < 1.0) ? 0.0 : std::numeric_limits<double>::quiet_NaN());
  }
  static void eval(double r, const Params& p, double& e, double& de_dr) {
    if (!(r > 0.0 && r * r * p.inv_R0_sq < 1.0)) out_of_range(r, p.R0);
    double g = 0.0;
    eval_sq(r * r, p, e, g);
    de_dr = g * r;
  }
  static void describe(std::ostream& s, const Coeffs& c) {
    s << "K = " << c.K << ", R0 = " << c.R0 << ", epsilon = " << c.epsilon << ", sigma = " << c.sigma;
  }
  static void define(ParameterRecord& r, const Coeffs& c) {
    r.add("K", c.K);
    r.add("R0", c.R0);
    r.add("epsilon", c.epsilon);
    r.add("sigma", c.sigma);
  }

  [[noreturn]] static void out_of_range(double r, double R0) {
    std::ostringstream m;
    m.precision(10);
    if (r > 0.0)
      m << "stretched to r = " << r << " >= R0 = " << R0 << " (FENE is defined only for r < R0)";
    else if (r == 0.0)
      m << "the particles coincide (r = 0, the force direction is undefined)";
    else
      m << "a non-finite length r = " << r;
    throw NumericalError(m.str());
  }
};

// `morse` (LAMMPS bond_style morse: same D0, alpha, r0): E(r) = D₀ [1 − e^{−α(r − r₀)}]².
// An anharmonic bond that dissociates: E → D₀ as r → ∞; near r₀ it is harmonic with the
// curvature E″(r₀) = 2 D₀ α² (LAMMPS bond_style harmonic K = D₀ α²).
struct Morse {
  struct Coeffs {
    double D0 = 0.0;     // well depth (dissociation energy), energy
    double alpha = 0.0;  // width, inverse length
    double r0 = 0.0;     // equilibrium length
  };
  using Params = Coeffs;
  static constexpr std::string_view kStyle = "morse";

  static void validate(const Coeffs& c) {
    require(c.D0, kEnergy, "D0");
    require(c.alpha, kInverseLength, "alpha");
    require(c.r0, kLength, "r0");
  }
  static Params params(const Coeffs& c) { return c; }
  static void eval(double r, const Params& p, double& e, double& de_dr) {
    // 1 − e^{−α(r−r₀)} by expm1: no cancellation near r₀, where E is O((r − r₀)²).
    const double one_minus = -std::expm1(-p.alpha * (r - p.r0));
    const double decay = 1.0 - one_minus;  // e^{−α(r−r₀)}
    e = p.D0 * one_minus * one_minus;
    de_dr = 2.0 * p.D0 * p.alpha * decay * one_minus;
  }
  static void describe(std::ostream& s, const Coeffs& c) {
    s << "D0 = " << c.D0 << ", alpha = " << c.alpha << ", r0 = " << c.r0;
  }
  static void define(ParameterRecord& r, const Coeffs& c) {
    r.add("D0", c.D0);
    r.add("alpha", c.alpha);
    r.add("r0", c.r0);
  }
};

// `harmonic-bond`: E(r) = ½ k (r − r₀)², the soft (non-constraint-defining) harmonic bond; as
// harmonic-angle, k is the curvature, so LAMMPS's bond_style harmonic K (E = K (r − r₀)²) is k/2.
struct HarmonicBond {
  struct Coeffs {
    double k = 0.0;   // stiffness, energy/length²
    double r0 = 0.0;  // rest length
  };
  using Params = Coeffs;
  static constexpr std::string_view kStyle = "harmonic-bond";

  static void validate(const Coeffs& c) {
    require(c.k, kStiffness, "k");
    require(c.r0, kLength, "r0");
  }
  static Params params(const Coeffs& c) { return c; }
  static void eval(double r, const Params& p, double& e, double& de_dr) {
    const double g = r - p.r0;
    e = 0.5 * p.k * g * g;
    de_dr = p.k * g;
  }
  static void describe(std::ostream& s, const Coeffs& c) { s << "k = " << c.k << ", r0 = " << c.r0; }
  static void define(ParameterRecord& r, const Coeffs& c) {
    r.add("k", c.k);
    r.add("r0", c.r0);
  }
};

}  // namespace stiffmd
