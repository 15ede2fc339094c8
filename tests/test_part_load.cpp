// A rank's molecules made by their source (engine/domain/part_load.hpp): the linear chains built by
// molecule, with velocities by particle, give on each of 1–4 fake ranks (tests/fake_processes.hpp)
// exactly the block the whole path cuts from the whole scene (whole_block and cut_part,
// engine/domain/part_molecules.hpp) — global indices, inverse masses, types, charges, molecule
// ids, Langevin frictions, every bond and angle with its place in the whole lists, positions and
// velocities, bit for bit; and the decks the source cannot make by parts are refused, each with
// its reason.
#include <gtest/gtest.h>

#include <string>
#include <vector>

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

class ChainsPart : public ::testing::TestWithParam<int> {};

TEST_P(ChainsPart, IsTheWholeScenesBlockBitForBit) {
  const int ranks = GetParam();
  const Deck deck(tree_path(kDeck), {});
  const Scene whole = load_scene(deck);
  ASSERT_EQ(chains_part_refusal(deck, whole), "");
  const int n = whole.state.size();
  ASSERT_GT(whole.topology.angles.size(), 0u);
  ASSERT_EQ(whole.integrator.thermostat.friction.size(), n);
  std::vector<ScenePart> parts(static_cast<size_t>(ranks));
  run_ranks(ranks, [&](const Communicator& comm) { parts[comm.rank()] = chains_part(deck, whole, comm); });
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
    EXPECT_TRUE(got.molecules.impropers.empty());
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

INSTANTIATE_TEST_SUITE_P(Ranks, ChainsPart, ::testing::Values(1, 2, 3, 4));

TEST(ChainsPartRefusal, NamesWhatTheSourceCannotMakeByParts) {
  auto refusal = [](const std::string& rel, const std::vector<std::string>& overrides) {
    const Deck deck(tree_path(rel), overrides);
    return chains_part_refusal(deck, load_scene(deck));
  };
  EXPECT_EQ(refusal(kDeck, {}), "");
  EXPECT_EQ(refusal(kDeck, {"thermostat.scale.bead=2.0"}), "");
  EXPECT_NE(refusal(kDeck, {"velocities.by_particle=false"}).find("[velocities]"), std::string::npos);
  EXPECT_NE(refusal(kDeck, {"build.0.growth=\"together\""}).find("together"), std::string::npos);
  EXPECT_NE(refusal("inputs/melt_by_molecule.toml", {}).find("[minimize]"), std::string::npos);
  EXPECT_NE(refusal("inputs/stiff_melt_nvt.toml", {}).find("[prepare]"), std::string::npos);
  EXPECT_NE(refusal("inputs/butane_torsions.toml", {}), "");
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
