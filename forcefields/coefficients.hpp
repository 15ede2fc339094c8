// The kinds of coefficient a force kernel takes and the range each allows, written once: the
// kernels' validate() (bond_potentials.hpp, pair_potentials.hpp) and the deck readers
// (engine/scene/force_registry.cpp) check through them, so a constructor argument and a deck key are
// refused by the same rule, in the same words.
#pragma once

#include <cmath>
#include <sstream>
#include <stdexcept>
#include <string>
#include <string_view>

namespace stiffmd {

struct Quantity {
  std::string_view noun;  // "a length"
  bool zero_allowed;      // ≥ 0 (0 switches the interaction off) rather than > 0
  bool any_sign = false;  // any finite value (torsion amplitudes: negative is a different minimum)

  bool admits(double v) const { return std::isfinite(v) && (any_sign || (zero_allowed ? v >= 0.0 : v > 0.0)); }
  // "a length > 0, got -1"
  std::string expected(double got) const {
    std::ostringstream s;
    s << (any_sign ? "a finite " : "") << (any_sign ? noun.substr(noun.find(' ') + 1) : noun)
      << (any_sign       ? ""
          : zero_allowed ? " >= 0"
                         : " > 0")
      << ", got " << got;
    return s.str();
  }
};

inline constexpr Quantity kLength{"a length", false};                 // σ, R₀, r₀, ℓ, cutoffs
inline constexpr Quantity kSkin{"a length", true};                    // the Verlet skin may be 0
inline constexpr Quantity kEnergy{"an energy", true};                 // ε, D₀, A of `soft`
inline constexpr Quantity kStiffness{"a stiffness", true};            // spring constants K, k
inline constexpr Quantity kInverseLength{"an inverse length", true};  // Morse α, Yukawa κ
inline constexpr Quantity kTorsionEnergy{"an energy", true, true};    // dihedral K, A_n, K_n: any sign
inline constexpr Quantity kPositive{"a number", false};               // the stiffness scale ε, α_b

// Throws std::invalid_argument "<name>: expected <q>, got <v>" unless q admits v.
inline void require(double v, const Quantity& q, std::string_view name) {
  if (!q.admits(v)) throw std::invalid_argument(std::string(name) + ": expected " + q.expected(v));
}

}  // namespace stiffmd
