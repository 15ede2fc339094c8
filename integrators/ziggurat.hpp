// Standard normals from counter-based 64-bit words by the ziggurat method (Marsaglia & Tsang,
// J. Stat. Softw. 5(8) (2000); in the form of Doornik, "An improved ziggurat method to generate
// normal random samples" (2005): a signed uniform and an independent layer index per draw).
//
// The density f(x) = exp(−x²/2) on x ≥ 0 is covered by 256 layers of equal area V: a base strip
// (the rectangle [0, R] × [0, f(R)] plus the tail beyond R) and 255 rectangles [0, x_i] ×
// [f(x_i), f(x_{i+1})]. A draw picks a layer i and a signed uniform u ∈ (−1, 1); x = u x_i is
// accepted at once when |u| < x_{i+1}/x_i (the part of the layer under the next one: 99.3 % of
// draws, one table lookup and one multiply, no logarithm or sine), else from the wedge by a
// second uniform against f, or from the tail (Marsaglia 1964) in the base strip. Exact in
// distribution up to the 52-bit resolution of u.
//
// Counter-based use (integrators/thermostat.hpp): the first word of a draw is a hash of the
// counters; the rare draws that need more uniforms take them from a chain of words hashed
// from it, so a normal is a function of its counters alone.
#pragma once

#include <cmath>
#include <cstdint>

namespace stiffmd {

struct ZigguratTable {
  static constexpr int kLayers = 256;
  static constexpr double kR = 3.6541528853610088;  // the edge of the base strip (Marsaglia & Tsang)
  double x[kLayers + 1];                            // x[0] = V/f(R) (the base strip's width), x[1] = R, …, x[256] = 0
  double ratio[kLayers];                            // x[i+1] / x[i]
  ZigguratTable();
};

const ZigguratTable& ziggurat_table();  // built once, on first use

// The layer of a draw from word w: its low 8 bits.
inline int ziggurat_layer(std::uint64_t w) {
  return static_cast<int>(w & 0xffu);
}
// The signed uniform of a draw from word w: its top 53 bits as (k + ½)/2⁵² − 1 on (−1, 1)
// (disjoint from the layer's bits).
inline double signed_uniform(std::uint64_t w) {
  return (static_cast<double>(w >> 11) + 0.5) * 0x1p-52 - 1.0;
}

namespace detail {
double ziggurat_slow(std::uint64_t w, int layer, double u, const ZigguratTable& t);  // wedges and tail
}  // namespace detail

// A standard normal from the word w.
inline double ziggurat_normal(std::uint64_t w, const ZigguratTable& t) {
  const int layer = ziggurat_layer(w);
  const double u = signed_uniform(w);
  if (std::abs(u) < t.ratio[layer]) return u * t.x[layer];
  return detail::ziggurat_slow(w, layer, u, t);
}

}  // namespace stiffmd
