// A rank's molecules made by their source (engine/domain/part_load.hpp): the linear chains built by
// molecule and a LAMMPS data file read by blocks, with velocities by particle or the file's, give
// on each of 1–4 fake ranks (tests/fake_processes.hpp) exactly the block the whole path cuts from
// the whole scene (whole_block and cut_part, engine/domain/part_molecules.hpp) — global indices,
// inverse masses, types, charges, molecule ids, Langevin frictions, every bonded item with its
// place in the whole lists, positions and velocities, bit for bit; part_source picks the source
// and refuses the decks no source makes by parts, each with its reason; and a malformed number in
// the lines one rank reads stops every rank with that rank's message.
#include <gtest/gtest.h>
#include <unistd.h>

#include <filesystem>
#include <fstream>
#include <sstream>
#include <string>
#include <vector>

#include "core/errors.hpp"
#include "engine/domain/part_load.hpp"
#include "engine/domain/part_molecules.hpp"
#include "fake_processes.hpp"
#include "test_support.hpp"

namespace stiffmd {
namespace {

using fake::run_ranks;

// A file of this source tree (not test::source_path: an inline function whose definition the
// linker may take from another test's object, built with another tree's path).
std::string tree_path(const std::string& rel) {
  return std::string(STIFFMD_SOURCE_DIR) + "/" + rel;
}

constexpr const char* kDeck = "tests/decks/chains_by_parts.toml";

template <class Item>
void expect_same_items(const std::vector<PartMolecules::Placed<Item>>& got,
                       const std::vector<PartMolecules::Placed<Item>>& want, const char* what) {
  ASSERT_EQ(got.size(), want.size()) << what;
  for (size_t k = 0; k < got.size(); ++k) {
    EXPECT_EQ(got[k].place, want[k].place) << what << " " << k;
    EXPECT_EQ(got[k].item.i, want[k].item.i) << what << " " << k;
    EXPECT_EQ(got[k].item.j, want[k].item.j) << what << " " << k;
    EXPECT_EQ(got[k].item.type, want[k].item.type) << what << " " << k;
    if constexpr (requires { got[k].item.k; }) {
      EXPECT_EQ(got[k].item.k, want[k].item.k) << what << " " << k;
    }
    if constexpr (requires { got[k].item.l; }) {
      EXPECT_EQ(got[k].item.l, want[k].item.l) << what << " " << k;
    }
  }
}

// Each rank's part made by `source` on `ranks` fake ranks is the whole scene's block of that rank
// (whole_block, cut_part) bit for bit, and the parts cover the scene.
void expect_whole_blocks(const Deck& deck, const Scene& whole, PartMaker source, int ranks) {
  const int n = whole.state.size();
  std::vector<ScenePart> parts(static_cast<size_t>(ranks));
  run_ranks(ranks, [&](const Communicator& comm) { parts[comm.rank()] = source(deck, whole, comm); });
  const Eigen::VectorXd& friction = whole.integrator.thermostat.friction;
  const WholeParticles all{std::span<const double>(whole.state.inv_mass.data(), static_cast<size_t>(n)),
                           whole.particle_type,
                           whole.charge,
                           whole.topology.molecule,
                           std::span<const double>(friction.data(), static_cast<size_t>(friction.size())),
                           whole.topology};
  int covered = 0;
  for (int r = 0; r < ranks; ++r) {
    SCOPED_TRACE("rank " + std::to_string(r) + " of " + std::to_string(ranks));
    const std::vector<int> block = whole_block(whole.topology, n, ranks, r);
    const PartMolecules want = cut_part(all, block);
    const ScenePart& got = parts[static_cast<size_t>(r)];
    covered += got.molecules.size();
    EXPECT_EQ(got.molecules.global, want.global);
    EXPECT_EQ(got.molecules.inv_mass, want.inv_mass);
    EXPECT_EQ(got.molecules.type, want.type);
    EXPECT_EQ(got.molecules.charge, want.charge);
    EXPECT_EQ(got.molecules.molecule_id, want.molecule_id);
    EXPECT_EQ(got.molecules.friction, want.friction);
    expect_same_items(got.molecules.bonds, want.bonds, "bond");
    expect_same_items(got.molecules.angles, want.angles, "angle");
    expect_same_items(got.molecules.dihedrals, want.dihedrals, "dihedral");
    expect_same_items(got.molecules.impropers, want.impropers, "improper");
    ASSERT_EQ(got.x.cols(), static_cast<Eigen::Index>(block.size()));
    ASSERT_EQ(got.v.cols(), static_cast<Eigen::Index>(block.size()));
    for (size_t k = 0; k < block.size(); ++k) {
      const auto c = static_cast<Eigen::Index>(k);
      EXPECT_TRUE(got.x.col(c) == whole.state.x.col(block[k])) << "particle " << block[k];
      EXPECT_TRUE(got.v.col(c) == whole.state.v.col(block[k])) << "particle " << block[k];
    }
  }
  EXPECT_EQ(covered, n);
}

class ChainsPart : public ::testing::TestWithParam<int> {};

TEST_P(ChainsPart, IsTheWholeScenesBlockBitForBit) {
  const Deck deck(tree_path(kDeck), {});
  const Scene whole = load_scene(deck);
  const PartSource source = part_source(deck, whole);
  ASSERT_EQ(source.refusal, "");
  ASSERT_EQ(source.make, &chains_part);
  ASSERT_GT(whole.topology.angles.size(), 0u);
  ASSERT_EQ(whole.integrator.thermostat.friction.size(), whole.state.size());
  expect_whole_blocks(deck, whole, source.make, GetParam());
}

INSTANTIATE_TEST_SUITE_P(Ranks, ChainsPart, ::testing::Values(1, 2, 3, 4));

// A data file read by blocks: the Kremer–Grest-like melt beside vacuum (FENE bonds, Langevin, the
// file's velocities; and velocities drawn by particle instead), and TraPPE polyethylene (angles,
// dihedrals, two types, a friction scaled by type).
struct DataDeck {
  const char* deck;
  std::vector<std::string> overrides;
};

class DataFilePart : public ::testing::TestWithParam<std::tuple<int, int>> {};

TEST_P(DataFilePart, IsTheWholeScenesBlockBitForBit) {
  const auto [which, ranks] = GetParam();
  const DataDeck decks[] = {
      {"inputs/half_melt.toml", {}},
      {"inputs/half_melt.toml", {"velocities.temperature=1.5", "velocities.seed=3", "velocities.by_particle=true"}},
      {"inputs/trappe_pe.toml", {"thermostat.scale={ CH3 = 2.0 }"}},
  };
  const DataDeck& d = decks[which];
  const Deck deck(tree_path(d.deck), d.overrides);
  const Scene whole = load_scene(deck);
  const PartSource source = part_source(deck, whole);
  ASSERT_EQ(source.refusal, "");
  ASSERT_EQ(source.make, &data_file_part);
  ASSERT_GT(whole.topology.bonds.size(), 0u);
  ASSERT_GT(whole.integrator.thermostat.friction.size(), 0);
  ASSERT_FALSE(whole.state.v.isZero());
  expect_whole_blocks(deck, whole, source.make, ranks);
}

INSTANTIATE_TEST_SUITE_P(DecksRanks, DataFilePart,
                         ::testing::Combine(::testing::Values(0, 1, 2), ::testing::Values(1, 2, 3, 4)));

TEST(PartSource, PicksTheSourceOrNamesWhyNone) {
  auto source = [](const std::string& rel, const std::vector<std::string>& overrides) {
    const Deck deck(tree_path(rel), overrides);
    return part_source(deck, load_scene(deck));
  };
  auto refusal = [&](const std::string& rel, const std::vector<std::string>& overrides) {
    const PartSource s = source(rel, overrides);
    EXPECT_EQ(s.make == nullptr, !s.refusal.empty()) << rel;
    return s.refusal;
  };
  EXPECT_EQ(source(kDeck, {}).make, &chains_part);
  EXPECT_EQ(refusal(kDeck, {"thermostat.scale.bead=2.0"}), "");
  EXPECT_NE(refusal(kDeck, {"velocities.by_particle=false"}).find("[velocities]"), std::string::npos);
  EXPECT_NE(refusal(kDeck, {"build.0.growth=\"together\""}).find("together"), std::string::npos);
  EXPECT_NE(refusal("inputs/stiff_melt_nvt.toml", {}).find("[prepare]"), std::string::npos);
  EXPECT_NE(refusal("inputs/butane_torsions.toml", {}), "");
  // [minimize] (FIRE, CG or SD) is the parts' (the Run's, after the start).
  for (const char* style : {"fire", "cg", "sd"})
    EXPECT_EQ(source("inputs/melt_minimize_by_parts.toml", {std::string("minimize.style=\"") + style + "\""}).make,
              &chains_part)
        << style;
  // A method with rigid constraints projects the parts after the start; the effective dynamics
  // takes its actions from the whole state before it.
  EXPECT_EQ(source("inputs/melt_by_molecule.toml", {}).make, &chains_part);
  const std::string effective = refusal("inputs/melt_by_molecule.toml", {"integrator.method=\"effective\""});
  EXPECT_NE(effective.find("effective takes its actions from the whole state"), std::string::npos) << effective;
  // [prepare] is the parts' when its bond vibrations are drawn by particle, or there are none.
  EXPECT_EQ(source("inputs/stiff_melt_by_parts.toml", {}).make, &chains_part);
  const std::string stream = refusal("inputs/stiff_melt_by_parts.toml", {"prepare.by_particle=false"});
  EXPECT_NE(stream.find("by_particle = true"), std::string::npos) << stream;
  EXPECT_EQ(
      source("inputs/stiff_melt_by_parts.toml", {"prepare.by_particle=false", "prepare.vibrational_temperature=0"})
          .make,
      &chains_part);
  // A data file: its [import] read by blocks, with the file's velocities or drawn by particle.
  EXPECT_EQ(source("inputs/half_melt.toml", {}).make, &data_file_part);
  EXPECT_NE(refusal("inputs/half_melt.toml", {"velocities.temperature=1.0"}).find("[velocities]"), std::string::npos);
  EXPECT_NE(refusal("inputs/polyelectrolyte.toml", {}).find("[prepare]"), std::string::npos);
}

// The lines a rank reads alone: a malformed coordinate in the last molecule, which only the last
// rank's block holds, stops every rank with that rank's message (AgreedInputError, said by rank 0),
// not the last rank alone while the others wait in the velocities' sums — worded as one process
// words it (the whole load's message, which the failing rank takes by loading the deck whole).
TEST(DataFilePart, AMalformedNumberOneRankReadsStopsEveryRank) {
  const Deck good(tree_path("inputs/half_melt.toml"), {});
  const Scene whole = load_scene(good);
  const std::filesystem::path bad =
      std::filesystem::temp_directory_path() / ("stiffmd_part_load_bad_" + std::to_string(::getpid()) + ".data");
  {
    std::ifstream in(tree_path("inputs/half_melt.data"));
    std::vector<std::string> lines;
    for (std::string line; std::getline(in, line);) lines.push_back(line);
    size_t atoms = 0, last = 0;
    while (atoms < lines.size() && lines[atoms].rfind("Atoms", 0) != 0) ++atoms;
    ASSERT_LT(atoms, lines.size());
    for (size_t k = atoms + 2; k < lines.size() && !lines[k].empty(); ++k) last = k;
    std::istringstream words(lines[last]);
    std::string id, mol, type, x, rest;
    words >> id >> mol >> type >> x;
    std::getline(words, rest);
    lines[last] = id + " " + mol + " " + type + " 1.2.3" + rest;  // the last molecule's last atom
    std::ofstream out(bad);
    for (const std::string& line : lines) out << line << "\n";
  }
  const Deck deck(tree_path("inputs/half_melt.toml"), {"import.lammps_data=\"" + bad.string() + "\""});
  const int ranks = 3;
  std::vector<std::string> said(ranks);
  std::vector<int> printed(ranks, -1);
  run_ranks(ranks, [&](const Communicator& comm) {
    try {
      data_file_part(deck, whole, comm);
    } catch (const AgreedInputError& e) {
      said[comm.rank()] = e.what();
      printed[comm.rank()] = e.printed_here() ? 1 : 0;
    }
  });
  // One process's message: the whole load's (the failing rank words it so).
  std::string whole_said;
  try {
    load_scene(deck);
  } catch (const InputError& e) {
    whole_said = e.what();
  }
  std::filesystem::remove(bad);
  ASSERT_NE(whole_said.find("1.2.3"), std::string::npos) << whole_said;
  for (int r = 0; r < ranks; ++r) {
    SCOPED_TRACE("rank " + std::to_string(r));
    EXPECT_EQ(said[r], "rank 2: " + whole_said);
    EXPECT_EQ(printed[r], r == 0 ? 1 : 0);
  }
}

// A [thermostat.scale] ratio gives the built type's friction γ/ratio, as the whole scene's.
TEST(ChainsPart, TakesTheTypesLangevinFrictionAsTheWholeScene) {
  const Deck deck(tree_path(kDeck), {"thermostat.scale.bead=2.5"});
  const Scene whole = load_scene(deck);
  ScenePart part;
  run_ranks(1, [&](const Communicator& comm) { part = chains_part(deck, whole, comm); });
  ASSERT_EQ(part.molecules.friction.size(), static_cast<size_t>(whole.state.size()));
  for (int i = 0; i < whole.state.size(); ++i)
    EXPECT_EQ(part.molecules.friction[static_cast<size_t>(i)], whole.integrator.thermostat.friction[i]);
}

}  // namespace
}  // namespace stiffmd
