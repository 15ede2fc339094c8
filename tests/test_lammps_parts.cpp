// A LAMMPS data file read by parts (engine/io/lammps_data_parts.hpp) on 1–4 fake ranks
// (tests/fake_processes.hpp), from a file written of the decomposition's straddling melt
// (tests/decomposition_fixtures.hpp: chains across every periodic face and across the faces of any
// grid of up to 4 slabs per axis, a molecule joined by an angle alone, lone atoms outside the box,
// heavy beads).
//
// What must hold: the parts tile the whole import (read_lammps_data) — every atom in exactly one
// part, with the whole import's position, velocity, type, molecule id and charge bit for bit, and
// every bond and angle in the part of its atoms, as the whole import has it — and each rank's part
// is the set of particles Decomposition::distribute gives it on the whole scene (the same anchor
// to the last bit), for any rank count; a file whose ids are neither 1 … N nor in order tiles too;
// each kept item carries its place in the whole import's list, each atom its molecule id's rank
// among the file's; and the parts by block are whole_block's blocks of the import.
#include <gtest/gtest.h>
#include <unistd.h>

#include <algorithm>
#include <array>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <numeric>
#include <set>
#include <string>
#include <vector>

#include "core/errors.hpp"
#include "decomposition_fixtures.hpp"
#include "engine/domain/decomposition.hpp"
#include "engine/domain/part_molecules.hpp"
#include "engine/io/lammps_data.hpp"
#include "engine/io/lammps_data_parts.hpp"
#include "fake_processes.hpp"

namespace stiffmd {
namespace {

namespace fs = std::filesystem;

fs::path temp_file(const std::string& name) {
  return fs::temp_directory_path() / ("stiffmd_test_lammps_parts_" + std::to_string(::getpid()) + "_" + name);
}

// The melt as a data file: heavy beads are type 2 (mass 10), the others type 1; ids 1 … N in order
// unless `scrambled` (ids 3 p + 5, written in a permuted order).
ImportedSystem melt_system(const fake::Melt& melt, bool scrambled) {
  ImportedSystem s;
  const int n = melt.size();
  s.x = melt.state.x;
  s.v = melt.state.v;
  s.type.resize(n);
  s.molecule.resize(n);
  s.id.resize(n);
  for (int i = 0; i < n; ++i) {
    s.type[i] = melt.state.inv_mass[i] < 1.0 ? 2 : 1;
    s.molecule[i] = melt.label[i] + 1;
    s.id[i] = scrambled ? 3L * i + 5 : i + 1;
  }
  s.type_mass = {{1, 1.0}, {2, 10.0}};
  for (const Bond& b : melt.topology.bonds) s.bonds.push_back({1, b.i, b.j});
  for (const Angle& a : melt.topology.angles) s.angles.push_back({1, a.i, a.j, a.k});
  s.lo = melt.box.origin;
  s.hi = melt.box.origin + melt.box.lengths;
  s.num_atom_types = 2;
  s.num_bond_types = 1;
  s.num_angle_types = 1;
  if (scrambled) {  // the rows in another order: p → 5p mod n
    int step = 5;
    while (std::gcd(step, n) != 1) ++step;
    ImportedSystem t = s;
    std::vector<int> at(n);
    for (int p = 0; p < n; ++p) {
      const int i = static_cast<int>((static_cast<long>(step) * p) % n);
      at[i] = p;
      t.x.col(p) = s.x.col(i), t.v.col(p) = s.v.col(i);
      t.type[p] = s.type[i], t.molecule[p] = s.molecule[i], t.id[p] = s.id[i];
    }
    for (auto& b : t.bonds) b.i = at[b.i], b.j = at[b.j];
    for (auto& a : t.angles) a.i = at[a.i], a.j = at[a.j], a.k = at[a.k];
    return t;
  }
  return s;
}

// The whole import as a scene holds it: topology by index, inverse masses 1/m of the types.
struct Whole {
  ImportedSystem in;
  Topology topology;
  State state;
  Box box;
};

Whole whole_import(const std::string& path) {
  Whole w;
  w.in = read_lammps_data(path);
  const int n = static_cast<int>(w.in.x.cols());
  w.topology.bond_types = {"1"};
  w.topology.angle_types = {"1"};
  for (const auto& b : w.in.bonds) w.topology.bonds.push_back({b.i, b.j, 0});
  for (const auto& a : w.in.angles) w.topology.angles.push_back({a.i, a.j, a.k, 0});
  w.state.x = w.in.x;
  w.state.v = w.in.v;
  w.state.inv_mass.resize(n);
  for (int i = 0; i < n; ++i) w.state.inv_mass[i] = 1.0 / w.in.type_mass.at(w.in.type[i]);
  w.box.origin = w.in.lo;
  w.box.lengths = w.in.hi - w.in.lo;
  w.box.periodic = Eigen::Vector3i::Ones();
  return w;
}

bool same_bits(const Eigen::Vector3d& a, const Eigen::Vector3d& b) {
  return std::memcmp(a.data(), b.data(), sizeof(double) * 3) == 0;
}

// Every rank's part checked against the whole import; returns the parts' global indices.
void expect_tiling(const Whole& w, const std::vector<ImportedPart>& parts) {
  const int n = static_cast<int>(w.in.x.cols());
  std::vector<int> owner(n, -1);
  std::multiset<std::array<int, 3>> bonds, angles;
  for (size_t r = 0; r < parts.size(); ++r) {
    const ImportedPart& p = parts[r];
    const ImportedSystem& s = p.system;
    EXPECT_EQ(p.num_atoms, n);
    ASSERT_EQ(s.x.cols(), static_cast<long>(p.global.size()));
    EXPECT_TRUE(std::is_sorted(p.global.begin(), p.global.end()));
    for (size_t k = 0; k < p.global.size(); ++k) {
      const int g = p.global[k];
      ASSERT_TRUE(g >= 0 && g < n);
      EXPECT_EQ(owner[g], -1) << "atom " << g << " in two parts";
      owner[g] = static_cast<int>(r);
      EXPECT_TRUE(same_bits(s.x.col(k), w.in.x.col(g))) << "atom " << g;
      EXPECT_TRUE(same_bits(s.v.col(k), w.in.v.col(g))) << "atom " << g;
      EXPECT_EQ(s.type[k], w.in.type[g]);
      EXPECT_EQ(s.molecule[k], w.in.molecule[g]);
      EXPECT_EQ(s.id[k], w.in.id[g]);
    }
    for (const auto& b : s.bonds) bonds.insert({b.type, p.global[b.i], p.global[b.j]});
    for (const auto& a : s.angles) angles.insert({p.global[a.i], p.global[a.j], p.global[a.k]});
    // Each item's place: its index in the whole import's list, in increasing order.
    ASSERT_EQ(p.bond_place.size(), s.bonds.size());
    ASSERT_EQ(p.angle_place.size(), s.angles.size());
    EXPECT_TRUE(std::is_sorted(p.bond_place.begin(), p.bond_place.end()));
    for (size_t e = 0; e < s.bonds.size(); ++e) {
      const auto& want = w.in.bonds[static_cast<size_t>(p.bond_place[e])];
      EXPECT_EQ(want.type, s.bonds[e].type);
      EXPECT_EQ(want.i, p.global[s.bonds[e].i]);
      EXPECT_EQ(want.j, p.global[s.bonds[e].j]);
    }
    for (size_t e = 0; e < s.angles.size(); ++e) {
      const auto& want = w.in.angles[static_cast<size_t>(p.angle_place[e])];
      EXPECT_EQ(want.i, p.global[s.angles[e].i]);
      EXPECT_EQ(want.j, p.global[s.angles[e].j]);
      EXPECT_EQ(want.k, p.global[s.angles[e].k]);
    }
    // The molecule ids' ranks among the file's distinct ids.
    ASSERT_EQ(p.molecule_rank.size(), p.global.size());
    std::vector<int> ids(w.in.molecule.begin(), w.in.molecule.end());
    std::sort(ids.begin(), ids.end());
    ids.erase(std::unique(ids.begin(), ids.end()), ids.end());
    for (size_t k = 0; k < p.global.size(); ++k)
      EXPECT_EQ(ids[static_cast<size_t>(p.molecule_rank[k])], w.in.molecule[static_cast<size_t>(p.global[k])]);
    EXPECT_EQ(p.types_used.atom, (std::vector<int>{1, 2}));
    EXPECT_EQ(p.types_used.bond, (std::vector<int>{1}));
    EXPECT_EQ(s.type_mass, w.in.type_mass);
    EXPECT_EQ(s.lo, w.in.lo);
    EXPECT_EQ(s.hi, w.in.hi);
    EXPECT_TRUE(s.image_flags);
  }
  for (int g = 0; g < n; ++g) EXPECT_GE(owner[g], 0) << "atom " << g << " in no part";
  std::multiset<std::array<int, 3>> whole_bonds, whole_angles;
  for (const auto& b : w.in.bonds) whole_bonds.insert({b.type, b.i, b.j});
  for (const auto& a : w.in.angles) whole_angles.insert({a.i, a.j, a.k});
  EXPECT_EQ(bonds, whole_bonds);
  EXPECT_EQ(angles, whole_angles);
}

class LammpsParts : public ::testing::TestWithParam<int> {};

TEST_P(LammpsParts, EachRankKeepsTheMoleculesDecompositionGivesItAndThePartsTileTheImport) {
  const fake::Melt melt = fake::straddling_melt();
  const fs::path path = temp_file("dense.data");
  write_lammps_data(path.string(), melt_system(melt, false), "molecular");
  const Whole w = whole_import(path.string());
  const int ranks = GetParam();
  std::vector<ImportedPart> parts(ranks);
  std::vector<std::vector<int>> owned(ranks);
  fake::run_ranks(ranks, [&](const Communicator& comm) {
    Decomposition d(w.box, comm, 2.5, 0.8, nullptr);
    Eigen::Matrix3Xd x, v;
    d.distribute(w.topology, w.state, x, v);
    owned[comm.rank()] = d.owned_ids();
    const DomainGrid grid = d.grid();
    parts[comm.rank()] = read_lammps_data_part(
        path.string(), "auto", [&](const Eigen::Vector3d& anchor) { return grid.domain_of(anchor) == comm.rank(); });
  });
  fs::remove(path);
  expect_tiling(w, parts);
  for (int r = 0; r < ranks; ++r) {
    EXPECT_EQ(parts[r].global, owned[r]) << "rank " << r;
    EXPECT_EQ(parts[r].num_molecules, melt.molecules);
  }
}

TEST_P(LammpsParts, AFileWithScatteredIdsInAnyOrderTilesTheImport) {
  const fake::Melt melt = fake::straddling_melt();
  const fs::path path = temp_file("scrambled.data");
  write_lammps_data(path.string(), melt_system(melt, true), "molecular");
  const Whole w = whole_import(path.string());
  const int ranks = GetParam();
  Box box = w.box;
  const DomainGrid grid = make_domain_grid(box, ranks, nullptr, Eigen::Matrix3Xd());
  std::vector<ImportedPart> parts;
  for (int r = 0; r < ranks; ++r)
    parts.push_back(read_lammps_data_part(path.string(), "auto",
                                          [&](const Eigen::Vector3d& anchor) { return grid.domain_of(anchor) == r; }));
  fs::remove(path);
  expect_tiling(w, parts);
}

TEST_P(LammpsParts, EachBlockOfMoleculesIsWholeBlocksAndTheBlocksTileTheImport) {
  const fake::Melt melt = fake::straddling_melt();
  const int ranks = GetParam();
  for (const bool scrambled : {false, true}) {
    const fs::path path = temp_file(scrambled ? "blocks_scrambled.data" : "blocks.data");
    write_lammps_data(path.string(), melt_system(melt, scrambled), "molecular");
    const Whole w = whole_import(path.string());
    std::vector<ImportedPart> parts;
    for (int r = 0; r < ranks; ++r) {
      parts.push_back(read_lammps_data_part(path.string(), "auto", KeepBlock{r, ranks}));
      EXPECT_EQ(parts.back().global, whole_block(w.topology, static_cast<int>(w.in.x.cols()), ranks, r));
    }
    fs::remove(path);
    expect_tiling(w, parts);
  }
}

INSTANTIATE_TEST_SUITE_P(Ranks, LammpsParts, ::testing::Values(1, 2, 3, 4),
                         [](const ::testing::TestParamInfo<int>& info) {
                           return std::to_string(info.param) + "_ranks";
                         });

TEST(LammpsParts, BondedTermsWithoutImageFlagsAreRefusedNamingTheFile) {
  const fs::path path = temp_file("noimages.data");
  {
    std::ofstream out(path);
    out << "title\n\n2 atoms\n1 bonds\n1 atom types\n1 bond types\n0 4 xlo xhi\n0 4 ylo yhi\n0 4 zlo zhi\n\n"
           "Masses\n\n1 1.0\n\nAtoms # bond\n\n1 1 1 0.5 0.5 0.5\n2 1 1 1.5 0.5 0.5\n\nBonds\n\n1 1 1 2\n";
  }
  try {
    read_lammps_data_part(path.string(), "auto", [](const Eigen::Vector3d&) { return true; });
    ADD_FAILURE() << "no error";
  } catch (const InputError& e) {
    EXPECT_NE(std::string(e.what()).find(path.string() + ": Atoms: no image flags"), std::string::npos) << e.what();
  }
  fs::remove(path);
}

}  // namespace
}  // namespace stiffmd
