// The deck text that imports tests/data/butanes.data (united-atom butanes: CH3 and CH2 sites, end and
// middle bonds, one angle and one dihedral type), for the tests that build decks on it with their
// own force terms.
#pragma once

#include <string>

#include "test_support.hpp"

namespace stiffmd::test {

inline std::string butanes_import() {
  return "[types.CH3]\nmass = 15.0\n[types.CH2]\nmass = 14.0\n"
         "[import]\nlammps_data = \"" +
         source_path("tests/data/butanes.data") +
         "\"\natom_types = { \"1\" = \"CH3\", \"2\" = \"CH2\" }\nbond_types = { \"1\" = \"end\", \"2\" = \"mid\" }\n"
         "angle_types = { \"1\" = \"ccc\" }\ndihedral_types = { \"1\" = \"butane\" }\n";
}

}  // namespace stiffmd::test
