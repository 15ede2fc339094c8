// The real-space Ewald pair functions as a table in s = r², for the coul/long pair loop
// (coulomb_potentials.hpp's coulomb_long), docs/electrostatics.md "The real-space table":
//
//   E(s) = erfc(g√s)/√s                                  (the pair's energy per qq)
//   G(s) = [erfc(g√s) + (2/√π) g√s e^{−g²s}]/√s          (−r dE/dr per qq: fpair = qq G(s)/s)
//
// Both are smooth in s > 0, so each is a piecewise polynomial: the intervals are those of the
// top kMantissaBits bits of s's double mantissa — 2^5 = 32 per octave of s, each of relative
// width ≤ 1/32 — over kOctaves octaves ending at the first power of two ≥ rc²; on each, the
// degree-7 polynomial interpolating the function at 8 Chebyshev nodes (values and the solve in
// long double), in monomial form in u = t − 1/2, t ∈ [0, 1) the position in the interval. An
// evaluation is a bit shift for the interval, an exact t (s minus the interval's start, which
// shares s's leading bits, times a power of two) and two polynomials of degree 7 (Estrin's scheme): no sqrt, exp,
// erfc or division, where the exact form (erfc_scaled.hpp) takes all four.
//
// Accuracy: relative error of E and G ≤ 1e-13 for g r_c ≤ 3.5 (LAMMPS's accuracies 1e-4 … 1e-5 at
// the usual cutoffs), ≤ 1e-11 for g r_c ≤ 5 (1e-8), measured against the exact form by
// tests/test_coulomb.cpp (EwaldTable.*); LAMMPS's default table (pair_modify table 12, linear in
// r²) errs by ~1e-6. Below the table (s < s_min = 2^(top − kOctaves), r < r_c/90) and for a
// non-finite s the caller takes the exact form.
#pragma once

#include <bit>
#include <cstdint>
#include <vector>

namespace stiffmd {

class EwaldRealSpaceTable {
 public:
  static constexpr int kMantissaBits = 5;
  static constexpr int kOctaves = 13;
  static constexpr int kCoefficients = 8;  // degree 7

  // g > 0 (inverse length), rc > 0 (the Coulomb cutoff, length), both finite; throws
  // std::invalid_argument otherwise.
  EwaldRealSpaceTable(double g, double rc);

  double g() const { return g_; }
  double s_min() const { return s_min_; }
  double s_max() const { return s_max_; }
  bool covers(double s) const { return s >= s_min_ && s < s_max_; }

  // E(s) and G(s) for covers(s).
  void eval(double s, double& energy, double& force) const {
    const std::uint64_t bits = std::bit_cast<std::uint64_t>(s);
    constexpr int kShift = 52 - kMantissaBits;
    const Interval& in = interval_[(bits >> kShift) - key_min_];
    // t = (s − s_k)/w_k: s_k is s with the bits below the interval's cleared (exact difference), w_k
    // = 2^(e − 1023 − kMantissaBits), so 1/w_k is the double of exponent 2·1023 + kMantissaBits − e.
    const double start = std::bit_cast<double>(bits & ~((std::uint64_t{1} << kShift) - 1));
    const std::uint64_t e = bits >> 52;
    const double inv_width = std::bit_cast<double>((2 * 1023 + kMantissaBits - e) << 52);
    const double u = (s - start) * inv_width - 0.5;
    energy = estrin(in.energy, u);
    force = estrin(in.force, u);
  }

 private:
  // c₀ + c₁u + … + c₇u⁷ by Estrin's scheme: four independent pairs, then two levels (a chain of
  // three multiplications where Horner's has seven).
  static double estrin(const double* c, double u) {
    static_assert(kCoefficients == 8);
    const double u2 = u * u, u4 = u2 * u2;
    const double a = c[0] + c[1] * u, b = c[2] + c[3] * u, d = c[4] + c[5] * u, e = c[6] + c[7] * u;
    return (a + u2 * b) + u4 * (d + u2 * e);
  }
  struct alignas(64) Interval {
    double energy[kCoefficients];
    double force[kCoefficients];
  };
  double g_ = 0.0;
  double s_min_ = 0.0, s_max_ = 0.0;
  std::uint64_t key_min_ = 0;  // s_min's bits >> (52 − kMantissaBits)
  std::vector<Interval> interval_;
};

}  // namespace stiffmd
