// The builders' periodic geometry on portable vectors (core/portable_random.hpp): a position
// wrapped into the periodic cell, and the minimum image of a difference of wrapped positions.
// Shared by the builder that grows every molecule together (builders.cpp) and the one that grows
// each molecule from its own stream (chains_by_molecule.cpp), so both place beads alike.
#pragma once

#include <cmath>

#include "core/box.hpp"
#include "core/portable_random.hpp"

namespace stiffmd::portable {

// p wrapped into [origin, origin + L) on every periodic axis.
inline V3 wrap_into_cell(const Box& box, V3 p) {
  for (int a = 0; a < 3; ++a)
    if (box.periodic[a]) {
      const double L = box.lengths[a];
      double w = at(p, a) - box.origin[a];
      w -= L * std::floor(w / L);
      at(p, a) = w < L ? w : 0.0;  // a tiny negative w rounds to L
    }
  return p;
}

// The minimum image of the difference of two wrapped positions: one shift at most, by comparison
// (cheaper than rounding d/L in the builders' innermost loops).
inline V3 min_image_of_wrapped(const Box& box, V3 d) {
  for (int a = 0; a < 3; ++a)
    if (box.periodic[a]) {
      const double L = box.lengths[a];
      double& x = at(d, a);
      if (x > 0.5 * L)
        x -= L;
      else if (x < -0.5 * L)
        x += L;
    }
  return d;
}

}  // namespace stiffmd::portable
