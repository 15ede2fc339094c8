// Platform-independent arithmetic and random numbers for the builders (builders.cpp) and
// Maxwell–Boltzmann velocities (maxwell_boltzmann, at the end): the same
// seed must give the same configuration and velocities, bit for bit, on every machine. Hence
// plain 3-vectors summed in a fixed order, log/exp/cbrt from + − × ÷ only, and our own
// distributions on top of std::mt19937_64 (whose sequence the standard fixes).
#pragma once

#include <Eigen/Core>
#include <cmath>
#include <cstdint>
#include <limits>
#include <random>
#include <stdexcept>
#include <string>

#include "core/format.hpp"

// No fused multiply-adds (see builders.cpp): GCC in ISO mode does not contract; clang does.
#if defined(__clang__)
#pragma clang fp contract(off)
#endif

namespace stiffmd::portable {

// ---------------------------------------------------------------------------------------------
// Plain 3-vectors with scalar arithmetic in a fixed order: Eigen may vectorise a dot product
// differently on different instruction sets, and the builders' accept/reject decisions must not
// depend on that.
struct V3 {
  double x = 0.0, y = 0.0, z = 0.0;
};
inline V3 operator+(const V3& a, const V3& b) {
  return {a.x + b.x, a.y + b.y, a.z + b.z};
}
inline V3 operator-(const V3& a, const V3& b) {
  return {a.x - b.x, a.y - b.y, a.z - b.z};
}
inline V3 operator*(double s, const V3& a) {
  return {s * a.x, s * a.y, s * a.z};
}
inline double dot(const V3& a, const V3& b) {
  return a.x * b.x + a.y * b.y + a.z * b.z;
}
inline V3 cross(const V3& a, const V3& b) {
  return {a.y * b.z - a.z * b.y, a.z * b.x - a.x * b.z, a.x * b.y - a.y * b.x};
}
inline double& at(V3& v, int a) {
  return a == 0 ? v.x : (a == 1 ? v.y : v.z);
}
inline double at(const V3& v, int a) {
  return a == 0 ? v.x : (a == 1 ? v.y : v.z);
}

// Two unit vectors e1, e2 completing the unit vector n to an orthonormal basis.
inline void perpendicular_basis(const V3& n, V3& e1, V3& e2) {
  // Cross with the coordinate axis least aligned with n, so that the cross product is never small.
  const double ax = std::fabs(n.x), ay = std::fabs(n.y), az = std::fabs(n.z);
  const V3 axis = (ax <= ay && ax <= az) ? V3{1, 0, 0} : (ay <= az ? V3{0, 1, 0} : V3{0, 0, 1});
  e1 = cross(n, axis);
  e1 = (1.0 / std::sqrt(dot(e1, e1))) * e1;
  e2 = cross(n, e1);
}

// ---------------------------------------------------------------------------------------------
// log, exp and cbrt from + − × ÷ (and the exact frexp/ldexp/nearbyint) only: libm's versions
// may differ in the last bit between platforms, and the same seed must give the same numbers
// everywhere. Accuracy is a few ulp, plenty for sampling.
constexpr double kLn2Hi = 6.93147180369123816490e-01;  // fdlibm's split of ln 2: k·kLn2Hi is exact
constexpr double kLn2Lo = 1.90821492927058770002e-10;  // for |k| < 2^11

inline double portable_log(double x) {  // x > 0, finite
  int e = 0;
  double m = std::frexp(x, &e);  // x = m·2^e, m ∈ [½, 1)
  if (m < 0.70710678118654752440) {
    m *= 2.0;
    --e;
  }  // m ∈ [√½, √2): |s| ≤ 0.1716 below
  // ln m = 2 atanh s = 2 (s + s³/3 + s⁵/5 + …), s = (m − 1)/(m + 1); 13 terms reach s²⁵ < 1e-19.
  const double s = (m - 1.0) / (m + 1.0), s2 = s * s;
  double term = s, sum = s;
  for (int k = 1; k <= 12; ++k) {
    term *= s2;
    sum += term / (2 * k + 1);
  }
  return e * kLn2Hi + (e * kLn2Lo + 2.0 * sum);
}

inline double portable_exp(double x) {  // x finite
  if (x < -745.0) return 0.0;
  if (x > 709.0) return std::numeric_limits<double>::infinity();
  // e^x = 2^k e^r with |r| ≤ ½ ln 2; Taylor to r¹³ (error < 1e-17) by Horner.
  const double k = std::nearbyint(x * 1.44269504088896338700);
  const double r = (x - k * kLn2Hi) - k * kLn2Lo;
  double p = 1.0;
  for (int n = 13; n >= 1; --n) p = 1.0 + p * r / n;
  return std::ldexp(p, static_cast<int>(k));
}

inline double portable_cbrt(double v) {  // v > 0, finite
  int e = 0;
  double m = std::frexp(v, &e);
  const int r = ((e % 3) + 3) % 3;  // make the exponent a multiple of 3: m ∈ [½, 4)
  m = std::ldexp(m, r);
  e -= r;
  double y = 1.0;  // Newton from 1 converges monotonically after one step; 12 steps is ample
  for (int i = 0; i < 12; ++i) y -= (y * y * y - m) / (3.0 * y * y);
  return std::ldexp(y, e / 3);
}

// Sums with Neumaier's compensation: the total momentum must vanish to ~1e-15 of its terms.
struct CompensatedSum {
  double sum = 0.0, c = 0.0;
  void add(double v) {
    const double t = sum + v;
    c += std::fabs(sum) >= std::fabs(v) ? (sum - t) + v : (v - t) + sum;
    sum = t;
  }
  double value() const { return sum + c; }
};

// ---------------------------------------------------------------------------------------------
// Random numbers with a platform-independent output: std::mt19937_64's sequence is fixed by the
// standard; everything on top of it is ours.
class Rng {
 public:
  explicit Rng(std::uint64_t seed) : g_(seed) {}

  // Uniform in [0, 1) on the 2⁻⁵³ grid: the top 53 bits, converted exactly.
  double uniform() { return static_cast<double>(g_() >> 11) * 0x1.0p-53; }
  // Uniform in [−1, 1), still exact (2u − 1 on the 2⁻⁵² grid).
  double symmetric() { return 2.0 * uniform() - 1.0; }

  // Standard normal by Marsaglia's polar method (only log and sqrt; sqrt is exactly rounded
  // by IEEE 754); the second normal of each pair is kept for the next call.
  double normal() {
    if (has_spare_) {
      has_spare_ = false;
      return spare_;
    }
    for (;;) {
      const double u = symmetric(), v = symmetric(), s = u * u + v * v;
      if (s >= 1.0 || s == 0.0) continue;
      const double f = std::sqrt(-2.0 * portable_log(s) / s);
      spare_ = v * f;
      has_spare_ = true;
      return u * f;
    }
  }

  // Uniform on the unit sphere (Marsaglia 1972): no trigonometry.
  V3 unit_vector() {
    for (;;) {
      const double a = symmetric(), b = symmetric(), s = a * a + b * b;
      if (s >= 1.0) continue;
      const double q = 2.0 * std::sqrt(1.0 - s);
      return {a * q, b * q, 1.0 - 2.0 * s};
    }
  }

  // Uniform on the unit circle, by rejection from the square.
  void unit_circle(double& c, double& s) {
    for (;;) {
      const double a = symmetric(), b = symmetric(), r2 = a * a + b * b;
      if (r2 > 1.0 || r2 < 1e-12) continue;  // tiny r2: avoid amplifying the grid of a, b
      const double inv = 1.0 / std::sqrt(r2);
      c = a * inv;
      s = b * inv;
      return;
    }
  }

 private:
  std::mt19937_64 g_;
  bool has_spare_ = false;
  double spare_ = 0.0;
};

}  // namespace stiffmd::portable

namespace stiffmd {

// Velocities at temperature T (k_B = 1) for the given inverse masses, one column per particle:
// v ~ N(0, T/m) per component for mobile particles (inv_mass > 0), exactly 0 for fixed ones
// (inv_mass = 0); then the centre-of-mass velocity of the mobile particles is subtracted, and
// all velocities are scaled so that the kinetic temperature
//     T_kin = Σ m v² / (3·N_mobile − 3)
// equals T exactly: 3 degrees of freedom are taken away for the removed total momentum
// (whether or not fixed particles are present). With N_mobile ≤ 1 (no degree of freedom left)
// or T = 0 every velocity is zero. T < 0 or non-finite, or an inverse mass that is negative or
// non-finite: std::invalid_argument.
// Used by [velocities] (builders' scenes) and [prepare]'s bond vibrations (integrators/prepare.cpp).
inline Eigen::Matrix3Xd maxwell_boltzmann(const Eigen::VectorXd& inv_mass, double temperature, std::uint64_t seed) {
  if (!(temperature >= 0.0) || !std::isfinite(temperature))
    throw std::invalid_argument("maxwell_boltzmann: temperature = " + format_number(temperature) +
                                ": expected a finite T >= 0");
  const Eigen::Index n = inv_mass.size();
  int mobile = 0;
  for (Eigen::Index i = 0; i < n; ++i) {
    if (!(inv_mass[i] >= 0.0) || !std::isfinite(inv_mass[i]))
      throw std::invalid_argument("maxwell_boltzmann: inverse mass of particle " + std::to_string(i) + " = " +
                                  format_number(inv_mass[i]) + ": expected a finite value >= 0 (0 = fixed)");
    if (inv_mass[i] > 0.0) ++mobile;
  }
  Eigen::Matrix3Xd v = Eigen::Matrix3Xd::Zero(3, n);
  const int dof = 3 * mobile - 3;
  if (dof <= 0 || temperature == 0.0) return v;  // nothing can move once the momentum is removed

  portable::Rng rng(seed);
  for (Eigen::Index i = 0; i < n; ++i) {
    if (inv_mass[i] == 0.0) continue;  // fixed particles draw no numbers: at rest
    const double s = std::sqrt(temperature * inv_mass[i]);
    for (int a = 0; a < 3; ++a) v(a, i) = s * rng.normal();
  }
  // Remove the centre-of-mass velocity of the mobile particles; a second pass removes what
  // rounding left from the first, so that Σ m v vanishes to ~1e-16 of Σ m|v|.
  for (int pass = 0; pass < 2; ++pass) {
    portable::CompensatedSum mass, p[3];
    for (Eigen::Index i = 0; i < n; ++i) {
      if (inv_mass[i] == 0.0) continue;
      const double m = 1.0 / inv_mass[i];
      mass.add(m);
      for (int a = 0; a < 3; ++a) p[a].add(m * v(a, i));
    }
    const double vcm[3] = {p[0].value() / mass.value(), p[1].value() / mass.value(), p[2].value() / mass.value()};
    for (Eigen::Index i = 0; i < n; ++i)
      if (inv_mass[i] > 0.0)
        for (int a = 0; a < 3; ++a) v(a, i) -= vcm[a];
  }
  // Rescale to the exact kinetic temperature: Σ m v² = dof·T (a common factor keeps Σ m v = 0).
  portable::CompensatedSum twice_kinetic;
  for (Eigen::Index i = 0; i < n; ++i)
    if (inv_mass[i] > 0.0)
      for (int a = 0; a < 3; ++a) twice_kinetic.add(v(a, i) * v(a, i) / inv_mass[i]);
  if (twice_kinetic.value() > 0.0) v *= std::sqrt(dof * temperature / twice_kinetic.value());
  return v;
}

}  // namespace stiffmd
