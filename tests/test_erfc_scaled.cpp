// forcefields/erfc_scaled.hpp: erfcx(x) = e^{x²} erfc(x) as a piecewise polynomial, e^{−x²} with
// the rounding of x² accounted for, and their product erfc(x) as the coul/long kernel forms it —
// against a long-double reference and against glibc's std::erfc, on a dense grid and on every
// interval edge.
#include <gtest/gtest.h>

#include <bit>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <limits>
#include <vector>

#include "forcefields/erfc_scaled.hpp"

namespace stiffmd {
namespace {

constexpr double kXMax = erfc_scaled_detail::kTableEnd;
constexpr double kInf = std::numeric_limits<double>::infinity();

// x² = a + b in long double with a exact and b rounded only to long double's 64 bits relative to
// b (not to x²): e^{±x²} to ~1e-19 relative however large x² is. x = xh + xl by masking off the
// low 27 bits of the significand (not Veltkamp's split, which a contracted multiply-add breaks).
void square_long(double x, long double& a, long double& b) {
  const double xh = std::bit_cast<double>(std::bit_cast<std::uint64_t>(x) & ~((std::uint64_t{1} << 27) - 1));
  const double xl = x - xh;  // exact, ≤ 27 bits
  a = static_cast<long double>(xh) * xh;
  b = 2.0L * xh * xl + static_cast<long double>(xl) * xl;
}

// erfcx(x) in long double: erfcl(x) e^{x²} (x ≤ 106, where erfcl does not underflow).
long double erfcx_reference(double x) {
  long double a = 0, b = 0;
  square_long(x, a, b);
  return std::erfc(static_cast<long double>(x)) * std::exp(a) * std::exp(b);
}

long double exp_minus_square_reference(double x) {
  long double a = 0, b = 0;
  square_long(x, a, b);
  return std::exp(-a) * std::exp(-b);
}

double relative(double got, long double ref) {
  return static_cast<double>(std::fabs((static_cast<long double>(got) - ref) / ref));
}

// A uniform grid of [0, X_max] (2^20 steps), every interval edge i/4 ± 8 ulp, and the tiny values.
std::vector<double> table_points() {
  std::vector<double> xs;
  constexpr int n = 1 << 20;
  for (int k = 0; k <= n; ++k) xs.push_back(kXMax * k / n);
  for (int i = 0; i <= erfc_scaled_detail::kIntervals; ++i) {
    const double edge = static_cast<double>(i) / erfc_scaled_detail::kIntervalsPerUnit;
    double up = edge, down = edge;
    for (int s = 0; s < 8; ++s) {
      xs.push_back(up);
      up = std::nextafter(up, kInf);
      down = std::nextafter(down, -kInf);
      if (down >= 0.0) xs.push_back(down);
    }
  }
  for (double x : {5e-324, 1e-300, 1e-200, 1e-100, 1e-30, 1e-16, 1e-8, 1e-4}) xs.push_back(x);
  return xs;
}

TEST(ErfcScaled, MatchesLongDoubleReferenceOnTheTable) {
  double worst = 0.0, at = 0.0;
  for (double x : table_points()) {
    const double e = relative(erfc_scaled(x), erfcx_reference(x));
    if (e > worst) worst = e, at = x;
  }
  std::printf("erfc_scaled on [0, %g]: max relative error %.3g at x = %.17g\n", kXMax, worst, at);
  EXPECT_LE(worst, 4e-16);
}

TEST(ErfcScaled, MatchesLongDoubleReferenceOnTheTail) {
  double worst = 0.0, at = 0.0;
  for (int k = 0; k <= 100000; ++k) {  // X_max to 100, log-spaced
    const double x = kXMax * std::pow(100.0 / kXMax, k / 100000.0);
    const double e = relative(erfc_scaled(x), erfcx_reference(x));
    if (e > worst) worst = e, at = x;
  }
  std::printf("erfc_scaled on [%g, 100]: max relative error %.3g at x = %.17g\n", kXMax, worst, at);
  EXPECT_LE(worst, 4e-16);
  // Far out erfcx(x) → 1/(x√π); at ∞, 0.
  for (double x : {1e3, 1e8, 1e20, 1e150, 1e300}) {
    const long double asymptote = 1.0L / (x * std::sqrt(std::acos(-1.0L)));
    const long double v = 1.0L / (static_cast<long double>(x) * x);
    EXPECT_LE(relative(erfc_scaled(x), asymptote * (1.0L - v / 2 + 3 * v * v / 4)), 4e-16) << x;
  }
  EXPECT_EQ(erfc_scaled(kInf), 0.0);
}

TEST(ErfcScaled, OutsideTheDomain) {
  EXPECT_EQ(erfc_scaled(0.0), 1.0);
  EXPECT_TRUE(std::isnan(erfc_scaled(std::numeric_limits<double>::quiet_NaN())));
  // x < 0: 2 e^{x²} − erfcx(−x)
  for (double x = -0.001; x > -26.0; x *= 1.01) EXPECT_LE(relative(erfc_scaled(x), erfcx_reference(x)), 1e-15) << x;
  EXPECT_EQ(erfc_scaled(-27.0), kInf);
  EXPECT_EQ(erfc_scaled(-kInf), kInf);
}

TEST(ErfcScaled, ExpMinusSquareIsExactToRounding) {
  double worst = 0.0, plain = 0.0;
  for (double x : table_points()) {
    worst = std::max(worst, relative(exp_minus_square(x), exp_minus_square_reference(x)));
    plain = std::max(plain, relative(std::exp(-x * x), exp_minus_square_reference(x)));
  }
  std::printf("exp_minus_square on [0, %g]: max relative error %.3g (std::exp(-x*x): %.3g)\n", kXMax, worst, plain);
  EXPECT_LE(worst, 4e-16);
  EXPECT_EQ(exp_minus_square(0.0), 1.0);
  EXPECT_EQ(exp_minus_square(-3.0), exp_minus_square(3.0));
  EXPECT_EQ(exp_minus_square(40.0), 0.0);
  EXPECT_EQ(exp_minus_square(1e300), 0.0);
  EXPECT_EQ(exp_minus_square(kInf), 0.0);
  EXPECT_TRUE(std::isnan(exp_minus_square(std::numeric_limits<double>::quiet_NaN())));
}

// erfc as the coul/long kernel forms it, against std::erfc (glibc's, itself good to about an ulp).
TEST(ErfcScaled, ProductMatchesStdErfc) {
  double worst = 0.0, at = 0.0;
  for (double x : table_points()) {
    const double e = std::fabs(exp_minus_square(x) * erfc_scaled(x) / std::erfc(x) - 1.0);
    if (e > worst) worst = e, at = x;
  }
  std::printf(
      "exp_minus_square · erfc_scaled against std::erfc on [0, %g]: max relative difference %.3g at x = %.17g\n", kXMax,
      worst, at);
  EXPECT_LE(worst, 1e-15);
}

}  // namespace
}  // namespace stiffmd
