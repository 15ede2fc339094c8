// The real-space Ewald table's construction (ewald_table.hpp): per interval, the degree-7
// interpolant of E and G at the 8 Chebyshev nodes, solved in long double.
#include "forcefields/ewald_table.hpp"

#include <Eigen/Dense>
#include <cmath>
#include <numbers>
#include <stdexcept>
#include <string>

namespace stiffmd {

namespace {

using Matrix = Eigen::Matrix<long double, EwaldRealSpaceTable::kCoefficients, EwaldRealSpaceTable::kCoefficients>;
using Vector = Eigen::Matrix<long double, EwaldRealSpaceTable::kCoefficients, 1>;

// E(s), G(s) at s in long double (erfcl, expl: glibc's long-double functions, ~1e-19).
void exact(long double g, long double s, long double& energy, long double& force) {
  const long double r = std::sqrt(s), x = g * r;
  const long double erfc = std::erfc(x);
  energy = erfc / r;
  force = (erfc + 2.0L / std::sqrt(std::numbers::pi_v<long double>) * x * std::exp(-x * x)) / r;
}

}  // namespace

EwaldRealSpaceTable::EwaldRealSpaceTable(double g, double rc) : g_(g) {
  if (!(g > 0.0) || !std::isfinite(g) || !(rc > 0.0) || !std::isfinite(rc))
    throw std::invalid_argument("the real-space Ewald table needs a finite g > 0 and a finite cutoff > 0 (got g = " +
                                std::to_string(g) + ", rc = " + std::to_string(rc) + ")");
  const int top = static_cast<int>(std::ceil(std::log2(rc * rc)));  // s_max = 2^top ≥ rc²
  s_max_ = std::ldexp(1.0, top + (std::ldexp(1.0, top) < rc * rc ? 1 : 0));
  s_min_ = std::ldexp(s_max_, -kOctaves);
  constexpr int kShift = 52 - kMantissaBits;
  key_min_ = std::bit_cast<std::uint64_t>(s_min_) >> kShift;
  const std::uint64_t key_max = std::bit_cast<std::uint64_t>(s_max_) >> kShift;
  interval_.resize(key_max - key_min_);
  // Nodes u_j = cos((2j + 1)π/16)/2 in [−1/2, 1/2] and the Vandermonde matrix in u, one for all.
  Vector u;
  Matrix vandermonde;
  for (int j = 0; j < kCoefficients; ++j) {
    u[j] = 0.5L * std::cos((2 * j + 1) * std::numbers::pi_v<long double> / (2 * kCoefficients));
    for (int k = 0; k < kCoefficients; ++k) vandermonde(j, k) = std::pow(u[j], k);
  }
  const Eigen::PartialPivLU<Matrix> lu(vandermonde);
  for (std::size_t i = 0; i < interval_.size(); ++i) {
    const double start = std::bit_cast<double>((key_min_ + i) << kShift);
    const double width = std::bit_cast<double>(((key_min_ + i + 1) << kShift)) - start;
    Vector ve, vf;
    for (int j = 0; j < kCoefficients; ++j)
      exact(g, static_cast<long double>(start) + static_cast<long double>(width) * (u[j] + 0.5L), ve[j], vf[j]);
    const Vector ce = lu.solve(ve), cf = lu.solve(vf);
    for (int k = 0; k < kCoefficients; ++k) {
      interval_[i].energy[k] = static_cast<double>(ce[k]);
      interval_[i].force[k] = static_cast<double>(cf[k]);
    }
  }
}

}  // namespace stiffmd
