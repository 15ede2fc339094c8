// The scene fingerprint combinable by blocks (engine/run/checkpoint.hpp, format versions 7 and 8):
// the value scene_fingerprint_parts gives from each rank's part of the molecules is the whole
// scene's scene_fingerprint, for any partition of the molecules on 1–4 fake ranks (tests/
// fake_processes.hpp) — all on one rank, scattered at random, the whole path's blocks; and a
// change of one bond's type, one particle's mass or charge, one molecule id or one coefficient
// changes it. Version 8: the same value from a description whose force terms are their
// descriptions alone (each made on no particle) and which holds no particle or item, on 1–3 fake
// ranks; a change of a coefficient or of a rule that only the whole terms' lists showed (a stiff
// bond's length, a rigid angle, a 1-4 table, an external term's selection) changes it. A
// checkpoint of format version 6 (the sequential fingerprint) or 7 (by blocks, the terms' own
// definitions) still restarts, and one whose fingerprint is not the scene's is refused, in every
// version.
#include <gtest/gtest.h>

#include <zlib.h>

#include <cmath>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <random>
#include <span>
#include <string>
#include <vector>

#include "core/errors.hpp"
#include "core/topology.hpp"
#include "engine/deck/deck.hpp"
#include "engine/domain/part_load.hpp"
#include "engine/domain/part_molecules.hpp"
#include "engine/run/checkpoint.hpp"
#include "engine/scene/scene.hpp"
#include "fake_processes.hpp"
#include "forcefields/force_field.hpp"
#include "test_support.hpp"

namespace stiffmd {
namespace {

using fake::FakeCommunicator;
using fake::run_ranks;

WholeParticles whole_of(const Scene& sc) {
  return {std::span<const double>(sc.state.inv_mass.data(), static_cast<size_t>(sc.state.size())),
          sc.particle_type,
          sc.charge,
          sc.topology.molecule,
          {},
          sc.topology};
}

// Per molecule (bonded_molecules' numbering) the rank it goes to: all on `ranks` − 1, at random,
// or the whole path's contiguous blocks.
enum class Partition { one_rank, random, blocks };

std::vector<int> particles_of_rank(const Scene& sc, int ranks, int rank, Partition how, unsigned seed) {
  const int n = sc.state.size();
  if (how == Partition::blocks) return whole_block(sc.topology, n, ranks, rank);
  const std::vector<int> molecule = bonded_molecules(sc.topology, n);
  const int molecules = molecule.empty() ? 0 : *std::max_element(molecule.begin(), molecule.end()) + 1;
  std::vector<int> to(static_cast<size_t>(molecules), ranks - 1);
  if (how == Partition::random) {
    std::mt19937 draw(seed);
    std::uniform_int_distribution<int> pick(0, ranks - 1);
    for (int& r : to) r = pick(draw);
  }
  std::vector<int> out;
  for (int g = 0; g < n; ++g)
    if (to[static_cast<size_t>(molecule[static_cast<size_t>(g)])] == rank) out.push_back(g);
  return out;
}

// The value every rank computes from its part of `sc`, with `description` as the scene's
// description, checked equal across the ranks.
std::uint64_t by_parts(const Scene& sc, const Scene& description, int ranks, Partition how, unsigned seed) {
  std::vector<std::uint64_t> got(static_cast<size_t>(ranks), 0);
  run_ranks(ranks, [&](const FakeCommunicator& comm) {
    const std::vector<int> mine = particles_of_rank(sc, ranks, comm.rank(), how, seed);
    const PartMolecules part = cut_part(whole_of(sc), mine);
    got[static_cast<size_t>(comm.rank())] = scene_fingerprint_parts(description, part, comm);
  });
  for (int r = 1; r < ranks; ++r) EXPECT_EQ(got[static_cast<size_t>(r)], got[0]) << "rank " << r << " of " << ranks;
  return got[0];
}
std::uint64_t by_parts(const Scene& sc, int ranks, Partition how, unsigned seed) {
  return by_parts(sc, sc, ranks, how, seed);
}

// Decks with bonds, angles, dihedrals, impropers, charges and molecule ids among them, and a
// term of every force style (stiff bonds with rigid angles, charmm 1-4 tables, tethers, walls,
// gravity, every pair and k-space style).
const char* const kDecks[] = {"inputs/kremer_grest.toml",
                              "inputs/peptide.toml",
                              "inputs/polyelectrolyte.toml",
                              "inputs/butane_torsions.toml",
                              "tests/decks/every_force_style.toml",
                              "tests/decks/every_all_atom_style.toml",
                              "tests/decks/every_charged_style.toml",
                              "tests/decks/every_mesh_style.toml"};

// The scene's description as a decomposed run may hold it (docs/parallel.md, "What is not
// distributed yet"): its types, box, levels and units, and every force term made again from its
// description alone (ForceTerm::on_subset on a subset of no particle: no item, no particle list,
// no per-particle array) — pair and k-space terms too; no particle and no topology item.
Scene described_scene(const std::string& deck, const std::vector<std::string>& overrides = {}) {
  Scene sc = test::load(deck, overrides);
  const std::vector<int> none;
  const Topology empty;
  sc.forces = sc.forces->on_subset(ParticleSubset{none, none, empty});
  sc.state = State{};
  sc.particle_type.clear();
  sc.charge.clear();
  sc.topology = Topology{};
  return sc;
}

// The whole scene's terms with their descriptions in their place (the particles and items kept).
Scene with_described_terms(const std::string& deck) {
  Scene sc = test::load(deck);
  const std::vector<int> none;
  const Topology empty;
  sc.forces = sc.forces->on_subset(ParticleSubset{none, none, empty});
  return sc;
}

TEST(SceneFingerprintParts, EveryPartitionOnOneToFourRanksGivesTheWholeScenesValue) {
  for (const char* deck : kDecks) {
    SCOPED_TRACE(deck);
    const Scene sc = test::load(deck);
    const std::uint64_t whole = scene_fingerprint(sc);
    for (int ranks = 1; ranks <= 4; ++ranks) {
      SCOPED_TRACE("ranks " + std::to_string(ranks));
      EXPECT_EQ(by_parts(sc, ranks, Partition::one_rank, 0), whole);
      EXPECT_EQ(by_parts(sc, ranks, Partition::blocks, 0), whole);
      for (unsigned seed = 1; seed <= 3; ++seed) EXPECT_EQ(by_parts(sc, ranks, Partition::random, seed), whole);
    }
  }
}

// A source's own parts (chains built by molecule, each rank its block: engine/domain/part_load.hpp)
// give the whole scene's value too.
TEST(SceneFingerprintParts, ChainsBuiltByPartsGiveTheWholeScenesValue) {
  const Deck deck(test::source_path("tests/decks/chains_by_parts.toml"), {});
  const Scene whole = load_scene(deck);
  ASSERT_EQ(part_source(deck, whole).refusal, "");
  const std::uint64_t expected = scene_fingerprint(whole);
  for (int ranks = 1; ranks <= 4; ++ranks) {
    std::vector<std::uint64_t> got(static_cast<size_t>(ranks), 0);
    run_ranks(ranks, [&](const FakeCommunicator& comm) {
      const ScenePart mine = chains_part(deck, whole, comm);
      got[static_cast<size_t>(comm.rank())] = scene_fingerprint_parts(whole, mine.molecules, comm);
    });
    for (const std::uint64_t v : got) EXPECT_EQ(v, expected) << ranks << " ranks";
  }
}

// Each change below, on the whole scene, changes the whole value and the parts' value alike.
void expect_changed(Scene& sc, std::uint64_t before, const std::string& what) {
  EXPECT_NE(scene_fingerprint(sc), before) << what;
  EXPECT_EQ(by_parts(sc, 3, Partition::random, 7), scene_fingerprint(sc)) << what;
}

TEST(SceneFingerprintParts, OneBondsTypeChangedIsAnotherScene) {
  Scene sc = test::load("inputs/peptide.toml");
  ASSERT_GT(sc.topology.bond_types.size(), 1u);
  const std::uint64_t before = scene_fingerprint(sc);
  Bond& b = sc.topology.bonds[sc.topology.bonds.size() / 2];
  b.type = (b.type + 1) % static_cast<int>(sc.topology.bond_types.size());
  expect_changed(sc, before, "a bond's type");
}

TEST(SceneFingerprintParts, OneAnglesOrDihedralsTypeChangedIsAnotherScene) {
  Scene sc = test::load("inputs/peptide.toml");
  ASSERT_GT(sc.topology.angle_types.size(), 1u);
  ASSERT_GT(sc.topology.dihedral_types.size(), 1u);
  const std::uint64_t before = scene_fingerprint(sc);
  Angle& a = sc.topology.angles[3];
  a.type = (a.type + 1) % static_cast<int>(sc.topology.angle_types.size());
  expect_changed(sc, before, "an angle's type");
  Scene other = test::load("inputs/peptide.toml");
  Dihedral& d = other.topology.dihedrals[5];
  d.type = (d.type + 1) % static_cast<int>(other.topology.dihedral_types.size());
  expect_changed(other, before, "a dihedral's type");
}

TEST(SceneFingerprintParts, TwoBondsTypesSwappedIsAnotherScene) {
  // A sum of per-item hashes that left out the place (or the particles) would miss a swap.
  Scene sc = test::load("inputs/peptide.toml");
  const std::uint64_t before = scene_fingerprint(sc);
  auto& bonds = sc.topology.bonds;
  size_t k = 1;
  while (k < bonds.size() && bonds[k].type == bonds[0].type) ++k;
  ASSERT_LT(k, bonds.size());
  std::swap(bonds[0].type, bonds[k].type);
  expect_changed(sc, before, "two bonds' types swapped");
}

TEST(SceneFingerprintParts, OneParticlesMassIsAnotherScene) {
  Scene sc = test::load("inputs/kremer_grest.toml");
  const std::uint64_t before = scene_fingerprint(sc);
  double& im = sc.state.inv_mass[1234];
  im = std::nextafter(im, 2.0);
  expect_changed(sc, before, "a particle's inverse mass in its last bit");
}

TEST(SceneFingerprintParts, OneParticlesChargeIsAnotherScene) {
  Scene sc = test::load("inputs/polyelectrolyte.toml");
  ASSERT_TRUE(sc.charged());
  const std::uint64_t before = scene_fingerprint(sc);
  sc.charge[7] = std::nextafter(sc.charge[7], 10.0);
  expect_changed(sc, before, "a particle's charge in its last bit");
}

TEST(SceneFingerprintParts, OneParticlesTypeOrMoleculeIdIsAnotherScene) {
  Scene sc = test::load("inputs/peptide.toml");
  ASSERT_FALSE(sc.topology.molecule.empty());
  const std::uint64_t before = scene_fingerprint(sc);
  sc.topology.molecule[2] += 1;
  expect_changed(sc, before, "a particle's molecule id");
  Scene other = test::load("inputs/peptide.toml");
  other.particle_type[4] = (other.particle_type[4] + 1) % static_cast<int>(other.types.size());
  expect_changed(other, before, "a particle's type");
}

TEST(SceneFingerprintParts, OneCoefficientIsAnotherScene) {
  const Scene sc = test::load("inputs/kremer_grest.toml");
  const std::uint64_t before = scene_fingerprint(sc);
  for (const std::string set :
       {"forces.fene.bond_types.fene.K=30.000000000000004", "forces.lj.epsilon=1.0000000000000002"}) {
    Scene other = test::load("inputs/kremer_grest.toml", {set});
    expect_changed(other, before, set);
  }
}

TEST(SceneFingerprintParts, TheTermsDescriptionsAloneGiveTheWholeScenesValue) {
  for (const char* deck : kDecks) {
    SCOPED_TRACE(deck);
    const Scene sc = test::load(deck);
    const Scene description = described_scene(deck);
    ASSERT_EQ(description.forces->terms().size(), sc.forces->terms().size());
    const std::uint64_t whole = scene_fingerprint(sc);
    for (int ranks = 1; ranks <= 3; ++ranks) {
      SCOPED_TRACE("ranks " + std::to_string(ranks));
      EXPECT_EQ(by_parts(sc, description, ranks, Partition::one_rank, 0), whole);
      EXPECT_EQ(by_parts(sc, description, ranks, Partition::blocks, 0), whole);
      for (unsigned seed = 1; seed <= 2; ++seed)
        EXPECT_EQ(by_parts(sc, description, ranks, Partition::random, seed), whole);
    }
    // The whole scene with its terms' descriptions in their place: the same value in version 8,
    // another in version 7 (whose terms write their lists), for a deck with bonded items.
    const Scene described_terms = with_described_terms(deck);
    EXPECT_EQ(scene_fingerprint(described_terms), whole);
    if (!sc.topology.bonds.empty()) {
      EXPECT_NE(scene_fingerprint_v7(described_terms), scene_fingerprint_v7(sc));
    }
  }
}

// A change that only the whole terms' lists showed — or a coefficient — changes the value of the
// descriptions alone as the whole scene's (both, with the deck changed, agree).
TEST(SceneFingerprintParts, ARuleOrCoefficientChangedIsAnotherSceneOfTheDescriptions) {
  struct Change {
    const char* deck;
    std::string set;
  };
  const std::vector<Change> changes = {
      {"inputs/kremer_grest.toml", "forces.fene.bond_types.fene.K=30.000000000000004"},
      {"inputs/kremer_grest.toml", "forces.lj.epsilon=1.0000000000000002"},
      {"tests/decks/every_force_style.toml", "forces.bonds.bond_types.stiff.length=0.9700000000000001"},
      {"tests/decks/every_force_style.toml", "forces.bonds.angle_types.bend_h.theta0=110.0000000001"},
      {"tests/decks/every_force_style.toml", "forces.bonds.angle_types.bend_h.alpha=1.5000000000000002"},
      {"tests/decks/every_force_style.toml", "forces.tether.particles.1=8"},
      {"tests/decks/every_force_style.toml", "forces.wall.type=\"A\""},
      {"tests/decks/every_force_style.toml", "forces.gravity.g.2=-0.5000000000000001"},
      {"tests/decks/every_all_atom_style.toml", "forces.torsions.lj14.A.epsilon=0.010000000000000002"},
  };
  for (const Change& c : changes) {
    SCOPED_TRACE(std::string(c.deck) + " --set " + c.set);
    const Scene sc = test::load(c.deck), other = test::load(c.deck, {c.set});
    const Scene description = described_scene(c.deck, {c.set});
    const std::uint64_t before = scene_fingerprint(sc), after = scene_fingerprint(other);
    EXPECT_NE(after, before);
    EXPECT_EQ(by_parts(other, description, 2, Partition::random, 5), after);
  }
}

// The checkpoint's header, rewritten: bytes 12–15 the version, 32–39 the fingerprint, 8–11 the
// crc32 of bytes 12 … end (engine/run/checkpoint.hpp).
void rewrite_header(const std::string& path, std::uint32_t version, std::uint64_t fingerprint) {
  std::vector<char> b;
  {
    std::ifstream in(path, std::ios::binary);
    b.assign(std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>());
  }
  std::memcpy(b.data() + 12, &version, 4);
  std::memcpy(b.data() + 32, &fingerprint, 8);
  const auto crc = static_cast<std::uint32_t>(
      ::crc32(0, reinterpret_cast<const Bytef*>(b.data() + 12), static_cast<uInt>(b.size() - 12)));
  std::memcpy(b.data() + 8, &crc, 4);
  std::ofstream(path, std::ios::binary).write(b.data(), static_cast<std::streamsize>(b.size()));
}

TEST(SceneFingerprintParts, AVersion6Or7CheckpointIsCheckedByItsVersionsFingerprint) {
  Scene sc = test::load("inputs/peptide.toml");
  const std::string path =
      (std::filesystem::temp_directory_path() / ("fingerprint_v6_" + std::to_string(::getpid()) + ".bin")).string();
  Checkpoint c;
  c.state = sc.state;
  c.method = "velocity-verlet";
  c.h = 0.001;
  c.scene_fingerprint = scene_fingerprint(sc);
  c.run_state = {0, 0, 0, 0};
  for (size_t k = 0; k < sc.forces->terms().size(); ++k) c.force_term_states.emplace_back();
  c.box = sc.box;
  write_checkpoint(path, c);
  EXPECT_EQ(read_checkpoint_of(sc, path).version, kCheckpointVersion);
  ASSERT_EQ(kCheckpointVersion, 8u);
  const std::uint64_t v8 = scene_fingerprint(sc), v7 = scene_fingerprint_v7(sc), v6 = scene_fingerprint_sequential(sc);
  ASSERT_NE(v6, v8);
  ASSERT_NE(v7, v8);
  ASSERT_NE(v6, v7);

  rewrite_header(path, 7, v7);  // what the stiffmd of version 7 wrote
  EXPECT_EQ(read_checkpoint_of(sc, path).version, 7u);
  EXPECT_EQ(read_checkpoint_for(sc, path).version, 7u);  // and it loads: the restart goes on
  rewrite_header(path, 6, v6);                           // what the stiffmd before version 7 wrote
  EXPECT_EQ(read_checkpoint_of(sc, path).version, 6u);

  // Each version holds its own fingerprint: another version's value is another scene.
  for (const std::uint32_t version : {6u, 7u, 8u})
    for (const std::uint64_t value : {v6, v7, v8}) {
      if ((version == 6u && value == v6) || (version == 7u && value == v7) || (version == 8u && value == v8)) continue;
      rewrite_header(path, version, value);
      EXPECT_THROW(read_checkpoint_of(sc, path), InputError) << "version " << version << ", value " << value;
    }
  std::filesystem::remove(path);
}

}  // namespace
}  // namespace stiffmd
