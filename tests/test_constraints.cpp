// Tests of the constraint toolbox (Lubich & Weiss §2.2–2.3, Lemma "alpha").
//
// The references here are written independently of the toolbox's sources (integrators/constraint*,
// shake.cpp, mollifier.cpp): G(x) as an explicit dense m × 3N matrix, S = G M⁻¹ Gᵀ inverted
// densely, and finite differences of U(α(x)) for the mollified force.
#include <gtest/gtest.h>

#include "core/molecule_blocks.hpp"

#include <Eigen/Dense>
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <limits>
#include <numbers>
#include <numeric>
#include <random>
#include <string>
#include <vector>

#include "core/disjoint_sets.hpp"
#include "core/errors.hpp"
#include "integrators/constraints.hpp"

namespace stiffmd {
namespace {

struct Scene {
  std::string name;
  std::vector<StiffBond> bonds;
  Eigen::VectorXd inv_mass;
  Eigen::Matrix3Xd x;  // slightly off the constraint manifold
};

void PrintTo(const Scene& scene, std::ostream* os) {
  *os << scene.name;
}

// The seed experiment (docs/design.md §7): pivot 0 fixed at the origin, unit masses, l = α = 1,
// x(0) = (√½, −√½), (√2, 5ε): bond 1 is exact, bond 2 is stretched by O(ε).
Scene pendulum(double eps) {
  Scene s{"pendulum", {{0, 1, 1.0, 1.0}, {1, 2, 1.0, 1.0}}, Eigen::Vector3d(0.0, 1.0, 1.0), Eigen::Matrix3Xd(3, 3)};
  s.x.col(0) << 0.0, 0.0, 0.0;
  s.x.col(1) << std::sqrt(0.5), -std::sqrt(0.5), 0.0;
  s.x.col(2) << std::sqrt(2.0), 5.0 * eps, 0.0;
  return s;
}

// Built from raw mt19937 output, which the standard fixes (the <random> distributions are
// library-specific), so that every standard library builds the same scenes.
double uniform(std::mt19937& rng, double lo, double hi) {
  return lo + (hi - lo) * (static_cast<double>(rng()) / 4294967296.0);
}

Eigen::Vector3d random_unit(std::mt19937& rng) {
  for (;;) {
    const Eigen::Vector3d d(uniform(rng, -1.0, 1.0), uniform(rng, -1.0, 1.0), uniform(rng, -1.0, 1.0));
    if (d.squaredNorm() > 1e-2 && d.squaredNorm() <= 1.0) return d.normalized();
  }
}

Eigen::Matrix3Xd random_matrix(int n, unsigned seed) {
  std::mt19937 rng(seed);
  Eigen::Matrix3Xd a(3, n);
  for (int k = 0; k < n; ++k) a.col(k) << uniform(rng, -1.0, 1.0), uniform(rng, -1.0, 1.0), uniform(rng, -1.0, 1.0);
  return a;
}

// A random open chain on the manifold (random masses in [0.5, 3], lengths in [0.8, 1.2]),
// then displaced by `off` times a fixed random pattern.
Scene random_chain(int beads, unsigned seed, double off) {
  std::mt19937 rng(seed);
  Scene s{"chain" + std::to_string(beads), {}, Eigen::VectorXd(beads), Eigen::Matrix3Xd::Zero(3, beads)};
  for (int k = 0; k < beads; ++k) s.inv_mass[k] = 1.0 / uniform(rng, 0.5, 3.0);
  for (int k = 0; k + 1 < beads; ++k) {
    s.bonds.push_back({k, k + 1, uniform(rng, 0.8, 1.2), 1.0});
    s.x.col(k + 1) = s.x.col(k) + s.bonds.back().length * random_unit(rng);
  }
  s.x += off * random_matrix(beads, seed + 1);
  return s;
}

// A puckered ring (a cycle of bonds: S is not tridiagonal) with random masses.
Scene ring(int beads, unsigned seed, double off) {
  std::mt19937 rng(seed);
  Scene s{"ring" + std::to_string(beads), {}, Eigen::VectorXd(beads), Eigen::Matrix3Xd(3, beads)};
  const double radius = beads / (2.0 * std::numbers::pi);
  for (int k = 0; k < beads; ++k) {
    const double phi = 2.0 * std::numbers::pi * k / beads;
    s.x.col(k) << radius * std::cos(phi), radius * std::sin(phi), 0.3 * ((k % 2) - 0.5);
    s.inv_mass[k] = 1.0 / uniform(rng, 0.5, 3.0);
  }
  for (int k = 0; k < beads; ++k) {
    const int next = (k + 1) % beads;
    s.bonds.push_back({k, next, (s.x.col(k) - s.x.col(next)).norm(), 1.0});
  }
  s.x += off * random_matrix(beads, seed + 1);
  return s;
}

// A branched molecule: a centre bead with `arms` arms of two bonds each.
Scene star(int arms, unsigned seed, double off) {
  std::mt19937 rng(seed);
  const int beads = 1 + 2 * arms;
  Scene s{"star" + std::to_string(arms), {}, Eigen::VectorXd::Constant(beads, 0.7), Eigen::Matrix3Xd::Zero(3, beads)};
  for (int a = 0; a < arms; ++a) {
    const int first = 1 + 2 * a;
    s.x.col(first) = random_unit(rng);
    s.x.col(first + 1) = s.x.col(first) + 1.5 * random_unit(rng);
    s.bonds.push_back({0, first, 1.0, 1.0});
    s.bonds.push_back({first, first + 1, 1.5, 1.0});
  }
  s.x += off * random_matrix(beads, seed + 1);
  return s;
}

// Two molecules: a 4-bead chain and a triangle far away; two clusters.
Scene two_molecules(double off) {
  Scene chain = random_chain(4, 11, 0.0);
  Scene triangle = ring(3, 12, 0.0);
  Scene s{"two_molecules", chain.bonds, Eigen::VectorXd(7), Eigen::Matrix3Xd(3, 7)};
  s.inv_mass << chain.inv_mass, triangle.inv_mass;
  s.x << chain.x, (triangle.x.colwise() + Eigen::Vector3d(10.0, 0.0, 0.0));
  for (StiffBond b : triangle.bonds) {
    b.i += 4;
    b.j += 4;
    s.bonds.push_back(b);
  }
  s.x += off * random_matrix(7, 13);
  return s;
}

// Chain 0–1–2–3–4 with bead 2 fixed: two bonds meet only at a fixed particle.
Scene chain_through_fixed_bead(double off) {
  Scene s = random_chain(5, 21, off);
  s.name = "chain_through_fixed_bead";
  s.inv_mass[2] = 0.0;
  return s;
}

// An open chain whose path is not the index order: particles numbered at random, bonds listed in
// random order, half of them from the far end to the near one (i = the later bead along the
// chain), and the last bead fixed. SHAKE's chord walks the chain along its path
// (ConstraintToolbox's chain_displace), so the path, the bonds' orientation and the fixed end
// must come out right whatever the numbering.
Scene scrambled_chain(double off) {
  Scene chain = random_chain(12, 6, 0.0);
  const int beads = static_cast<int>(chain.x.cols());
  std::mt19937 rng(7);
  std::vector<int> label(beads);
  std::iota(label.begin(), label.end(), 0);
  std::shuffle(label.begin(), label.end(), rng);
  Scene s{"scrambled_chain", {}, Eigen::VectorXd(beads), Eigen::Matrix3Xd(3, beads)};
  for (int k = 0; k < beads; ++k) {
    s.x.col(label[k]) = chain.x.col(k);
    s.inv_mass[label[k]] = chain.inv_mass[k];
  }
  s.inv_mass[label[beads - 1]] = 0.0;
  for (std::size_t b = 0; b < chain.bonds.size(); ++b) {
    StiffBond bond = chain.bonds[b];
    bond.i = label[chain.bonds[b].i];
    bond.j = label[chain.bonds[b].j];
    if (b % 2 == 1) std::swap(bond.i, bond.j);
    s.bonds.push_back(bond);
  }
  std::shuffle(s.bonds.begin(), s.bonds.end(), rng);
  s.x += off * random_matrix(beads, 8);
  return s;
}

// Every back end: tridiagonal (chains, pendulum), dense (rings, stars, triangle),
// sparse (the 100-bond ring), plus fixed particles.
std::vector<Scene> all_scenes() {
  const double off = 1e-2;
  std::vector<Scene> scenes = {
      pendulum(1e-2),      random_chain(10, 1, off),      ring(6, 2, off),           star(4, 3, off),
      two_molecules(off),  chain_through_fixed_bead(off), random_chain(101, 4, off), ring(100, 5, off),
      scrambled_chain(off)};
  scenes[6].name = "long_chain";
  scenes[7].name = "long_ring";
  return scenes;
}

// ---- independent dense references ---------------------------------------------------------

Eigen::VectorXd flat(const Eigen::Matrix3Xd& a) {
  return Eigen::Map<const Eigen::VectorXd>(a.data(), a.size());
}

Eigen::Matrix3Xd unflat(const Eigen::VectorXd& a) {
  return Eigen::Map<const Eigen::Matrix3Xd>(a.data(), 3, a.size() / 3);
}

// G(x) = g′(x): row b has +u_b in the columns of particle i and −u_b in those of j.
Eigen::MatrixXd jacobian(const Scene& s, const Eigen::Matrix3Xd& x) {
  Eigen::MatrixXd G = Eigen::MatrixXd::Zero(static_cast<Eigen::Index>(s.bonds.size()), x.size());
  for (int b = 0; b < static_cast<int>(s.bonds.size()); ++b) {
    const Eigen::Vector3d u = (x.col(s.bonds[b].i) - x.col(s.bonds[b].j)).normalized();
    G.block<1, 3>(b, 3 * s.bonds[b].i) = u.transpose();
    G.block<1, 3>(b, 3 * s.bonds[b].j) = -u.transpose();
  }
  return G;
}

Eigen::VectorXd inv_mass_diagonal(const Scene& s) {
  Eigen::VectorXd w(3 * s.inv_mass.size());
  for (int k = 0; k < s.inv_mass.size(); ++k) w.segment<3>(3 * k).setConstant(s.inv_mass[k]);
  return w;
}

// P f = f − Gᵀ S⁻¹ G M⁻¹ f, with S inverted densely.
Eigen::Matrix3Xd reference_projected_force(const Scene& s, const Eigen::Matrix3Xd& f) {
  const Eigen::MatrixXd G = jacobian(s, s.x);
  const Eigen::MatrixXd GW = G * inv_mass_diagonal(s).asDiagonal();
  const Eigen::VectorXd lambda = (GW * G.transpose()).inverse() * (GW * flat(f));
  return unflat(flat(f) - G.transpose() * lambda);
}

// v − M⁻¹ Gᵀ S⁻¹ G v.
Eigen::Matrix3Xd reference_projected_velocity(const Scene& s, const Eigen::Matrix3Xd& v) {
  const Eigen::MatrixXd G = jacobian(s, s.x);
  const Eigen::MatrixXd WGt = inv_mass_diagonal(s).asDiagonal() * G.transpose();
  const Eigen::VectorXd mu = (G * WGt).inverse() * (G * flat(v));
  return unflat(flat(v) - WGt * mu);
}

// A random velocity-like field that leaves fixed particles at rest.
Eigen::Matrix3Xd random_motion(const Scene& s, unsigned seed) {
  Eigen::Matrix3Xd v = random_matrix(static_cast<int>(s.x.cols()), seed);
  for (int k = 0; k < s.inv_mass.size(); ++k)
    if (s.inv_mass[k] == 0.0) v.col(k).setZero();
  return v;
}

double relative(const Eigen::Matrix3Xd& a, const Eigen::Matrix3Xd& b) {
  return (a - b).lpNorm<Eigen::Infinity>() / b.lpNorm<Eigen::Infinity>();
}

// ---- clusters -------------------------------------------------------------------------------

// Blocks of whole molecules: a block never ends inside a molecule (an index range joined by
// overlapping intervals), closes at the first molecule end at least min_particles past its start,
// and the last block takes what is left.
TEST(MoleculeBlocks, CloseOnlyAtMoleculeEndsPastTheMinimum) {
  // Molecules: 0–2 (0→2), 3–6 (3→4, 4→6: overlapping intervals join), 7, 8–9.
  const std::vector<std::int64_t> reach = {2, 1, 2, 4, 6, 5, 6, 7, 9, 9};
  std::vector<std::pair<std::int64_t, std::int64_t>> blocks;
  const auto block_of =
      stiffmd::molecule_blocks(reach, 4, [&](std::int64_t f, std::int64_t l) { blocks.emplace_back(f, l); });
  using B = std::pair<std::int64_t, std::int64_t>;
  EXPECT_EQ(blocks, (std::vector<B>{{0, 7}, {7, 10}}));
  EXPECT_EQ(block_of, (std::vector<std::int64_t>{0, 0, 0, 0, 0, 0, 0, 1, 1, 1}));
  blocks.clear();
  stiffmd::molecule_blocks(reach, 1, [&](std::int64_t f, std::int64_t l) { blocks.emplace_back(f, l); });
  EXPECT_EQ(blocks, (std::vector<B>{{0, 3}, {3, 7}, {7, 8}, {8, 10}}));
  blocks.clear();
  stiffmd::molecule_blocks(std::vector<std::int64_t>{9, 1, 2, 3, 4, 5, 6, 7, 8, 9}, 1,
                           [&](std::int64_t f, std::int64_t l) { blocks.emplace_back(f, l); });
  EXPECT_EQ(blocks, (std::vector<B>{{0, 10}}));  // a bond across the whole range: one block
}

TEST(ConstraintClusters, PendulumIsOneCluster) {
  const Scene s = pendulum(1e-2);
  ConstraintToolbox toolbox(s.bonds, s.inv_mass);
  ASSERT_EQ(toolbox.clusters().size(), 1u);
  EXPECT_EQ(toolbox.clusters()[0].bonds, (std::vector<int>{0, 1}));
  EXPECT_EQ(toolbox.clusters()[0].particles, (std::vector<int>{0, 1, 2}));
}

TEST(ConstraintClusters, SeparateMoleculesAreSeparateClusters) {
  const Scene s = two_molecules(0.0);
  ConstraintToolbox toolbox(s.bonds, s.inv_mass);
  ASSERT_EQ(toolbox.clusters().size(), 2u);
  EXPECT_EQ(toolbox.clusters()[0].bonds, (std::vector<int>{0, 1, 2}));
  EXPECT_EQ(toolbox.clusters()[1].bonds, (std::vector<int>{3, 4, 5}));
}

TEST(ConstraintClusters, FixedBeadDoesNotCoupleItsBonds) {
  const Scene s = chain_through_fixed_bead(0.0);
  ConstraintToolbox toolbox(s.bonds, s.inv_mass);
  EXPECT_EQ(toolbox.clusters().size(), 2u);
}

// A pinned core (0) with arm A (bonds 0 and 3) and arm B (bond 2), a free dimer's bond (1) listed
// between them: the core couples nothing (S_bc = ±(u_b·u_c) m⁻¹ = 0 there), so its molecule holds
// two clusters, which come in the order of their first bond (0, 1, 2), not molecule by molecule.
TEST(ConstraintClusters, PinnedCoreSplitsItsMoleculeAndClustersComeByFirstBond) {
  const std::vector<StiffBond> bonds = {{0, 1, 1.0, 1.0}, {3, 4, 1.0, 1.0}, {0, 2, 1.0, 1.0}, {1, 5, 1.0, 1.0}};
  Eigen::VectorXd inv_mass = Eigen::VectorXd::Ones(6);
  inv_mass[0] = 0.0;
  const std::vector<ConstraintCluster> clusters = find_clusters(bonds, inv_mass);
  ASSERT_EQ(clusters.size(), 3u);
  EXPECT_EQ(clusters[0].bonds, (std::vector<int>{0, 3}));
  EXPECT_EQ(clusters[0].particles, (std::vector<int>{0, 1, 5}));
  EXPECT_EQ(clusters[1].bonds, (std::vector<int>{1}));
  EXPECT_EQ(clusters[1].particles, (std::vector<int>{3, 4}));
  EXPECT_EQ(clusters[2].bonds, (std::vector<int>{2}));
  EXPECT_EQ(clusters[2].particles, (std::vector<int>{0, 2}));
  // The molecules join through the pinned core all the same: one molecule, named by its first
  // particle, and the dimer.
  std::vector<std::pair<int, int>> pairs;
  for (const StiffBond& b : bonds) pairs.emplace_back(b.i, b.j);
  EXPECT_EQ(connected_components(6, pairs), (std::vector<int>{0, 0, 0, 1, 1, 0}));
  // A mobile core couples its two arms into one cluster, still first by its first bond.
  inv_mass[0] = 1.0;
  const std::vector<ConstraintCluster> joined = find_clusters(bonds, inv_mass);
  ASSERT_EQ(joined.size(), 2u);
  EXPECT_EQ(joined[0].bonds, (std::vector<int>{0, 2, 3}));
  EXPECT_EQ(joined[1].bonds, (std::vector<int>{1}));
}

TEST(DisjointSets, RootIsTheLeastElementWhateverTheOrderOfTheJoins) {
  DisjointSets sets(7);
  sets.join(6, 4), sets.join(4, 5), sets.join(2, 6), sets.join(3, 1);
  for (int a : {2, 4, 5, 6}) EXPECT_EQ(sets.root(a), 2) << a;
  EXPECT_EQ(sets.root(3), 1);
  EXPECT_EQ(sets.root(0), 0);
  sets.join(5, 1);
  for (int a : {1, 2, 3, 4, 5, 6}) EXPECT_EQ(sets.root(a), 1) << a;
}

// Vertices 0 … 8: 0–1–2 and 2–3 a path, 5 a non-coupling vertex between 4 and 6, 7–8 joined,
// listed in no particular order.
TEST(ConnectedComponents, LabelsByFirstVertexAndANonCouplingVertexJoinsNothing) {
  const std::vector<std::pair<int, int>> edges = {{8, 7}, {5, 4}, {3, 2}, {6, 5}, {1, 0}, {2, 1}};
  EXPECT_EQ(connected_components(9, edges), (std::vector<int>{0, 0, 0, 0, 1, 1, 1, 2, 2}));
  std::vector<char> couples(9, 1);
  couples[5] = 0;
  EXPECT_EQ(connected_components(9, edges, &couples), (std::vector<int>{0, 0, 0, 0, 1, 2, 3, 4, 4}));
  couples[2] = 0;  // the path splits at 2: {0, 1}, {2}, {3}
  EXPECT_EQ(connected_components(9, edges, &couples), (std::vector<int>{0, 0, 1, 2, 3, 4, 5, 6, 6}));
  EXPECT_EQ(connected_components(3, {}), (std::vector<int>{0, 1, 2}));
  EXPECT_TRUE(connected_components(0, {}).empty());
}

// find_clusters against its definition, on random bonds among few particles (branches, rings,
// repeated pairs) with random pinned ones: bonds b < c are in one cluster iff a path of bonds
// joins them, each sharing a mobile particle with the next; clusters by first bond, bonds and
// particles ascending.
TEST(ConstraintClusters, AreTheBondsJoinedThroughMobileParticles) {
  std::mt19937 rng(5);
  for (int trial = 0; trial < 200; ++trial) {
    const int n = 2 + trial % 13, m = trial % 17;
    std::uniform_int_distribution<int> particle(0, n - 1);
    std::vector<StiffBond> bonds;
    for (int b = 0; b < m; ++b) {
      const int i = particle(rng);
      int j = particle(rng);
      if (j == i) j = (i + 1) % n;
      bonds.push_back({i, j, 1.0, 1.0});
    }
    Eigen::VectorXd inv_mass = Eigen::VectorXd::Ones(n);
    for (int p = 0; p < n; ++p)
      if (rng() % 4 == 0) inv_mass[p] = 0.0;
    // The reference: bonds as vertices, joined at each mobile particle they share.
    std::vector<int> cluster_of(m);
    std::iota(cluster_of.begin(), cluster_of.end(), 0);
    for (bool changed = true; changed;) {
      changed = false;
      for (int b = 0; b < m; ++b)
        for (int c = 0; c < m; ++c)
          for (int p : {bonds[b].i, bonds[b].j})
            if (inv_mass[p] != 0.0 && (p == bonds[c].i || p == bonds[c].j) && cluster_of[c] > cluster_of[b])
              cluster_of[c] = cluster_of[b], changed = true;
    }
    std::vector<ConstraintCluster> expected;
    std::vector<int> index(m, -1);
    for (int b = 0; b < m; ++b) {
      int& k = index[cluster_of[b]];
      if (k < 0) k = static_cast<int>(expected.size()), expected.emplace_back();
      expected[k].bonds.push_back(b);
      for (int p : {bonds[b].i, bonds[b].j}) expected[k].particles.push_back(p);
    }
    for (ConstraintCluster& c : expected) {
      std::sort(c.particles.begin(), c.particles.end());
      c.particles.erase(std::unique(c.particles.begin(), c.particles.end()), c.particles.end());
    }
    const std::vector<ConstraintCluster> found = find_clusters(bonds, inv_mass);
    ASSERT_EQ(found.size(), expected.size()) << "trial " << trial;
    for (size_t k = 0; k < found.size(); ++k) {
      EXPECT_EQ(found[k].bonds, expected[k].bonds) << "trial " << trial << ", cluster " << k;
      EXPECT_EQ(found[k].particles, expected[k].particles) << "trial " << trial << ", cluster " << k;
    }
  }
}

TEST(ConstraintInput, RejectsBondsThatMakeSSingular) {
  const Eigen::VectorXd inv_mass = Eigen::Vector3d(0.0, 0.0, 1.0);
  EXPECT_THROW(ConstraintToolbox({{0, 1, 1.0, 1.0}}, inv_mass), InputError);                    // both ends fixed
  EXPECT_THROW(ConstraintToolbox({{1, 2, 1.0, 1.0}, {2, 1, 1.0, 1.0}}, inv_mass), InputError);  // duplicate
  EXPECT_THROW(ConstraintToolbox({{2, 2, 1.0, 1.0}}, inv_mass), InputError);                    // self
  EXPECT_THROW(ConstraintToolbox({{1, 3, 1.0, 1.0}}, inv_mass), InputError);                    // out of range
}

// ---- projections on every scene ---------------------------------------------------------------

class OnEveryScene : public testing::TestWithParam<Scene> {};

INSTANTIATE_TEST_SUITE_P(Constraints, OnEveryScene, testing::ValuesIn(all_scenes()),
                         [](const testing::TestParamInfo<Scene>& info) { return info.param.name; });

TEST_P(OnEveryScene, ProjectForceMatchesDenseFormula) {
  const Scene& s = GetParam();
  ConstraintToolbox toolbox(s.bonds, s.inv_mass);
  Eigen::Matrix3Xd f = random_matrix(static_cast<int>(s.x.cols()), 7);
  const Eigen::Matrix3Xd expected = reference_projected_force(s, f);
  toolbox.project_force(s.x, f);
  EXPECT_LT(relative(f, expected), 1e-10);
}

TEST_P(OnEveryScene, ProjectForceIsAProjection) {
  const Scene& s = GetParam();
  ConstraintToolbox toolbox(s.bonds, s.inv_mass);
  const Eigen::Matrix3Xd f = random_matrix(static_cast<int>(s.x.cols()), 8);
  Eigen::Matrix3Xd once = f;
  toolbox.project_force(s.x, once);
  Eigen::Matrix3Xd twice = once;
  toolbox.project_force(s.x, twice);
  EXPECT_LT(relative(twice, once), 1e-12);  // P² = P
  // G M⁻¹ P f = 0: the projected force accelerates nothing along the bond normals.
  const Eigen::MatrixXd GW = jacobian(s, s.x) * inv_mass_diagonal(s).asDiagonal();
  EXPECT_LT((GW * flat(once)).lpNorm<Eigen::Infinity>(), 1e-12 * (GW * flat(f)).lpNorm<Eigen::Infinity>());
}

TEST_P(OnEveryScene, ProjectForceLeavesTangentForceAlone) {
  const Scene& s = GetParam();
  ConstraintToolbox toolbox(s.bonds, s.inv_mass);
  // f = M t with G t = 0 (t tangent, zero at fixed particles), so G M⁻¹ f = 0 already.
  const Eigen::Matrix3Xd t = reference_projected_velocity(s, random_motion(s, 9));
  Eigen::Matrix3Xd f = Eigen::Matrix3Xd::Zero(3, s.x.cols());
  for (int k = 0; k < s.inv_mass.size(); ++k)
    if (s.inv_mass[k] > 0.0) f.col(k) = t.col(k) / s.inv_mass[k];
  const Eigen::Matrix3Xd tangent = f;
  toolbox.project_force(s.x, f);
  EXPECT_LT(relative(f, tangent), 1e-12);
}

TEST_P(OnEveryScene, ProjectVelocityRemovesBondStretching) {
  const Scene& s = GetParam();
  ConstraintToolbox toolbox(s.bonds, s.inv_mass);
  Eigen::Matrix3Xd v = random_motion(s, 10);
  const Eigen::Matrix3Xd expected = reference_projected_velocity(s, v);
  const double scale = (jacobian(s, s.x) * flat(v)).lpNorm<Eigen::Infinity>();
  toolbox.project_velocity(s.x, v);
  EXPECT_LT((jacobian(s, s.x) * flat(v)).lpNorm<Eigen::Infinity>(), 1e-12 * scale);  // G v = 0
  EXPECT_LT(relative(v, expected), 1e-10);  // and it is the M-orthogonal projection
  Eigen::Matrix3Xd again = v;
  toolbox.project_velocity(s.x, again);
  EXPECT_LT(relative(again, v), 1e-12);
}

TEST_P(OnEveryScene, ProjectVelocityAddsItsConstraintForce) {
  // The force output: force += M (P v − v) · rate at mobile particles, untouched at fixed ones
  // (Rattle's pressure reads it; against the dense reference projection).
  const Scene& s = GetParam();
  ConstraintToolbox toolbox(s.bonds, s.inv_mass);
  Eigen::Matrix3Xd v = random_motion(s, 11);
  const Eigen::Matrix3Xd before = random_motion(s, 12);  // what the force held already
  Eigen::Matrix3Xd expected = before;
  const Eigen::Matrix3Xd projected = reference_projected_velocity(s, v);
  const double rate = 7.0;
  for (int k = 0; k < static_cast<int>(s.inv_mass.size()); ++k)
    if (s.inv_mass[k] > 0.0) expected.col(k) += (projected.col(k) - v.col(k)) * (rate / s.inv_mass[k]);
  Eigen::Matrix3Xd force = before, plain = v;
  toolbox.project_velocity(s.x, v, &force, rate);
  toolbox.project_velocity(s.x, plain);
  EXPECT_EQ(v, plain) << "the force output changed the projection";
  EXPECT_LT(relative(force - before, expected - before), 1e-10);
  for (int k = 0; k < static_cast<int>(s.inv_mass.size()); ++k) {
    if (s.inv_mass[k] == 0.0) {
      EXPECT_EQ(force.col(k), before.col(k)) << "fixed particle " << k;
    }
  }
}

// A flat triangle: its three bond directions are parallel, G has rank 2 and S is singular.
// That must be an error naming the cluster, not NaN forces.
TEST(ConstraintProjectForce, CollinearTriangleThrowsInsteadOfReturningNaN) {
  Scene s = ring(3, 2, 0.0);
  s.x << 0.0, 1.0, 2.5,  //
      0.0, 0.0, 0.0,     //
      0.0, 0.0, 0.0;
  ConstraintToolbox toolbox(s.bonds, s.inv_mass);
  Eigen::Matrix3Xd f = random_matrix(3, 15);
  try {
    toolbox.project_force(s.x, f);
    FAIL() << "no NumericalError";
  } catch (const NumericalError& e) {
    EXPECT_NE(std::string(e.what()).find("cluster 0"), std::string::npos) << e.what();
    EXPECT_NE(std::string(e.what()).find("singular"), std::string::npos) << e.what();
  }
}

// ---- SHAKE / the mollifier α ------------------------------------------------------------------

TEST_P(OnEveryScene, ShakeProjectsOntoTheManifoldAlongMinvGT) {
  const Scene& s = GetParam();
  ConstraintToolbox toolbox(s.bonds, s.inv_mass);
  ASSERT_GT(toolbox.max_violation(s.x), 1e-4);
  Eigen::Matrix3Xd X = s.x;
  Eigen::VectorXd lambda;
  toolbox.shake(s.x, X, &lambda);
  EXPECT_LE(toolbox.max_violation(X), 1e-12);  // g(α(x)) = 0
  // α(x) − x = M⁻¹ G(x)ᵀ λ (paper eq. (ProMol)); fixed particles have zero rows of M⁻¹.
  const Eigen::VectorXd step = inv_mass_diagonal(s).asDiagonal() * jacobian(s, s.x).transpose() * lambda;
  EXPECT_LT((flat(X) - flat(s.x) - step).lpNorm<Eigen::Infinity>(), 1e-12);
  EXPECT_GT(step.lpNorm<Eigen::Infinity>(), 1e-4);
  // α(α(x)) = α(x).
  Eigen::Matrix3Xd XX = X;
  toolbox.shake(X, XX, &lambda);
  EXPECT_LT((XX - X).lpNorm<Eigen::Infinity>(), 1e-12);
  EXPECT_LT(lambda.lpNorm<Eigen::Infinity>(), 1e-12);
}

// shake(x, x): the reference and the iterate are the same matrix (RATTLE's start-up does this).
TEST_P(OnEveryScene, ShakeMayProjectItsOwnReferenceInPlace) {
  const Scene& s = GetParam();
  ConstraintToolbox toolbox(s.bonds, s.inv_mass);
  Eigen::Matrix3Xd X = s.x;
  toolbox.shake(s.x, X);
  Eigen::Matrix3Xd x = s.x;
  toolbox.shake(x, x);
  EXPECT_EQ((x - X).lpNorm<Eigen::Infinity>(), 0.0);
}

// RATTLE's use: y0 ≠ x_ref. The correction is along G(x_ref)ᵀ, not G(y0)ᵀ.
TEST_P(OnEveryScene, ShakeCorrectsAlongTheReferenceConfiguration) {
  const Scene& s = GetParam();
  ConstraintToolbox toolbox(s.bonds, s.inv_mass);
  const Eigen::Matrix3Xd y0 = s.x + 0.05 * random_motion(s, 14);
  Eigen::Matrix3Xd y = y0;
  Eigen::VectorXd lambda;
  toolbox.shake(s.x, y, &lambda);
  EXPECT_LE(toolbox.max_violation(y), 1e-12);
  const Eigen::VectorXd step = inv_mass_diagonal(s).asDiagonal() * jacobian(s, s.x).transpose() * lambda;
  EXPECT_LT((flat(y) - flat(y0) - step).lpNorm<Eigen::Infinity>(), 1e-12);
}

// Far from x_ref, J = G(y) M⁻¹ G(x_ref)ᵀ is far from S and the chain solver swaps rows on the
// way; exact Newton needs 5 iterations from this start, a broken row swap needs more.
TEST(ConstraintShake, ConvergesQuadraticallyFarFromTheReference) {
  const Scene s = random_chain(10, 8, 0.0);
  ConstraintToolbox toolbox(s.bonds, s.inv_mass);
  const Eigen::Matrix3Xd y0 = s.x + 0.3 * random_matrix(10, 108);
  Eigen::Matrix3Xd y = y0;
  Eigen::VectorXd lambda;
  ASSERT_NO_THROW(toolbox.shake(s.x, y, &lambda, 1e-12, 5));
  EXPECT_LE(toolbox.max_violation(y), 1e-12);
  const Eigen::VectorXd step = inv_mass_diagonal(s).asDiagonal() * jacobian(s, s.x).transpose() * lambda;
  EXPECT_LT((flat(y) - flat(y0) - step).lpNorm<Eigen::Infinity>(), 1e-12);
}

// Open chains of one length are solved in groups, their recurrences in lockstep
// (ChainLdlt::factorize_group, solve_group): each chain must get the bits it gets alone. Nine
// chains of 12 beads (groups of 4, 4, 1) against a toolbox per chain, for SHAKE of a drift (its
// chord path), a velocity and a force projection; one of the nine chains is far off the manifold,
// so SHAKE takes Newton steps on it while the others of its group take chord steps.
// `chains` random chains of `beads` beads on the manifold, far apart, as one scene (particles of
// chain c from c · beads on); parts receives each chain alone.
Scene chains_side_by_side(int chains, int beads, std::vector<Scene>& parts) {
  Scene all{"chains", {}, Eigen::VectorXd(chains * beads), Eigen::Matrix3Xd(3, chains * beads)};
  for (int c = 0; c < chains; ++c) {
    Scene part = random_chain(beads, 100 + c, 0.0);
    part.x.colwise() += Eigen::Vector3d(20.0 * c, 0.0, 0.0);
    all.inv_mass.segment(c * beads, beads) = part.inv_mass;
    all.x.middleCols(c * beads, beads) = part.x;
    for (StiffBond b : part.bonds) {
      b.i += c * beads;
      b.j += c * beads;
      all.bonds.push_back(b);
    }
    parts.push_back(part);
  }
  return all;
}

TEST(ConstraintShake, ChainsSolvedTogetherGetTheBitsTheyGetAlone) {
  const int chains = 9, beads = 12;
  std::vector<Scene> parts;
  const Scene all = chains_side_by_side(chains, beads, parts);
  const Eigen::Matrix3Xd v = random_matrix(chains * beads, 31), f = random_matrix(chains * beads, 32);
  ConstraintToolbox together(all.bonds, all.inv_mass);
  ASSERT_EQ(together.clusters().size(), static_cast<std::size_t>(chains));
  Eigen::Matrix3Xd y = all.x + 0.01 * v;
  y.middleCols(5 * beads, beads) += 0.06 * random_matrix(beads, 33);  // chain 5: Newton
  ASSERT_GT(ConstraintToolbox(parts[5].bonds, parts[5].inv_mass).max_violation(y.middleCols(5 * beads, beads)),
            1.2e-2);  // beyond the chord's start (1e-2 ℓ, ℓ ≤ 1.2)
  Eigen::Matrix3Xd v_all = v, f_all = f;
  together.shake(all.x, y);
  together.project_velocity(y, v_all);
  together.project_force(y, f_all);
  for (int c = 0; c < chains; ++c) {
    SCOPED_TRACE(testing::Message() << "chain " << c);
    ConstraintToolbox alone(parts[c].bonds, parts[c].inv_mass);
    Eigen::Matrix3Xd y_c = all.x.middleCols(c * beads, beads) + 0.01 * v.middleCols(c * beads, beads);
    if (c == 5) y_c += 0.06 * random_matrix(beads, 33);
    Eigen::Matrix3Xd v_c = v.middleCols(c * beads, beads), f_c = f.middleCols(c * beads, beads);
    alone.shake(all.x.middleCols(c * beads, beads), y_c);
    alone.project_velocity(y_c, v_c);
    alone.project_force(y_c, f_c);
    EXPECT_EQ((y.middleCols(c * beads, beads) - y_c).cwiseAbs().maxCoeff(), 0.0);
    EXPECT_EQ((v_all.middleCols(c * beads, beads) - v_c).cwiseAbs().maxCoeff(), 0.0);
    EXPECT_EQ((f_all.middleCols(c * beads, beads) - f_c).cwiseAbs().maxCoeff(), 0.0);
  }
}

// SHAKE's chord updates take two chains of a group at a time, side by side in the lanes of one
// register (ConstraintToolbox::Impl::chain_displace_pair), the last of an odd count alone. Seven
// chains of 9 beads (groups of 4 and 3: two pairs and a pair and a single), their last beads
// fixed (a zero inverse mass on the path), each drifted off the manifold: the positions and the
// multipliers of each chain must be the bits of the chain shaken alone, after one SHAKE and after
// a second from the first's result (chord steps on the kept factors).
TEST(ConstraintShake, ChainsUpdatedInPairsGetTheBitsTheyGetAlone) {
  const int chains = 7, beads = 9;
  std::vector<Scene> parts;
  Scene all = chains_side_by_side(chains, beads, parts);
  for (int c = 0; c < chains; ++c) {
    all.inv_mass[c * beads + beads - 1] = 0.0;
    parts[c].inv_mass[beads - 1] = 0.0;
  }
  const Eigen::Matrix3Xd drift = random_matrix(chains * beads, 41);
  ConstraintToolbox together(all.bonds, all.inv_mass);
  Eigen::Matrix3Xd y = all.x + 0.01 * drift;
  Eigen::VectorXd lambda;
  together.shake(all.x, y, &lambda);
  Eigen::Matrix3Xd y2 = y + 0.005 * drift;
  Eigen::VectorXd lambda2;
  together.shake(y, y2, &lambda2);
  for (int c = 0; c < chains; ++c) {
    SCOPED_TRACE(testing::Message() << "chain " << c);
    ConstraintToolbox alone(parts[c].bonds, parts[c].inv_mass);
    const Eigen::Matrix3Xd x_c = all.x.middleCols(c * beads, beads);
    const Eigen::Matrix3Xd y0_c = x_c + 0.01 * drift.middleCols(c * beads, beads);
    Eigen::Matrix3Xd y_c = y0_c;
    Eigen::VectorXd lambda_c;
    alone.shake(x_c, y_c, &lambda_c);
    Eigen::Matrix3Xd y2_c = y_c + 0.005 * drift.middleCols(c * beads, beads);
    Eigen::VectorXd lambda2_c;
    alone.shake(y_c, y2_c, &lambda2_c);
    const int bonds = beads - 1;
    EXPECT_EQ(std::memcmp(y.middleCols(c * beads, beads).data(), y_c.data(), sizeof(double) * 3 * beads), 0);
    EXPECT_EQ(std::memcmp(y2.middleCols(c * beads, beads).data(), y2_c.data(), sizeof(double) * 3 * beads), 0);
    EXPECT_EQ(std::memcmp(lambda.segment(c * bonds, bonds).data(), lambda_c.data(), sizeof(double) * bonds), 0);
    EXPECT_EQ(std::memcmp(lambda2.segment(c * bonds, bonds).data(), lambda2_c.data(), sizeof(double) * bonds), 0);
    EXPECT_LE(alone.max_violation(y2_c), 1e-12);
    EXPECT_EQ(y_c.col(beads - 1), y0_c.col(beads - 1));  // the fixed bead is not moved
  }
}

// Chains solved in a group fail as they would one after the other: the error names the first
// failing cluster in cluster order. Chains 6 and 7 (both in the second group of four) get a
// non-finite position; SHAKE, the velocity projection and the force projection must all name
// cluster 6.
TEST(ConstraintShake, ChainsInAGroupReportTheFirstFailingCluster) {
  const int chains = 9, beads = 12;
  std::vector<Scene> parts;
  const Scene all = chains_side_by_side(chains, beads, parts);
  Eigen::Matrix3Xd bad = all.x;
  bad(0, 6 * beads + 3) = std::numeric_limits<double>::quiet_NaN();
  bad(1, 7 * beads + 5) = std::numeric_limits<double>::infinity();
  auto message = [](auto&& call) -> std::string {
    try {
      call();
    } catch (const NumericalError& e) {
      return e.what();
    }
    return "no error";
  };
  {
    ConstraintToolbox toolbox(all.bonds, all.inv_mass);
    Eigen::Matrix3Xd y = bad;
    const std::string m = message([&] { toolbox.shake(all.x, y); });
    EXPECT_NE(m.find("cluster 6"), std::string::npos) << m;
  }
  {
    ConstraintToolbox toolbox(all.bonds, all.inv_mass);
    Eigen::Matrix3Xd v = random_matrix(chains * beads, 34);
    const std::string m = message([&] { toolbox.project_velocity(bad, v); });
    EXPECT_NE(m.find("cluster 6"), std::string::npos) << m;
  }
  {
    ConstraintToolbox toolbox(all.bonds, all.inv_mass);
    Eigen::Matrix3Xd f = random_matrix(chains * beads, 35);
    const std::string m = message([&] { toolbox.project_force(bad, f); });
    EXPECT_NE(m.find("cluster 6"), std::string::npos) << m;
  }
}

// A chain turned rigidly by 1.2 rad about z, plus a stretch of 1e-6: |g| is tiny, so SHAKE starts
// with chord steps on S(x_ref), but J = G(y) M⁻¹ G(x_ref)ᵀ is far from S (its diagonal is S's times
// cos 1.2 ≈ 0.36) and the chord cannot contract. SHAKE must notice and finish by Newton: converged,
// along G(x_ref)ᵀ, having factored J. (A chord kept to the end runs out of iterations.)
TEST(ConstraintShake, FallsBackToNewtonWhenTheChordDoesNotContract) {
  const Scene s = random_chain(10, 31, 0.0);
  ConstraintToolbox toolbox(s.bonds, s.inv_mass);
  Eigen::Matrix3Xd x = s.x;
  toolbox.shake(x, x);
  const Eigen::Vector3d centre = x.rowwise().mean();
  const double phi = 1.2;
  Eigen::Matrix3d turn;
  turn << std::cos(phi), -std::sin(phi), 0.0, std::sin(phi), std::cos(phi), 0.0, 0.0, 0.0, 1.0;
  Eigen::Matrix3Xd y0 = (turn * (x.colwise() - centre)).colwise() + centre;
  y0 += 1e-6 * random_matrix(10, 32);
  ASSERT_LT(toolbox.max_violation(y0), 1e-2);
  Eigen::Matrix3Xd y = y0;
  Eigen::VectorXd lambda;
  const std::int64_t before = toolbox.factorizations();
  ASSERT_NO_THROW(toolbox.shake(x, y, &lambda, 1e-12, 30));
  EXPECT_GT(toolbox.factorizations(), before);  // Newton's J
  EXPECT_LE(toolbox.max_violation(y), 1e-12);
  const Eigen::VectorXd step = inv_mass_diagonal(s).asDiagonal() * jacobian(s, x).transpose() * lambda;
  EXPECT_LT((flat(y) - flat(y0) - step).lpNorm<Eigen::Infinity>(), 1e-10);
}

TEST(ConstraintShake, ZeroLengthBondThrowsNamingTheCluster) {
  Scene s = two_molecules(0.0);
  s.x.col(5) = s.x.col(4);  // collapse bond (4, 5) of the triangle, cluster 1
  ConstraintToolbox toolbox(s.bonds, s.inv_mass);
  Eigen::Matrix3Xd y = s.x;
  try {
    toolbox.shake(s.x, y);
    FAIL() << "no NumericalError";
  } catch (const NumericalError& e) {
    EXPECT_NE(std::string(e.what()).find("cluster 1"), std::string::npos) << e.what();
    EXPECT_NE(std::string(e.what()).find("zero length"), std::string::npos) << e.what();
  }
}

// A U-shaped chain 0–1–2–3 (unit masses) whose middle bond is pulled to three times its
// length 1, the arms (length 0.9) perpendicular to it. Along X = x + M⁻¹G(x)ᵀλ the middle
// bond's x-extent is 3 + 2λ₁, while the arms keep |λ₁| ≤ 0.9: |3 + 2λ₁| = 1 is out of reach.
TEST(ConstraintShake, ChainWithABondStretchedThreefoldThrows) {
  const Eigen::VectorXd inv_mass = Eigen::Vector4d::Ones();
  const std::vector<StiffBond> bonds = {{0, 1, 0.9, 1.0}, {1, 2, 1.0, 1.0}, {2, 3, 0.9, 1.0}};
  Eigen::Matrix3Xd x(3, 4);
  x << 0.0, 0.0, 3.0, 3.0,  //
      0.9, 0.0, 0.0, 0.9,   //
      0.0, 0.0, 0.0, 0.0;
  ConstraintToolbox toolbox(bonds, inv_mass);
  Eigen::Matrix3Xd y = x;
  try {
    toolbox.shake(x, y);
    FAIL() << "no NumericalError";
  } catch (const NumericalError& e) {
    EXPECT_NE(std::string(e.what()).find("cluster 0"), std::string::npos) << e.what();
  }
}

// Pivots 0 and 3 fixed 9 apart, three unit bonds between them: the manifold is empty, so
// Newton cannot converge and must say so instead of returning NaN.
TEST(ConstraintShake, OverstretchedAnchoredChainThrows) {
  const Eigen::VectorXd inv_mass = Eigen::Vector4d(0.0, 1.0, 1.0, 0.0);
  const std::vector<StiffBond> bonds = {{0, 1, 1.0, 1.0}, {1, 2, 1.0, 1.0}, {2, 3, 1.0, 1.0}};
  Eigen::Matrix3Xd x(3, 4);
  x << 0.0, 3.0, 6.0, 9.0,  //
      0.0, 0.5, -0.5, 0.0,  //
      0.0, 0.0, 0.0, 0.0;
  ConstraintToolbox toolbox(bonds, inv_mass);
  Eigen::Matrix3Xd y = x;
  try {
    toolbox.shake(x, y);
    FAIL() << "no NumericalError";
  } catch (const NumericalError& e) {
    EXPECT_NE(std::string(e.what()).find("cluster 0"), std::string::npos) << e.what();
  }
}

TEST(ConstraintShake, NonConvergenceNamesClusterWorstBondAndIterations) {
  Scene s = two_molecules(0.0);
  s.x.col(6) += Eigen::Vector3d(0.3, 0.2, 0.0);  // disturb the triangle only, cluster 1
  ConstraintToolbox toolbox(s.bonds, s.inv_mass);
  Eigen::Matrix3Xd y = s.x;
  try {
    toolbox.shake(s.x, y, nullptr, 1e-12, 1);
    FAIL() << "no NumericalError";
  } catch (const NumericalError& e) {
    const std::string message = e.what();
    EXPECT_NE(message.find("cluster 1 after 1 iterations"), std::string::npos) << message;
    EXPECT_NE(message.find("worst bond"), std::string::npos) << message;
  }
}

// LAMMPS's fix shake tolerance (multiplier_tol): on a single cluster, the iterates y_k are those
// of the default solve cut off after k updates (max_iter = k: the throw leaves y_k). Each update
// δ_k = S(x_ref)⁻¹ G(x_ref)(y_k − y_{k−1}) (the step is M⁻¹G(x_ref)ᵀδ), formed here densely, is in
// LAMMPS's scaling |δ_b| / |d_b(x_ref)|. With the tolerance between the (K−1)th and the Kth
// update's, the solve must return y_K bit for bit: not y_{K−1} (stopped early), nor a later iterate
// (iterated on towards |g| ≤ 1e-12), while y_K is still off the manifold by more than 1e-12. Chains from a
// drift take chord steps on S(x_ref), the triangle and the star Newton steps on J, and a chain
// far from x_ref Newton from the start.
TEST(ConstraintShake, MultiplierToleranceStopsAtTheFirstIterateMeetingIt) {
  struct Case {
    Scene scene;
    double drift;
  };
  const std::vector<Case> cases = {{random_chain(10, 41, 0.0), 0.05},
                                   {ring(3, 42, 0.0), 0.05},
                                   {star(3, 43, 0.0), 0.05},
                                   {random_chain(6, 44, 0.0), 0.3}};
  for (const Case& c : cases) {
    const Scene& s = c.scene;
    SCOPED_TRACE(s.name + " drift " + std::to_string(c.drift));
    Eigen::Matrix3Xd x = s.x;
    ConstraintToolbox(s.bonds, s.inv_mass).shake(x, x);
    ASSERT_EQ(ConstraintToolbox(s.bonds, s.inv_mass).clusters().size(), 1u);
    const Eigen::Matrix3Xd y0 = x + c.drift * random_motion(s, 45);
    auto iterate = [&](int k) {
      Eigen::Matrix3Xd y = y0;
      try {
        ConstraintToolbox(s.bonds, s.inv_mass).shake(x, y, nullptr, 1e-12, k);
      } catch (const NumericalError&) {  // y_k: not converged to 1e-12 after k updates
      }
      return y;
    };
    const Eigen::MatrixXd G = jacobian(s, x);
    const Eigen::MatrixXd S = G * inv_mass_diagonal(s).asDiagonal() * G.transpose();
    auto update = [&](const Eigen::Matrix3Xd& from, const Eigen::Matrix3Xd& to) {
      const Eigen::VectorXd delta = S.ldlt().solve(G * (flat(to) - flat(from)));
      double worst = 0.0;
      for (int b = 0; b < static_cast<int>(s.bonds.size()); ++b)
        worst = std::max(worst, std::abs(delta[b]) / (x.col(s.bonds[b].i) - x.col(s.bonds[b].j)).norm());
      return worst;
    };
    // Stop at y_K, K = 3 where y_3 is still off the manifold by more than 1e-12, else K = 2 (Newton
    // converges quadratically: on the triangle y_3 is already within it).
    std::vector<Eigen::Matrix3Xd> ys = {y0};
    for (int k = 1; k <= 4; ++k) ys.push_back(iterate(k));
    const ConstraintToolbox measure(s.bonds, s.inv_mass);
    const int K = measure.max_violation(ys[3]) > 1e-12 ? 3 : 2;
    ASSERT_GT(measure.max_violation(ys[K]), 1e-12);
    ASSERT_NE(flat(ys[K]), flat(ys[K + 1]));
    ASSERT_NE(flat(ys[K - 1]), flat(ys[K]));
    const double before = update(ys[K - 2], ys[K - 1]), last = update(ys[K - 1], ys[K]);
    ASSERT_GT(before, 10.0 * last);
    const double tol = std::sqrt(before * last);
    Eigen::Matrix3Xd y = y0;
    Eigen::VectorXd lambda;
    ConstraintToolbox toolbox(s.bonds, s.inv_mass);
    toolbox.shake(x, y, &lambda, 1e-12, 50, tol);
    EXPECT_EQ(flat(y), flat(ys[K]));
    // The multipliers are the sum of the K updates: y − y0 = M⁻¹G(x_ref)ᵀλ.
    const Eigen::VectorXd step = inv_mass_diagonal(s).asDiagonal() * G.transpose() * lambda;
    EXPECT_LT((flat(y) - flat(y0) - step).lpNorm<Eigen::Infinity>(), 1e-12);
    // The velocity projection that follows at y uses G(y), measured when the iterate was accepted.
    Eigen::Matrix3Xd v = random_motion(s, 46);
    toolbox.project_velocity(y, v);
    const Scene at_y{s.name, s.bonds, s.inv_mass, y};
    EXPECT_LT((jacobian(at_y, y) * flat(v)).lpNorm<Eigen::Infinity>(), 1e-12);
  }
}

// ---- one configuration, measured and factored once (docs/design.md §2) ---------------------------

// RATTLE's drift: x_ref on the manifold, v tangent there, y0 = x_ref + τv, so |g(y0)| ~ τ²|v|².
// Open chains then take SHAKE's chord steps on the kept S(x_ref) and need no factorization; the
// result satisfies Newton's identities, and it has the bits of a toolbox that never saw x_ref
// (what a restarted run computes).
TEST_P(OnEveryScene, ShakeOfADriftIsTheConstrainedStepAlongTheReference) {
  const Scene& s = GetParam();
  ConstraintToolbox toolbox(s.bonds, s.inv_mass);
  Eigen::Matrix3Xd x = s.x;
  toolbox.shake(x, x);
  Eigen::Matrix3Xd v = random_motion(s, 21);
  toolbox.project_velocity(x, v);
  for (const double tau : {1e-3, 1e-2, 3e-2}) {
    const Eigen::Matrix3Xd y0 = x + tau * v;
    ASSERT_GT(toolbox.max_violation(y0), 1e-9);
    Eigen::Matrix3Xd y = y0;
    Eigen::VectorXd lambda;
    const std::int64_t before = toolbox.factorizations();
    toolbox.shake(x, y, &lambda);
    if (s.name == "chain10" || s.name == "long_chain" ||
        s.name == "scrambled_chain") {  // open chains: chord steps on S(x)
      EXPECT_EQ(toolbox.factorizations(), before) << "tau " << tau;
    }
    EXPECT_LE(toolbox.max_violation(y), 1e-12);
    const Eigen::VectorXd step = inv_mass_diagonal(s).asDiagonal() * jacobian(s, x).transpose() * lambda;
    EXPECT_LT((flat(y) - flat(y0) - step).lpNorm<Eigen::Infinity>(), 1e-12);
    ConstraintToolbox fresh(s.bonds, s.inv_mass);
    Eigen::Matrix3Xd y_fresh = y0;
    fresh.shake(x, y_fresh);
    EXPECT_EQ((y - y_fresh).lpNorm<Eigen::Infinity>(), 0.0) << "tau " << tau;
    toolbox.project_velocity(x, v);  // x kept again for the next τ
  }
}

// A constrained BAOAB step asks for S at one position up to three times (velocity projections,
// the force projection, the next step's SHAKE): one factorization. A configuration changed in
// place, by however little, is measured and factored afresh.
TEST_P(OnEveryScene, FactorsSOncePerConfiguration) {
  const Scene& s = GetParam();
  ConstraintToolbox toolbox(s.bonds, s.inv_mass);
  Eigen::Matrix3Xd x = s.x;
  toolbox.shake(x, x);
  Eigen::Matrix3Xd v = random_motion(s, 22), f = random_motion(s, 23);
  const std::int64_t before = toolbox.factorizations();
  toolbox.project_velocity(x, v);
  Eigen::Matrix3Xd v2 = random_motion(s, 24);
  toolbox.project_velocity(x, v2);
  toolbox.project_force(x, f);
  EXPECT_EQ(toolbox.factorizations() - before, static_cast<std::int64_t>(toolbox.clusters().size()));
  ConstraintToolbox fresh(s.bonds, s.inv_mass);
  Eigen::Matrix3Xd v2_fresh = random_motion(s, 24), f_fresh = random_motion(s, 23);
  fresh.project_velocity(x, v2_fresh);
  fresh.project_force(x, f_fresh);
  EXPECT_EQ((v2 - v2_fresh).lpNorm<Eigen::Infinity>(), 0.0);
  EXPECT_EQ((f - f_fresh).lpNorm<Eigen::Infinity>(), 0.0);

  const int moved = s.bonds.back().j;
  x(1, moved) = std::nextafter(x(1, moved), 2.0);  // one bit of one coordinate
  Eigen::Matrix3Xd v3 = random_motion(s, 25), v3_fresh = v3;
  const std::int64_t middle = toolbox.factorizations();
  toolbox.project_velocity(x, v3);
  EXPECT_EQ(toolbox.factorizations() - middle, static_cast<std::int64_t>(toolbox.clusters().size()));
  ConstraintToolbox(s.bonds, s.inv_mass).project_velocity(x, v3_fresh);
  EXPECT_EQ((v3 - v3_fresh).lpNorm<Eigen::Infinity>(), 0.0);
}

// ---- the mollified force ------------------------------------------------------------------

// U = Σ_k X_k,y (gravity along −y, unit weights) + ½|X_t − c|² (a tether on particle t).
struct SlowPotential {
  int tethered;
  Eigen::Vector3d anchor{0.3, -0.7, 0.4};
  double energy(const Eigen::Matrix3Xd& x) const {
    return x.row(1).sum() + 0.5 * (x.col(tethered) - anchor).squaredNorm();
  }
  void force(const Eigen::Matrix3Xd& x, Eigen::Matrix3Xd& f) const {
    f.setZero();
    f.row(1).setConstant(-1.0);
    f.col(tethered) -= x.col(tethered) - anchor;
  }
};

class MollifiedForce : public testing::TestWithParam<Scene> {};

// The sparse back end (SparseLU for Jᵀ).
Scene long_ring() {
  Scene s = ring(100, 5, 1e-2);
  s.name = "long_ring";
  return s;
}

// far_chain is bonds stretched by up to 0.44 of their length: there Jᵀ is far enough from S
// that the chain solver swaps rows, which the near-manifold scenes never make it do.
Scene far_chain() {
  Scene s = random_chain(10, 186, 0.3);
  s.name = "far_chain";
  return s;
}

INSTANTIATE_TEST_SUITE_P(Constraints, MollifiedForce,
                         testing::Values(pendulum(1e-2), random_chain(10, 1, 1e-2), ring(6, 2, 1e-2), star(3, 3, 1e-2),
                                         two_molecules(1e-2), chain_through_fixed_bead(1e-2), far_chain(), long_ring()),
                         [](const testing::TestParamInfo<Scene>& info) { return info.param.name; });

// F̄(x) = −∇_x U(α(x)), checked against central differences (every coordinate, fixed ones too:
// α depends on them through the bonds).
TEST_P(MollifiedForce, IsTheGradientOfTheMollifiedPotential) {
  const Scene& s = GetParam();
  ConstraintToolbox toolbox(s.bonds, s.inv_mass);
  const SlowPotential U{static_cast<int>(s.x.cols()) - 1};
  const double tol = 1e-14;
  auto mollified_energy = [&](const Eigen::Matrix3Xd& x) {
    Eigen::Matrix3Xd X = x;
    toolbox.shake(x, X, nullptr, tol);
    return U.energy(X);
  };
  int calls = 0;
  const ForceFunction f_slow = [&](const Eigen::Matrix3Xd& x, Eigen::Matrix3Xd& out) {
    ++calls;
    U.force(x, out);
  };
  Eigen::Matrix3Xd X(3, s.x.cols()), force(3, s.x.cols());
  toolbox.mollified_force(s.x, f_slow, X, force, tol);
  EXPECT_EQ(calls, 1);
  EXPECT_LE(toolbox.max_violation(X), tol);

  // Fourth-order central differences: far from the manifold α is strongly curved, and the
  // second-order stencil's truncation error would blur a real discrepancy.
  const double h = 1e-5;
  Eigen::Matrix3Xd numeric(3, s.x.cols());
  for (int k = 0; k < s.x.cols(); ++k)
    for (int a = 0; a < 3; ++a) {
      auto shifted = [&](double t) {
        Eigen::Matrix3Xd y = s.x;
        y(a, k) += t;
        return mollified_energy(y);
      };
      numeric(a, k) = -(8.0 * (shifted(h) - shifted(-h)) - (shifted(2 * h) - shifted(-2 * h))) / (12.0 * h);
    }
  EXPECT_LT(relative(force, numeric), 1e-7) << "analytic\n" << force << "\nnumeric\n" << numeric;
}

// On the manifold α(x) = x and λ = 0, so J = S and α′(x)ᵀ = P(x) exactly.
TEST(ConstraintMollifiedForce, EqualsTheProjectedForce) {
  Scene s = random_chain(10, 1, 0.0);
  ConstraintToolbox toolbox(s.bonds, s.inv_mass);
  const SlowPotential U{3};
  const ForceFunction f_slow = [&](const Eigen::Matrix3Xd& x, Eigen::Matrix3Xd& out) { U.force(x, out); };
  Eigen::Matrix3Xd X(3, s.x.cols()), mollified(3, s.x.cols()), projected(3, s.x.cols());
  toolbox.mollified_force(s.x, f_slow, X, mollified);
  U.force(s.x, projected);
  toolbox.project_force(s.x, projected);
  EXPECT_LT(relative(mollified, projected), 1e-12);
}

// ‖α′(x)ᵀ f − P(x) f‖ for gravity f (so f(α(x)) = f(x)) at a state with g(x) = O(ε).
double mollified_minus_projected(const Scene& s) {
  ConstraintToolbox toolbox(s.bonds, s.inv_mass);
  const ForceFunction gravity = [](const Eigen::Matrix3Xd&, Eigen::Matrix3Xd& out) {
    out.setZero();
    out.row(1).setConstant(-1.0);
  };
  Eigen::Matrix3Xd X(3, s.x.cols()), mollified(3, s.x.cols()), projected(3, s.x.cols());
  toolbox.mollified_force(s.x, gravity, X, mollified);
  gravity(s.x, projected);
  toolbox.project_force(s.x, projected);
  return (mollified - projected).norm();
}

// Paper Lemma (alpha): α′(x)ᵀ = P(x) + O(ε). Ten times smaller ε, ten times smaller gap.
TEST(ConstraintMollifiedForce, DiffersFromProjectedForceByOrderEpsilon) {
  const double pendulum_ratio = mollified_minus_projected(pendulum(1e-2)) / mollified_minus_projected(pendulum(1e-3));
  const double chain_ratio =
      mollified_minus_projected(random_chain(10, 1, 1e-2)) / mollified_minus_projected(random_chain(10, 1, 1e-3));
  std::printf("O(eps) ratios (eps = 1e-2 over eps = 1e-3): pendulum %.3f, chain %.3f\n", pendulum_ratio, chain_ratio);
  EXPECT_GT(pendulum_ratio, 5.0);
  EXPECT_LT(pendulum_ratio, 20.0);
  EXPECT_GT(chain_ratio, 5.0);
  EXPECT_LT(chain_ratio, 20.0);
}

}  // namespace
}  // namespace stiffmd
