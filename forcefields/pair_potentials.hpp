// Pair-potential kernels for the pair loop (pair_loop.hpp), after HOOMD's EvaluatorPair*: a
// kernel is a small value type, the loop over pairs is written once. Each kernel supplies
//   Coeffs                        the per-type-pair coefficients a user gives (with units);
//   Params                        constants derived from them for the inner loop; `rc2` is the
//                                 squared cutoff, read by the loop before calling eval;
//   kStyle                        the style name (as in a deck);
//   validate(c)                   throws std::invalid_argument naming the bad coefficient
//                                 (coefficients.hpp);
//   cutoff(c), params(c)          the interaction range and the derived constants;
//   define(record, c)             every coefficient of c, exactly (parameter_record.hpp), for
//                                 the scene fingerprint of checkpoints;
//   eval(r², p, e, fpair)         the energy e and fpair = −(dE/dr)/r, so that the force on i
//                                 is fpair · (x_i − x_j) and the pair virial r_ij · f_ij is
//                                 fpair · r². Valid for r² < rc²; the pair loop also calls it
//                                 for listed pairs a little beyond rc and masks the result
//                                 (no branch), so it must stay finite for every r² > 0.
// Working in r² spares the square root for the Lennard-Jones family.
#pragma once

#include <cmath>
#include <numbers>
#include <sstream>
#include <stdexcept>
#include <string>
#include <string_view>

#include "forcefields/coefficients.hpp"
#include "forcefields/parameter_record.hpp"

namespace stiffmd {

// Lennard-Jones constants shared by `lj` and `wca`: with s6 = σ⁶/r⁶,
//   E = 4ε (s6² − s6) − E_shift,   −(dE/dr)/r = 24ε (2 s6² − s6) / r².
struct LennardJonesParams {
  double rc2 = 0.0;
  double lj1 = 0.0;    // 48 ε σ¹²
  double lj2 = 0.0;    // 24 ε σ⁶
  double lj3 = 0.0;    // 4 ε σ¹²
  double lj4 = 0.0;    // 4 ε σ⁶
  double shift = 0.0;  // E_LJ(rc): subtracted so that E(rc) = 0 (cut and shifted)

  static LennardJonesParams make(double epsilon, double sigma, double rc) {
    LennardJonesParams p;
    const double s6 = std::pow(sigma, 6);
    p.rc2 = rc * rc;
    p.lj1 = 48.0 * epsilon * s6 * s6;
    p.lj2 = 24.0 * epsilon * s6;
    p.lj3 = 4.0 * epsilon * s6 * s6;
    p.lj4 = 4.0 * epsilon * s6;
    const double rc6inv = 1.0 / (p.rc2 * p.rc2 * p.rc2);
    p.shift = rc6inv * (p.lj3 * rc6inv - p.lj4);
    return p;
  }

  static void eval(double r2, const LennardJonesParams& p, double& e, double& fpair) {
    const double r2inv = 1.0 / r2;
    const double r6inv = r2inv * r2inv * r2inv;
    e = r6inv * (p.lj3 * r6inv - p.lj4) - p.shift;
    fpair = r6inv * (p.lj1 * r6inv - p.lj2) * r2inv;
  }
};

// LAMMPS pair_lj_cut's long-range tail (pair_modify tail yes; init_one) of one type pair, without the
// type counts N_a N_b:
//   etail_ab = 8π ε σ⁶ (σ⁶ − 3 rc⁶) / (9 rc⁹),   ptail_ab = 16π ε σ⁶ (2σ⁶ − 3 rc⁶) / (9 rc⁹);
// the energy is Σ_ab N_a N_b etail_ab / V, each diagonal component of the virial Σ N_a N_b ptail_ab / V
// (the sums over ordered type pairs). A kernel with `tail(c, e, p)` offers it (PairTerm::set_tail).
inline void lennard_jones_tail(double epsilon, double sigma, double rc, double& e, double& p) {
  const double sig2 = sigma * sigma, sig6 = sig2 * sig2 * sig2;
  const double rc3 = rc * rc * rc, rc6 = rc3 * rc3, rc9 = rc3 * rc6;
  const double prefactor = 8.0 * std::numbers::pi * epsilon * sig6 / (9.0 * rc9);
  e = prefactor * (sig6 - 3.0 * rc6);
  p = 2.0 * prefactor * (2.0 * sig6 - 3.0 * rc6);
}

// `lj`: E = 4ε[(σ/r)¹² − (σ/r)⁶] − E(rc) for r < rc, 0 beyond (LAMMPS lj/cut with
// pair_modify shift yes). The force is not shifted: it jumps by F(rc) at the cutoff.
struct LennardJones {
  struct Coeffs {
    double epsilon = 0.0;  // well depth, energy
    double sigma = 1.0;    // length
    double rc = 2.5;       // cutoff, length
  };
  using Params = LennardJonesParams;
  static constexpr std::string_view kStyle = "lj";

  static void validate(const Coeffs& c) {
    require(c.epsilon, kEnergy, "epsilon");
    require(c.sigma, kLength, "sigma");
    require(c.rc, kLength, "cutoff rc");
  }
  static double cutoff(const Coeffs& c) { return c.rc; }
  static Params params(const Coeffs& c) { return Params::make(c.epsilon, c.sigma, c.rc); }
  static void define(ParameterRecord& r, const Coeffs& c) {
    r.add("epsilon", c.epsilon);
    r.add("sigma", c.sigma);
    r.add("rc", c.rc);
  }
  static void tail(const Coeffs& c, double& e, double& p) { lennard_jones_tail(c.epsilon, c.sigma, c.rc, e, p); }
  static void eval(double r2, const Params& p, double& e, double& fpair) { Params::eval(r2, p, e, fpair); }
};

// `wca` (Weeks, Chandler & Andersen 1971): the Lennard-Jones potential cut at its minimum
// rc = 2^{1/6} σ and shifted up by ε, E = 4ε[(σ/r)¹² − (σ/r)⁶] + ε — purely repulsive, with E
// and F both continuous (zero) at rc. The excluded-volume part of the Kremer–Grest model.
struct WeeksChandlerAndersen {
  struct Coeffs {
    double epsilon = 1.0;  // energy
    double sigma = 1.0;    // length
  };
  using Params = LennardJonesParams;
  static constexpr std::string_view kStyle = "wca";
  static constexpr double kMinimumOverSigma = 1.122462048309373;  // 2^{1/6}

  static void validate(const Coeffs& c) {
    require(c.epsilon, kEnergy, "epsilon");
    require(c.sigma, kLength, "sigma");
  }
  static double cutoff(const Coeffs& c) { return kMinimumOverSigma * c.sigma; }
  static Params params(const Coeffs& c) { return Params::make(c.epsilon, c.sigma, cutoff(c)); }
  static void define(ParameterRecord& r, const Coeffs& c) {
    r.add("epsilon", c.epsilon);
    r.add("sigma", c.sigma);
  }
  static void eval(double r2, const Params& p, double& e, double& fpair) { Params::eval(r2, p, e, fpair); }
};

// `soft` (LAMMPS pair_style soft): E = A [1 + cos(π r / rc)] for r < rc. Finite at r = 0
// (E = 2A), so it pushes overlapping beads apart without the r⁻¹² blow-up; E and F are zero at rc.
struct SoftCosine {
  struct Coeffs {
    double A = 1.0;   // prefactor, energy
    double rc = 1.0;  // cutoff, length
  };
  struct Params {
    double rc2 = 0.0;
    double A = 0.0;
    double pi_over_rc = 0.0;
  };
  static constexpr std::string_view kStyle = "soft";

  static void validate(const Coeffs& c) {
    require(c.A, kEnergy, "prefactor A");
    require(c.rc, kLength, "cutoff rc");
  }
  static double cutoff(const Coeffs& c) { return c.rc; }
  static Params params(const Coeffs& c) { return {c.rc * c.rc, c.A, std::numbers::pi / c.rc}; }
  static void define(ParameterRecord& r, const Coeffs& c) {
    r.add("A", c.A);
    r.add("rc", c.rc);
  }

  static void eval(double r2, const Params& p, double& e, double& fpair) {
    const double r = std::sqrt(r2);
    const double arg = p.pi_over_rc * r;
    e = p.A * (1.0 + std::cos(arg));
    // −dE/dr = A (π/rc) sin(π r/rc); at r = 0 the direction is undefined and the force is 0
    // (LAMMPS does the same).
    fpair = r > 0.0 ? p.A * p.pi_over_rc * std::sin(arg) / r : 0.0;
  }
};

// `yukawa` (LAMMPS pair_style yukawa kappa cutoff with pair_modify shift yes): the screened
// Coulomb (Debye–Hückel) interaction E = A e^{−κr}/r − A e^{−κ r_c}/r_c for r < r_c, shifted so
// that E(r_c) = 0 like `lj`; the force is not shifted. A > 0 repels (like charges); κ = 0 is the
// cut and shifted Coulomb interaction.
struct Yukawa {
  struct Coeffs {
    double A = 1.0;      // prefactor, energy × length; any sign
    double kappa = 1.0;  // inverse screening length
    double rc = 2.5;     // cutoff, length
  };
  struct Params {
    double rc2 = 0.0;
    double A = 0.0;
    double kappa = 0.0;
    double shift = 0.0;  // A e^{−κ r_c}/r_c (LAMMPS's offset)
  };
  static constexpr std::string_view kStyle = "yukawa";

  static void validate(const Coeffs& c) {
    if (!std::isfinite(c.A)) throw std::invalid_argument("prefactor A must be finite");
    require(c.kappa, kInverseLength, "kappa");
    require(c.rc, kLength, "cutoff rc");
  }
  static double cutoff(const Coeffs& c) { return c.rc; }
  static Params params(const Coeffs& c) { return {c.rc * c.rc, c.A, c.kappa, c.A * std::exp(-c.kappa * c.rc) / c.rc}; }
  static void define(ParameterRecord& r, const Coeffs& c) {
    r.add("A", c.A);
    r.add("kappa", c.kappa);
    r.add("rc", c.rc);
  }

  static void eval(double r2, const Params& p, double& e, double& fpair) {
    const double r = std::sqrt(r2);
    const double r_inv = 1.0 / r;
    const double screened = p.A * std::exp(-p.kappa * r) * r_inv;  // A e^{−κr}/r
    e = screened - p.shift;
    fpair = screened * (p.kappa + r_inv) * r_inv;  // −(dE/dr)/r = A e^{−κr}(κ + 1/r)/r²
  }
};

}  // namespace stiffmd
