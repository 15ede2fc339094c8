// Import and export of LAMMPS data files (the `read_data` / `write_data` format) as a plain
// ImportedSystem, independent of decks and scenes.
//
// Reading is strict: a malformed file, and anything this engine cannot use (tilted boxes,
// dangling bond ends, duplicate bonds, missing masses), is an InputError whose one line names the
// file, the line (or the section) and what was expected. Header counts are checked against the
// file's size before anything is allocated for them.
//
// Exactness: positions are unwrapped as  x = w + image * (hi - lo)  (std::fma, so the rounding is
// the same whatever the compiler contracts), and the writer picks, per coordinate, a wrapped w in
// [lo, hi) and an image such that this reproduces x bit for bit. When no such pair exists, it
// writes x itself with image 0, which LAMMPS remaps into a periodic box on reading. That happens
// only for an x outside the box that is finer than any w can express (x = -1e-5 in a box [0, 10]:
// w near 10 has a coarser ulp) or more than 2^20 box lengths away; in a box centred on the
// origin (lo = -hi) every coordinate wraps. Numbers are written in the shortest form that reads back as the same
// double (std::to_chars), so write_lammps_data → read_lammps_data reproduces x, v, charges,
// masses and box exactly (in the same order when the ids ascend, as read_lammps_data returns
// them: the reader sorts by id).

#pragma once

#include <Eigen/Core>
#include <map>
#include <string>
#include <string_view>
#include <vector>

namespace stiffmd {

struct ImportedSystem {
  Eigen::Matrix3Xd x;               // positions, unwrapped with the image flags when the file has them
  bool image_flags = false;         // the Atoms section had image flags (x is then unwrapped)
  Eigen::Matrix3Xd v;               // velocities (zero when the file has none)
  std::vector<int> type;            // 1-based atom type as read
  std::vector<int> molecule;        // molecule id (0 when the atom style has none)
  std::vector<double> charge;       // atom_style full only; empty otherwise
  std::vector<long> id;             // the file's atom ids, ascending (atoms are sorted by id)
  std::map<int, double> type_mass;  // Masses section
  struct Bond {
    int type;
    int i, j;  // 0-based indices into x (after sorting by id)
  };
  std::vector<Bond> bonds;
  struct Angle {
    int type;
    int i, j, k;  // j is the vertex
  };
  std::vector<Angle> angles;
  struct Quad {
    int type;
    int i, j, k, l;  // a dihedral about j–k; an improper as LAMMPS lists it (i the centre for most styles)
  };
  std::vector<Quad> dihedrals, impropers;
  // The force-field sections ("Pair Coeffs", "Bond Coeffs", "Dihedral Coeffs", …) as read, in file
  // order: the style hint after '#' and each row's data (type and coefficients, comment dropped).
  // Kept so that an export writes them back; which of them a deck maps to force terms is the
  // import's business (engine/scene/scene_sources.cpp).
  struct CoeffSection {
    std::string name;   // "Dihedral Coeffs"
    std::string style;  // "opls" from "Dihedral Coeffs # opls"; "" when there is no hint
    std::vector<std::string> rows;
  };
  std::vector<CoeffSection> coeffs;
  Eigen::Vector3d lo = Eigen::Vector3d::Zero(), hi = Eigen::Vector3d::Zero();  // orthorhombic box
  int num_atom_types = 0, num_bond_types = 0, num_angle_types = 0, num_dihedral_types = 0, num_improper_types = 0;
  // Beyond the minimal interface: what the readers learnt that would otherwise be lost.
  std::string atom_style;               // the LAMMPS style the Atoms section was read as ("" for XYZ)
  std::vector<std::string> type_names;  // XYZ species of type k+1; empty for LAMMPS files
};

// atom_style: "auto" (the "Atoms # style" hint LAMMPS writes, else the column count), or one of
// "atomic", "bond", "angle", "molecular", "full". An explicit style wins over the hint, as in LAMMPS.
// Dihedrals and Impropers are read like Angles; the force-field "… Coeffs" sections are checked
// (types in range, each once) and kept as text in `coeffs`.
ImportedSystem read_lammps_data(const std::string& path, const std::string& atom_style = "auto");

// atom_style: "atomic" (no bonds), "bond" (no angles), "angle" (no dihedrals or impropers), "molecular"
// or "full". The "… Coeffs" sections of s.coeffs are written back as they are. Image flags
// are always written; Velocities only when s.v has one column per atom. Throws InputError when s
// cannot be represented (sizes disagree, a type without a mass, an empty box, …).
void write_lammps_data(const std::string& path, const ImportedSystem& s, const std::string& atom_style = "bond",
                       const std::string& title = "written by stiffmd");

namespace detail {
// Shared with the XYZ reader (engine/io/xyz_bonds.cpp) so both readers word their errors alike.

// The whole file; InputError naming `path` if it is missing, a directory, unreadable or gzip-compressed.
std::string read_text_file(const std::string& path);
// What read_text_file and read_lammps_data refuse before they read a line (a directory, a device,
// a file that cannot be opened, gzip-compressed or empty), with their words: for a reader that
// streams the file (engine/io/lammps_data_parts.hpp).
void check_lammps_data_file(const std::string& path);
// Whole-token parses: no leading/trailing junk, finite values only, integers within range.
bool parse_double(std::string_view s, double& out);
bool parse_long(std::string_view s, long long& out);
// `s` quoted for an error message: at most a few dozen characters, non-printables shown as '?'.
std::string quote(std::string_view s);
// Whitespace-separated tokens of `s`.
std::vector<std::string_view> split_ws(std::string_view s);
// The same into `out` (cleared first), reusing its storage: the data reader splits every line.
void split_ws_into(std::string_view s, std::vector<std::string_view>& out);
// The whitespace split_ws splits on.
bool is_space(char c);
// `s` without the whitespace at its ends.
std::string_view trim(std::string_view s);
}  // namespace detail

}  // namespace stiffmd
