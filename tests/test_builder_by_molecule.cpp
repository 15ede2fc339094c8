// Linear chains built molecule by molecule (engine/scene/chains_by_molecule.hpp): the molecules of
// any partition, built apart and put together, are the whole build bit for bit; the geometry
// (exact bonds, min_distance within a chain) by brute force; the deck's growth and by_particle keys.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <random>
#include <set>
#include <string>
#include <vector>

#include "core/errors.hpp"
#include "engine/scene/chains_by_molecule.hpp"
#include "integrators/part_velocities.hpp"
#include "test_support.hpp"

namespace stiffmd {
namespace {

bool same_bits(double a, double b) {
  return std::memcmp(&a, &b, sizeof a) == 0;
}

ChainSpec melt_spec(int chains = 60, int beads = 30, std::uint64_t seed = 7) {
  ChainSpec s;
  s.chains = chains;
  s.beads = beads;
  s.bond_length = 0.97;
  s.min_distance = 0.8;
  s.seed = seed;
  return s;
}

Box open_region(double side) {
  Box b;
  b.lengths.setConstant(side);
  return b;
}

// The whole build's items whose first bead belongs to one of `molecules`, in the whole build's order.
template <class Item>
std::vector<Item> restricted(const std::vector<Item>& whole, const std::vector<int>& molecule_of,
                             const std::set<int>& molecules) {
  std::vector<Item> out;
  for (const Item& it : whole) {
    const int first = [&] {
      if constexpr (requires { it.first; })
        return it.first;
      else
        return it[0];
    }();
    if (molecules.count(molecule_of[first])) out.push_back(it);
  }
  return out;
}

// Every part (a set of molecules per fake rank) against the whole build: each bead's position,
// global index and molecule, each item and each anchor, bit for bit; the parts together hold every
// bead once.
void expect_parts_tile_whole(const ChainSpec& spec, const Box& box, const std::vector<int>& rank_of, int ranks) {
  const BuiltMolecules whole = build_linear_chains_by_molecule(
      spec, box, [](int) { return true; }, 0.5);
  const Eigen::Matrix3Xd anchors = chain_anchors_by_molecule(spec, box, 0.5);
  ASSERT_EQ(whole.x.cols(), static_cast<Eigen::Index>(spec.chains) * spec.beads);
  std::vector<int> seen(static_cast<size_t>(whole.x.cols()), 0);
  for (int r = 0; r < ranks; ++r) {
    const BuiltMolecules part = build_linear_chains_by_molecule(
        spec, box, [&](int m) { return rank_of[static_cast<size_t>(m)] == r; }, 0.5);
    std::set<int> mine;
    for (int m = 0; m < spec.chains; ++m)
      if (rank_of[static_cast<size_t>(m)] == r) mine.insert(m);
    ASSERT_EQ(std::vector<int>(mine.begin(), mine.end()), part.molecules) << "rank " << r;
    ASSERT_EQ(part.x.cols(), static_cast<Eigen::Index>(mine.size()) * spec.beads);
    ASSERT_TRUE(std::is_sorted(part.global.begin(), part.global.end()));
    for (Eigen::Index k = 0; k < part.x.cols(); ++k) {
      const int g = part.global[static_cast<size_t>(k)];
      ++seen[static_cast<size_t>(g)];
      EXPECT_EQ(part.molecule[static_cast<size_t>(k)], whole.molecule[static_cast<size_t>(g)]);
      for (int a = 0; a < 3; ++a)
        ASSERT_TRUE(same_bits(part.x(a, k), whole.x(a, g))) << "rank " << r << " bead " << g << " axis " << a;
    }
    EXPECT_EQ(part.bonds, restricted(whole.bonds, whole.molecule, mine));
    EXPECT_EQ(part.angles, restricted(whole.angles, whole.molecule, mine));
    EXPECT_EQ(part.dihedrals, restricted(whole.dihedrals, whole.molecule, mine));
    for (size_t c = 0; c < part.molecules.size(); ++c)
      for (int a = 0; a < 3; ++a) {
        const int m = part.molecules[c];
        EXPECT_TRUE(same_bits(part.anchors(a, static_cast<Eigen::Index>(c)), anchors(a, m)));
        EXPECT_TRUE(same_bits(part.anchors(a, static_cast<Eigen::Index>(c)), whole.anchors(a, m)));
      }
  }
  for (size_t g = 0; g < seen.size(); ++g) ASSERT_EQ(seen[g], 1) << "bead " << g;
}

TEST(BuilderByMolecule, PartsOfAnyPartitionAreTheWholeBuildBitForBit) {
  const ChainSpec spec = melt_spec();
  const Box box = box_for_density(spec.chains * spec.beads, 0.85);
  std::mt19937 pick(3);
  for (int ranks = 1; ranks <= 4; ++ranks) {
    std::vector<int> interleaved(static_cast<size_t>(spec.chains)), contiguous(interleaved.size()),
        scattered(interleaved.size());
    for (int m = 0; m < spec.chains; ++m) {
      interleaved[static_cast<size_t>(m)] = m % ranks;
      contiguous[static_cast<size_t>(m)] = m * ranks / spec.chains;
      scattered[static_cast<size_t>(m)] = static_cast<int>(pick() % static_cast<unsigned>(ranks));
    }
    SCOPED_TRACE("ranks " + std::to_string(ranks));
    expect_parts_tile_whole(spec, box, interleaved, ranks);
    expect_parts_tile_whole(spec, box, contiguous, ranks);
    expect_parts_tile_whole(spec, box, scattered, ranks);
  }
  // In open space (a start region around the origin) too.
  std::vector<int> halves(20);
  for (int m = 0; m < 20; ++m) halves[static_cast<size_t>(m)] = (m * 7) % 3 == 0;
  expect_parts_tile_whole(melt_spec(20, 40), open_region(12.0), halves, 2);
}

TEST(BuilderByMolecule, ARangeIsThePredicateOfItsMolecules) {
  const ChainSpec spec = melt_spec(30, 20);
  const Box box = box_for_density(spec.chains * spec.beads, 0.85);
  const BuiltMolecules range = build_linear_chains_by_molecule(spec, box, 11, 19);
  const BuiltMolecules pred = build_linear_chains_by_molecule(spec, box, [](int m) { return m >= 11 && m < 19; });
  EXPECT_EQ(range.molecules, pred.molecules);
  EXPECT_EQ(range.global, pred.global);
  EXPECT_TRUE(range.x.cwiseEqual(pred.x).all());
  EXPECT_EQ(range.global.front(), 11 * 20);
  EXPECT_EQ(range.global.back(), 19 * 20 - 1);
}

TEST(BuilderByMolecule, TheSameSeedGivesTheSameSystemAnotherSeedAnother) {
  const Box box = box_for_density(40 * 25, 0.85);
  const Polymer a = build_linear_chains_by_molecule(melt_spec(40, 25, 5), box);
  const Polymer b = build_linear_chains_by_molecule(melt_spec(40, 25, 5), box);
  const Polymer c = build_linear_chains_by_molecule(melt_spec(40, 25, 6), box);
  ASSERT_EQ(a.x.cols(), b.x.cols());
  EXPECT_EQ(std::memcmp(a.x.data(), b.x.data(), sizeof(double) * a.x.size()), 0);
  EXPECT_EQ(a.bonds, b.bonds);
  // Another seed: every molecule elsewhere (each stream keyed by the seed).
  for (int m = 0; m < 40; ++m) EXPECT_NE(a.x.col(m * 25), c.x.col(m * 25)) << "molecule " << m;
  // Another molecule: another stream (no two molecules start alike).
  EXPECT_NE(molecule_stream_key(5, 0), molecule_stream_key(5, 1));
  EXPECT_NE(molecule_stream_key(5, 1), molecule_stream_key(6, 0));
}

// Bonds exactly bond_length; within each chain no two non-bonded beads closer than min_distance
// (minimum image, all pairs); the angles and dihedrals those of a chain; first beads in the box.
void expect_chain_geometry(const ChainSpec& spec, const Box& box) {
  const Polymer p = build_linear_chains_by_molecule(spec, box);
  const int n = spec.beads;
  ASSERT_EQ(p.x.cols(), static_cast<Eigen::Index>(spec.chains) * n);
  ASSERT_EQ(p.bonds.size(), static_cast<size_t>(spec.chains) * (n - 1));
  for (const auto& [i, j] : p.bonds) {
    EXPECT_EQ(j, i + 1);
    EXPECT_EQ(p.molecule[static_cast<size_t>(i)], p.molecule[static_cast<size_t>(j)]);
    EXPECT_NEAR((p.x.col(i) - p.x.col(j)).norm(), spec.bond_length, 1e-12);  // unwrapped: no image
  }
  double closest = INFINITY;
  for (int m = 0; m < spec.chains; ++m) {
    const Eigen::Vector3d s = p.x.col(m * n);
    for (int a = 0; a < 3; ++a)
      if (box.periodic[a]) {
        EXPECT_GE(s[a], box.origin[a]);
        EXPECT_LT(s[a], box.origin[a] + box.lengths[a]);
      }
    for (int i = m * n; i < (m + 1) * n; ++i)
      for (int j = i + 2; j < (m + 1) * n; ++j)
        closest = std::min(closest, box.min_image(p.x.col(i) - p.x.col(j)).norm());
  }
  EXPECT_GE(closest, spec.min_distance);
  EXPECT_LT(closest, spec.min_distance + 0.1);  // the walk does come close: the test is not vacuous
  const Polymer reference = build_linear_chains(melt_spec(1, n), box);  // the other builder's chain topology
  ASSERT_EQ(p.angles.size(), static_cast<size_t>(spec.chains) * reference.angles.size());
  ASSERT_EQ(p.dihedrals.size(), static_cast<size_t>(spec.chains) * reference.dihedrals.size());
  for (int m = 0; m < spec.chains; ++m)
    for (size_t k = 0; k < reference.angles.size(); ++k)
      for (int e = 0; e < 3; ++e)
        EXPECT_EQ(p.angles[static_cast<size_t>(m) * reference.angles.size() + k][e], reference.angles[k][e] + m * n);
  for (int m = 0; m < spec.chains; ++m)
    for (size_t k = 0; k < reference.dihedrals.size(); ++k)
      for (int e = 0; e < 4; ++e)
        EXPECT_EQ(p.dihedrals[static_cast<size_t>(m) * reference.dihedrals.size() + k][e],
                  reference.dihedrals[k][e] + m * n);
}

TEST(BuilderByMolecule, ExactBondsAndMinDistanceWithinEachChain) {
  expect_chain_geometry(melt_spec(30, 60), box_for_density(30 * 60, 0.85));
  expect_chain_geometry(melt_spec(10, 50), open_region(8.0));
  // One long chain in a small periodic box meets its own images: min_distance holds under the
  // minimum image, and at 0.95 the walk backs off (85 times) on the way.
  ChainSpec tight = melt_spec(1, 3000, 2);
  tight.min_distance = 0.95;
  expect_chain_geometry(tight, box_for_density(3000, 0.6));
}

// Across molecules nothing is tested (the header): a molecule is the same whatever else is built,
// so in a melt the chains do overlap one another — the soft start's job.
TEST(BuilderByMolecule, MoleculesIgnoreEachOtherAndDoOverlap) {
  const ChainSpec spec = melt_spec(40, 50);
  const Box box = box_for_density(spec.chains * spec.beads, 0.85);
  const BuiltMolecules one = build_linear_chains_by_molecule(spec, box, 17, 18);
  ChainSpec fewer = spec;
  fewer.chains = 18;  // molecule 17 of a smaller system, in the same box
  const BuiltMolecules same = build_linear_chains_by_molecule(fewer, box, 17, 18);
  EXPECT_TRUE(one.x.cwiseEqual(same.x).all());
  const Polymer p = build_linear_chains_by_molecule(spec, box);
  double closest = INFINITY;
  for (Eigen::Index i = 0; i < p.x.cols(); ++i)
    for (Eigen::Index j = i + 1; j < p.x.cols(); ++j)
      if (p.molecule[static_cast<size_t>(i)] != p.molecule[static_cast<size_t>(j)])
        closest = std::min(closest, box.min_image(p.x.col(i) - p.x.col(j)).norm());
  EXPECT_LT(closest, spec.min_distance);
}

TEST(BuilderByMolecule, MinDistanceZeroIsAFreeWalk) {
  ChainSpec s = melt_spec(5, 40);
  s.min_distance = 0.0;
  for (const Box& box : {open_region(6.0), box_for_density(200, 0.85)}) {
    const Polymer p = build_linear_chains_by_molecule(s, box);
    ASSERT_EQ(p.x.cols(), 200);
    for (const auto& [i, j] : p.bonds) EXPECT_NEAR((p.x.col(i) - p.x.col(j)).norm(), s.bond_length, 1e-12);
  }
}

TEST(BuilderByMolecule, RefusesWhatTheOtherBuildersRefuse) {
  const Box box = box_for_density(100, 0.85);
  ChainSpec s = melt_spec(10, 10);
  s.beads = 1;
  EXPECT_THROW(build_linear_chains_by_molecule(s, box), std::invalid_argument);
  s = melt_spec(10, 10);
  s.min_distance = 2.0;
  EXPECT_THROW(build_linear_chains_by_molecule(s, box), std::invalid_argument);
  s = melt_spec(0, 10);
  EXPECT_THROW(chain_anchors_by_molecule(s, box), std::invalid_argument);
}

// The deck (inputs/melt_by_molecule.toml, before [minimize] moves anything): growth =
// "by-molecule" places the builder's whole build, and [velocities] by_particle = true draws each
// particle's velocity by its index, both bit for bit.
TEST(BuilderByMolecule, DeckGrowsByMoleculeAndDrawsVelocitiesByParticle) {
  const Deck deck(test::source_path("inputs/melt_by_molecule.toml"), {});
  const Scene sc = load_scene(deck);
  ChainSpec spec = melt_spec(80, 50, 11);
  const Polymer p = build_linear_chains_by_molecule(spec, box_for_density(spec.chains * spec.beads, 0.85));
  ASSERT_EQ(sc.state.x.cols(), p.x.cols());
  EXPECT_EQ(std::memcmp(sc.state.x.data(), p.x.data(), sizeof(double) * p.x.size()), 0);
  ASSERT_EQ(sc.topology.bonds.size(), p.bonds.size());
  for (size_t k = 0; k < p.bonds.size(); ++k) {
    EXPECT_EQ(sc.topology.bonds[k].i, p.bonds[k].first);
    EXPECT_EQ(sc.topology.bonds[k].j, p.bonds[k].second);
  }
  std::vector<int> global(static_cast<size_t>(p.x.cols()));
  for (size_t i = 0; i < global.size(); ++i) global[i] = static_cast<int>(i);
  const Eigen::Matrix3Xd v = maxwell_boltzmann_by_particle(sc.state.inv_mass, global, 1.0, 12, nullptr);
  EXPECT_EQ(std::memcmp(sc.state.v.data(), v.data(), sizeof(double) * v.size()), 0);
  // Without by_particle, [velocities] keeps its one stream: other velocities.
  const Scene one_stream =
      load_scene(Deck(test::source_path("inputs/melt_by_molecule.toml"), {"velocities.by_particle=false"}));
  EXPECT_NE(std::memcmp(one_stream.state.v.data(), v.data(), sizeof(double) * v.size()), 0);
}

}  // namespace
}  // namespace stiffmd
