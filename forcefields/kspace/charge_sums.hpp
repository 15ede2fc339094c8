// What the k-space terms' parameters and the scene's charge checks read of the particles: their
// number, the number that carry a charge, Σq, Σq² and the largest |q|, each summed in particle
// order, one particle at a time, in double — so a scene whose particles are only counted (a
// description: so many beads of a type's charge) gives the same numbers to the last bit as the
// same particles listed one by one. choose_ewald and choose_pppm (ewald_parameters.hpp) take
// N = particles and q2 = qqrd2e · sum_q2 (the error estimates of docs/electrostatics.md).
#pragma once

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <span>

namespace stiffmd {

struct ChargeSums {
  std::int64_t particles = 0;  // every particle, charged or not
  std::int64_t charged = 0;    // those with q ≠ 0
  double sum_q = 0.0;          // Σq, the net charge
  double sum_q2 = 0.0;         // Σq²
  double max_abs = 0.0;        // max |q| (0 for none)
  bool finite = true;          // every charge finite

  // One particle of charge q, after those added before it.
  void add(double q) {
    ++particles;
    charged += q != 0.0;
    sum_q += q;
    sum_q2 += rounded_square(q);
    max_abs = std::max(max_abs, std::abs(q));
    finite = finite && std::isfinite(q);
  }

  // `count` particles of charge q in a row: the sums of count calls of add(q), to the bit. A
  // floating-point sum of equal terms is not count · q (each partial sum rounds), so the terms
  // are added in turn, O(count) time and no memory; a zero charge leaves the sums as they are
  // (s + 0 = s exactly, and the sums start at +0).
  void add(double q, std::int64_t count) {
    if (count <= 0) return;
    particles += count;
    max_abs = std::max(max_abs, std::abs(q));
    finite = finite && std::isfinite(q);
    if (q == 0.0) return;
    charged += count;
    const double q2 = rounded_square(q);
    double s = sum_q, s2 = sum_q2;
    for (std::int64_t k = 0; k < count; ++k) s += q, s2 += q2;
    sum_q = s, sum_q2 = s2;
  }

  void add(std::span<const double> charges) {
    for (const double q : charges) add(q);
  }

  // q² rounded to a double before it is added: a compiler allowed to contract a multiply and an
  // add into one fused operation (-ffp-contract=fast with FMA, -march=native) could fuse it in
  // one of the two paths above and not in the other; the square passes through memory, so
  // neither can.
  static double rounded_square(double q) {
    volatile double q2 = q * q;
    return q2;
  }
};

inline ChargeSums charge_sums_of(std::span<const double> charges) {
  ChargeSums c;
  c.add(charges);
  return c;
}

}  // namespace stiffmd
