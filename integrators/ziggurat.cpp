#include "integrators/ziggurat.hpp"

#include "integrators/thermostat.hpp"  // mix64, kGolden

namespace stiffmd {

namespace {
double density(double x) {
  return std::exp(-0.5 * x * x);
}
// The next word of a draw's chain: splitmix64's step from w.
std::uint64_t next_word(std::uint64_t w) {
  return mix64(w + kGolden);
}
// The top 53 bits of w as a uniform on (0, 1): (k + ½)/2⁵³.
double unit_uniform(std::uint64_t w) {
  return (static_cast<double>(w >> 11) + 0.5) * 0x1p-53;
}
}  // namespace

// Doornik (2005), zigNorInit: x_1 = R, then each layer's top edge from its area V,
// x_{i+1} = f⁻¹(V/x_i + f(x_i)); V = R f(R) + ∫_R^∞ f, the base strip's area (4.928673234e-3).
ZigguratTable::ZigguratTable() {
  const double v = kR * density(kR) + std::sqrt(2.0 * std::atan(1.0)) * std::erfc(kR / std::sqrt(2.0));
  double f = density(kR);
  x[0] = v / f;
  x[1] = kR;
  x[kLayers] = 0.0;
  for (int i = 2; i < kLayers; ++i) {
    x[i] = std::sqrt(-2.0 * std::log(v / x[i - 1] + f));
    f = density(x[i]);
  }
  for (int i = 0; i < kLayers; ++i) ratio[i] = x[i + 1] / x[i];
}

const ZigguratTable& ziggurat_table() {
  static const ZigguratTable table;
  return table;
}

namespace detail {

// Outside the rectangle under the next layer: in the base strip, a draw from the tail x > R
// (Marsaglia 1964: x = −log(u₁)/R, accepted when −2 log u₂ ≥ x²); in a wedge, x = u x_i accepted
// when a uniform height between f(x_{i+1}) and f(x_i) falls under f(x); else a new draw. Every
// further uniform comes from the chain of words after w.
double ziggurat_slow(std::uint64_t w, int layer, double u, const ZigguratTable& t) {
  for (;;) {
    if (layer == 0) {
      double a, b;
      do {
        w = next_word(w);
        a = std::log(unit_uniform(w)) / ZigguratTable::kR;
        w = next_word(w);
        b = std::log(unit_uniform(w));
      } while (-2.0 * b < a * a);
      return u < 0.0 ? a - ZigguratTable::kR : ZigguratTable::kR - a;
    }
    const double x = u * t.x[layer];
    const double f0 = std::exp(-0.5 * (t.x[layer] * t.x[layer] - x * x));
    const double f1 = std::exp(-0.5 * (t.x[layer + 1] * t.x[layer + 1] - x * x));
    w = next_word(w);
    if (f1 + unit_uniform(w) * (f0 - f1) < 1.0) return x;
    w = next_word(w);  // a new draw
    layer = ziggurat_layer(w);
    u = signed_uniform(w);
    if (std::abs(u) < t.ratio[layer]) return u * t.x[layer];
  }
}

}  // namespace detail
}  // namespace stiffmd
