// Polymer builders and Maxwell–Boltzmann velocities (engine/scene/builders.hpp): geometry checked by
// brute force against Box::min_image, topology against the bonds, statistics of the velocities.
#include <gtest/gtest.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <set>
#include <stdexcept>
#include <string>
#include <vector>

#include "engine/scene/builders.hpp"

namespace stiffmd {
namespace {

using Eigen::Matrix3Xd;
using Eigen::Vector3d;
using Eigen::VectorXd;

Box open_box(double side = 0.0) {
  Box b;
  b.lengths.setConstant(side);
  return b;
}

double distance(const Polymer& p, const Box& box, int i, int j) {
  return box.min_image(p.x.col(i) - p.x.col(j)).norm();
}

// All pairs, O(N²): the closest non-bonded pair under the minimum image.
struct Closest {
  double d = INFINITY;
  int i = -1, j = -1;
};
Closest closest_nonbonded(const Polymer& p, const Box& box) {
  const int n = static_cast<int>(p.x.cols());
  std::set<std::pair<int, int>> bonded;
  for (auto [i, j] : p.bonds) bonded.insert({std::min(i, j), std::max(i, j)});
  Closest c;
  double best2 = INFINITY;
  for (int i = 0; i < n; ++i)
    for (int j = i + 1; j < n; ++j) {
      const double d2 = box.min_image(p.x.col(i) - p.x.col(j)).squaredNorm();
      if (d2 < best2 && !bonded.count({i, j})) {
        best2 = d2;
        c = {std::sqrt(d2), i, j};
      }
    }
  return c;
}

void expect_no_overlap(const Polymer& p, const Box& box, double min_distance) {
  const Closest c = closest_nonbonded(p, box);
  EXPECT_GE(c.d, min_distance - 1e-12) << "beads " << c.i << " and " << c.j;
}

// Every bond exactly bond_length, both under the minimum image and unwrapped (chains are
// continuous across the boundaries).
void expect_exact_bonds(const Polymer& p, const Box& box, double bond_length) {
  double worst = 0.0, worst_raw = 0.0;
  for (auto [i, j] : p.bonds) {
    worst = std::max(worst, std::abs(distance(p, box, i, j) - bond_length));
    worst_raw = std::max(worst_raw, std::abs((p.x.col(i) - p.x.col(j)).norm() - bond_length));
  }
  EXPECT_LT(worst, 1e-12);
  EXPECT_LT(worst_raw, 1e-12);
}

std::vector<std::vector<int>> neighbours(const Polymer& p) {
  std::vector<std::vector<int>> nb(static_cast<size_t>(p.x.cols()));
  for (auto [i, j] : p.bonds) {
    nb[i].push_back(j);
    nb[j].push_back(i);
  }
  return nb;
}

// The angles are exactly the bonded triplets i–j–k (i ≠ k), each once.
void expect_angles_match_bonds(const Polymer& p) {
  std::multiset<std::array<int, 3>> got, want;
  for (auto a : p.angles) got.insert({std::min(a[0], a[2]), a[1], std::max(a[0], a[2])});
  const auto nb = neighbours(p);
  for (int j = 0; j < static_cast<int>(nb.size()); ++j)
    for (size_t u = 0; u < nb[j].size(); ++u)
      for (size_t v = u + 1; v < nb[j].size(); ++v)
        want.insert({std::min(nb[j][u], nb[j][v]), j, std::max(nb[j][u], nb[j][v])});
  EXPECT_EQ(got, want);
  for (auto a : p.angles) EXPECT_NE(a[0], a[2]);
}

// No bond within a molecule is missing or crosses molecules; molecule ids are 0..M−1 in blocks.
void expect_molecules(const Polymer& p, int molecules, int per_molecule) {
  ASSERT_EQ(static_cast<int>(p.molecule.size()), molecules * per_molecule);
  for (int i = 0; i < molecules * per_molecule; ++i) ASSERT_EQ(p.molecule[i], i / per_molecule) << "bead " << i;
  for (auto [i, j] : p.bonds) EXPECT_EQ(p.molecule[i], p.molecule[j]);
}

// ---------------------------------------------------------------------------------------------

TEST(BoxForDensity, CubeOfTheRequestedDensity) {
  for (auto [n, rho] : {std::pair{10000, 0.85}, {1, 1.0}, {3000, 0.1}, {777, 2.5}}) {
    const Box b = box_for_density(n, rho);
    EXPECT_TRUE((b.periodic.array() == 1).all());
    EXPECT_EQ(b.origin, Vector3d::Zero());
    EXPECT_EQ(b.lengths[0], b.lengths[1]);
    EXPECT_EQ(b.lengths[0], b.lengths[2]);
    EXPECT_NEAR(n / b.lengths.prod(), rho, 1e-13 * rho);
  }
  EXPECT_THROW(box_for_density(0, 0.85), std::invalid_argument);
  EXPECT_THROW(box_for_density(10, 0.0), std::invalid_argument);
  EXPECT_THROW(box_for_density(10, -1.0), std::invalid_argument);
  EXPECT_THROW(box_for_density(10, NAN), std::invalid_argument);
}

TEST(LinearChains, MeltGeometryAndTopology) {
  ChainSpec spec;
  spec.chains = 30;
  spec.beads = 100;
  spec.min_distance = 0.9;
  spec.seed = 7;
  const Box box = box_for_density(spec.chains * spec.beads, 0.85);
  const Polymer p = build_linear_chains(spec, box);
  ASSERT_EQ(p.x.cols(), 3000);
  EXPECT_NEAR(p.x.cols() / box.lengths.prod(), 0.85, 1e-12);
  expect_molecules(p, 30, 100);
  ASSERT_EQ(p.bonds.size(), 30u * 99u);
  for (int c = 0, b = 0; c < 30; ++c)
    for (int k = 0; k + 1 < 100; ++k, ++b) EXPECT_EQ(p.bonds[b], std::make_pair(c * 100 + k, c * 100 + k + 1));
  expect_exact_bonds(p, box, spec.bond_length);
  expect_no_overlap(p, box, spec.min_distance);
  expect_angles_match_bonds(p);
  EXPECT_EQ(p.angles.size(), 30u * 98u);
  for (auto a : p.angles) {  // consecutive triplets along the backbone, vertex in the middle
    EXPECT_EQ(a[0] + 1, a[1]);
    EXPECT_EQ(a[1] + 1, a[2]);
  }
  // Starts lie in the periodic cell; the chains are unwrapped (some leave it).
  for (int c = 0; c < 30; ++c)
    for (int a = 0; a < 3; ++a) {
      EXPECT_GE(p.x(a, c * 100), 0.0);
      EXPECT_LT(p.x(a, c * 100), box.lengths[a]);
    }
  EXPECT_TRUE((p.x.array() < 0.0).any() || (p.x.array() > box.lengths[0]).any());
}

TEST(LinearChains, BoxWithAnOriginAndUnequalSides) {
  Box box;
  box.origin = Vector3d(-5.0, 10.0, 2.5);
  box.lengths = Vector3d(12.0, 9.0, 15.0);
  box.periodic.setOnes();
  ChainSpec spec;
  spec.chains = 12;
  spec.beads = 60;
  spec.bond_length = 1.1;
  spec.min_distance = 0.95;
  spec.seed = 3;
  const Polymer p = build_linear_chains(spec, box);
  expect_exact_bonds(p, box, 1.1);
  expect_no_overlap(p, box, 0.95);
  for (int c = 0; c < 12; ++c)
    for (int a = 0; a < 3; ++a) {
      EXPECT_GE(p.x(a, c * 60), box.origin[a]);
      EXPECT_LT(p.x(a, c * 60), box.origin[a] + box.lengths[a]);
    }
}

TEST(LinearChains, OpenSpace) {
  // One chain, no region: it starts on the origin.
  ChainSpec one;
  one.beads = 300;
  one.min_distance = 0.9;
  const Box none = open_box();
  const Polymer p = build_linear_chains(one, none);
  EXPECT_EQ(p.x.col(0), Vector3d::Zero());
  expect_exact_bonds(p, none, one.bond_length);
  expect_no_overlap(p, none, 0.9);
  expect_angles_match_bonds(p);

  // Several chains: starts in the region of the box's lengths centred on its origin.
  Box region = open_box(20.0);
  region.origin = Vector3d(100.0, -50.0, 0.0);
  ChainSpec many;
  many.chains = 25;
  many.beads = 40;
  many.seed = 11;
  const Polymer q = build_linear_chains(many, region);
  expect_exact_bonds(q, region, many.bond_length);
  expect_no_overlap(q, region, many.min_distance);
  for (int c = 0; c < 25; ++c)
    for (int a = 0; a < 3; ++a) EXPECT_LE(std::abs(q.x(a, c * 40) - region.origin[a]), 10.0);
}

TEST(LinearChains, SlabPeriodicInXYOpenInZ) {
  Box slab;
  slab.origin = Vector3d(0.0, 0.0, 3.0);
  slab.lengths = Vector3d(10.0, 10.0, 4.0);
  slab.periodic = Eigen::Vector3i(1, 1, 0);
  ChainSpec spec;
  spec.chains = 20;
  spec.beads = 30;
  spec.min_distance = 0.9;
  spec.seed = 4;
  const Polymer p = build_linear_chains(spec, slab);
  expect_exact_bonds(p, slab, spec.bond_length);
  expect_no_overlap(p, slab, spec.min_distance);
  for (int c = 0; c < 20; ++c) {
    EXPECT_GE(p.x(0, c * 30), 0.0);
    EXPECT_LT(p.x(0, c * 30), 10.0);
    EXPECT_LE(std::abs(p.x(2, c * 30) - 3.0), 2.0);  // open axis: centred on the origin
  }
}

TEST(LinearChains, ZeroMinDistanceIsAPlainRandomWalk) {
  ChainSpec spec;
  spec.chains = 3;
  spec.beads = 50;
  spec.min_distance = 0.0;
  const Box box = box_for_density(150, 0.85);
  const Polymer p = build_linear_chains(spec, box);
  expect_exact_bonds(p, box, spec.bond_length);
  expect_molecules(p, 3, 50);
}

TEST(Rings, ClosedExactAndSelfAvoiding) {
  ChainSpec spec;
  spec.chains = 20;
  spec.beads = 100;
  spec.min_distance = 0.85;
  spec.seed = 5;
  const Box box = box_for_density(2000, 0.85);
  const Polymer p = build_rings(spec, box);
  expect_molecules(p, 20, 100);
  ASSERT_EQ(p.bonds.size(), 2000u);  // n bonds per ring of n
  std::set<std::pair<int, int>> bonds;
  for (auto [i, j] : p.bonds) bonds.insert({std::min(i, j), std::max(i, j)});
  for (int c = 0; c < 20; ++c) {
    const int f = c * 100;
    EXPECT_TRUE(bonds.count({f, f + 99})) << "ring " << c << " is not closed";
    for (int k = 0; k + 1 < 100; ++k) EXPECT_TRUE(bonds.count({f + k, f + k + 1}));
  }
  for (const auto& nb : neighbours(p)) EXPECT_EQ(nb.size(), 2u);
  expect_exact_bonds(p, box, spec.bond_length);  // the closing bonds too
  expect_no_overlap(p, box, spec.min_distance);
  expect_angles_match_bonds(p);
  EXPECT_EQ(p.angles.size(), 2000u);
}

// Small rings leave the bridge little slack: without the reach restriction the tips would often
// end up more than two bonds apart, and the closing bead could not bond to both.
TEST(Rings, ManySmallRingsCloseExactly) {
  for (int n = 4; n <= 10; ++n) {
    ChainSpec spec;
    spec.chains = 300;
    spec.beads = n;
    spec.min_distance = 0.8;
    spec.seed = static_cast<std::uint64_t>(n);
    const Box box = box_for_density(300 * n, 0.3);
    const Polymer p = build_rings(spec, box);
    expect_exact_bonds(p, box, spec.bond_length);
  }
}

TEST(Rings, SmallestRingIsAnEquilateralTriangle) {
  ChainSpec spec;
  spec.beads = 3;
  spec.bond_length = 1.3;
  const Polymer p = build_rings(spec, open_box());
  ASSERT_EQ(p.bonds.size(), 3u);
  const Box none = open_box();
  expect_exact_bonds(p, none, 1.3);
  EXPECT_EQ(p.angles.size(), 3u);
  expect_angles_match_bonds(p);
}

TEST(Rings, OpenSpaceSingleRing) {
  ChainSpec spec;
  spec.beads = 200;
  spec.min_distance = 0.9;
  const Box none = open_box();
  const Polymer p = build_rings(spec, none);
  expect_exact_bonds(p, none, spec.bond_length);
  expect_no_overlap(p, none, 0.9);
  EXPECT_EQ(p.x.col(0), Vector3d::Zero());
}

TEST(Stars, TopologyAndGeometry) {
  const int arms = 5, beads = 20, stars = 10, size = 1 + arms * beads;
  ChainSpec spec;
  spec.chains = stars;
  spec.beads = beads;
  spec.min_distance = 0.85;
  spec.seed = 9;
  const Box box = box_for_density(stars * size, 0.85);
  const Polymer p = build_stars(spec, arms, box);
  expect_molecules(p, stars, size);
  ASSERT_EQ(static_cast<int>(p.bonds.size()), stars * arms * beads);  // a tree per star
  const auto nb = neighbours(p);
  for (int s = 0; s < stars; ++s) {
    const int core = s * size;
    EXPECT_EQ(static_cast<int>(nb[core].size()), arms) << "star " << s;
    for (int a = 0; a < arms; ++a)
      for (int k = 0; k < beads; ++k) {
        const int b = core + 1 + a * beads + k;
        const int inner = k == 0 ? core : b - 1;
        EXPECT_TRUE(std::count(nb[b].begin(), nb[b].end(), inner)) << "bead " << b;
        EXPECT_EQ(nb[b].size(), k + 1 < beads ? 2u : 1u);
      }
  }
  expect_exact_bonds(p, box, spec.bond_length);
  expect_no_overlap(p, box, spec.min_distance);
  expect_angles_match_bonds(p);
  // Per star: C(arms, 2) at the core, beads − 1 along each arm (the first with the core as end).
  EXPECT_EQ(static_cast<int>(p.angles.size()), stars * (arms * (arms - 1) / 2 + arms * (beads - 1)));
}

TEST(Stars, OneBeadArms) {
  ChainSpec spec;
  spec.beads = 1;
  spec.min_distance = 0.9;
  const Box none = open_box();
  const Polymer p = build_stars(spec, 6, none);
  ASSERT_EQ(p.x.cols(), 7);
  expect_exact_bonds(p, none, spec.bond_length);
  expect_no_overlap(p, none, 0.9);
  EXPECT_EQ(p.angles.size(), 15u);
}

TEST(Builders, SameSeedSameOutputOtherSeedOther) {
  ChainSpec spec;
  spec.chains = 10;
  spec.beads = 30;
  spec.seed = 42;
  const Box box = box_for_density(1 + 10 * 31 * 3, 0.7);
  auto all = [&](const ChainSpec& s) {
    return std::vector<Matrix3Xd>{build_linear_chains(s, box).x, build_rings(s, box).x, build_stars(s, 3, box).x};
  };
  const auto a = all(spec), b = all(spec);
  ChainSpec other = spec;
  other.seed = 43;
  const auto c = all(other);
  for (int k = 0; k < 3; ++k) {
    EXPECT_TRUE(a[k] == b[k]) << "builder " << k;  // bit for bit
    EXPECT_FALSE(a[k].isApprox(c[k])) << "builder " << k;
  }
}

// The numbers are fixed by std::mt19937_64 and our own arithmetic alone, so they are the same on
// every platform (IEEE doubles, no fused multiply-adds: see builders.hpp). A changed value means
// the stream changed — std::*_distribution or libm crept in, or the algorithm was changed (then
// update the values deliberately, and say so: old seeds give new configurations).
TEST(Builders, PlatformIndependentStream) {
  ChainSpec chain;  // a lone walk from the origin: uniform directions
  chain.beads = 4;
  chain.seed = 2024;
  const Polymer p = build_linear_chains(chain, open_box());
  const double want_chain[3][4] = {// rows x, y, z; columns beads
                                   {0, 0.21659971105940723, 0.68725962829573695, 1.2587184752490663},
                                   {0, -0.86398507471000741, -1.5964870248930501, -1.0975957728194283},
                                   {0, 0.38407597665998866, 0.81165068976300991, 0.20713244781891027}};
  for (int i = 0; i < 4; ++i)
    for (int a = 0; a < 3; ++a) EXPECT_NEAR(p.x(a, i), want_chain[a][i], 1e-13) << a << ',' << i;

  ChainSpec ring = chain;  // bridge steps (our log and exp) and the closing circle
  ring.beads = 5;
  const Polymer r = build_rings(ring, open_box());
  const double want_ring[3][5] = {
      {0, 0.90464312558925641, 0.11949111227140763, -0.78601500505021804, -0.7202221418977347},
      {0, 0.13849929047045886, 0.55057604983624009, 0.30815024581288197, -0.49377894172456688},
      {0, 0.32146346894053213, 0.71469248665606688, 0.96406851003590699, 0.42232975626825786}};
  for (int i = 0; i < 5; ++i)
    for (int a = 0; a < 3; ++a) EXPECT_NEAR(r.x(a, i), want_ring[a][i], 1e-13) << a << ',' << i;

  ChainSpec dense = chain;  // contacts, dead ends and back-tracking in a periodic box
  dense.chains = 8;
  dense.beads = 25;
  dense.min_distance = 0.9;
  const Polymer d = build_linear_chains(dense, box_for_density(200, 0.85));
  EXPECT_NEAR(d.x.row(0).sum(), 975.94430749953119, 1e-9);
  EXPECT_NEAR(d.x.row(1).sum(), 559.28600255525862, 1e-9);
  EXPECT_NEAR(d.x.row(2).sum(), 663.14743826392748, 1e-9);
  EXPECT_NEAR(d.x(0, 199), 4.9375533492911829, 1e-12);
  EXPECT_NEAR(d.x(1, 199), 8.223271545335729, 1e-12);
  EXPECT_NEAR(d.x(2, 199), 5.1587811132553556, 1e-12);

  const Matrix3Xd v = maxwell_boltzmann(VectorXd::Constant(3, 1.0), 1.5, 2024);
  const double want_v[3][3] = {{1.3970205562159184, -0.26439698386306126, -1.1326235723528568},
                               {0.67413660990449098, -0.030470600964577734, -0.64366600893991321},
                               {-1.5800307655830603, 0.05477689899863615, 1.5252538665844244}};
  for (int i = 0; i < 3; ++i)
    for (int a = 0; a < 3; ++a) EXPECT_NEAR(v(a, i), want_v[a][i], 1e-13) << a << ',' << i;
}

TEST(Builders, MeltOf100ChainsOf100AtDensity085) {
  ChainSpec spec;
  spec.chains = 100;
  spec.beads = 100;
  spec.min_distance = 0.9;  // every seed tried builds up to 0.93 (builders.hpp)
  const Box box = box_for_density(10000, 0.85);
  for (std::uint64_t seed : {1u, 2u}) {
    spec.seed = seed;
    const auto t0 = std::chrono::steady_clock::now();
    const Polymer p = build_linear_chains(spec, box);
    const double seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
    // Speed is reported, not asserted (benchmarks measure speed; a loaded CI machine must not fail).
    std::printf("[ melt     ] seed %d: built in %.2f s\n", static_cast<int>(seed), seconds);
    expect_exact_bonds(p, box, spec.bond_length);
    expect_no_overlap(p, box, spec.min_distance);
  }
}

TEST(Builders, ImpossiblePackingFailsNamingTheMolecule) {
  ChainSpec spec;
  spec.chains = 4;
  spec.beads = 25;
  spec.min_distance = 1.2;  // hard spheres of diameter 1.2 at density 1.2: beyond close packing
  const Box box = box_for_density(100, 1.2);
  try {
    build_linear_chains(spec, box);
    FAIL() << "expected std::runtime_error";
  } catch (const std::runtime_error& e) {
    const std::string what = e.what();
    EXPECT_NE(what.find("could not place chain "), std::string::npos) << what;
    EXPECT_NE(what.find("lower the density or min_distance"), std::string::npos) << what;
  }
}

TEST(Builders, InvalidArguments) {
  const Box box = box_for_density(1000, 0.5);
  auto spec_with = [](auto change) {
    ChainSpec s;
    change(s);
    return s;
  };
  auto expect_invalid = [&](const ChainSpec& s, const std::string& mentions) {
    for (int k = 0; k < 3; ++k) {
      try {
        if (k == 0) build_linear_chains(s, box);
        if (k == 1) build_rings(s, box);
        if (k == 2) build_stars(s, 3, box);
        ADD_FAILURE() << "no exception from builder " << k << " (" << mentions << ")";
      } catch (const std::invalid_argument& e) {
        EXPECT_NE(std::string(e.what()).find(mentions), std::string::npos) << e.what();
      }
    }
  };
  expect_invalid(spec_with([](ChainSpec& s) { s.chains = 0; }), "chains");
  expect_invalid(spec_with([](ChainSpec& s) { s.beads = 0; }), "beads");
  expect_invalid(spec_with([](ChainSpec& s) { s.bond_length = 0.0; }), "bond_length");
  expect_invalid(spec_with([](ChainSpec& s) { s.bond_length = -1.0; }), "bond_length");
  expect_invalid(spec_with([](ChainSpec& s) { s.bond_length = NAN; }), "bond_length");
  expect_invalid(spec_with([](ChainSpec& s) { s.min_distance = -0.1; }), "min_distance");
  expect_invalid(spec_with([](ChainSpec& s) { s.min_distance = 2.0; }), "min_distance");
  expect_invalid(spec_with([](ChainSpec& s) { s.min_distance = NAN; }), "min_distance");
  // Per builder: a chain needs 2 beads, a ring 3, a star arm 1; a star at least one arm.
  EXPECT_THROW(build_linear_chains(spec_with([](ChainSpec& s) { s.beads = 1; }), box), std::invalid_argument);
  EXPECT_NO_THROW(build_linear_chains(spec_with([](ChainSpec& s) { s.beads = 2; }), box));
  EXPECT_THROW(build_rings(spec_with([](ChainSpec& s) { s.beads = 2; }), box), std::invalid_argument);
  EXPECT_NO_THROW(build_rings(spec_with([](ChainSpec& s) { s.beads = 3; }), box));
  EXPECT_NO_THROW(build_stars(spec_with([](ChainSpec& s) { s.beads = 1; }), 3, box));
  EXPECT_THROW(build_stars(ChainSpec{}, 0, box), std::invalid_argument);
  // Boxes: a periodic side must hold a bond twice over; several molecules need a start region.
  Box small = box_for_density(10, 1.0);
  small.lengths[1] = 1.9;  // < 2·0.97
  EXPECT_THROW(build_linear_chains(ChainSpec{}, small), std::invalid_argument);
  EXPECT_THROW(build_linear_chains(spec_with([](ChainSpec& s) { s.chains = 2; }), open_box()), std::invalid_argument);
  Box bad = box;
  bad.lengths[0] = NAN;
  EXPECT_THROW(build_linear_chains(ChainSpec{}, bad), std::invalid_argument);
}

// ---------------------------------------------------------------------------------------------

// Σ m v with Neumaier's compensated summation: a plain sum of 10³–10⁵ momenta of order one
// has rounding errors of ~1e-12 itself, and we test for less.
Vector3d total_momentum(const Matrix3Xd& v, const VectorXd& inv_mass) {
  Vector3d p = Vector3d::Zero();
  for (int a = 0; a < 3; ++a) {
    double sum = 0.0, c = 0.0;
    for (Eigen::Index i = 0; i < v.cols(); ++i) {
      if (inv_mass[i] == 0) continue;
      const double x = v(a, i) / inv_mass[i], t = sum + x;
      c += std::abs(sum) >= std::abs(x) ? (sum - t) + x : (x - t) + sum;
      sum = t;
    }
    p[a] = sum + c;
  }
  return p;
}

double kinetic_temperature(const Matrix3Xd& v, const VectorXd& inv_mass) {
  double twice_k = 0.0;
  int mobile = 0;
  for (Eigen::Index i = 0; i < v.cols(); ++i)
    if (inv_mass[i] > 0) {
      twice_k += v.col(i).squaredNorm() / inv_mass[i];
      ++mobile;
    }
  return twice_k / (3 * mobile - 3);
}

TEST(MaxwellBoltzmann, ZeroMomentumExactTemperatureFixedAtRest) {
  const int n = 5000;
  VectorXd inv_mass(n);
  for (int i = 0; i < n; ++i) inv_mass[i] = i % 97 == 0 ? 0.0 : 1.0 / (0.5 + (i % 13) * 0.75);  // masses 0.5–9.5
  const double T = 2.3;
  const Matrix3Xd v = maxwell_boltzmann(inv_mass, T, 17);
  ASSERT_EQ(v.cols(), n);
  EXPECT_LT(total_momentum(v, inv_mass).cwiseAbs().maxCoeff(), 1e-12);
  EXPECT_NEAR(kinetic_temperature(v, inv_mass), T, 1e-12 * T);
  for (int i = 0; i < n; i += 97) EXPECT_EQ(v.col(i), Vector3d::Zero()) << "fixed particle " << i;
}

TEST(MaxwellBoltzmann, LargeSystemMomentumStillVanishes) {
  const VectorXd inv_mass = VectorXd::Constant(200000, 1.0 / 3.0);
  const Matrix3Xd v = maxwell_boltzmann(inv_mass, 10.0, 5);
  EXPECT_LT(total_momentum(v, inv_mass).cwiseAbs().maxCoeff(), 1e-12 * std::sqrt(200000.0 * 3.0 * 10.0));
}

// Per component over 10⁵ unit masses: mean 0, variance T (standard error 0.45%), skewness 0,
// kurtosis 3 (standard error 0.5%), 68.27% within one standard deviation.
TEST(MaxwellBoltzmann, GaussianPerComponent) {
  const int n = 100000;
  const double T = 1.7;
  const Matrix3Xd v = maxwell_boltzmann(VectorXd::Ones(n), T, 123);
  for (int a = 0; a < 3; ++a) {
    const Eigen::ArrayXd x = v.row(a).transpose().array();
    const double mean = x.mean();
    const Eigen::ArrayXd c = x - mean;
    const double var = c.square().mean(), skew = c.cube().mean() / std::pow(var, 1.5);
    const double kurt = c.square().square().mean() / (var * var);
    const double within = (c.abs() < std::sqrt(var)).cast<double>().mean();
    EXPECT_NEAR(mean, 0.0, 1e-12) << "axis " << a;
    EXPECT_NEAR(var, T, 0.02 * T) << "axis " << a;
    EXPECT_NEAR(skew, 0.0, 0.05) << "axis " << a;
    EXPECT_NEAR(kurt, 3.0, 0.05 * 3.0) << "axis " << a;
    EXPECT_NEAR(within, 0.682689, 0.01) << "axis " << a;
  }
}

TEST(MaxwellBoltzmann, VarianceScalesWithInverseMass) {
  const int n = 100000;
  VectorXd inv_mass(n);
  for (int i = 0; i < n; ++i) inv_mass[i] = i % 2 ? 0.25 : 1.0;  // masses 1 and 4
  const double T = 0.8;
  const Matrix3Xd v = maxwell_boltzmann(inv_mass, T, 99);
  for (int parity = 0; parity < 2; ++parity) {
    double s = 0.0;
    for (int i = parity; i < n; i += 2) s += v.col(i).squaredNorm();
    const double var = s / (3.0 * n / 2), want = T * (parity ? 0.25 : 1.0);
    EXPECT_NEAR(var, want, 0.02 * want) << (parity ? "heavy" : "light");
  }
}

TEST(MaxwellBoltzmann, EdgeCasesAndValidation) {
  EXPECT_EQ(maxwell_boltzmann(VectorXd::Ones(10), 0.0, 1), Matrix3Xd::Zero(3, 10));  // T = 0
  VectorXd one_mobile = VectorXd::Zero(5);
  one_mobile[2] = 1.0;
  EXPECT_EQ(maxwell_boltzmann(one_mobile, 1.0, 1), Matrix3Xd::Zero(3, 5));  // no degree of freedom left
  EXPECT_EQ(maxwell_boltzmann(VectorXd(0), 1.0, 1).cols(), 0);
  const VectorXd two = VectorXd::Ones(2);
  const Matrix3Xd v2 = maxwell_boltzmann(two, 2.0, 1);  // 3 degrees of freedom
  EXPECT_NEAR(kinetic_temperature(v2, two), 2.0, 1e-14);
  EXPECT_LT((v2.col(0) + v2.col(1)).norm(), 1e-15);

  EXPECT_TRUE(maxwell_boltzmann(VectorXd::Ones(50), 1.0, 8) == maxwell_boltzmann(VectorXd::Ones(50), 1.0, 8));
  EXPECT_FALSE(maxwell_boltzmann(VectorXd::Ones(50), 1.0, 8).isApprox(maxwell_boltzmann(VectorXd::Ones(50), 1.0, 9)));

  EXPECT_THROW(maxwell_boltzmann(VectorXd::Ones(3), -1.0, 1), std::invalid_argument);
  EXPECT_THROW(maxwell_boltzmann(VectorXd::Ones(3), NAN, 1), std::invalid_argument);
  EXPECT_THROW(maxwell_boltzmann(VectorXd::Constant(3, -1.0), 1.0, 1), std::invalid_argument);
  EXPECT_THROW(maxwell_boltzmann(VectorXd::Constant(3, INFINITY), 1.0, 1), std::invalid_argument);
}

}  // namespace
}  // namespace stiffmd
