// A sum whose value does not depend on the order of its terms: each non-negative term is
// rounded once to a multiple of 2⁻⁶⁴ and the multiples are added as integers (exactly, so in
// any order, over threads and over processes alike). For a global quantity that feeds back into
// the dynamics (csvr's kinetic energy): a run on N processes then takes the same value as on one,
// bit for bit (docs/parallel.md).
#pragma once

#include <cmath>
#include <cstdint>

namespace stiffmd {

struct ExactSum {
  // t = whole + high·2⁻³² + low·2⁻⁶⁴, each word an integer: up to 2³¹ terms, a total < 2⁶³.
  std::int64_t whole = 0, high = 0, low = 0;

  // Adds t ≥ 0 (finite, < 2⁶³), truncated to a multiple of 2⁻⁶⁴ (a relative 1e-19 of a term of
  // order 1), `times` times. In integer arithmetic and one conversion each way: a cast truncates,
  // which for t ≥ 0 is the floor, and t − ⌊t⌋ and its product with 2⁶⁴ are exact.
  void add(double t, std::int64_t times = 1) {
    const auto w = static_cast<std::int64_t>(t);
    const auto fraction = static_cast<std::uint64_t>((t - static_cast<double>(w)) * 18446744073709551616.0);
    whole += times * w;
    high += times * static_cast<std::int64_t>(fraction >> 32);
    low += times * static_cast<std::int64_t>(fraction & 0xffffffffULL);
  }
  void add(const ExactSum& o) { whole += o.whole, high += o.high, low += o.low; }
  double value() const {
    // Carries first, in integers: then one rounding, the same for every order of the terms.
    std::int64_t l = low, h = high, w = whole;
    h += l >> 32, l &= 0xffffffffLL;
    w += h >> 32, h &= 0xffffffffLL;
    const std::uint64_t fraction = (static_cast<std::uint64_t>(h) << 32) | static_cast<std::uint64_t>(l);
    return static_cast<double>(w) + std::ldexp(static_cast<double>(fraction), -64);
  }
};

// An exact sum of terms of either sign: the positive and the negative ones apart, each an
// ExactSum; value() = Σ⁺ − Σ⁻, each rounded once. A term that is not finite (or too large for
// the words, ≥ 2⁶²) is counted, not added, and makes value() NaN.
struct SignedExactSum {
  ExactSum positive, negative;
  std::int64_t nonfinite = 0;
  void add(double t, std::int64_t times = 1) {
    if (!(std::abs(t) < 4.6e18)) {
      nonfinite += times;
    } else if (t >= 0.0) {
      positive.add(t, times);
    } else {
      negative.add(-t, times);
    }
  }
  void add(const SignedExactSum& o) {
    positive.add(o.positive), negative.add(o.negative);
    nonfinite += o.nonfinite;
  }
  double value() const { return nonfinite > 0 ? std::nan("") : positive.value() - negative.value(); }
  static constexpr int kWords = 7;  // for a sum over processes: the integer words, added as integers
  void to_words(std::int64_t* w) const {
    const ExactSum* s[2] = {&positive, &negative};
    for (int k = 0; k < 2; ++k) w[3 * k] = s[k]->whole, w[3 * k + 1] = s[k]->high, w[3 * k + 2] = s[k]->low;
    w[6] = nonfinite;
  }
  void from_words(const std::int64_t* w) {
    ExactSum* s[2] = {&positive, &negative};
    for (int k = 0; k < 2; ++k) *s[k] = {w[3 * k], w[3 * k + 1], w[3 * k + 2]};
    nonfinite = w[6];
  }
};

// The diagonal of a virial tensor, Σ r_a f_a for a = x, y, z, summed exactly: the barostat's
// pressure is then the same bits for any order of its terms — any thread count, any number of
// processes (integrators/barostat.hpp).
struct ExactDiagonal {
  SignedExactSum axis[3];
  void add(const ExactDiagonal& o) {
    for (int a = 0; a < 3; ++a) axis[a].add(o.axis[a]);
  }
};

}  // namespace stiffmd
