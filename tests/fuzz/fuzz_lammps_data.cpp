// libFuzzer target: the bytes as a LAMMPS data file (read_lammps_data), as an XYZ file with an
// empty bond list, and as a bond list for a fixed four-atom XYZ file (read_xyz_with_bonds).
// stiffmd::InputError is the expected outcome of a bad file; any other exception, a crash, a
// hang, an allocation beyond -malloc_limit_mb or a sanitizer report is a finding.
//
// The same bytes read by parts (read_lammps_data_part, engine/io/lammps_data_parts.hpp), keeping
// every molecule and keeping none: InputError or a part; when both readers read the file, the part
// that keeps every molecule is the whole import (positions, velocities, types, ids, bonded terms).
//
// A data file that reads must also survive the documented round trip: write_lammps_data (in a
// style that can hold what was read) and read_lammps_data give back the same positions,
// velocities, types and bonds, bit for bit.
//
//   build-fuzz/fuzz_lammps_data -dict=tests/fuzz/lammps_data.dict CORPUS_DIR   (see tools/fuzz.sh)
#include <cstddef>
#include <cstdint>
#include <cstring>
#include <string>

#include "core/errors.hpp"
#include "engine/io/lammps_data.hpp"
#include "engine/io/lammps_data_parts.hpp"
#include "engine/io/xyz_bonds.hpp"
#include "fuzz_support.hpp"

namespace {

using stiffmd::ImportedSystem;

bool same_bits(const Eigen::Matrix3Xd& a, const Eigen::Matrix3Xd& b) {
  return a.cols() == b.cols() &&
         (a.size() == 0 || std::memcmp(a.data(), b.data(), sizeof(double) * static_cast<std::size_t>(a.size())) == 0);
}

// A style that can hold everything the reader returned.
std::string style_for(const ImportedSystem& s) {
  if (!s.charge.empty()) return "full";
  if (!s.dihedrals.empty() || !s.impropers.empty()) return "molecular";
  if (!s.angles.empty()) return "angle";
  if (!s.bonds.empty() || s.atom_style == "bond") return "bond";
  if (s.atom_style == "angle" || s.atom_style == "molecular") return s.atom_style;
  return "atomic";
}

void round_trip(const ImportedSystem& s, const std::string& path) {
  const std::string style = style_for(s);
  try {
    stiffmd::write_lammps_data(path, s, style, "fuzz round trip");
  } catch (const stiffmd::InputError&) {
    return;  // e.g. a type without a mass: readable here, not by LAMMPS
  }
  ImportedSystem back;
  try {
    back = stiffmd::read_lammps_data(path, style);
  } catch (const std::exception& e) {
    stiffmd::fuzz::finding("write_lammps_data wrote a file that read_lammps_data refuses", &e);
  }
  if (!same_bits(s.x, back.x)) stiffmd::fuzz::finding("round trip changed the positions");
  if (!same_bits(s.v, back.v)) stiffmd::fuzz::finding("round trip changed the velocities");
  if (s.type != back.type || s.id != back.id) stiffmd::fuzz::finding("round trip changed the types or ids");
  if (s.bonds.size() != back.bonds.size() || s.angles.size() != back.angles.size() ||
      s.dihedrals.size() != back.dihedrals.size() || s.impropers.size() != back.impropers.size())
    stiffmd::fuzz::finding("round trip changed the bonds, angles, dihedrals or impropers");
  if (s.coeffs.size() != back.coeffs.size()) stiffmd::fuzz::finding("round trip changed the coefficient sections");
  for (std::size_t k = 0; k < s.coeffs.size() && k < back.coeffs.size(); ++k)
    if (s.coeffs[k].rows != back.coeffs[k].rows) stiffmd::fuzz::finding("round trip changed a coefficient row");
  for (std::size_t k = 0; k < s.bonds.size(); ++k)
    if (s.bonds[k].i != back.bonds[k].i || s.bonds[k].j != back.bonds[k].j || s.bonds[k].type != back.bonds[k].type)
      stiffmd::fuzz::finding("round trip changed a bond");
}

// The part that keeps every molecule against the whole import (`whole`: null when it was refused).
void read_by_parts(const std::string& path, const ImportedSystem* whole) {
  for (const bool keep : {true, false}) {
    stiffmd::ImportedPart part;
    try {
      part = stiffmd::read_lammps_data_part(path, "auto", [keep](const Eigen::Vector3d&) { return keep; });
    } catch (const stiffmd::InputError&) {
      return;
    } catch (const std::exception& e) {
      stiffmd::fuzz::finding("read_lammps_data_part threw something other than InputError", &e);
    }
    if (!keep) {
      if (part.system.x.cols() != 0 || !part.global.empty())
        stiffmd::fuzz::finding("a part that keeps nothing has atoms");
      continue;
    }
    if (!whole) continue;
    const ImportedSystem& p = part.system;
    if (!same_bits(p.x, whole->x) || !same_bits(p.v, whole->v) || p.type != whole->type || p.id != whole->id ||
        p.molecule != whole->molecule || p.charge != whole->charge)
      stiffmd::fuzz::finding("the part that keeps every molecule is not the whole import's atoms");
    if (p.bonds.size() != whole->bonds.size() || p.angles.size() != whole->angles.size() ||
        p.dihedrals.size() != whole->dihedrals.size() || p.impropers.size() != whole->impropers.size())
      stiffmd::fuzz::finding("the part that keeps every molecule is not the whole import's bonded terms");
    for (std::size_t k = 0; k < p.bonds.size() && k < whole->bonds.size(); ++k)
      if (p.bonds[k].i != whole->bonds[k].i || p.bonds[k].j != whole->bonds[k].j ||
          p.bonds[k].type != whole->bonds[k].type)
        stiffmd::fuzz::finding("the part that keeps every molecule changed a bond");
  }
}

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  using namespace stiffmd;
  static const fuzz::ScratchFile input("input"), written("written.data"), empty_bonds("empty.bonds"),
      four_atoms("four.xyz");
  static const bool fixed_files = [] {
    empty_bonds.write("", 0);
    const std::string xyz = "4\nfour atoms\nC 0 0 0\nC 1 0 0\nO 1 1 0\nH 0 1 0\n";
    four_atoms.write(xyz.data(), xyz.size());
    return true;
  }();
  (void)fixed_files;
  input.write(data, size);

  try {
    const ImportedSystem s = read_lammps_data(input.path);
    read_by_parts(input.path, &s);
    round_trip(s, written.path);
  } catch (const InputError&) {
    read_by_parts(input.path, nullptr);
  } catch (const std::exception& e) {
    fuzz::finding("read_lammps_data threw something other than InputError", &e);
  }
  try {
    (void)read_xyz_with_bonds(input.path, empty_bonds.path);
  } catch (const InputError&) {
  } catch (const std::exception& e) {
    fuzz::finding("read_xyz_with_bonds (input as XYZ) threw something other than InputError", &e);
  }
  try {
    (void)read_xyz_with_bonds(four_atoms.path, input.path);
  } catch (const InputError&) {
  } catch (const std::exception& e) {
    fuzz::finding("read_xyz_with_bonds (input as bonds) threw something other than InputError", &e);
  }
  return 0;
}
