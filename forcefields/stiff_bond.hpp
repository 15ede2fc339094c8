// A stiff, constraint-defining bond b = (i, j) (design.md §1):
//   V_b = ½ α_b² g_b(x)²,   g_b(x) = |x_i − x_j| − ℓ_b,   energy ε⁻² V_b.
// The set of these bonds defines the constraint manifold g(x) = 0 used by the
// constraint toolbox (integrators/constraints.hpp).
#pragma once

#include <vector>

namespace stiffmd {

struct StiffBond {
  int i = 0;  // particle indices
  int j = 0;
  double length = 1.0;  // ℓ_b, rest length
  double alpha = 1.0;   // α_b, stiffness in units of 1/ε
};

// All constraint-defining bonds of a scene and their common ε.
struct StiffBonds {
  std::vector<StiffBond> bonds;
  double epsilon = 1.0;
};

}  // namespace stiffmd
