// LAMMPS data and XYZ+bonds import/export: a real benchmark file, exact round trips, and every
// malformed input refused with one line naming the file, the line (or section) and the expectation.
#include <gtest/gtest.h>
#include <sys/wait.h>
#include <unistd.h>

#include <algorithm>
#include <array>
#include <chrono>
#include <cmath>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <limits>
#include <random>
#include <set>
#include <sstream>
#include <string>

#include "core/errors.hpp"
#include "engine/io/lammps_data.hpp"
#include "engine/io/xyz_bonds.hpp"

namespace stiffmd {
namespace {

namespace fs = std::filesystem;

std::string data(const std::string& name) {
  return std::string(STIFFMD_SOURCE_DIR) + "/tests/data/" + name;
}

// The FENE bead-spring benchmark shipped by Debian's lammps-examples.
const std::string kChain = "/usr/share/lammps/examples/COUPLE/multiple/data.chain";

// Per-process scratch folder (other test binaries may run at the same time), removed at exit.
fs::path scratch_dir() {
  return fs::temp_directory_path() / ("stiffmd_test_lammps_data_" + std::to_string(::getpid()));
}

std::string scratch(const std::string& name) {
  fs::create_directories(scratch_dir());
  return (scratch_dir() / name).string();
}

class RemoveScratch : public ::testing::Environment {
 public:
  void TearDown() override {
    std::error_code ec;
    fs::remove_all(scratch_dir(), ec);
  }
};
[[maybe_unused]] ::testing::Environment* const kRemoveScratch = ::testing::AddGlobalTestEnvironment(new RemoveScratch);

std::string slurp(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  std::ostringstream s;
  s << in.rdbuf();
  return s.str();
}

void spit(const std::string& path, const std::string& text) {
  std::ofstream(path, std::ios::binary) << text;
}

// Bit for bit, so that -0.0 vs 0.0 or a last-ulp difference both fail.
::testing::AssertionResult bitwise_equal(const Eigen::Matrix3Xd& a, const Eigen::Matrix3Xd& b) {
  if (a.cols() != b.cols()) return ::testing::AssertionFailure() << a.cols() << " vs " << b.cols() << " columns";
  for (Eigen::Index k = 0; k < a.cols(); ++k)
    for (int d = 0; d < 3; ++d)
      if (std::memcmp(&a(d, k), &b(d, k), sizeof(double)) != 0)
        return ::testing::AssertionFailure() << "column " << k << " axis " << d << ": " << a(d, k) << " vs " << b(d, k);
  return ::testing::AssertionSuccess();
}

void expect_same(const ImportedSystem& a, const ImportedSystem& b) {
  EXPECT_TRUE(bitwise_equal(a.x, b.x));
  EXPECT_TRUE(bitwise_equal(a.v, b.v));
  EXPECT_EQ(a.type, b.type);
  EXPECT_EQ(a.molecule, b.molecule);
  EXPECT_EQ(a.charge, b.charge);
  EXPECT_EQ(a.id, b.id);
  EXPECT_EQ(a.type_mass, b.type_mass);
  ASSERT_EQ(a.bonds.size(), b.bonds.size());
  for (size_t k = 0; k < a.bonds.size(); ++k) {
    EXPECT_EQ(a.bonds[k].type, b.bonds[k].type);
    EXPECT_EQ(a.bonds[k].i, b.bonds[k].i);
    EXPECT_EQ(a.bonds[k].j, b.bonds[k].j);
  }
  ASSERT_EQ(a.angles.size(), b.angles.size());
  for (size_t k = 0; k < a.angles.size(); ++k) {
    EXPECT_EQ(a.angles[k].type, b.angles[k].type);
    EXPECT_EQ(a.angles[k].i, b.angles[k].i);
    EXPECT_EQ(a.angles[k].j, b.angles[k].j);
    EXPECT_EQ(a.angles[k].k, b.angles[k].k);
  }
  EXPECT_EQ(a.lo, b.lo);
  EXPECT_EQ(a.hi, b.hi);
  EXPECT_EQ(a.num_atom_types, b.num_atom_types);
  EXPECT_EQ(a.num_bond_types, b.num_bond_types);
  EXPECT_EQ(a.num_angle_types, b.num_angle_types);
}

template <class F>
std::string input_error(F f) {
  try {
    f();
  } catch (const InputError& e) {
    return e.what();
  }
  return "<no InputError thrown>";
}

// Coordinates as written in the Atoms section (the wrapped values, before image flags).
std::vector<std::array<double, 3>> written_coordinates(const std::string& path, size_t xcol) {
  std::istringstream in(slurp(path));
  std::string line;
  while (std::getline(in, line) && line.rfind("Atoms", 0) != 0) {
  }
  std::getline(in, line);
  std::vector<std::array<double, 3>> out;
  while (std::getline(in, line) && !line.empty()) {
    std::istringstream row(line);
    std::vector<std::string> tok;
    for (std::string t; row >> t;) tok.push_back(t);
    out.push_back({std::stod(tok[xcol]), std::stod(tok[xcol + 1]), std::stod(tok[xcol + 2])});
  }
  return out;
}

// ---------------------------------------------------------------------------------------------
// data.chain: 320 bead-spring chains of 100 beads, atom_style bond, image flags and velocities.

class DataChain : public ::testing::Test {
 protected:
  static void SetUpTestSuite() {
    if (fs::exists(kChain)) chain_ = new ImportedSystem(read_lammps_data(kChain));
  }
  static void TearDownTestSuite() {
    delete chain_;
    chain_ = nullptr;
  }
  void SetUp() override {
    if (!chain_) GTEST_SKIP() << kChain << " not installed (Debian package lammps-examples)";
  }
  static ImportedSystem* chain_;
};
ImportedSystem* DataChain::chain_ = nullptr;

TEST_F(DataChain, HeaderBoxMassesAndCounts) {
  const ImportedSystem& s = *chain_;
  EXPECT_EQ(s.x.cols(), 32000);
  EXPECT_EQ(s.bonds.size(), 31680u);
  EXPECT_TRUE(s.angles.empty());
  EXPECT_EQ(s.num_atom_types, 1);
  EXPECT_EQ(s.num_bond_types, 1);
  EXPECT_EQ(s.num_angle_types, 0);
  EXPECT_EQ(s.lo, Eigen::Vector3d::Constant(-16.796));
  EXPECT_EQ(s.hi, Eigen::Vector3d::Constant(16.796));
  EXPECT_EQ(s.type_mass, (std::map<int, double>{{1, 1.0}}));
  EXPECT_EQ(s.atom_style, "bond");  // inferred from 9 columns: the file has no "# bond" hint
  EXPECT_TRUE(s.charge.empty());
  for (int t : s.type) ASSERT_EQ(t, 1);
}

TEST_F(DataChain, ChainsOf100ConsecutiveIds) {
  const ImportedSystem& s = *chain_;
  for (size_t k = 0; k < s.id.size(); ++k) {
    ASSERT_EQ(s.id[k], static_cast<long>(k + 1));
    ASSERT_EQ(s.molecule[k], static_cast<int>(k / 100) + 1) << "atom id " << s.id[k];
  }
  // Every bond joins consecutive ids of one molecule, each such pair exactly once.
  std::vector<int> bonds_per_molecule(321, 0);
  std::set<int> starts;
  for (const auto& b : s.bonds) {
    ASSERT_EQ(b.type, 1);
    ASSERT_EQ(b.j, b.i + 1);
    ASSERT_EQ(s.molecule[static_cast<size_t>(b.i)], s.molecule[static_cast<size_t>(b.j)]);
    ASSERT_TRUE(starts.insert(b.i).second);
    ++bonds_per_molecule[static_cast<size_t>(s.molecule[static_cast<size_t>(b.i)])];
  }
  for (int m = 1; m <= 320; ++m) EXPECT_EQ(bonds_per_molecule[static_cast<size_t>(m)], 99) << "molecule " << m;
}

TEST_F(DataChain, ImageFlagsAreApplied) {
  const ImportedSystem& s = *chain_;
  const Eigen::Vector3d L = s.hi - s.lo;
  double longest = 0, longest_wrapped = 0;
  for (const auto& b : s.bonds) {
    const Eigen::Vector3d xi = s.x.col(b.i), xj = s.x.col(b.j);
    longest = std::max(longest, (xi - xj).norm());
    // The same bond between the positions folded back into the box (what the file lists).
    const auto fold = [&](Eigen::Vector3d x) {
      for (int d = 0; d < 3; ++d) x[d] -= L[d] * std::floor((x[d] - s.lo[d]) / L[d]);
      return x;
    };
    longest_wrapped = std::max(longest_wrapped, (fold(xi) - fold(xj)).norm());
  }
  EXPECT_LT(longest, 1.5);  // FENE R0: no bond can be longer
  EXPECT_GT(longest_wrapped, 10.0) << "the file has bonds across the boundary, so folding must break some";

  // Atom 5204 is listed as "8.89737 15.8254 -16.1852 -1 -1 1".
  const Eigen::Index k = 5203;
  ASSERT_EQ(s.id[static_cast<size_t>(k)], 5204);
  EXPECT_DOUBLE_EQ(s.x(0, k), 8.89737 - L[0]);
  EXPECT_DOUBLE_EQ(s.x(1, k), 15.8254 - L[1]);
  EXPECT_DOUBLE_EQ(s.x(2, k), -16.1852 + L[2]);
  // Atom 1, image 0: the file's digits exactly.
  EXPECT_EQ(s.x(0, 0), 5.09947);
  EXPECT_EQ(s.x(1, 0), 3.82766);
  EXPECT_EQ(s.x(2, 0), 14.0409);
}

TEST_F(DataChain, Velocities) {
  const ImportedSystem& s = *chain_;
  EXPECT_EQ(s.v(0, 0), -1.38574);
  EXPECT_EQ(s.v(1, 0), -0.958747);
  EXPECT_EQ(s.v(2, 0), -0.931615);
  EXPECT_EQ(s.v(2, 31999), -0.583196);
  EXPECT_GT(s.v.squaredNorm() / 32000, 1.0);  // a thermalised melt, not the zero default
}

TEST_F(DataChain, ReadsInWellUnderASecond) {
  const auto t0 = std::chrono::steady_clock::now();
  const ImportedSystem s = read_lammps_data(kChain);
  const double seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  EXPECT_EQ(s.x.cols(), 32000);
  // Generous for unoptimised builds; a quadratic step would take minutes.
  EXPECT_LT(seconds, 2.0);
}

TEST_F(DataChain, RoundTripIsExactAndWrapped) {
  const std::string out = scratch("chain_roundtrip.data");
  write_lammps_data(out, *chain_);
  const ImportedSystem back = read_lammps_data(out);
  expect_same(*chain_, back);
  EXPECT_EQ(back.atom_style, "bond");

  // What LAMMPS reads: every coordinate inside [lo, hi) (these values admit an exact wrap).
  const auto w = written_coordinates(out, 3);
  ASSERT_EQ(w.size(), 32000u);
  for (const auto& x : w)
    for (int d = 0; d < 3; ++d) ASSERT_TRUE(x[static_cast<size_t>(d)] >= -16.796 && x[static_cast<size_t>(d)] < 16.796);

  // Writing what was read back gives the same bytes.
  const std::string again = scratch("chain_roundtrip2.data");
  write_lammps_data(again, back);
  EXPECT_EQ(slurp(out), slurp(again));
}

TEST_F(DataChain, LammpsReadsTheExportAsTheSameUnwrappedPositions) {
  if (std::system("command -v lmp > /dev/null 2>&1") != 0) GTEST_SKIP() << "lmp not installed (Debian package lammps)";
  const fs::path dir = scratch("lmp");
  fs::create_directories(dir);
  write_lammps_data((dir / "chain.data").string(), *chain_);
  spit((dir / "in.read").string(),
       "units lj\natom_style bond\nread_data chain.data\n"
       "write_dump all custom chain.dump id xu yu zu modify sort id format float %.17g\n");
  const std::string cmd = "cd '" + dir.string() + "' && lmp -in in.read -log none -screen none";
  ASSERT_EQ(std::system(cmd.c_str()), 0) << cmd;
  std::istringstream dump(slurp((dir / "chain.dump").string()));
  std::string line;
  while (std::getline(dump, line) && line.rfind("ITEM: ATOMS", 0) != 0) {
  }
  Eigen::Index k = 0;
  for (; std::getline(dump, line); ++k) {
    ASSERT_LT(k, chain_->x.cols());
    std::istringstream row(line);
    long id = 0;
    std::string x, y, z;
    row >> id >> x >> y >> z;
    ASSERT_EQ(id, chain_->id[static_cast<size_t>(k)]);
    // LAMMPS unwraps with its own arithmetic; %.17g and strtod carry its doubles exactly.
    ASSERT_EQ(std::strtod(x.c_str(), nullptr), chain_->x(0, k)) << "atom id " << id;
    ASSERT_EQ(std::strtod(y.c_str(), nullptr), chain_->x(1, k)) << "atom id " << id;
    ASSERT_EQ(std::strtod(z.c_str(), nullptr), chain_->x(2, k)) << "atom id " << id;
  }
  EXPECT_EQ(k, chain_->x.cols());
}

// ---------------------------------------------------------------------------------------------
// A hand-made atom_style full file: ids out of order, image flags, velocities, angles, comments,
// coefficient sections.

TEST(SmallFull, Contents) {
  const ImportedSystem s = read_lammps_data(data("small_full.data"));
  EXPECT_EQ(s.atom_style, "full");
  ASSERT_EQ(s.x.cols(), 5);
  EXPECT_EQ(s.id, (std::vector<long>{1, 2, 3, 4, 5}));
  EXPECT_EQ(s.type, (std::vector<int>{2, 1, 1, 2, 2}));
  EXPECT_EQ(s.molecule, (std::vector<int>{1, 1, 1, 2, 2}));
  EXPECT_EQ(s.charge, (std::vector<double>{-0.82, 0.41, 0.41, 0.5, -0.5}));
  EXPECT_EQ(s.type_mass, (std::map<int, double>{{1, 1.008}, {2, 16.0}}));
  EXPECT_EQ(s.lo, Eigen::Vector3d(-2.5, 0, -1));
  EXPECT_EQ(s.hi, Eigen::Vector3d(2.5, 4, 1));
  EXPECT_EQ(s.x.col(0), Eigen::Vector3d(-2.4, 0.5, 0.0));
  EXPECT_EQ(s.x.col(2), Eigen::Vector3d(2.25 - 5.0, 0.5, 0.0));  // image -1 in x
  EXPECT_DOUBLE_EQ(s.x(1, 4), 3.9 - 2 * 4.0);                    // image -2 in y
  EXPECT_EQ(s.x(2, 4), 0.75 + 2.0);                              // image +1 in z
  EXPECT_EQ(s.v.col(1), Eigen::Vector3d(-1e-3, 0, 0));
  EXPECT_EQ(s.v.col(2), Eigen::Vector3d(0, 0, 25));
  ASSERT_EQ(s.bonds.size(), 3u);
  EXPECT_EQ(s.bonds[2].type, 2);
  EXPECT_EQ(s.bonds[2].i, 3);
  EXPECT_EQ(s.bonds[2].j, 4);
  ASSERT_EQ(s.angles.size(), 1u);
  EXPECT_EQ(s.angles[0].i, 1);
  EXPECT_EQ(s.angles[0].j, 0);
  EXPECT_EQ(s.angles[0].k, 2);
  EXPECT_EQ(s.num_atom_types, 2);
  EXPECT_EQ(s.num_bond_types, 2);
  EXPECT_EQ(s.num_angle_types, 1);
}

TEST(SmallFull, RoundTripIsExact) {
  const ImportedSystem s = read_lammps_data(data("small_full.data"));
  const std::string out = scratch("small_full_roundtrip.data");
  write_lammps_data(out, s, "full", "round trip");
  const ImportedSystem back = read_lammps_data(out);
  EXPECT_EQ(back.atom_style, "full");
  expect_same(s, back);
  EXPECT_EQ(slurp(out).rfind("round trip\n", 0), 0u);
}

TEST(SmallFull, ExplicitStyleWinsAndIsChecked) {
  EXPECT_EQ(read_lammps_data(data("small_full.data"), "full").charge.size(), 5u);
  const std::string e = input_error([] { read_lammps_data(data("small_full.data"), "molecular"); });
  EXPECT_NE(e.find("small_full.data: line 33: Atoms: atom_style molecular expects 6 or 9 columns"), std::string::npos)
      << e;
  const std::string u = input_error([] { read_lammps_data(data("small_full.data"), "sphere"); });
  EXPECT_NE(u.find("atom_style 'sphere' is not supported"), std::string::npos) << u;
}

TEST(SmallBond, ReadsWithHintAndAsMolecular) {
  const ImportedSystem s = read_lammps_data(data("small_bond.data"));
  EXPECT_EQ(s.atom_style, "bond");
  EXPECT_EQ(s.x.cols(), 4);
  EXPECT_TRUE(s.v.isZero());
  EXPECT_EQ(read_lammps_data(data("small_bond.data"), "molecular").type, s.type);
}

TEST(SmallBond, CrlfLineEndings) {
  std::string text = slurp(data("small_bond.data")), crlf;
  for (char c : text) crlf += (c == '\n') ? std::string("\r\n") : std::string(1, c);
  const std::string path = scratch("crlf.data");
  spit(path, crlf);
  expect_same(read_lammps_data(data("small_bond.data")), read_lammps_data(path));
}

// ---------------------------------------------------------------------------------------------
// Exactness where floating point makes it delicate.

TEST(RoundTrip, ExactForAwkwardCoordinates) {
  ImportedSystem s;
  std::mt19937_64 rng(12345);
  std::uniform_real_distribution<double> u(-1.0, 1.0);
  const int n = 3000;
  s.x.resize(3, n);
  s.v.resize(3, n);
  s.type.assign(n, 1);
  s.type_mass[1] = 1.0;
  // An x box not representable in binary, a y box away from the origin, a z box from 0.
  s.lo = Eigen::Vector3d(-0.1, 3.3, 0.0);
  s.hi = Eigen::Vector3d(0.2, 7.7, 10.0);
  for (int k = 0; k < n; ++k)
    for (int d = 0; d < 3; ++d) {
      const double L = s.hi[d] - s.lo[d];
      const double reach = std::pow(10.0, k % 5);  // up to 10^4 box lengths away
      s.x(d, k) = s.lo[d] + L * (0.5 + reach * u(rng));
      s.v(d, k) = u(rng) * std::pow(10.0, (k % 7) - 3);
    }
  const double special[] = {-0.0,
                            0.0,
                            -0.1,
                            0.2,
                            3.3,
                            7.7,
                            10.0,
                            -1e-300,
                            5e-324,
                            1e300,
                            -1e-17,
                            0.1 + 0.2,
                            std::nextafter(0.2, 0.0),
                            std::nextafter(-0.1, -1.0)};
  int k = 0;
  for (double x : special) {
    s.x.col(k++) = Eigen::Vector3d::Constant(x);
  }
  s.v(0, 0) = -0.0;
  const std::string out = scratch("awkward.data");
  write_lammps_data(out, s, "atomic");
  const ImportedSystem back = read_lammps_data(out);
  EXPECT_EQ(back.atom_style, "atomic");
  EXPECT_TRUE(bitwise_equal(s.x, back.x));
  EXPECT_TRUE(bitwise_equal(s.v, back.v));
  EXPECT_EQ(back.molecule, std::vector<int>(n, 0));
  EXPECT_EQ(back.id.front(), 1);  // ids 1..N when the system has none
  EXPECT_EQ(back.id.back(), n);
}

TEST(RoundTrip, BoxAroundTheOriginWrapsEveryCoordinate) {
  // Outside such a box |x| > |w|, so the wrapped coordinate is never coarser than x and an exact
  // (w, image) pair exists: LAMMPS gets every atom inside the box. (In a box [0, L] an x just
  // below 0 is finer than any w near L can express; that one is written unwrapped, image 0.)
  ImportedSystem s;
  std::mt19937_64 rng(99);
  std::uniform_real_distribution<double> u(-3.0, 3.0);
  const int n = 20000;
  s.x.resize(3, n);
  s.type.assign(n, 1);
  s.type_mass[1] = 1.0;
  s.lo = Eigen::Vector3d(-16.796, -0.1, -123.456);
  s.hi = -s.lo;
  for (int k = 0; k < n; ++k)
    for (int d = 0; d < 3; ++d) s.x(d, k) = s.hi[d] * u(rng);
  const std::string out = scratch("centred.data");
  write_lammps_data(out, s, "atomic");
  EXPECT_TRUE(bitwise_equal(s.x, read_lammps_data(out).x));
  const auto w = written_coordinates(out, 2);
  ASSERT_EQ(w.size(), static_cast<size_t>(n));
  size_t outside = 0;
  for (const auto& x : w)
    for (int d = 0; d < 3; ++d)
      outside += !(x[static_cast<size_t>(d)] >= s.lo[d] && x[static_cast<size_t>(d)] < s.hi[d]);
  EXPECT_EQ(outside, 0u);
}

// ---------------------------------------------------------------------------------------------
// Malformed LAMMPS data files: one line with the file, the line (or section) and the expectation.

struct BadCase {
  const char* file;
  const char* where;     // "line N: Section" (or the section for whole-file problems)
  const char* expected;  // a hint of what was expected
};

const BadCase kBadData[] = {
    {"bad_truncated.data", "line 20: Atoms", "file ends after 2 of the 4 entries"},
    {"bad_fewer_atoms.data", "line 23: Atoms", "only 3 of the 4 entries declared in the header"},
    {"bad_more_bonds.data", "line 29: Bonds", "more entries than the 3 declared in the header"},
    {"bad_unknown_section.data", "line 24: unknown section 'Bondz'", "expected Masses, Atoms, Velocities, Bonds"},
    {"bad_columns.data", "line 21: Atoms", "expected 9 columns 'id mol type x y z ix iy iz' as on line 19, found 8"},
    {"bad_non_numeric.data", "line 20: Atoms", "column 5 (y) is 'abc', expected a finite number"},
    {"bad_nan.data", "line 19: Atoms", "column 5 (y) is 'nan', expected a finite number"},
    {"bad_image_flag.data", "line 22: Atoms", "column 8 (iy) is '1.5', expected an integer"},
    {"bad_duplicate_id.data", "line 21: Atoms", "atom id 2 given twice (first on line 20)"},
    {"bad_atom_type.data", "line 22: Atoms", "atom type 3 is out of range 1..2"},
    {"bad_bond_missing_atom.data", "line 28: Bonds", "atom id 7 (column 4) is not in the Atoms section"},
    {"bad_bond_type.data", "line 27: Bonds",
     "type 2 is out of range 1..1 (the header declares 1 bond types on line 6)"},
    {"bad_self_bond.data", "line 27: Bonds", "expected 2 distinct atoms"},
    {"bad_duplicate_bond.data", "line 28: Bonds", "duplicate bond"},
    {"bad_velocity_id.data", "line 35: Velocities", "atom id 9 is not in the Atoms section"},
    {"bad_mass_zero.data", "line 15: Masses", "must be > 0"},
    {"bad_no_masses.data", "no Masses section", "atom type 1 (atom id 1, line 14) needs a mass"},
    {"bad_no_atom_types.data", "line 3: header", "expected at least 1 atom type"},
    {"bad_absurd_count.data", "line 3: header 'atoms'", "cannot fit in this file of 308 bytes"},
    {"bad_tilt.data", "line 11: header 'xy xz yz'", "expected an orthorhombic box"},
    {"bad_box.data", "line 9: header 'ylo yhi'", "expected lo < hi"},
    {"bad_unknown_header.data", "line 6: header: unknown keyword 'bond typez'", "expected 'atoms', 'bonds'"},
    {"bad_hint_mismatch.data", "line 19: Atoms", "the '# full' hint on line 17 expects 7 or 10 columns"},
    {"bad_ambiguous_columns.data", "line 19: Atoms", "cannot tell the atom style from 11 columns"},
    {"bad_unsupported_hint.data", "line 17: Atoms", "atom_style 'charge' (from the hint) is not supported"},
    {"bad_duplicate_section.data", "line 17: Masses", "section given twice (first on line 12)"},
    {"bad_section_not_declared.data", "line 30: Angles", "expected a 'N angles' header line"},
    {"bad_missing_bonds_section.data", "no Bonds section", "declares 3 bonds on line 4"},
    {"bad_empty.data", "file is empty", "expected a LAMMPS data file"},
    {"bad_fewer_bonds.data", "line 27: Bonds", "file ends after 2 of the 3 entries"},
    {"bad_more_atoms.data", "line 22: Atoms", "more entries than the 3 declared in the header"},
    {"bad_dihedral_atom.data", "line 33: Dihedrals", "atom id 9 (column 6) is not in the Atoms section"},
    {"bad_improper_repeat.data", "line 33: Impropers", "atom id 2 appears twice; expected 4 distinct atoms"},
    {"bad_coeffs_range.data", "line 20: Dihedral Coeffs",
     "type 2 is out of range 1..1 (the header declares 1 dihedral types on line 8)"},
    {"bad_coeffs_twice.data", "line 21: Dihedral Coeffs", "type 1 given twice; expected one row per type"},
};

TEST(MalformedData, EachNamesFileLineAndExpectation) {
  for (const BadCase& c : kBadData) {
    SCOPED_TRACE(c.file);
    const std::string path = data(c.file);
    const std::string e = input_error([&] { read_lammps_data(path); });
    EXPECT_EQ(e.rfind(path + ": ", 0), 0u) << e;
    EXPECT_NE(e.find(c.where), std::string::npos) << e;
    EXPECT_NE(e.find(c.expected), std::string::npos) << e;
    EXPECT_EQ(e.find('\n'), std::string::npos) << "one line: " << e;
  }
}

// ---------------------------------------------------------------------------------------------
// Angles, dihedrals, impropers and the "… Coeffs" sections: read, kept, written back.

void expect_same_topology_and_coeffs(const ImportedSystem& a, const ImportedSystem& b) {
  ASSERT_EQ(a.bonds.size(), b.bonds.size());
  for (size_t k = 0; k < a.bonds.size(); ++k)
    EXPECT_TRUE(a.bonds[k].type == b.bonds[k].type && a.bonds[k].i == b.bonds[k].i && a.bonds[k].j == b.bonds[k].j);
  ASSERT_EQ(a.angles.size(), b.angles.size());
  for (size_t k = 0; k < a.angles.size(); ++k) {
    const auto &p = a.angles[k], &q = b.angles[k];
    EXPECT_TRUE(p.type == q.type && p.i == q.i && p.j == q.j && p.k == q.k) << "angle " << k;
  }
  for (auto [qa, qb] : {std::pair{&a.dihedrals, &b.dihedrals}, std::pair{&a.impropers, &b.impropers}}) {
    ASSERT_EQ(qa->size(), qb->size());
    for (size_t k = 0; k < qa->size(); ++k) {
      const auto &p = (*qa)[k], &q = (*qb)[k];
      EXPECT_TRUE(p.type == q.type && p.i == q.i && p.j == q.j && p.k == q.k && p.l == q.l) << k;
    }
  }
  EXPECT_EQ(a.num_angle_types, b.num_angle_types);
  EXPECT_EQ(a.num_dihedral_types, b.num_dihedral_types);
  EXPECT_EQ(a.num_improper_types, b.num_improper_types);
  ASSERT_EQ(a.coeffs.size(), b.coeffs.size());
  for (size_t k = 0; k < a.coeffs.size(); ++k) {
    EXPECT_EQ(a.coeffs[k].name, b.coeffs[k].name);
    EXPECT_EQ(a.coeffs[k].style, b.coeffs[k].style);
    EXPECT_EQ(a.coeffs[k].rows, b.coeffs[k].rows);
  }
  EXPECT_EQ(a.x, b.x);
  EXPECT_EQ(a.type, b.type);
  EXPECT_EQ(a.type_mass, b.type_mass);
}

TEST(LammpsDataTopology, ReadsDihedralsImpropersAndCoefficientSections) {
  const ImportedSystem s = read_lammps_data(data("quads_full.data"));
  ASSERT_EQ(s.dihedrals.size(), 1u);
  EXPECT_EQ(s.dihedrals[0].type, 2);
  EXPECT_EQ((std::array{s.dihedrals[0].i, s.dihedrals[0].j, s.dihedrals[0].k, s.dihedrals[0].l}),
            (std::array{1, 0, 2, 3}));  // 0-based indices of atom ids 2 1 3 4
  ASSERT_EQ(s.impropers.size(), 1u);
  EXPECT_EQ(s.impropers[0].l, 3);
  EXPECT_EQ(s.num_dihedral_types, 2);
  EXPECT_EQ(s.num_improper_types, 1);
  ASSERT_EQ(s.coeffs.size(), 5u);
  EXPECT_EQ(s.coeffs[0].name, "PairIJ Coeffs");
  EXPECT_EQ(s.coeffs[0].style, "lj/cut");
  EXPECT_EQ(s.coeffs[0].rows, (std::vector<std::string>{"1 1 0.1 3.4", "1 2 0.05 3.0 8.0", "2 2 0.02 2.5"}));
  EXPECT_EQ(s.coeffs[3].name, "Dihedral Coeffs");
  EXPECT_EQ(s.coeffs[3].rows[1], "2 1.0 1.5 -0.5 0.2 0.125");
}

// Read, write, read: the same topology (bonds, angles, dihedrals, impropers with their types)
// and the same coefficient sections; and the written file, written again, is the same text.
TEST(LammpsDataTopology, RoundTripKeepsAnglesDihedralsImpropersAndCoefficients) {
  for (const char* name : {"quads_full.data", "butanes.data"}) {
    SCOPED_TRACE(name);
    const ImportedSystem a = read_lammps_data(data(name));
    const std::string once = scratch("once.data"), twice = scratch("twice.data");
    write_lammps_data(once, a, a.atom_style);
    const ImportedSystem b = read_lammps_data(once);
    expect_same_topology_and_coeffs(a, b);
    write_lammps_data(twice, b, b.atom_style);
    EXPECT_EQ(slurp(once), slurp(twice));
  }
  // An angle-style file cannot hold dihedrals: refused, not dropped.
  const ImportedSystem s = read_lammps_data(data("butanes.data"));
  EXPECT_NE(input_error([&] {
              write_lammps_data(scratch("angle.data"), s, "angle");
            }).find("atom_style angle cannot hold dihedrals or impropers"),
            std::string::npos);
}

TEST(MalformedData, MissingFileDirectoryAndGzip) {
  const std::string missing = data("no_such_file.data");
  EXPECT_EQ(input_error([&] { read_lammps_data(missing); }), missing + ": cannot open file (missing or unreadable)");
  const std::string dir = data("");
  EXPECT_NE(input_error([&] { read_lammps_data(dir); }).find("is a directory"), std::string::npos);
  const std::string gz = scratch("chain.data.gz");
  spit(gz, std::string("\x1f\x8b\x08\x00 binary", 11));
  EXPECT_EQ(input_error([&] { read_lammps_data(gz); }), gz + ": is gzip-compressed; decompress it first (gunzip)");
}

TEST(MalformedData, EveryTruncationOfAValidFileIsRefusedCleanly) {
  const std::string text = slurp(data("small_full.data"));
  const std::string path = scratch("cut.data");
  // Every cut short of the final "3\n" loses a declared entry or section, so each must be refused.
  for (size_t cut = 0; cut + 1 < text.size(); cut += 3) {
    spit(path, text.substr(0, cut));
    const std::string e = input_error([&] { read_lammps_data(path); });
    ASSERT_EQ(e.rfind(path + ": ", 0), 0u) << "cut at " << cut << ": " << e;
  }
}

// ---------------------------------------------------------------------------------------------
// Writer refusals: what LAMMPS could not read back.

TEST(WriteLammpsData, RefusesWhatLammpsCannotRead) {
  ImportedSystem s = read_lammps_data(data("small_full.data"));
  const std::string out = scratch("refused.data");
  EXPECT_NE(input_error([&] { write_lammps_data(out, s, "atomic"); }).find("atom_style atomic cannot hold bonds"),
            std::string::npos);
  EXPECT_NE(input_error([&] { write_lammps_data(out, s, "bond"); }).find("atom_style bond cannot hold angles"),
            std::string::npos);
  EXPECT_NE(input_error([&] { write_lammps_data(out, s, "charge"); }).find("atom_style 'charge' is not supported"),
            std::string::npos);
  ImportedSystem no_mass = s;
  no_mass.type_mass.erase(2);
  EXPECT_NE(input_error([&] { write_lammps_data(out, no_mass, "full"); }).find("atom type 2 has no mass"),
            std::string::npos);
  ImportedSystem flat = s;
  flat.hi[1] = flat.lo[1];
  EXPECT_NE(input_error([&] { write_lammps_data(out, flat, "full"); }).find("expected finite lo < hi"),
            std::string::npos);
  ImportedSystem short_types = s;
  short_types.type.pop_back();
  EXPECT_NE(input_error([&] { write_lammps_data(out, short_types, "full"); }).find("type has 4 entries, expected 5"),
            std::string::npos);
  ImportedSystem dangling = s;
  dangling.bonds[0].j = 9;
  EXPECT_NE(input_error([&] { write_lammps_data(out, dangling, "full"); }).find("bond 0 refers to atom index 9"),
            std::string::npos);
  ImportedSystem nan = s;
  nan.x(1, 3) = std::numeric_limits<double>::quiet_NaN();
  EXPECT_THROW(write_lammps_data(out, nan, "full"), NumericalError);
  EXPECT_NE(input_error([&] {
              write_lammps_data(data("no_such_dir/x.data"), s, "full");
            }).find("cannot open the file for writing"),
            std::string::npos);
}

// ---------------------------------------------------------------------------------------------
// XYZ + bond list.

TEST(XyzWithBonds, ExtendedXyz) {
  const ImportedSystem s = read_xyz_with_bonds(data("small.xyz"), data("small.bonds"));
  ASSERT_EQ(s.x.cols(), 4);
  EXPECT_EQ(s.type, (std::vector<int>{1, 1, 2, 3}));
  EXPECT_EQ(s.type_names, (std::vector<std::string>{"C", "O", "H"}));
  EXPECT_EQ(s.num_atom_types, 3);
  EXPECT_EQ(s.x.col(3), Eigen::Vector3d(9.25, -3.0, 0.1));
  EXPECT_EQ(s.v.col(0), Eigen::Vector3d(0.1, 0.2, 0.3));
  EXPECT_EQ(s.v.col(2), Eigen::Vector3d(-1, -2, -3));
  EXPECT_EQ(s.lo, Eigen::Vector3d(-5, -6, -7));
  EXPECT_EQ(s.hi, Eigen::Vector3d(5, 6, 7));
  EXPECT_EQ(s.id, (std::vector<long>{1, 2, 3, 4}));
  EXPECT_EQ(s.molecule, std::vector<int>(4, 0));
  EXPECT_TRUE(s.type_mass.empty());
  ASSERT_EQ(s.bonds.size(), 3u);
  EXPECT_EQ(s.bonds[1].i, 1);
  EXPECT_EQ(s.bonds[1].j, 2);
  EXPECT_EQ(s.bonds[1].type, 2);
  EXPECT_EQ(s.bonds[0].type, 1);
  EXPECT_EQ(s.num_bond_types, 2);
}

TEST(XyzWithBonds, PlainXyzWithNumericSpecies) {
  const ImportedSystem s = read_xyz_with_bonds(data("plain.xyz"), data("plain.bonds"));
  EXPECT_EQ(s.type, (std::vector<int>{1, 2, 1}));
  EXPECT_TRUE(s.type_names.empty());
  EXPECT_EQ(s.x.col(2), Eigen::Vector3d(2, 0, 0));
  EXPECT_TRUE(s.v.isZero());
  EXPECT_EQ(s.lo, s.hi);  // no Lattice: no box
  EXPECT_EQ(s.bonds.size(), 2u);
}

TEST(XyzWithBonds, ExportsToLammpsOnceGivenABoxAndMasses) {
  ImportedSystem s = read_xyz_with_bonds(data("small.xyz"), data("small.bonds"));
  s.type_mass = {{1, 12.011}, {2, 15.999}, {3, 1.008}};
  const std::string out = scratch("from_xyz.data");
  write_lammps_data(out, s, "bond");
  const ImportedSystem back = read_lammps_data(out);
  EXPECT_TRUE(bitwise_equal(s.x, back.x));
  EXPECT_TRUE(bitwise_equal(s.v, back.v));
  EXPECT_EQ(s.type, back.type);
}

// Malformed XYZ files (read with small.bonds) and bond lists (read with two.xyz): the message
// after "PATH: ".
const std::pair<const char*, const char*> kBadXyz[] = {
    {"bad_truncated.xyz", "line 4: file ends after 2 of the 3 atom lines declared on line 1"},
    {"bad_count.xyz", "line 1: expected the atom count (a non-negative integer), found 'three'"},
    {"bad_non_numeric.xyz", "line 3: z is 'zero'; expected a finite number"},
    {"bad_columns.xyz", "line 3: expected 4 columns 'species x y z', found 5 columns"},
    {"bad_no_pos.xyz", "line 2: Properties has no pos:R:3"},
    {"bad_lattice.xyz", "line 2: Lattice: tilted cells are not supported; expected a diagonal"},
};
const std::pair<const char*, const char*> kBadBonds[] = {
    {"bad_range.bonds", "line 1: bond: atom index 2 is out of range 0..1"},
    {"bad_self.bonds", "line 1: bond: atom 1 is bonded to itself"},
    {"bad_duplicate.bonds", "line 2: bond: duplicate bond between atoms 0 and 1"},
    {"bad_non_integer.bonds", "line 1: bond: 'one' is not an integer; expected a 0-based atom index"},
    {"bad_type.bonds", "line 1: bond: type '0' is not an integer >= 1"},
    {"bad_columns.bonds", "line 1: bond: expected 'i j [type]', found 4 columns"},
};

TEST(XyzWithBonds, MalformedXyz) {
  for (const auto& [file, expected] : kBadXyz) {
    const std::string path = data(file);
    const std::string e = input_error([&] { read_xyz_with_bonds(path, data("small.bonds")); });
    EXPECT_EQ(e.rfind(path + ": " + expected, 0), 0u) << e;
  }
  const std::string huge = scratch("huge.xyz");
  spit(huge, "1000000000000000\ncomment\nC 0 0 0\n");
  EXPECT_NE(input_error([&] {
              read_xyz_with_bonds(huge, data("small.bonds"));
            }).find("line 1: atom count 1000000000000000 cannot fit"),
            std::string::npos);
  const std::string gz = scratch("traj.xyz.gz");
  spit(gz, std::string("\x1f\x8b\x08", 3));
  EXPECT_NE(input_error([&] { read_xyz_with_bonds(gz, data("small.bonds")); }).find("gzip-compressed"),
            std::string::npos);
  EXPECT_NE(input_error([&] {
              read_xyz_with_bonds(data("nope.xyz"), data("small.bonds"));
            }).find("nope.xyz: cannot open file"),
            std::string::npos);
}

TEST(XyzWithBonds, MalformedBonds) {
  for (const auto& [file, expected] : kBadBonds) {
    const std::string path = data(file);
    const std::string e = input_error([&] { read_xyz_with_bonds(data("two.xyz"), path); });
    EXPECT_EQ(e.rfind(path + ": " + expected, 0), 0u) << e;
  }
  EXPECT_NE(input_error([&] {
              read_xyz_with_bonds(data("two.xyz"), data("nope.bonds"));
            }).find("nope.bonds: cannot open file"),
            std::string::npos);
}

// ---------------------------------------------------------------------------------------------
// The same malformed files through the real command line: a deck that imports each one, run by
// `stiffmd run`, must exit 2 (no crash, no hang) with exactly one line on stderr that names the
// deck line of the import key, the data file and its line (or section) and the expectation —
// and must write nothing to the output directory.

struct CliRun {
  int code;
  std::string err;
  bool wrote_output;
};

CliRun run_import_deck(const std::string& import_lines, const std::string& name) {
  const std::string deck = scratch(name + ".toml");
  spit(deck,
       "[types.bead]\nmass = 1.0\n\n[types.heavy]\nmass = 2.5\n\n[import]\n" + import_lines +
           "\n[forces.springs]\nstyle = \"stiff-harmonic\"\nepsilon = 0.01\n"
           "bond_types.b = { length = 1.0, alpha = 1.0 }\n\n[integrator]\nmethod = \"velocity-verlet\"\nh = 0.001\n\n"
           "[run]\nt_end = 0.01\n");
  const std::string out = scratch(name + "_out"), err = scratch(name + ".err");
  const std::string cmd =
      "timeout 60 " + std::string(STIFFMD_EXE) + " run " + deck + " --no-progress -o " + out + " > /dev/null 2> " + err;
  const int status = std::system(cmd.c_str());
  return {WIFEXITED(status) ? WEXITSTATUS(status) : 128 + WTERMSIG(status), slurp(err), fs::exists(out)};
}

::testing::AssertionResult one_line_naming(const CliRun& r, const std::string& deck, const std::string& file,
                                           const std::vector<std::string>& texts) {
  if (r.code != 2) return ::testing::AssertionFailure() << "exit " << r.code << ": " << r.err;
  if (std::count(r.err.begin(), r.err.end(), '\n') != 1)
    return ::testing::AssertionFailure() << "not one line: " << r.err;
  if (r.wrote_output) return ::testing::AssertionFailure() << "the output directory was created";
  if (r.err.find(deck + ":") == std::string::npos) return ::testing::AssertionFailure() << "no deck line: " << r.err;
  if (r.err.find(file + ": ") == std::string::npos) return ::testing::AssertionFailure() << "no file: " << r.err;
  for (const auto& t : texts)
    if (r.err.find(t) == std::string::npos) return ::testing::AssertionFailure() << "no '" << t << "': " << r.err;
  return ::testing::AssertionSuccess();
}

TEST(MalformedDataCli, EachLammpsFileThroughADeck) {
  for (const BadCase& c : kBadData) {
    const std::string path = data(c.file), name = fs::path(c.file).stem().string();
    const CliRun r = run_import_deck("lammps_data = \"" + path +
                                         "\"\natom_types = { \"1\" = \"bead\", \"2\" = \"heavy\" }\n"
                                         "bond_types = { \"1\" = \"b\" }\n",
                                     name);
    EXPECT_TRUE(one_line_naming(r, scratch(name + ".toml"), path, {"import.lammps_data", c.where, c.expected}))
        << c.file;
  }
}

TEST(MalformedDataCli, EachXyzAndBondsFileThroughADeck) {
  for (const auto& [file, expected] : kBadXyz) {
    const std::string path = data(file), name = fs::path(file).stem().string() + "_xyz";
    const CliRun r = run_import_deck("xyz = \"" + path + "\"\nbonds = \"" + data("small.bonds") + "\"\n", name);
    EXPECT_TRUE(one_line_naming(r, scratch(name + ".toml"), path, {"import.xyz", expected})) << file;
  }
  for (const auto& [file, expected] : kBadBonds) {
    const std::string path = data(file), name = fs::path(file).stem().string() + "_bonds";
    const CliRun r = run_import_deck("xyz = \"" + data("two.xyz") + "\"\nbonds = \"" + path + "\"\n", name);
    EXPECT_TRUE(one_line_naming(r, scratch(name + ".toml"), path, {"import.bonds", expected})) << file;
  }
}

// Every malformed file in tests/data is in one of the tables above, so all of them go through the
// command line (the scene_*.data files, readable but refused by a deck, have decks in
// tests/bad_decks).
TEST(MalformedDataCli, EveryBadFileIsCovered) {
  std::set<std::string> listed;
  for (const BadCase& c : kBadData) listed.insert(c.file);
  for (const auto& [file, expected] : kBadXyz) listed.insert(file);
  for (const auto& [file, expected] : kBadBonds) listed.insert(file);
  int bad = 0;
  for (const auto& e : fs::directory_iterator(data(""))) {
    const std::string name = e.path().filename().string();
    if (name.rfind("bad_", 0) != 0) continue;
    ++bad;
    EXPECT_TRUE(listed.count(name)) << name << " is not run through the command line";
  }
  EXPECT_EQ(bad, static_cast<int>(listed.size()));
}

}  // namespace
}  // namespace stiffmd
