// What the LAMMPS data-file readers (lammps_data.cpp, lammps_data_parts.cpp) and writer
// (lammps_data_writer.cpp) share: the atom styles and their Atoms columns, the unwrapping
// x = w + n L, the header's counts and the test that tells a number line from a keyword line.
#pragma once

#include <array>
#include <cmath>
#include <cstddef>
#include <string_view>

namespace stiffmd::lammps_format {

struct Style {
  std::string_view name;
  size_t columns;           // without image flags
  std::string_view layout;  // for messages
  bool molecule, charge;
};
inline constexpr Style kStyles[] = {
    {"atomic", 5, "id type x y z", false, false},   {"bond", 6, "id mol type x y z", true, false},
    {"angle", 6, "id mol type x y z", true, false}, {"molecular", 6, "id mol type x y z", true, false},
    {"full", 7, "id mol type q x y z", true, true},
};
inline const Style* find_style(std::string_view name) {
  for (const Style& s : kStyles)
    if (s.name == name) return &s;
  return nullptr;
}

inline constexpr std::string_view kSupportedStyles = "atomic, bond, angle, molecular or full";

// x = w + n L, exactly as the writer checks it; fma rounds once whatever the compiler contracts.
// n = 0 returns w untouched so that -0.0 survives.
inline double unwrap(double w, int n, double L) {
  return n == 0 ? w : std::fma(static_cast<double>(n), L, w);
}

// Keyword lines start with a letter; header and entry lines with a number.
inline bool starts_numeric(std::string_view s) {
  if (s.empty()) return false;
  size_t k = (s[0] == '-' || s[0] == '+') ? 1 : 0;
  if (k < s.size() && s[k] == '.') ++k;
  return k < s.size() && s[k] >= '0' && s[k] <= '9';
}

// The header's counts, then the entries of the PairIJ Coeffs section (not a header line: one per
// pair of atom types).
enum Count {
  kAtoms,
  kBonds,
  kAngles,
  kDihedrals,
  kImpropers,
  kAtomTypes,
  kBondTypes,
  kAngleTypes,
  kDihedralTypes,
  kImproperTypes,
  kPairIJ,
  kNumCounts
};
inline constexpr std::array<std::string_view, kPairIJ> kCountKeyword = {
    "atoms",      "bonds",      "angles",      "dihedrals",      "impropers",
    "atom types", "bond types", "angle types", "dihedral types", "improper types"};

}  // namespace stiffmd::lammps_format
