// Whole molecules and one bond vector (core/state.hpp): wrapped inputs are unwrapped along the
// bonds at load, what cannot be made whole is refused, and the stiff-bond rules shared by the
// force term, the constraint toolbox and the stiff modes (forcefields/stiff_bond.hpp).
#include <gtest/gtest.h>

#include <cmath>
#include <filesystem>
#include <fstream>

#include "core/errors.hpp"
#include "engine/io/lammps_data.hpp"
#include "engine/scene/whole_molecules.hpp"
#include "forcefields/stiff_bond.hpp"
#include "forcefields/stiff_harmonic_bond.hpp"
#include "integrators/constraints.hpp"
#include "integrators/modes.hpp"
#include "tests/cli_support.hpp"
#include "tests/test_support.hpp"

namespace stiffmd {
namespace {

namespace fs = std::filesystem;
using namespace test;

std::vector<std::pair<int, int>> pairs_of(const ImportedSystem& s) {
  std::vector<std::pair<int, int>> p;
  for (const auto& b : s.bonds) p.emplace_back(b.i, b.j);
  return p;
}

Box cube(double L) {
  Box box;
  box.lengths = Eigen::Vector3d::Constant(L);
  box.periodic = Eigen::Vector3i::Ones();
  return box;
}

// tests/data/wrapped_chains.data: two chains of unit bonds crossing the x and z faces, wrapped,
// no image flags; wrapped_chains_images.data: the same atoms with the image flags of the
// unwrapped chains (the reference).
TEST(WholeMolecules, WrappedDataFileBecomesTheUnwrappedReferenceUpToOneBoxVectorPerMolecule) {
  ImportedSystem wrapped = read_lammps_data(source_path("tests/data/wrapped_chains.data"));
  const ImportedSystem ref = read_lammps_data(source_path("tests/data/wrapped_chains_images.data"));
  ASSERT_FALSE(wrapped.image_flags);
  ASSERT_TRUE(ref.image_flags);
  const Box box = cube(6.0);
  // Before: some raw bond differences jump by a box length.
  double worst_before = 0.0;
  for (const auto& [i, j] : pairs_of(wrapped))
    worst_before = std::max(worst_before, std::abs((wrapped.x.col(i) - wrapped.x.col(j)).norm() - 1.0));
  ASSERT_GT(worst_before, 2.0);
  ASSERT_FALSE(make_molecules_whole(wrapped.x, pairs_of(wrapped), box));
  for (const auto& [i, j] : pairs_of(wrapped))
    EXPECT_NEAR(bond_vector(wrapped.x, i, j).norm(), 1.0, 1e-13) << "bond " << i << "-" << j;
  // Same as the reference up to one whole box vector per molecule.
  for (int m : {1, 2}) {
    Eigen::Vector3d shift = Eigen::Vector3d::Constant(NAN);
    for (int k = 0; k < wrapped.x.cols(); ++k) {
      if (wrapped.molecule[k] != m) continue;
      const Eigen::Vector3d s = (wrapped.x.col(k) - ref.x.col(k)) / 6.0;
      for (int a = 0; a < 3; ++a) EXPECT_NEAR(s[a], std::round(s[a]), 1e-12);
      if (std::isnan(shift[0])) shift = s.array().round();
      EXPECT_EQ(s.array().round().matrix(), shift) << "atom " << k << " of molecule " << m;
    }
  }
  // Whole already: nothing moves, bit for bit.
  Eigen::Matrix3Xd again = wrapped.x;
  ASSERT_FALSE(make_molecules_whole(again, pairs_of(wrapped), box));
  EXPECT_TRUE((again.array() == wrapped.x.array()).all());
  // The reference itself is whole as its image flags unwrap it.
  Eigen::Matrix3Xd r = ref.x;
  EXPECT_FALSE(make_molecules_whole(r, pairs_of(ref), box, true));
}

TEST(WholeMolecules, RefusesWhatCannotBeMadeWholeAndLeavesThePositions) {
  const Box box = cube(9.0);
  Eigen::Matrix3Xd x(3, 3);
  x << 0, 3, 6, 1, 1, 1, 1, 1, 1;
  const Eigen::Matrix3Xd x0 = x;
  // A ring around the periodic x axis: closes only across a box length.
  auto p = make_molecules_whole(x, {{0, 1}, {1, 2}, {2, 0}}, box);
  ASSERT_TRUE(p);
  EXPECT_EQ(p->bond, 1);  // breadth first from 0: bonds 0 and 2 form the tree, 1 closes the ring
  EXPECT_NE(p->what.find("closes a ring only across"), std::string::npos) << p->what;
  EXPECT_TRUE((x.array() == x0.array()).all());
  // The same three as a chain are fine (0 → 3 → 6).
  EXPECT_FALSE(make_molecules_whole(x, {{0, 1}, {1, 2}}, box));
  // Image flags that put a bond across more than half the box.
  Eigen::Matrix3Xd y(3, 2);
  y << 0, 6, 0, 0, 0, 0;
  p = make_molecules_whole(y, {{0, 1}}, box, true);
  ASSERT_TRUE(p);
  EXPECT_NE(p->what.find("at least half the periodic box length 9"), std::string::npos) << p->what;
  // Without image flags the same bond is unwrapped to its minimum image, length 3.
  ASSERT_FALSE(make_molecules_whole(y, {{0, 1}}, box));
  EXPECT_EQ(y(0, 1), -3.0);
  // Exactly half a box: ambiguous. One box length apart: zero length once whole.
  Eigen::Matrix3Xd h(3, 2);
  h << 0, 4.5, 0, 0, 0, 0;
  p = make_molecules_whole(h, {{0, 1}}, box);
  ASSERT_TRUE(p);
  EXPECT_NE(p->what.find("ambiguous"), std::string::npos) << p->what;
  h(0, 1) = 9.0;
  p = make_molecules_whole(h, {{0, 1}}, box);
  ASSERT_TRUE(p);
  EXPECT_NE(p->what.find("zero length"), std::string::npos) << p->what;
}

// Without [prepare], the wrapped file runs with max |g| at round-off and a sane end-to-end
// distance (before: max |g| 8.2 at the crossing bonds, or an end-to-end distance of a box).
TEST(WholeMolecules, WrappedImportRunsWholeWithoutPrepare) {
  const std::string lammps = "[import]\nlammps_data = \"" + source_path("tests/data/wrapped_chains.data") +
                             "\"\natom_types = { \"1\" = \"bead\" }\nbond_types = { \"1\" = \"b\" }\n";
  // The XYZ + bonds import takes its box from the deck; its molecules are the bonded components.
  const std::string xyz = "[box]\nperiodic = true\nlengths = [6, 6, 6]\n[import]\nxyz = \"" +
                          source_path("tests/data/wrapped_chains.xyz") + "\"\nbonds = \"" +
                          source_path("tests/data/wrapped_chains.bonds") + "\"\nbond_type = \"b\"\n";
  for (const auto& [name, import] : {std::pair{"lammps", lammps}, std::pair{"xyz", xyz}}) {
    const fs::path dir = scratch_dir(std::string("wrapped_import_") + name);
    std::ofstream(dir / "deck.toml") << "[types.bead]\nmass = 1.0\n"
                                     << import
                                     << "[forces.springs]\nstyle = \"stiff-harmonic\"\nepsilon = 0.01\n"
                                        "bond_types.b = { length = 1.0, alpha = 1.0 }\n"
                                        "[integrator]\nmethod = \"projected-impulse\"\nh = 0.01\nmicro_steps = 10\n"
                                        "[run]\nt_end = 0.1\n[output]\nxyz = \"\"\n";
    const CliResult r = cli("run " + (dir / "deck.toml").string() + " -o " + (dir / "out").string() + " --no-progress");
    ASSERT_EQ(r.code, 0) << name << ": " << r.err;
    const CsvTable t = read_csv((dir / "out" / "thermo.csv").string());
    for (const auto& row : t.rows) {
      EXPECT_LT(row[t.col("max_violation")], 1e-12) << name;
      EXPECT_LT(row[t.col("end_to_end")], 7.0) << name;  // 7 unit bonds
      EXPECT_GT(row[t.col("end_to_end")], 1.0) << name;
      EXPECT_LT(row[t.col("rg")], 3.0) << name;
    }
  }
}

TEST(StiffBondRules, OneValidationForTermToolboxAndModes) {
  const Eigen::VectorXd free3 = Eigen::VectorXd::Ones(3);
  auto triangle = [](double c) { return std::vector<StiffBond>{{0, 1, 1.0, 1.0}, {1, 2, 1.0, 1.0}, {2, 0, c, 1.0}}; };
  EXPECT_FALSE(find_stiff_bond_problem(triangle(1.9), &free3));
  for (double c : {2.0, 3.0, 0.1 + 0.2 + 1.7}) {  // 2: only collinear; 3: none at all
    const auto p = find_stiff_bond_problem(triangle(c), &free3);
    ASSERT_TRUE(p) << c;
    EXPECT_EQ(p->bond, 2);
    EXPECT_NE(p->what.find("no configuration satisfies"), std::string::npos) << p->what;
    EXPECT_THROW(ConstraintToolbox(triangle(c), free3), InputError);
    EXPECT_THROW(StiffModes(triangle(c), free3, 0.01), InputError);
    StiffBonds sb{triangle(c), 0.01};
    EXPECT_THROW(StiffHarmonicBond("b", Level::fast, sb), std::invalid_argument);
  }
  // Any bond of the cycle may be the long one; a short edge with a long detour is fine.
  const std::vector<StiffBond> square_diagonal = {
      {0, 1, 1.0, 1.0}, {1, 2, 1.0, 1.0}, {2, 3, 1.0, 1.0}, {3, 0, 1.0, 1.0}, {0, 2, 1.5, 1.0}};
  const Eigen::VectorXd free4 = Eigen::VectorXd::Ones(4);
  EXPECT_FALSE(find_stiff_bond_problem(square_diagonal, &free4));
  auto bad = square_diagonal;
  bad[4].length = 2.5;
  EXPECT_TRUE(find_stiff_bond_problem(bad, &free4));
  bad = square_diagonal;
  bad[1].length = 3.0;  // longer than 1 + 1.5 and than 1 + 1 + 1
  EXPECT_TRUE(find_stiff_bond_problem(bad, &free4));
  // Two fixed ends: refused where the masses are known.
  Eigen::VectorXd fixed = free3;
  fixed[0] = fixed[1] = 0.0;
  const std::vector<StiffBond> pinned = {{0, 1, 1.0, 1.0}, {1, 2, 1.0, 1.0}};
  const auto p = find_stiff_bond_problem(pinned, &fixed);
  ASSERT_TRUE(p);
  EXPECT_NE(p->what.find("two fixed particles"), std::string::npos);
  EXPECT_FALSE(find_stiff_bond_problem(pinned, nullptr));
  // A long chain and rings pass quickly.
  std::vector<StiffBond> chain;
  for (int k = 0; k + 1 < 100000; ++k) chain.push_back({k, k + 1, 0.97, 1.0});
  chain.push_back({0, 23, 0.97, 1.0});  // closes a ring of 24
  const Eigen::VectorXd many = Eigen::VectorXd::Ones(100000);
  EXPECT_FALSE(find_stiff_bond_problem(chain, &many));
}

}  // namespace
}  // namespace stiffmd
