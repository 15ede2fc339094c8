// Ghost particles (NeighborList::set_first_ghost, ForceTerm::set_first_ghost): particles
// first_ghost … N − 1 are copies of another domain's particles, whose forces are ignored. No pair
// of two ghosts is listed; the rows of the owned particles are the full list's, pair for pair and
// in the same order, so the forces on owned particles are the full system's; and with
// first_ghost ≥ N nothing changes, bit for bit.
#include <gtest/gtest.h>

#include <algorithm>
#include <memory>
#include <numeric>
#include <random>
#include <vector>

#include "engine/core/parallel.hpp"
#include "forcefields/force_field.hpp"
#include "forcefields/neighbor_list.hpp"
#include "forcefields/pair_term.hpp"

namespace stiffmd {
namespace {

constexpr double kCutoff = 2.5;  // LJ
constexpr double kSkin = 0.3;

// A jittered cubic lattice of m³ particles (spacing 1.2, density ≈ 0.58, every pair ≥ 0.7 apart),
// periodic on the axes of `periodic`, joined into trimers (3k, 3k + 1, 3k + 2) of the index
// order. Indices run over x-planes first, so the last third of them, the ghosts, fill a slab of
// the box as a domain's ghost shell does; with `scatter` they are a random permutation (ghosts
// everywhere, trimers across the box).
struct System {
  Eigen::Matrix3Xd x;
  Box box;
  std::vector<Bond> bonds;
  int first_ghost = 0;
  int size() const { return static_cast<int>(x.cols()); }
};

System lattice(int m, Eigen::Vector3i periodic, bool scatter, unsigned seed) {
  const double a = 1.2;
  std::mt19937 rng(seed);
  std::uniform_real_distribution<double> jitter(-0.25, 0.25);
  const int n = m * m * m;
  std::vector<int> index(n);
  std::iota(index.begin(), index.end(), 0);
  if (scatter) std::shuffle(index.begin(), index.end(), rng);
  System s;
  s.x.resize(3, n);
  for (int ix = 0; ix < m; ++ix)
    for (int iy = 0; iy < m; ++iy)
      for (int iz = 0; iz < m; ++iz)
        s.x.col(index[(ix * m + iy) * m + iz]) =
            Eigen::Vector3d((ix + 0.5) * a + jitter(rng), (iy + 0.5) * a + jitter(rng), (iz + 0.5) * a + jitter(rng));
  s.box.lengths = Eigen::Vector3d::Constant(m * a);
  s.box.periodic = periodic;
  for (int k = 0; 3 * k + 2 < n; ++k) {
    s.bonds.push_back({3 * k, 3 * k + 1, 0});
    s.bonds.push_back({3 * k + 1, 3 * k + 2, 0});
  }
  s.first_ghost = n - n / 3;
  return s;
}

// 1-2 pairs left out, 1-3 pairs scaled: the list has exclusions, the pair term scaled pairs.
constexpr SpecialWeights kWeights{0.0, 0.5, 1.0};

struct Case {
  const char* name;
  int m;
  Eigen::Vector3i periodic;
  bool scatter;
};
// 17³ = 4913 particles (above kParallelMin: the search runs on the threads) in 7 cells per axis;
// 5³ in a periodic box of 2 cells per axis, which takes the small-box search.
const Case kCases[] = {
    {"periodic, ghosts in a slab", 17, Eigen::Vector3i::Ones(), false},
    {"periodic, ghosts scattered", 17, Eigen::Vector3i::Ones(), true},
    {"open along z, ghosts in a slab", 17, Eigen::Vector3i(1, 1, 0), false},
    {"small periodic box", 5, Eigen::Vector3i::Ones(), true},
};

NeighborList make_list(const System& s, int first_ghost = NeighborList::kNoGhosts) {
  NeighborList list(kCutoff, kSkin);
  list.set_exclusions(s.size(), special_pairs(s.size(), s.bonds, kWeights));
  if (first_ghost != NeighborList::kNoGhosts) list.set_first_ghost(first_ghost);
  return list;
}

std::vector<int> row(const NeighborList& list, int i) {
  const auto off = list.offsets();
  return {list.neighbors().begin() + off[i], list.neighbors().begin() + off[i + 1]};
}

// Row by row: `ghosts` is `full` without its pairs of two particles ≥ first_ghost, in full's order.
void expect_full_rows_less_ghost_pairs(const NeighborList& ghosts, const NeighborList& full, int first_ghost) {
  ASSERT_EQ(ghosts.num_particles(), full.num_particles());
  std::size_t ghost_pairs = 0;
  for (int i = 0; i < full.num_particles(); ++i) {
    std::vector<int> expected;
    for (const int j : row(full, i)) {
      if (i >= first_ghost && j >= first_ghost)
        ++ghost_pairs;
      else
        expected.push_back(j);
    }
    ASSERT_EQ(row(ghosts, i), expected) << "row " << i;
  }
  EXPECT_GT(ghost_pairs, full.num_pairs() / 20) << "the full list should hold pairs of two ghosts";
  EXPECT_EQ(ghosts.num_pairs() + ghost_pairs, full.num_pairs());
}

class ThreadCount {
 public:
  explicit ThreadCount(int threads) { set_max_threads(threads); }
  ~ThreadCount() { set_max_threads(restore_); }

 private:
  int restore_ = max_threads();
};

TEST(GhostPairs, ListIsTheFullListLessThePairsOfTwoGhostsRowByRow) {
  for (const Case& c : kCases)
    for (const int threads : {1, 2, 3}) {
      SCOPED_TRACE(testing::Message() << c.name << ", " << threads << " thread(s)");
      const ThreadCount scope(threads);
      const System s = lattice(c.m, c.periodic, c.scatter, 3);
      NeighborList full = make_list(s), ghosts = make_list(s, s.first_ghost);
      full.build(s.x, s.box);
      ghosts.build(s.x, s.box);
      expect_full_rows_less_ghost_pairs(ghosts, full, s.first_ghost);
    }
}

using Lj = LennardJonesPair;

std::unique_ptr<Lj> lj_term(const System& s) {
  TypePairMatrix<LennardJones::Coeffs> c(1);
  c.set(0, 0, {1.0, 1.0, kCutoff});
  return std::make_unique<Lj>("lj", Level::slow, std::vector<int>(s.size(), 0), c, s.bonds, kWeights, s.box, kSkin);
}

struct Evaluation {
  Eigen::Matrix3Xd f;
  double energy;
};

Evaluation evaluate(ForceField& ff, const Eigen::Matrix3Xd& x) {
  Evaluation e{Eigen::Matrix3Xd(3, x.cols()), 0.0};
  e.energy = ff.compute(x, ff.all_levels(), e.f);
  return e;
}

// Through ForceField::set_first_ghost (which forwards to the pair term's list). On one thread the
// owned particles' forces are the same bits: their rows are the full list's, and a ghost's row,
// now empty, held only ghosts. On more, the pair loop splits the shorter list into other row
// blocks, so the sums differ by rounding.
TEST(GhostPairs, ForcesOnOwnedParticlesAreTheFullSystemsForces) {
  for (const Case& c : kCases)
    for (const int threads : {1, 2}) {
      SCOPED_TRACE(testing::Message() << c.name << ", " << threads << " thread(s)");
      const ThreadCount scope(threads);
      const System s = lattice(c.m, c.periodic, c.scatter, 5);
      ForceField full(s.box, s.size()), ghosts(s.box, s.size());
      full.add(lj_term(s));
      ghosts.add(lj_term(s));
      ghosts.set_first_ghost(s.first_ghost);
      const Evaluation a = evaluate(full, s.x), b = evaluate(ghosts, s.x);
      const int owned = s.first_ghost;
      const double scale = a.f.leftCols(owned).cwiseAbs().maxCoeff();
      ASSERT_GT(scale, 0.0);
      const double worst = (b.f.leftCols(owned) - a.f.leftCols(owned)).cwiseAbs().maxCoeff();
      if (threads == 1)
        EXPECT_EQ(b.f.leftCols(owned), a.f.leftCols(owned));
      else
        EXPECT_LE(worst, 1e-12 * scale);
      // The pairs of two ghosts were left out: the ghosts' forces lost them.
      EXPECT_GT((b.f.rightCols(s.size() - owned) - a.f.rightCols(s.size() - owned)).cwiseAbs().maxCoeff(), 1e-3);
    }
}

// Positions moved by `step` in random directions.
Eigen::Matrix3Xd moved(const Eigen::Matrix3Xd& x, double step, unsigned seed) {
  std::mt19937 rng(seed);
  std::normal_distribution<double> g;
  Eigen::Matrix3Xd y = x;
  for (int i = 0; i < x.cols(); ++i) {
    const Eigen::Vector3d d(g(rng), g(rng), g(rng));
    y.col(i) += step * d.normalized();
  }
  return y;
}

// After every particle moved 0.6 skin the list is rebuilt: still no pair of two ghosts, the
// full list's rows otherwise, and every pair within the cutoff with an owned particle listed
// but those of special weight ≠ 1 (against all pairs, minimum image).
TEST(GhostPairs, RebuildAfterMovesBeyondHalfTheSkinListsNoPairOfTwoGhosts) {
  for (const Case& c : kCases) {
    SCOPED_TRACE(c.name);
    const ThreadCount scope(2);
    const System s = lattice(c.m, c.periodic, c.scatter, 7);
    NeighborList full = make_list(s), ghosts = make_list(s, s.first_ghost);
    ASSERT_TRUE(ghosts.update(s.x, s.box));
    const Eigen::Matrix3Xd y = moved(s.x, 0.6 * kSkin, 8);
    ASSERT_TRUE(ghosts.update(y, s.box));
    EXPECT_EQ(ghosts.rebuilds(), 2);
    full.build(y, s.box);
    expect_full_rows_less_ghost_pairs(ghosts, full, s.first_ghost);

    std::vector<std::vector<int>> excluded(s.size());  // special weight ≠ 1: never listed
    for (const SpecialPair& p : special_pairs(s.size(), s.bonds, kWeights)) excluded[p.i].push_back(p.j);
    int checked = 0;
    for (int i = 0; i < s.first_ghost; ++i) {
      const std::vector<int> listed = row(ghosts, i);
      for (int j = i + 1; j < s.size(); ++j) {
        if (std::find(excluded[i].begin(), excluded[i].end(), j) != excluded[i].end()) continue;
        if (s.box.min_image(y.col(i) - y.col(j)).norm() >= kCutoff) continue;
        ++checked;
        ASSERT_NE(std::find(listed.begin(), listed.end(), j), listed.end()) << "pair (" << i << ", " << j << ")";
      }
    }
    EXPECT_GT(checked, s.first_ghost);
  }
}

// The fast particles' check ignores pairs of two ghosts: one ghost moved 0.6 skin is within the
// cutoff of ghosts it is not listed with (none are), yet no pair with an owned particle can have
// come in unlisted (the others did not move), so the list is kept. An owned particle and a ghost
// that approach each other from just beyond the list radius, both by 0.6 skin, do make it rebuild.
TEST(GhostPairs, FastParticlesCheckIgnoresPairsOfTwoGhosts) {
  const System s = lattice(17, Eigen::Vector3i::Ones(), false, 9);
  NeighborList list = make_list(s, s.first_ghost);
  ASSERT_TRUE(list.update(s.x, s.box));
  const int ghost = s.size() - 100;  // inside the ghost slab: its neighbours are ghosts
  Eigen::Matrix3Xd y = s.x;
  y.col(ghost) += Eigen::Vector3d(0.6 * kSkin, 0.0, 0.0);
  int near_ghosts = 0;
  for (int j = s.first_ghost; j < s.size(); ++j)
    near_ghosts += j != ghost && s.box.min_image(y.col(ghost) - y.col(j)).norm() < kCutoff;
  ASSERT_GT(near_ghosts, 0);
  EXPECT_FALSE(list.update(y, s.box));
  EXPECT_EQ(list.rebuilds(), 1);

  // An owned-ghost pair just beyond cutoff + skin, moved 0.6 skin each toward the other.
  int owned = -1, other = -1;
  const double lo = kCutoff + kSkin, hi = kCutoff + 1.15 * kSkin;
  for (int i = 0; i < s.first_ghost && owned < 0; ++i)
    for (int j = s.first_ghost; j < s.size(); ++j) {
      const double r = s.box.min_image(s.x.col(i) - s.x.col(j)).norm();
      if (r > lo && r < hi) {
        owned = i, other = j;
        break;
      }
    }
  ASSERT_GE(owned, 0);
  const Eigen::Vector3d d = s.box.min_image(s.x.col(other) - s.x.col(owned)).normalized();
  y = s.x;
  y.col(owned) += 0.6 * kSkin * d;
  y.col(other) -= 0.6 * kSkin * d;
  ASSERT_LT(s.box.min_image(y.col(owned) - y.col(other)).norm(), kCutoff);
  EXPECT_TRUE(list.update(y, s.box));
  const std::vector<int> r = row(list, owned);
  EXPECT_NE(std::find(r.begin(), r.end(), other), r.end());
}

// first_ghost ≥ N is no ghosts: the same list (rows, order), the same forces, energy and virial
// bits and the same checkpoint state as a list never told of ghosts.
TEST(GhostPairs, FirstGhostAtOrPastTheEndChangesNothing) {
  for (const int threads : {1, 2}) {
    SCOPED_TRACE(testing::Message() << threads << " thread(s)");
    const ThreadCount scope(threads);
    const System s = lattice(17, Eigen::Vector3i::Ones(), true, 11);
    NeighborList plain = make_list(s);
    plain.build(s.x, s.box);
    for (const int first_ghost : {s.size(), s.size() + 7, NeighborList::kNoGhosts}) {
      NeighborList list = make_list(s);
      list.set_first_ghost(first_ghost);
      list.build(s.x, s.box);
      EXPECT_TRUE(std::ranges::equal(list.offsets(), plain.offsets()));
      EXPECT_TRUE(std::ranges::equal(list.neighbors(), plain.neighbors()));
    }
    const auto a = lj_term(s), b = lj_term(s);
    b->set_first_ghost(s.size());
    Eigen::Matrix3Xd fa = Eigen::Matrix3Xd::Zero(3, s.size()), fb = fa;
    const Eigen::Matrix3Xd y = moved(s.x, 0.2 * kSkin, 12);
    for (const Eigen::Matrix3Xd* at : {&s.x, &y}) {
      EXPECT_EQ(a->add_forces(*at, s.box, fa), b->add_forces(*at, s.box, fb));
      EXPECT_EQ(fa, fb);
      EXPECT_EQ(a->virial(*at, s.box), b->virial(*at, s.box));
      EXPECT_EQ(a->save_state(), b->save_state());
    }
  }
}

TEST(GhostPairs, ChangingTheFirstGhostRebuildsAndANegativeOneIsRefused) {
  const System s = lattice(5, Eigen::Vector3i::Ones(), false, 13);
  NeighborList list = make_list(s);
  ASSERT_TRUE(list.update(s.x, s.box));
  EXPECT_FALSE(list.update(s.x, s.box));
  list.set_first_ghost(NeighborList::kNoGhosts);  // unchanged: the list stands
  EXPECT_FALSE(list.update(s.x, s.box));
  list.set_first_ghost(s.first_ghost);
  EXPECT_EQ(list.first_ghost(), s.first_ghost);
  EXPECT_TRUE(list.update(s.x, s.box));
  EXPECT_FALSE(list.update(s.x, s.box));
  list.set_first_ghost(s.size());
  EXPECT_TRUE(list.update(s.x, s.box));
  EXPECT_THROW(list.set_first_ghost(-1), std::invalid_argument);
  // ForceField forwards it to its pair terms' lists.
  ForceField ff(s.box, s.size());
  ff.add(lj_term(s));
  ff.set_first_ghost(s.first_ghost);
  Eigen::Matrix3Xd f;
  ff.compute(s.x, ff.all_levels(), f);
  const auto& term = dynamic_cast<const Lj&>(*ff.terms()[0]);
  EXPECT_EQ(term.neighbor_list().first_ghost(), s.first_ghost);
}

}  // namespace
}  // namespace stiffmd
