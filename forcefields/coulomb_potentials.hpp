// Charged pair kernels: the real-space Coulomb pair styles of LAMMPS, with its names and formulas
// (pair_style coul/cut, coul/debye, lj/cut/coul/cut, lj/cut/coul/debye, coul/long,
// lj/cut/coul/long, lj/charmm/coul/long). The shape is pair_potentials.hpp's, plus
//   kCharged = true               the loop hands eval the charges (pair_loop.hpp);
//   kLong = true                  (coul/long family) the Coulomb part is Ewald's real-space half: the
//                                 term needs the splitting g (EwaldRealSpace) and also evaluates the
//                                 pairs its special bonds exclude, within the cutoff;
//   eval(r², p, qq, factor_lj, factor_coul, evdwl, ecoul, fpair)
//                                 qq = qqrd2e q_i q_j; the factors are the pair's special-bond
//                                 weights (1, 1 for an ordinary pair); the van der Waals and
//                                 Coulomb energies apart, each already weighted, and fpair =
//                                 −(dE/dr)/r of their sum;
//   tail(c, e, p)                 (the lj/cut forms) LAMMPS's per-type-pair tail integrals etail_ij and
//                                 ptail_ij without the type counts (pair_modify tail yes).
// Each type pair's Params.rc2 is the larger of the two cutoffs squared (the list's range); eval
// applies the van der Waals and Coulomb cutoffs itself, by masks.
//
// Differences from LAMMPS: the coul/long family takes its ordinary pairs' E and −r dE/dr from a
// table in r² good to ~1e-14 relative (ewald_table.hpp; 1e-12 at g r_c = 4.8) and erfc exact to
// round-off elsewhere (e^{−x²} · erfcx(x), erfc_scaled.hpp: ≤ 1e-15 relative from std::erfc) where
// LAMMPS (pair_modify table 0) takes the Abramowitz–Stegun polynomial 7.1.26 (absolute error ≲
// 1.5e-7 in erfc), and 2/√π exactly where LAMMPS writes EWALD_F = 1.12837917; with tables
// (LAMMPS's default, table 12) LAMMPS interpolates erfc instead. So a coul/long ecoul agrees with
// LAMMPS's to about 1e-7 relative, not to round-off (tests/test_coulomb.cpp measures it).
#pragma once

#include <algorithm>
#include <cmath>
#include <limits>
#include <numbers>
#include <stdexcept>
#include <string>
#include <string_view>

#include "forcefields/coefficients.hpp"
#include "forcefields/erfc_scaled.hpp"
#include "forcefields/ewald_table.hpp"
#include "forcefields/pair_potentials.hpp"
#include "forcefields/parameter_record.hpp"

namespace stiffmd {

namespace coulomb_detail {

inline void require_cutoff(double rc, const char* what) {
  if (!(rc > 0.0) || !std::isfinite(rc))
    throw std::invalid_argument(std::string(what) + " must be finite and > 0 (got " + std::to_string(rc) + ")");
}

// The 12-6 Lennard-Jones part of the lj/cut/coul/* styles: LAMMPS lj1..lj4 and its offset (the
// energy at the LJ cutoff, subtracted only with pair_modify shift yes: `shift`).
struct LjPart {
  double lj_rc2 = 0.0;
  double lj1 = 0.0, lj2 = 0.0, lj3 = 0.0, lj4 = 0.0;
  double offset = 0.0;
  static LjPart make(double epsilon, double sigma, double rc, bool shift) {
    const LennardJonesParams l = LennardJonesParams::make(epsilon, sigma, rc);
    return {l.rc2, l.lj1, l.lj2, l.lj3, l.lj4, shift ? l.shift : 0.0};
  }
};

// The Coulomb forms: forcecoul = −r dE/dr and the energy, unweighted, at 1/r = rinv.
inline void coulomb_cut(double qq, double rinv, double& force, double& energy) {
  energy = qq * rinv;
  force = energy;
}
inline void coulomb_debye(double qq, double kappa, double r, double rinv, double& force, double& energy) {
  const double screening = std::exp(-kappa * r);
  energy = qq * rinv * screening;
  force = qq * screening * (kappa + rinv);
}
// The real-space Ewald term with the special-bond correction, as LAMMPS's coul/long:
//   E = qq/r [erfc(g r) − (1 − w)],   −r dE/dr = qq/r [erfc(g r) + (2/√π) g r e^{−g²r²} − (1 − w)],
// that is the pair's erfc part less the (1 − w) share of its full Coulomb energy, which the
// reciprocal sum counts and special bonds remove.
inline void coulomb_long(double qq, double g, double r, double w, double& force, double& energy) {
  const double grij = g * r;
  const double expm2 = exp_minus_square(grij);
  const double erfc = expm2 * erfc_scaled(grij);  // one exp for both (erfc_scaled.hpp)
  const double prefactor = qq / r;
  const double excluded = (1.0 - w) * prefactor;
  force = prefactor * (erfc + std::numbers::inv_sqrtpi * 2.0 * grij * expm2) - excluded;
  energy = prefactor * erfc - excluded;
}

// The same at r² = r2, from the table (ewald_table.hpp; null: none) where it covers r2 and the pair
// is an ordinary one (w = 1: no correction, which needs 1/r), else exactly. The pair loop's pairs
// have w = 1 as a constant, so that test folds away there.
inline void coulomb_long_at(double qq, double g, const EwaldRealSpaceTable* table, double r2, double w, double& force,
                            double& energy) {
  if (w == 1.0 && table && table->covers(r2)) {
    table->eval(r2, energy, force);
    energy *= qq;
    force *= qq;
    return;
  }
  coulomb_long(qq, g, std::sqrt(r2), w, force, energy);
}

inline double unset_splitting() {
  return std::numeric_limits<double>::quiet_NaN();
}

}  // namespace coulomb_detail

// `coul/cut` (LAMMPS pair_style coul/cut): E = qqrd2e q_i q_j / r for r < rc, not shifted.
struct CoulombCut {
  static constexpr bool kCharged = true;
  struct Coeffs {
    double coulomb_cutoff = 10.0;  // length
  };
  struct Params {
    double rc2 = 0.0;
  };
  static constexpr std::string_view kStyle = "coul/cut";
  static void validate(const Coeffs& c) { coulomb_detail::require_cutoff(c.coulomb_cutoff, "coulomb_cutoff"); }
  static double cutoff(const Coeffs& c) { return c.coulomb_cutoff; }
  static double coulomb_cutoff(const Coeffs& c) { return c.coulomb_cutoff; }
  static Params params(const Coeffs& c) { return {c.coulomb_cutoff * c.coulomb_cutoff}; }
  static void define(ParameterRecord& r, const Coeffs& c) { r.add("coulomb_cutoff", c.coulomb_cutoff); }
  static void eval(double r2, const Params&, double qq, double, double factor_coul, double& evdwl, double& ecoul,
                   double& fpair) {
    const double r2inv = 1.0 / r2;
    double force = 0.0, energy = 0.0;
    coulomb_detail::coulomb_cut(qq, std::sqrt(r2inv), force, energy);
    evdwl = 0.0;
    ecoul = factor_coul * energy;
    fpair = factor_coul * force * r2inv;
  }
};

// `coul/debye` (LAMMPS pair_style coul/debye κ rc): E = qqrd2e q_i q_j e^{−κr}/r for r < rc, not shifted.
struct CoulombDebye {
  static constexpr bool kCharged = true;
  struct Coeffs {
    double kappa = 1.0;            // inverse length
    double coulomb_cutoff = 10.0;  // length
  };
  struct Params {
    double rc2 = 0.0;
    double kappa = 0.0;
  };
  static constexpr std::string_view kStyle = "coul/debye";
  static void validate(const Coeffs& c) {
    require(c.kappa, kInverseLength, "kappa");
    coulomb_detail::require_cutoff(c.coulomb_cutoff, "coulomb_cutoff");
  }
  static double cutoff(const Coeffs& c) { return c.coulomb_cutoff; }
  static double coulomb_cutoff(const Coeffs& c) { return c.coulomb_cutoff; }
  static Params params(const Coeffs& c) { return {c.coulomb_cutoff * c.coulomb_cutoff, c.kappa}; }
  static void define(ParameterRecord& r, const Coeffs& c) {
    r.add("kappa", c.kappa);
    r.add("coulomb_cutoff", c.coulomb_cutoff);
  }
  static void eval(double r2, const Params& p, double qq, double, double factor_coul, double& evdwl, double& ecoul,
                   double& fpair) {
    const double r2inv = 1.0 / r2;
    const double r = std::sqrt(r2);
    double force = 0.0, energy = 0.0;
    coulomb_detail::coulomb_debye(qq, p.kappa, r, 1.0 / r, force, energy);
    evdwl = 0.0;
    ecoul = factor_coul * energy;
    fpair = factor_coul * force * r2inv;
  }
};

// `coul/long` (LAMMPS pair_style coul/long rc, pair_modify table 0): the real-space Ewald term
// E = qqrd2e q_i q_j erfc(g r)/r for r < rc, with the special-bond correction (coulomb_long). g is the
// k-space term's (EwaldRealSpace).
struct CoulombLong {
  static constexpr bool kCharged = true;
  static constexpr bool kLong = true;
  struct Coeffs {
    double coulomb_cutoff = 10.0;  // length
  };
  struct Params {
    double rc2 = 0.0;
    double g_ewald = coulomb_detail::unset_splitting();
    const EwaldRealSpaceTable* table = nullptr;  // E, G in r² (the term's, set with g)
  };
  static constexpr std::string_view kStyle = "coul/long";
  static void validate(const Coeffs& c) { coulomb_detail::require_cutoff(c.coulomb_cutoff, "coulomb_cutoff"); }
  static double cutoff(const Coeffs& c) { return c.coulomb_cutoff; }
  static double coulomb_cutoff(const Coeffs& c) { return c.coulomb_cutoff; }
  static Params params(const Coeffs& c) { return {c.coulomb_cutoff * c.coulomb_cutoff}; }
  static void define(ParameterRecord& r, const Coeffs& c) { r.add("coulomb_cutoff", c.coulomb_cutoff); }
  static void eval(double r2, const Params& p, double qq, double, double factor_coul, double& evdwl, double& ecoul,
                   double& fpair) {
    double force = 0.0;
    coulomb_detail::coulomb_long_at(qq, p.g_ewald, p.table, r2, factor_coul, force, ecoul);
    evdwl = 0.0;
    fpair = force / r2;
  }
};

// The lj/cut/coul/* styles: LAMMPS's 12-6 LJ E = 4ε[(σ/r)¹² − (σ/r)⁶] (− E(rc_lj) with shift) for
// r < rc_lj plus a Coulomb form for r < rc_coul, each weighted by its special factor.
struct LjCoulCoeffs {
  double epsilon = 0.0;         // energy
  double sigma = 1.0;           // length
  double rc = 2.5;              // the LJ cutoff, length
  double coulomb_cutoff = 2.5;  // length (a deck's default: the LJ cutoff)
  double kappa = 0.0;           // inverse length (lj/cut/coul/debye only)
  bool shift = false;           // LAMMPS pair_modify shift yes: the LJ part shifted to 0 at rc
};

template <int kForm>  // 0: cut, 1: debye, 2: long
struct LjCutCoul {
  static constexpr bool kCharged = true;
  static constexpr bool kLong = kForm == 2;
  using Coeffs = LjCoulCoeffs;
  struct Params {
    double rc2 = 0.0;
    coulomb_detail::LjPart lj;
    double coul_rc2 = 0.0;
    double kappa = 0.0;
    double g_ewald = coulomb_detail::unset_splitting();
    const EwaldRealSpaceTable* table = nullptr;  // E, G in r² (the term's, set with g)
  };
  static constexpr std::string_view kStyle = kForm == 0   ? "lj/cut/coul/cut"
                                             : kForm == 1 ? "lj/cut/coul/debye"
                                                          : "lj/cut/coul/long";
  static void validate(const Coeffs& c) {
    require(c.epsilon, kEnergy, "epsilon");
    require(c.sigma, kLength, "sigma");
    require(c.rc, kLength, "cutoff rc");
    coulomb_detail::require_cutoff(c.coulomb_cutoff, "coulomb_cutoff");
    if constexpr (kForm == 1) require(c.kappa, kInverseLength, "kappa");
  }
  static double cutoff(const Coeffs& c) { return std::max(c.rc, c.coulomb_cutoff); }
  static double coulomb_cutoff(const Coeffs& c) { return c.coulomb_cutoff; }
  static Params params(const Coeffs& c) {
    Params p;
    p.rc2 = cutoff(c) * cutoff(c);
    p.lj = coulomb_detail::LjPart::make(c.epsilon, c.sigma, c.rc, c.shift);
    p.coul_rc2 = c.coulomb_cutoff * c.coulomb_cutoff;
    p.kappa = c.kappa;
    return p;
  }
  static void define(ParameterRecord& r, const Coeffs& c) {
    r.add("epsilon", c.epsilon);
    r.add("sigma", c.sigma);
    r.add("rc", c.rc);
    r.add("coulomb_cutoff", c.coulomb_cutoff);
    if constexpr (kForm == 1) r.add("kappa", c.kappa);
    r.add("shift", c.shift ? 1 : 0);
  }
  static void tail(const Coeffs& c, double& e, double& p) { lennard_jones_tail(c.epsilon, c.sigma, c.rc, e, p); }

  static void eval(double r2, const Params& p, double qq, double factor_lj, double factor_coul, double& evdwl,
                   double& ecoul, double& fpair) {
    const double r2inv = 1.0 / r2;
    const double in_coul = r2 < p.coul_rc2 ? 1.0 : 0.0;
    const double in_lj = r2 < p.lj.lj_rc2 ? 1.0 : 0.0;
    double forcecoul = 0.0, energy = 0.0;
    if constexpr (kForm == 0) {
      coulomb_detail::coulomb_cut(qq, std::sqrt(r2inv), forcecoul, energy);
      forcecoul *= factor_coul;
      energy *= factor_coul;
    } else if constexpr (kForm == 1) {
      const double r = std::sqrt(r2);
      coulomb_detail::coulomb_debye(qq, p.kappa, r, 1.0 / r, forcecoul, energy);
      forcecoul *= factor_coul;
      energy *= factor_coul;
    } else {
      coulomb_detail::coulomb_long_at(qq, p.g_ewald, p.table, r2, factor_coul, forcecoul, energy);
    }
    const double r6inv = r2inv * r2inv * r2inv;
    const double forcelj = r6inv * (p.lj.lj1 * r6inv - p.lj.lj2);
    ecoul = in_coul * energy;
    evdwl = in_lj * factor_lj * (r6inv * (p.lj.lj3 * r6inv - p.lj.lj4) - p.lj.offset);
    fpair = (in_coul * forcecoul + in_lj * factor_lj * forcelj) * r2inv;
  }
};

using LjCutCoulCut = LjCutCoul<0>;
using LjCutCoulDebye = LjCutCoul<1>;
using LjCutCoulLong = LjCutCoul<2>;

// `lj/charmm/coul/long` (LAMMPS pair_style lj/charmm/coul/long inner outer [rc_coul]): the 12-6 LJ
// switched smoothly to zero between the inner and outer cutoffs by CHARMM's
//   S(r) = (rc² − r²)² (rc² + 2r² − 3ri²) / (rc² − ri²)³   (E and F continuous, zero at rc),
// plus the real-space Ewald Coulomb term (coul/long) for r < rc_coul (default: the outer cutoff).
// epsilon14 and sigma14 are the 1-4 coefficients of the charmm dihedral's 1-4 pairs (LAMMPS pair_coeff
// i j ε σ ε14 σ14; default ε, σ); the pair loop does not use them.
struct LjCharmmCoulLong {
  static constexpr bool kCharged = true;
  static constexpr bool kLong = true;
  struct Coeffs {
    double epsilon = 0.0;          // energy
    double sigma = 1.0;            // length
    double epsilon14 = 0.0;        // energy
    double sigma14 = 1.0;          // length
    double inner = 8.0;            // where the switching starts, length
    double rc = 10.0;              // the outer LJ cutoff, length
    double coulomb_cutoff = 10.0;  // length
  };
  struct Params {
    double rc2 = 0.0;
    double lj_rc2 = 0.0, inner2 = 0.0, inv_denom = 0.0;
    double lj1 = 0.0, lj2 = 0.0, lj3 = 0.0, lj4 = 0.0;
    double coul_rc2 = 0.0;
    double g_ewald = coulomb_detail::unset_splitting();
    const EwaldRealSpaceTable* table = nullptr;  // E, G in r² (the term's, set with g)
  };
  static constexpr std::string_view kStyle = "lj/charmm/coul/long";
  static void validate(const Coeffs& c) {
    require(c.epsilon, kEnergy, "epsilon");
    require(c.sigma, kLength, "sigma");
    require(c.epsilon14, kEnergy, "epsilon14");
    require(c.sigma14, kLength, "sigma14");
    require(c.inner, kLength, "inner cutoff");
    require(c.rc, kLength, "cutoff rc");
    if (!(c.inner < c.rc)) throw std::invalid_argument("the inner cutoff must be below the outer cutoff rc");
    coulomb_detail::require_cutoff(c.coulomb_cutoff, "coulomb_cutoff");
  }
  static double cutoff(const Coeffs& c) { return std::max(c.rc, c.coulomb_cutoff); }
  static double coulomb_cutoff(const Coeffs& c) { return c.coulomb_cutoff; }
  static Params params(const Coeffs& c) {
    Params p;
    p.rc2 = cutoff(c) * cutoff(c);
    p.lj_rc2 = c.rc * c.rc;
    p.inner2 = c.inner * c.inner;
    const double d = p.lj_rc2 - p.inner2;
    p.inv_denom = 1.0 / (d * d * d);
    const LennardJonesParams l = LennardJonesParams::make(c.epsilon, c.sigma, c.rc);
    p.lj1 = l.lj1, p.lj2 = l.lj2, p.lj3 = l.lj3, p.lj4 = l.lj4;
    p.coul_rc2 = c.coulomb_cutoff * c.coulomb_cutoff;
    return p;
  }
  static void define(ParameterRecord& r, const Coeffs& c) {
    r.add("epsilon", c.epsilon);
    r.add("sigma", c.sigma);
    r.add("epsilon14", c.epsilon14);
    r.add("sigma14", c.sigma14);
    r.add("inner", c.inner);
    r.add("rc", c.rc);
    r.add("coulomb_cutoff", c.coulomb_cutoff);
  }

  static void eval(double r2, const Params& p, double qq, double factor_lj, double factor_coul, double& evdwl,
                   double& ecoul, double& fpair) {
    const double r2inv = 1.0 / r2;
    const double in_coul = r2 < p.coul_rc2 ? 1.0 : 0.0;
    const double in_lj = r2 < p.lj_rc2 ? 1.0 : 0.0;
    double forcecoul = 0.0, energy = 0.0;
    coulomb_detail::coulomb_long_at(qq, p.g_ewald, p.table, r2, factor_coul, forcecoul, energy);
    const double r6inv = r2inv * r2inv * r2inv;
    double forcelj = r6inv * (p.lj1 * r6inv - p.lj2);
    double philj = r6inv * (p.lj3 * r6inv - p.lj4);
    // The switching region holds about half the pairs within the cutoff (the shell between 8 and
    // 10 Å of a sphere of 10), in no predictable order: the switched values are computed for every
    // pair and selected, not branched to (the same bits; no mispredicted branch).
    const double dc = p.lj_rc2 - r2;
    const double switch1 = dc * dc * (p.lj_rc2 + 2.0 * r2 - 3.0 * p.inner2) * p.inv_denom;
    const double switch2 = 12.0 * r2 * dc * (r2 - p.inner2) * p.inv_denom;
    const bool switched = r2 > p.inner2;
    forcelj = switched ? forcelj * switch1 + philj * switch2 : forcelj;
    philj = switched ? philj * switch1 : philj;
    ecoul = in_coul * energy;
    evdwl = in_lj * factor_lj * philj;
    fpair = (in_coul * forcecoul + in_lj * factor_lj * forcelj) * r2inv;
  }
};

}  // namespace stiffmd
