// What the LAMMPS data-file reader (lammps_data.cpp) and writer (lammps_data_writer.cpp) share:
// the atom styles and their Atoms columns, and the unwrapping x = w + n L.
#pragma once

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

}  // namespace stiffmd::lammps_format
