// ln(1 − s) in branch-free arithmetic, for loops the compiler vectorises: the FENE bond energy
// −½ K R₀² ln(1 − (r/R₀)²) (forcefields/bond_potentials.hpp) is evaluated for every bond at every
// step, and a call to the library's log1p in the loop keeps the loop scalar (≈ 20 ns a call).
//
// The algorithm is fdlibm's log1p (Sun Microsystems, e_log.c and s_log1p.c, as in glibc's and
// musl's), with its branches replaced by bit arithmetic:
//   u = fl(1 − s), and c = (1 − u) − s, so that u + c = 1 − s exactly (both subtractions are
//   exact by Sterbenz's lemma for −1 ≤ s < 1, u ∈ (0, 2], and c = 0 for s ≥ ½); ln(1 − s) = ln(u + c);
//   u = 2ᵏ z with z ∈ [√½, √2), read off the bits of u; f = z − 1 + c 2⁻ᵏ (z − 1 exact);
//   ln(1 + f) = 2 atanh(t), t = f/(2 + f), = f − (½f² − t(½f² + R(t²))), R fdlibm's minimax
//   polynomial of degree 14 (|error| < 2⁻⁵⁸·⁴⁵ on the range);
//   ln(1 − s) = k ln 2 + ln(1 + f), ln 2 split in hi + lo so that k ln2_hi is exact.
// Measured on 10⁶ arguments spread over [0, 1) (many near 0 and near 1): at most 0.79 ulp from
// the exact value, as glibc's log1p (tests/test_bond_loop.cpp, LogOneMinus).
//
// Domain: 0 ≤ s < 1, a FENE bond's (r/R₀)² (a double s < 1 gives 1 − s ≥ 2⁻⁵³, so k ≥ −53).
// Outside it the result is meaningless (no exception is raised): callers test the domain
// themselves. (For −1 ≤ s < 0 it is still within 1.4 ulp: there c 2⁻ᵏ added into f rounds.)
#pragma once

#include <bit>
#include <cstdint>

namespace stiffmd {

[[gnu::always_inline]] inline double log_one_minus(double s) {  // inlined: a call keeps a loop scalar
  const double u = 1.0 - s;
  const double c = (1.0 - u) - s;  // the rounding error of u: u + c = 1 − s
  // k and z: subtracting the bits of √½ makes the exponent field of the difference k (mod 2¹²)
  // for every u > 0, whatever its mantissa; z = u 2⁻ᵏ has u's mantissa and lies in [√½, √2).
  const std::uint64_t bits = std::bit_cast<std::uint64_t>(u);
  const std::uint64_t k_field = (bits - 0x3fe6a09e667f3bcdULL) & 0xfff0000000000000ULL;  // k · 2⁵²
  const double z = std::bit_cast<double>(bits - k_field);
  const double two_to_minus_k = std::bit_cast<double>(0x3ff0000000000000ULL - k_field);
  // k as a double without an integer conversion (none is vectorised before AVX-512): the 12-bit
  // two's-complement field, offset to 2048 + k, placed in the mantissa of 2⁵².
  const double k = std::bit_cast<double>(0x4330000000000000ULL | ((k_field >> 52) ^ 0x800ULL)) - 4503599627372544.0;
  const double f = (z - 1.0) + c * two_to_minus_k;
  const double t = f / (2.0 + f);
  const double t2 = t * t, t4 = t2 * t2;
  constexpr double kLg1 = 6.666666666666735130e-01, kLg2 = 3.999999999940941908e-01, kLg3 = 2.857142874366239149e-01,
                   kLg4 = 2.222219843214978396e-01, kLg5 = 1.818357216161805012e-01, kLg6 = 1.531383769920937332e-01,
                   kLg7 = 1.479819860511658591e-01;
  const double r = t2 * (kLg1 + t4 * (kLg3 + t4 * (kLg5 + t4 * kLg7))) + t4 * (kLg2 + t4 * (kLg4 + t4 * kLg6));
  const double half_f_sq = 0.5 * f * f;
  constexpr double kLn2Hi = 6.93147180369123816490e-01, kLn2Lo = 1.90821492927058770002e-10;
  return k * kLn2Hi - ((half_f_sq - (t * (half_f_sq + r) + k * kLn2Lo)) - f);
}

}  // namespace stiffmd
