// Ghost particles (NeighborList::set_ghosts, ForceTerm::set_ghosts): flagged particles are copies
// of another domain's particles, whose forces are ignored. No pair of two ghosts is listed; every
// other pair is, in the full list's order, so the forces on owned particles are the full system's;
// with no flag set nothing changes, bit for bit; and a pair force does not depend on when the
// list was built.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <memory>
#include <numeric>
#include <random>
#include <vector>

#include "core/parallel.hpp"
#include "engine/domain/decomposition.hpp"
#include "forcefields/force_field.hpp"
#include "forcefields/neighbor_list.hpp"
#include "forcefields/pair_term.hpp"
#include "test_support.hpp"

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
  std::vector<char> ghost;  // per particle
  int size() const { return static_cast<int>(x.cols()); }
  bool is_ghost(int i) const { return ghost[i] != 0; }
};

// With `interleave`, every third index is a ghost instead of the last third (a decomposed run's
// local arrays hold owned particles and ghosts mixed, in the whole system's order).
System lattice(int m, Eigen::Vector3i periodic, bool scatter, unsigned seed, bool interleave = false) {
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
  s.ghost.resize(n);
  for (int i = 0; i < n; ++i) s.ghost[i] = interleave ? i % 3 == 1 : i >= n - n / 3;
  return s;
}

// 1-2 pairs left out, 1-3 pairs scaled: the list has exclusions, the pair term scaled pairs.
constexpr SpecialWeights kWeights{0.0, 0.5, 1.0};

struct Case {
  const char* name;
  int m;
  Eigen::Vector3i periodic;
  bool scatter;
  bool interleave = false;
};
// 17³ = 4913 particles (above kParallelMin: the search runs on the threads) in 7 cells per axis;
// 5³ in a periodic box of 2 cells per axis, which takes the small-box search.
const Case kCases[] = {
    {"periodic, ghosts in a slab", 17, Eigen::Vector3i::Ones(), false},
    {"periodic, ghosts scattered", 17, Eigen::Vector3i::Ones(), true},
    {"open along z, ghosts in a slab", 17, Eigen::Vector3i(1, 1, 0), false},
    {"small periodic box", 5, Eigen::Vector3i::Ones(), true},
    {"periodic, ghosts interleaved in index", 17, Eigen::Vector3i::Ones(), false, true},
    {"small periodic box, ghosts interleaved", 5, Eigen::Vector3i::Ones(), true, true},
};

NeighborList make_list(const System& s, bool with_ghosts = false) {
  NeighborList list(kCutoff, kSkin);
  list.set_exclusions(s.size(), special_pairs(s.size(), s.bonds, kWeights));
  if (with_ghosts) list.set_ghosts(s.ghost);
  return list;
}

std::vector<int> row(const NeighborList& list, int i) {
  const auto off = list.offsets();
  return {list.neighbors().begin() + off[i], list.neighbors().begin() + off[i + 1]};
}

// Row by row: `ghosts` is `full` without its pairs of two ghosts, in full's order.
void expect_full_rows_less_ghost_pairs(const NeighborList& ghosts, const NeighborList& full, const System& s) {
  ASSERT_EQ(ghosts.num_particles(), full.num_particles());
  std::size_t ghost_pairs = 0;
  for (int i = 0; i < full.num_particles(); ++i) {
    std::vector<int> expected;
    for (const int j : row(full, i)) {
      if (s.is_ghost(i) && s.is_ghost(j))
        ++ghost_pairs;
      else
        expected.push_back(j);
    }
    ASSERT_EQ(row(ghosts, i), expected) << "row " << i;
  }
  EXPECT_GT(ghost_pairs, full.num_pairs() / 20) << "the full list should hold pairs of two ghosts";
  EXPECT_EQ(ghosts.num_pairs() + ghost_pairs, full.num_pairs());
}

// set_exclusions reads the pairs as special_pairs gives them (i < j, increasing (i, j)), whose
// rows come out sorted, and sorts the rows of any other order: the pairs shuffled, with i and j
// swapped, give the same list, and on a new particle set (a pair set moved onto) the rows of the
// new set only.
TEST(NeighborListExclusions, PairsInAnyOrderGiveTheSameList) {
  const System s = lattice(17, Eigen::Vector3i::Ones(), true, 9);
  const std::vector<SpecialPair> sorted = special_pairs(s.size(), s.bonds, kWeights);
  ASSERT_GT(sorted.size(), 1000u);
  std::vector<SpecialPair> shuffled = sorted;
  std::mt19937 rng(4);
  std::shuffle(shuffled.begin(), shuffled.end(), rng);
  for (std::size_t k = 0; k < shuffled.size(); k += 2) std::swap(shuffled[k].i, shuffled[k].j);
  NeighborList a(kCutoff, kSkin), b(kCutoff, kSkin), none(kCutoff, kSkin);
  a.set_exclusions(s.size(), sorted);
  b.set_exclusions(2 * s.size(), shuffled);  // first on a larger set, then on this one
  b.set_exclusions(s.size(), shuffled);
  a.build(s.x, s.box);
  b.build(s.x, s.box);
  none.build(s.x, s.box);
  for (int i = 0; i < s.size(); ++i) ASSERT_EQ(row(a, i), row(b, i)) << "row " << i;
  EXPECT_EQ(a.num_pairs(), b.num_pairs());
  auto listed = [](const NeighborList& list, int i, int j) {
    const std::vector<int> r = row(list, std::min(i, j));
    return std::find(r.begin(), r.end(), std::max(i, j)) != r.end();
  };
  std::size_t excluded_listed = 0;
  for (const SpecialPair& p : sorted) {
    EXPECT_FALSE(listed(a, p.i, p.j));
    excluded_listed += listed(none, p.i, p.j);
  }
  EXPECT_GT(excluded_listed, 0u);
  EXPECT_EQ(a.num_pairs() + excluded_listed, none.num_pairs());
}

using test::ThreadCount;

TEST(GhostPairs, ListIsTheFullListLessThePairsOfTwoGhostsRowByRow) {
  for (const Case& c : kCases)
    for (const int threads : {1, 2, 3}) {
      SCOPED_TRACE(testing::Message() << c.name << ", " << threads << " thread(s)");
      const ThreadCount scope(threads);
      const System s = lattice(c.m, c.periodic, c.scatter, 3, c.interleave);
      NeighborList full = make_list(s), ghosts = make_list(s, true);
      full.build(s.x, s.box);
      ghosts.build(s.x, s.box);
      expect_full_rows_less_ghost_pairs(ghosts, full, s);
    }
}

// With the ghost pairs once (a decomposed run's [parallel] halo_pairs = "once": each pair of a
// home bead and a halo bead computed by one of the two ranks that hold both) a pair i < j is
// listed only where i is not a ghost: the ghosts' rows are empty, every other row is the full
// list's. Both kinds of pair of a home bead and a ghost occur (the ghost's index below and above
// the home bead's), so a list that kept or dropped them all fails. Switching it off rebuilds the
// list with ghosts as before.
TEST(GhostPairs, WithTheGhostPairsOnceTheGhostsRowsAreEmptyAndTheOthersFull) {
  std::size_t home_below = 0, home_above = 0;  // over the cases: the ghosts interleaved give the second
  for (const Case& c : kCases)
    for (const int threads : {1, 2, 3}) {
      SCOPED_TRACE(testing::Message() << c.name << ", " << threads << " thread(s)");
      const ThreadCount scope(threads);
      const System s = lattice(c.m, c.periodic, c.scatter, 3, c.interleave);
      NeighborList full = make_list(s), once = make_list(s, true), ghosts = make_list(s, true);
      once.set_ghost_pairs_once(true);
      EXPECT_TRUE(once.ghost_pairs_once());
      full.build(s.x, s.box);
      once.build(s.x, s.box);
      ghosts.build(s.x, s.box);
      for (int i = 0; i < s.size(); ++i) {
        std::vector<int> expected;
        if (!s.is_ghost(i)) expected = row(full, i);
        for (const int j : row(full, i))
          if (s.is_ghost(i) != s.is_ghost(j)) ++(s.is_ghost(i) ? home_above : home_below);
        ASSERT_EQ(row(once, i), expected) << "row " << i;
      }
      std::size_t listed_with_ghost_row = 0;
      for (int i = 0; i < s.size(); ++i)
        if (s.is_ghost(i)) listed_with_ghost_row += row(ghosts, i).size();
      EXPECT_EQ(once.num_pairs() + listed_with_ghost_row, ghosts.num_pairs());
      once.set_ghost_pairs_once(false);
      EXPECT_TRUE(once.update(s.x, s.box)) << "a change of the rule rebuilds";
      for (int i = 0; i < s.size(); ++i) ASSERT_EQ(row(once, i), row(ghosts, i)) << "row " << i;
    }
  EXPECT_GT(home_below, 0u) << "pairs of a home bead and a ghost of a higher index";
  EXPECT_GT(home_above, 0u) << "pairs of a ghost and a home bead of a higher index";
}

// A rank's pair set (docs/parallel.md, "The design"): a melt of uniform random positions at
// density 0.85 in a box of side 30, cut into the domains of `grid`; the pair set of `domain` is
// every bead within R = r_c + margin of it (DomainGrid::within), in increasing global index, the
// halo (the ghosts) among the home beads (those domain_of places in it), chains of five
// consecutive global indices bonded. With the Kremer–Grest list radius (2^{1/6} + 0.4) the list's
// cells cover the whole box, most of them empty: with ghosts the box's own grid, without them
// a coarser one where the pair set is small against the box.
struct PairSetCase {
  const char* name;
  Eigen::Vector3i dims;
  int domain;
  Eigen::Vector3i periodic;
};
const PairSetCase kPairSets[] = {
    {"2 x 2 x 4, the domain at the box's corner (its halo across three faces)", {2, 2, 4}, 0, {1, 1, 1}},
    {"4 x 4 x 4, an inner domain (two halo beads per home bead)", {4, 4, 4}, 21, {1, 1, 1}},
    {"16 x 1 x 1, the last slab", {16, 1, 1}, 15, {1, 1, 1}},
    {"2 x 2 x 4, open along z", {2, 2, 4}, 5, {1, 1, 0}},
};

// The pair set of `c` (`global`: each slot's global index) and, with `whole`, the whole melt it was
// cut from (every bead, the same chains).
System pair_set(const PairSetCase& c, double reach, unsigned seed, System* whole = nullptr,
                std::vector<int>* global = nullptr) {
  const double side = 30.0;
  const int n = static_cast<int>(0.85 * side * side * side);
  std::mt19937 rng(seed);
  std::uniform_real_distribution<double> u(0.0, side);
  DomainGrid grid;
  grid.dims = c.dims;
  grid.origin.setZero();
  grid.length.setConstant(side);
  grid.periodic = c.periodic;
  System s;
  s.box.lengths = Eigen::Vector3d::Constant(side);
  s.box.periodic = c.periodic;
  if (whole) whole->box = s.box, whole->x.resize(3, n), whole->ghost.assign(n, 0), whole->bonds.clear();
  if (global) global->clear();
  std::vector<int> slot(n, -1);
  std::vector<Eigen::Vector3d> kept;
  for (int g = 0; g < n; ++g) {
    const Eigen::Vector3d p(u(rng), u(rng), u(rng));
    if (whole) whole->x.col(g) = p;
    if (!grid.within(c.domain, p, reach)) continue;
    slot[g] = static_cast<int>(kept.size());
    kept.push_back(p);
    if (global) global->push_back(g);
    s.ghost.push_back(grid.domain_of(p) != c.domain);
  }
  s.x.resize(3, static_cast<Eigen::Index>(kept.size()));
  for (std::size_t e = 0; e < kept.size(); ++e) s.x.col(static_cast<Eigen::Index>(e)) = kept[e];
  for (int g = 0; g + 1 < n; ++g) {
    if (g % 5 == 4) continue;
    if (whole) whole->bonds.push_back({g, g + 1, 0});
    if (slot[g] >= 0 && slot[g + 1] >= 0) s.bonds.push_back({slot[g], slot[g + 1], 0});
  }
  return s;
}

// The search on a pair set never tests a pair of two ghosts, yet lists every other pair the
// search without ghosts lists: the list with the ghost flags is, row by row and in the same
// order, the list of the same positions without them less its pairs of two ghosts, on any
// number of threads. (With ghosts the cells may be finer, so a pair across a periodic face may be
// tested from its other bead: the lists could differ in a pair within rounding of the list
// radius, as the lists of two cell grids can; none lies there in these melts.)
TEST(GhostPairs, PairSetListIsTheListWithoutGhostsLessThePairsOfTwoGhosts) {
  const double cutoff = std::pow(2.0, 1.0 / 6.0), skin = 0.4, margin = 1.5 * skin;
  for (const PairSetCase& c : kPairSets)
    for (const unsigned seed : {1u, 2u})
      for (const int threads : {1, 2, 3}) {
        SCOPED_TRACE(testing::Message() << c.name << ", seed " << seed << ", " << threads << " thread(s)");
        const ThreadCount scope(threads);
        const System s = pair_set(c, cutoff + margin, seed);
        const int halo = static_cast<int>(std::count(s.ghost.begin(), s.ghost.end(), char{1}));
        ASSERT_GT(halo, 0);
        ASSERT_LT(halo, s.size());
        NeighborList full(cutoff, skin), ghosts(cutoff, skin);
        const std::vector<SpecialPair> special = special_pairs(s.size(), s.bonds, kWeights);
        full.set_exclusions(s.size(), special);
        ghosts.set_exclusions(s.size(), special);
        ghosts.set_ghosts(s.ghost);
        full.build(s.x, s.box);
        ghosts.build(s.x, s.box);
        expect_full_rows_less_ghost_pairs(ghosts, full, s);
      }
}

// A list with ghosts (a pair set) may make 8 cells per particle it holds, where a list without
// them makes 2: here, as on in.chain's 16 ranks, that is the whole box's own cells, one process's.
// On a periodic box every pair is then tested from the same bead with the same shift as the whole
// system's search tests it: the pair set's list is, row by row, the whole system's list restricted
// to the pair set's beads less its pairs of two halo beads — the same pairs to the last bit, at
// the list radius too.
TEST(GhostPairs, PairSetListOnTheBoxsCellsIsTheWholeListRestrictedToIt) {
  const double cutoff = std::pow(2.0, 1.0 / 6.0), skin = 0.4, margin = 1.5 * skin;
  int compared = 0;
  for (const PairSetCase& c : kPairSets) {
    if (!c.periodic.all()) continue;  // an open axis is binned over the particles' own extent
    for (const unsigned seed : {1u, 2u})
      for (const int threads : {1, 2}) {
        SCOPED_TRACE(testing::Message() << c.name << ", seed " << seed << ", " << threads << " thread(s)");
        const ThreadCount scope(threads);
        std::vector<int> global;
        System whole;
        const System s = pair_set(c, cutoff + margin, seed, &whole, &global);
        ASSERT_EQ(static_cast<int>(global.size()), s.size());
        std::vector<int> slot(whole.size(), -1);
        for (int e = 0; e < s.size(); ++e) slot[global[e]] = e;
        // The whole system's special pairs among the pair set's beads, as GhostedPairs gives them.
        const std::vector<SpecialPair> whole_special = special_pairs(whole.size(), whole.bonds, kWeights);
        std::vector<SpecialPair> special;
        for (const SpecialPair& p : whole_special)
          if (slot[p.i] >= 0 && slot[p.j] >= 0) special.push_back({slot[p.i], slot[p.j], p.weight, p.weight_coul});
        NeighborList full(cutoff, skin), plain(cutoff, skin), ghosts(cutoff, skin);
        full.set_exclusions(whole.size(), whole_special);
        plain.set_exclusions(s.size(), special);
        ghosts.set_exclusions(s.size(), special);
        ghosts.set_ghosts(s.ghost);
        full.build(whole.x, whole.box);
        plain.build(s.x, s.box);
        ghosts.build(s.x, s.box);
        ASSERT_LE(full.cells_per_axis().prod(), 8 * s.size());
        ASSERT_EQ(ghosts.cells_per_axis(), full.cells_per_axis());
        // Of the box's cells the pair set's list stores the window its beads occupy: the domain
        // and its halo, across the box's faces where the domain meets them.
        EXPECT_LT(ghosts.stored_cells_per_axis().prod(), full.cells_per_axis().prod());
        EXPECT_EQ(full.stored_cells_per_axis(), full.cells_per_axis());
        if (2 * s.size() < full.cells_per_axis().prod()) {  // without ghosts: coarser cells
          EXPECT_LT(plain.cells_per_axis().prod(), full.cells_per_axis().prod());
        }
        // The whole list's rows of the pair set's beads, in slots (the slots increase with the
        // global index, so a row's j > i stays so; rows are sorted).
        std::size_t pairs = 0;
        for (int e = 0; e < s.size(); ++e) {
          std::vector<int> expected;
          for (const int j : row(full, global[e]))
            if (const int t = slot[j]; t >= 0 && !(s.is_ghost(e) && s.is_ghost(t))) expected.push_back(t);
          ASSERT_EQ(row(ghosts, e), expected) << "slot " << e << ", global " << global[e];
          pairs += expected.size();
        }
        EXPECT_EQ(ghosts.num_pairs(), pairs);
        ++compared;
      }
  }
  EXPECT_EQ(compared, 12);
}

// Positions given wrapped (a pair set's: Decomposition::forward wraps them): with every image 0
// the list stores no image or wrapped copy of them, and it is the list of the same positions not
// flagged so, row for row; a bead that the wrap's rounding left on the box's upper face (image L)
// brings the copies back, and the same list again. The fast beads' test (needs_rebuild after
// moves past half the skin) gives the same verdicts on both.
TEST(GhostPairs, WrappedPositionsWithNoImageStoreNoCopiesAndListTheSamePairs) {
  const double cutoff = std::pow(2.0, 1.0 / 6.0), skin = 0.4, margin = 1.5 * skin;
  int compared = 0;
  for (const PairSetCase& c : kPairSets) {
    if (!c.periodic.all()) continue;
    SCOPED_TRACE(c.name);
    System s = pair_set(c, cutoff + margin, 3u);
    BoxWrap(s.box).wrap_particles(s.x.data(), s.x.data(), 0, s.x.cols());
    const std::vector<SpecialPair> special = special_pairs(s.size(), s.bonds, kWeights);
    for (const bool on_face : {false, true}) {
      if (on_face) s.x(0, 0) = s.box.origin[0] + s.box.lengths[0];
      NeighborList plain(cutoff, skin), wrapped(cutoff, skin);
      for (NeighborList* l : {&plain, &wrapped}) {
        l->set_exclusions(s.size(), special);
        l->set_ghosts(s.ghost);
      }
      wrapped.set_positions_wrapped(true);
      plain.build(s.x, s.box);
      wrapped.build(s.x, s.box);
      EXPECT_TRUE(plain.images_stored());
      EXPECT_EQ(wrapped.images_stored(), on_face);
      ASSERT_EQ(wrapped.num_pairs(), plain.num_pairs());
      for (int i = 0; i < s.size(); ++i) ASSERT_EQ(row(wrapped, i), row(plain, i)) << "row " << i;
      // A few beads moved 0.75 skin (fast: past half the skin, within the skin), away from the
      // box's faces: the fast beads' test decides, the same on both.
      Eigen::Matrix3Xd moved = s.x;
      for (int i = 1; i < s.size(); i += 301)  // under 1/256 of the beads: tested one by one
        moved(1, i) += (moved(1, i) < 0.5 * s.box.lengths[1] ? 0.75 : -0.75) * skin;
      EXPECT_EQ(wrapped.needs_rebuild(moved, s.box), plain.needs_rebuild(moved, s.box));
      ++compared;
    }
  }
  EXPECT_EQ(compared, 6);
}

// The search with halo flags takes each cell's home beads as a prefix of its range and searches a
// halo bead's row only against the forward cells' home beads. Whatever the flags' pattern — each
// bead a halo bead at random (few, half, most), halo beads in clusters (cells of home beads only,
// of halo beads only, and mixed), every bead but a few — and whatever the box — periodic, open on
// one axis or all, a periodic axis or all of them under 3 list radii (the small-box searches), a
// box of one or two cells along an open axis — the list with the flags is, row by row and in the
// same order, the list of the same positions without them less its pairs of two halo beads, on 1
// to 3 threads. Both lists are binned on the same cells here (a dense melt: fewer than 2 cells per
// bead), so every pair is tested by both as one process tests it: a pair dropped, one of two halo
// beads kept, or a row out of order fails.
TEST(GhostPairs, HaloSearchOfAnyFlagsIsTheListWithoutThemLessThePairsOfTwoHaloBeads) {
  const double cutoff = std::pow(2.0, 1.0 / 6.0), skin = 0.4;
  struct BoxCase {
    const char* name;
    Eigen::Vector3d lengths;
    Eigen::Vector3i periodic;
  };
  const BoxCase boxes[] = {
      {"periodic, 11 cells per axis", {17.0, 17.0, 17.0}, {1, 1, 1}},
      {"open along z", {17.0, 17.0, 17.0}, {1, 1, 0}},
      {"open on every axis", {17.0, 17.0, 17.0}, {0, 0, 0}},
      {"periodic, z under 3 list radii", {17.0, 17.0, 4.2}, {1, 1, 1}},
      {"periodic in x, y, open z under 3 list radii", {17.0, 17.0, 4.2}, {1, 1, 0}},
      {"open z of one cell", {17.0, 17.0, 1.4}, {1, 1, 0}},
      {"periodic box under 3 list radii", {4.2, 4.2, 4.2}, {1, 1, 1}},
      {"open box under 3 list radii", {4.2, 4.2, 4.2}, {0, 0, 0}},
  };
  enum class Flags { few, half, most, clusters, all_but_a_few };
  int compared = 0;
  for (const BoxCase& b : boxes)
    for (const Flags flags : {Flags::few, Flags::half, Flags::most, Flags::clusters, Flags::all_but_a_few}) {
      std::mt19937 rng(11 + 7 * compared);
      System s;
      s.box.lengths = b.lengths;
      s.box.periodic = b.periodic;
      const int n = static_cast<int>(0.85 * b.lengths.prod());
      std::uniform_real_distribution<double> u(0.0, 1.0);
      s.x.resize(3, n);
      for (int i = 0; i < n; ++i)
        for (int a = 0; a < 3; ++a) s.x(a, i) = u(rng) * b.lengths[a];
      for (int i = 0; i + 1 < n; ++i)
        if (i % 5 != 4) s.bonds.push_back({i, i + 1, 0});  // chains of five: exclusions
      std::vector<Eigen::Vector3d> centres(6);
      for (auto& c : centres) c = Eigen::Vector3d(u(rng), u(rng), u(rng)).cwiseProduct(b.lengths);
      const double cluster = std::min(3.0, 0.3 * b.lengths.maxCoeff());  // a cluster's radius
      s.ghost.assign(n, 0);
      for (int i = 0; i < n; ++i) {
        const double p = u(rng);
        switch (flags) {
          case Flags::few:
            s.ghost[i] = p < 0.15;
            break;
          case Flags::half:
            s.ghost[i] = p < 0.5;
            break;
          case Flags::most:
            s.ghost[i] = p < 0.85;
            break;
          case Flags::all_but_a_few:
            s.ghost[i] = i % 40 != 7;
            break;
          case Flags::clusters:
            for (const auto& c : centres) s.ghost[i] |= (s.x.col(i) - c).norm() < cluster;
            break;
        }
      }
      const int halo = static_cast<int>(std::count(s.ghost.begin(), s.ghost.end(), char{1}));
      ASSERT_GT(halo, 0) << b.name;
      ASSERT_LT(halo, n) << b.name;
      const std::vector<SpecialPair> special = special_pairs(n, s.bonds, kWeights);
      for (const int threads : {1, 2, 3}) {
        SCOPED_TRACE(testing::Message() << b.name << ", flags " << static_cast<int>(flags) << ", " << threads
                                        << " thread(s)");
        const ThreadCount scope(threads);
        NeighborList full(cutoff, skin), ghosts(cutoff, skin);
        full.set_exclusions(n, special);
        ghosts.set_exclusions(n, special);
        ghosts.set_ghosts(s.ghost);
        full.build(s.x, s.box);
        ghosts.build(s.x, s.box);
        ASSERT_EQ(ghosts.cells_per_axis(), full.cells_per_axis());
        std::size_t pairs = 0, halo_pairs = 0;
        for (int i = 0; i < n; ++i) {
          std::vector<int> expected;
          for (const int j : row(full, i)) {
            if (s.is_ghost(i) && s.is_ghost(j))
              ++halo_pairs;
            else
              expected.push_back(j);
          }
          ASSERT_EQ(row(ghosts, i), expected) << "row " << i;
          pairs += expected.size();
        }
        EXPECT_GT(halo_pairs, 0u);
        EXPECT_GT(pairs, 0u);
        EXPECT_EQ(ghosts.num_pairs(), pairs);
      }
      ++compared;
    }
  EXPECT_EQ(compared, 40);
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

// The owned particles' columns of a 3×N array.
Eigen::Matrix3Xd owned_columns(const System& s, const Eigen::Matrix3Xd& a) {
  Eigen::Matrix3Xd out(3, 0);
  for (int i = 0; i < s.size(); ++i)
    if (!s.is_ghost(i)) {
      out.conservativeResize(3, out.cols() + 1);
      out.col(out.cols() - 1) = a.col(i);
    }
  return out;
}
Eigen::Matrix3Xd ghost_columns(const System& s, const Eigen::Matrix3Xd& a) {
  Eigen::Matrix3Xd out(3, 0);
  for (int i = 0; i < s.size(); ++i)
    if (s.is_ghost(i)) {
      out.conservativeResize(3, out.cols() + 1);
      out.col(out.cols() - 1) = a.col(i);
    }
  return out;
}

// Through ForceField::set_ghosts (which forwards to the pair term's list). On one thread the
// owned particles' forces are the same bits: their pairs are the full list's, in the same order,
// and only pairs of two ghosts are gone. On more, the pair loop splits the shorter list into other
// row blocks, so the sums differ by rounding.
TEST(GhostPairs, ForcesOnOwnedParticlesAreTheFullSystemsForces) {
  for (const Case& c : kCases)
    for (const int threads : {1, 2}) {
      SCOPED_TRACE(testing::Message() << c.name << ", " << threads << " thread(s)");
      const ThreadCount scope(threads);
      const System s = lattice(c.m, c.periodic, c.scatter, 5, c.interleave);
      ForceField full(s.box, s.size()), ghosts(s.box, s.size());
      full.add(lj_term(s));
      ghosts.add(lj_term(s));
      ghosts.set_ghosts(s.ghost);
      const Evaluation a = evaluate(full, s.x), b = evaluate(ghosts, s.x);
      const Eigen::Matrix3Xd fa = owned_columns(s, a.f), fb = owned_columns(s, b.f);
      const double scale = fa.cwiseAbs().maxCoeff();
      ASSERT_GT(scale, 0.0);
      const double worst = (fb - fa).cwiseAbs().maxCoeff();
      if (threads == 1)
        EXPECT_EQ(fb, fa);
      else
        EXPECT_LE(worst, 1e-12 * scale);
      // The pairs of two ghosts were left out: the ghosts' forces lost them.
      EXPECT_GT((ghost_columns(s, b.f) - ghost_columns(s, a.f)).cwiseAbs().maxCoeff(), 1e-3);
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
    const System s = lattice(c.m, c.periodic, c.scatter, 7, c.interleave);
    NeighborList full = make_list(s), ghosts = make_list(s, true);
    ASSERT_TRUE(ghosts.update(s.x, s.box));
    const Eigen::Matrix3Xd y = moved(s.x, 0.6 * kSkin, 8);
    ASSERT_TRUE(ghosts.update(y, s.box));
    EXPECT_EQ(ghosts.rebuilds(), 2);
    full.build(y, s.box);
    expect_full_rows_less_ghost_pairs(ghosts, full, s);

    std::vector<std::vector<int>> excluded(s.size());  // special weight ≠ 1: never listed
    for (const SpecialPair& p : special_pairs(s.size(), s.bonds, kWeights)) excluded[p.i].push_back(p.j);
    int checked = 0;
    int owned = 0;
    for (int i = 0; i < s.size(); ++i) {
      if (s.is_ghost(i)) continue;
      ++owned;
      const std::vector<int> listed = row(ghosts, i);
      for (int j = i + 1; j < s.size(); ++j) {
        if (std::find(excluded[i].begin(), excluded[i].end(), j) != excluded[i].end()) continue;
        if (s.box.min_image(y.col(i) - y.col(j)).norm() >= kCutoff) continue;
        ++checked;
        ASSERT_NE(std::find(listed.begin(), listed.end(), j), listed.end()) << "pair (" << i << ", " << j << ")";
      }
    }
    EXPECT_GT(checked, owned);
  }
}

// A released list (a decomposed run's whole-system term once the parts exist) holds no pair and no
// build; its next update builds it again as a fresh list with the same exclusions and ghosts would,
// row for row, and its rebuild count goes on.
TEST(GhostPairs, ReleasedListIsBuiltAgainAsAFreshOne) {
  for (const Case& c : kCases) {
    SCOPED_TRACE(c.name);
    const System s = lattice(c.m, c.periodic, c.scatter, 7, c.interleave);
    NeighborList released = make_list(s, true), fresh = make_list(s, true);
    ASSERT_TRUE(released.update(s.x, s.box));
    ASSERT_GT(released.num_pairs(), 0u);
    released.release();
    EXPECT_FALSE(released.built());
    EXPECT_EQ(released.num_pairs(), 0u);
    EXPECT_EQ(released.num_particles(), 0);
    const Eigen::Matrix3Xd y = moved(s.x, 0.1 * kSkin, 8);
    ASSERT_TRUE(released.update(y, s.box));
    fresh.build(y, s.box);
    EXPECT_EQ(released.rebuilds(), 2);
    ASSERT_EQ(released.num_particles(), fresh.num_particles());
    for (int i = 0; i < fresh.num_particles(); ++i) ASSERT_EQ(row(released, i), row(fresh, i)) << "row " << i;
  }
}

// Lists that agree on their rebuilds (a decomposed run's ranks): each update hands the agreement
// the list's own verdict and follows the agreed one, rebuilding when another list needs it, and
// an early rebuild leaves the forces as they were, bit for bit.
TEST(GhostPairs, ListsThatAgreeRebuildTogether) {
  const System s = lattice(9, Eigen::Vector3i::Ones(), false, 7, true);
  NeighborList mine = make_list(s, true);
  std::vector<char> verdicts;
  bool other_is_stale = false;  // the other lists' verdict
  mine.set_rebuild_agreement([&](bool stale) {
    verdicts.push_back(stale);
    return stale || other_is_stale;
  });
  ASSERT_TRUE(mine.update(s.x, s.box));  // never built
  const Eigen::Matrix3Xd y = moved(s.x, 0.1 * kSkin, 8);
  EXPECT_FALSE(mine.update(y, s.box));  // fresh here, and elsewhere
  other_is_stale = true;
  EXPECT_TRUE(mine.update(y, s.box));  // fresh here, stale elsewhere
  EXPECT_EQ(verdicts, (std::vector<char>{1, 0, 0}));
  EXPECT_EQ(mine.rebuilds(), 2);
  other_is_stale = false;
  EXPECT_TRUE(mine.update(moved(s.x, 0.6 * kSkin, 9), s.box));  // stale here
  EXPECT_EQ(verdicts.back(), 1);

  // The forces after a rebuild another list asked for are those of the list kept (one thread:
  // the pair loop's row blocks do not depend on the list then).
  const ThreadCount scope(1);
  auto rebuilt = lj_term(s);
  rebuilt->set_rebuild_agreement([](bool) { return true; });
  ForceField a(s.box, s.size()), b(s.box, s.size());
  a.add(lj_term(s)), b.add(std::move(rebuilt));
  a.set_ghosts(s.ghost), b.set_ghosts(s.ghost);
  evaluate(a, s.x), evaluate(b, s.x);
  const Evaluation ea = evaluate(a, y), eb = evaluate(b, y);
  EXPECT_EQ(b.terms()[0]->neighbor_list_rebuilds(), 2);
  EXPECT_EQ(a.terms()[0]->neighbor_list_rebuilds(), 1);
  EXPECT_TRUE(ea.f.cwiseEqual(eb.f).all());
  EXPECT_EQ(ea.energy, eb.energy);
}

// A list given positions wrapped into the box already (a decomposed run's halo writes them so):
// the same forces, bit for bit, as the list given the raw positions, which wraps them itself; no
// rebuild when beads cross a face by less than half the skin (their wrapped positions jump by a
// box length); a rebuild, as the raw list's, when they move more.
TEST(GhostPairs, ListOnWrappedPositionsIsTheListOnRawOnes) {
  const ThreadCount scope(1);
  const System s = lattice(9, Eigen::Vector3i::Ones(), false, 11, true);
  const BoxWrap into_box(s.box);
  const auto wrapped = [&](const Eigen::Matrix3Xd& x) {
    Eigen::Matrix3Xd w(3, x.cols());
    for (int i = 0; i < x.cols(); ++i)
      for (int a = 0; a < 3; ++a) w(a, i) = into_box(x(a, i), a);
    return w;
  };
  Eigen::Matrix3Xd x = s.x;
  x.row(0).array() -= 0.6;                     // the first plane of beads straddles the face x = 0
  x.row(2).array() += 3.0 * s.box.lengths[2];  // raw positions some box lengths away
  auto given_wrapped = lj_term(s);
  given_wrapped->set_positions_wrapped(true);
  ForceField raw(s.box, s.size()), pre(s.box, s.size());
  raw.add(lj_term(s)), pre.add(std::move(given_wrapped));
  raw.set_ghosts(s.ghost), pre.set_ghosts(s.ghost);
  for (const double step : {0.0, 0.1 * kSkin, 0.6 * kSkin}) {
    SCOPED_TRACE(step);
    x.row(0).array() -= step;  // beads near the face cross it
    const Evaluation a = evaluate(raw, x), b = evaluate(pre, wrapped(x));
    EXPECT_TRUE(a.f.cwiseEqual(b.f).all());
    EXPECT_EQ(a.energy, b.energy);
    EXPECT_EQ(pre.terms()[0]->neighbor_list_rebuilds(), raw.terms()[0]->neighbor_list_rebuilds());
  }
  EXPECT_EQ(raw.terms()[0]->neighbor_list_rebuilds(), 2);  // kept after 0.1 skin, rebuilt after 0.7
}

// The fast particles' check ignores pairs of two ghosts: one ghost moved 0.6 skin is within the
// cutoff of ghosts it is not listed with (none are), yet no pair with an owned particle can have
// come in unlisted (the others did not move), so the list is kept. An owned particle and a ghost
// that approach each other from just beyond the list radius, both by 0.6 skin, do make it rebuild.
TEST(GhostPairs, FastParticlesCheckIgnoresPairsOfTwoGhosts) {
  const System s = lattice(17, Eigen::Vector3i::Ones(), false, 9);
  NeighborList list = make_list(s, true);
  ASSERT_TRUE(list.update(s.x, s.box));
  const int ghost = s.size() - 100;  // inside the ghost slab: its neighbours are ghosts
  Eigen::Matrix3Xd y = s.x;
  y.col(ghost) += Eigen::Vector3d(0.6 * kSkin, 0.0, 0.0);
  int near_ghosts = 0;
  ASSERT_TRUE(s.is_ghost(ghost));
  for (int j = 0; j < s.size(); ++j)
    near_ghosts += s.is_ghost(j) && j != ghost && s.box.min_image(y.col(ghost) - y.col(j)).norm() < kCutoff;
  ASSERT_GT(near_ghosts, 0);
  EXPECT_FALSE(list.update(y, s.box));
  EXPECT_EQ(list.rebuilds(), 1);

  // An owned-ghost pair just beyond cutoff + skin, moved 0.6 skin each toward the other.
  int owned = -1, other = -1;
  const double lo = kCutoff + kSkin, hi = kCutoff + 1.15 * kSkin;
  for (int i = 0; i < s.size() && owned < 0; ++i)
    for (int j = 0; j < s.size() && !s.is_ghost(i); ++j) {
      if (!s.is_ghost(j)) continue;
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

// No ghost flag set is no ghosts: the same list (rows, order), the same forces, energy and virial
// bits and the same checkpoint state as a list never told of ghosts.
TEST(GhostPairs, NoGhostFlagSetChangesNothing) {
  for (const int threads : {1, 2}) {
    SCOPED_TRACE(testing::Message() << threads << " thread(s)");
    const ThreadCount scope(threads);
    const System s = lattice(17, Eigen::Vector3i::Ones(), true, 11);
    NeighborList plain = make_list(s);
    plain.build(s.x, s.box);
    for (const std::vector<char>& flags : {std::vector<char>(s.size(), 0), std::vector<char>{}}) {
      NeighborList list = make_list(s);
      list.set_ghosts(flags);
      list.build(s.x, s.box);
      EXPECT_TRUE(std::ranges::equal(list.offsets(), plain.offsets()));
      EXPECT_TRUE(std::ranges::equal(list.neighbors(), plain.neighbors()));
    }
    const auto a = lj_term(s), b = lj_term(s);
    b->set_ghosts(std::vector<char>(s.size(), 0));
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

TEST(GhostPairs, ChangingTheGhostsRebuildsAndABadFlagIsRefused) {
  const System s = lattice(5, Eigen::Vector3i::Ones(), false, 13);
  NeighborList list = make_list(s);
  ASSERT_TRUE(list.update(s.x, s.box));
  EXPECT_FALSE(list.update(s.x, s.box));
  list.set_ghosts(std::vector<char>(s.size(), 0));  // no ghosts, as before: the list stands
  EXPECT_FALSE(list.update(s.x, s.box));
  list.set_ghosts(s.ghost);
  EXPECT_EQ(list.ghosts(), s.ghost);
  EXPECT_TRUE(list.update(s.x, s.box));
  EXPECT_FALSE(list.update(s.x, s.box));
  list.set_ghosts({});
  EXPECT_TRUE(list.update(s.x, s.box));
  std::vector<char> bad(s.size(), 0);
  bad[3] = 2;
  EXPECT_THROW(list.set_ghosts(bad), std::invalid_argument);
  // ForceField forwards them to its pair terms' lists.
  ForceField ff(s.box, s.size());
  ff.add(lj_term(s));
  ff.set_ghosts(s.ghost);
  Eigen::Matrix3Xd f;
  ff.compute(s.x, ff.all_levels(), f);
  const auto& term = dynamic_cast<const Lj&>(*ff.terms()[0]);
  EXPECT_EQ(term.neighbor_list().ghosts(), s.ghost);
}

// A pair force does not depend on when the list was built (rows sorted, positions wrapped at the
// call): a list built at x and evaluated at y, particles having crossed periodic faces in between,
// gives the bits of a list built at y — the property that makes a decomposed run's forces, whose
// lists are built at other steps, the one-process forces (docs/parallel.md).
TEST(GhostPairs, ForcesDoNotDependOnWhenTheListWasBuilt) {
  for (const Case& c : kCases) {
    SCOPED_TRACE(c.name);
    const ThreadCount scope(1);
    System s = lattice(c.m, c.periodic, c.scatter, 15, c.interleave);
    s.x.array() += 0.5;  // the last plane straddles the faces: moves of 0.45 skin cross them
    const auto early = lj_term(s), late = lj_term(s);
    Eigen::Matrix3Xd f_early = Eigen::Matrix3Xd::Zero(3, s.size()), f_late = f_early;
    early->add_forces(s.x, s.box, f_early);  // built at x
    const Eigen::Matrix3Xd y = moved(s.x, 0.45 * kSkin, 16);
    int crossed = 0;
    for (int i = 0; i < s.size(); ++i)
      for (int a = 0; a < 3; ++a)
        crossed +=
            s.box.periodic[a] && std::floor(y(a, i) / s.box.lengths[a]) != std::floor(s.x(a, i) / s.box.lengths[a]);
    ASSERT_GT(crossed, 0);
    f_early.setZero();
    const double e_early = early->add_forces(y, s.box, f_early);
    ASSERT_EQ(early->rebuilds(), 1);  // the list of x serves y
    const double e_late = late->add_forces(y, s.box, f_late);
    EXPECT_EQ(f_early, f_late);
    EXPECT_EQ(e_early, e_late);
  }
}

// PairsOnParticles::move_to (a decomposed run's pair terms at each selection of the ghosts): a
// term moved onto a particle set, from a larger and from a smaller one, is the term built there
// (on_particles with the set's bonds, then set_ghosts) — the same list row by row, the same
// scaled pairs, the same forces and energy bit for bit.
TEST(GhostPairs, TermMovedOntoAParticleSetIsTheTermBuiltThere) {
  for (const Case& c : kCases) {
    SCOPED_TRACE(c.name);
    const ThreadCount scope(1);
    const System s = lattice(c.m, c.periodic, c.scatter, 17, c.interleave);
    // A smaller set: the first trimers (whole molecules), with the ghost flags of those particles.
    System part = s;
    const int n_part = 3 * (s.size() / 6);
    part.x = s.x.leftCols(n_part);
    part.ghost.resize(n_part);
    part.bonds.clear();
    for (const Bond& b : s.bonds)
      if (b.j < n_part) part.bonds.push_back(b);
    for (const auto& [from, to] : {std::pair<const System*, const System*>{&s, &part}, {&part, &s}}) {
      const auto moved_term = lj_term(*from);
      Eigen::Matrix3Xd f_before = Eigen::Matrix3Xd::Zero(3, from->size());
      moved_term->add_forces(from->x, from->box, f_before);  // its list built on the first set
      const std::vector<int> types(to->size(), 0);
      const std::vector<SpecialPair> special = special_pairs(to->size(), to->bonds, kWeights);
      moved_term->move_to(types, {}, special, to->ghost);
      const auto built = moved_term->on_particles(types, to->bonds, to->box);
      built->set_ghosts(to->ghost);
      Eigen::Matrix3Xd f_moved = Eigen::Matrix3Xd::Zero(3, to->size());
      Eigen::Matrix3Xd f_built = f_moved;
      const double e_moved = moved_term->add_forces(to->x, to->box, f_moved);
      const double e_built = built->add_forces(to->x, to->box, f_built);
      const auto& b = dynamic_cast<const Lj&>(*built);
      ASSERT_EQ(moved_term->neighbor_list().num_particles(), to->size());
      for (int i = 0; i < to->size(); ++i)
        ASSERT_EQ(row(moved_term->neighbor_list(), i), row(b.neighbor_list(), i)) << "row " << i;
      EXPECT_EQ(moved_term->excluded_pairs(), b.excluded_pairs());
      ASSERT_EQ(moved_term->scaled_pairs().size(), b.scaled_pairs().size());
      EXPECT_GT(b.scaled_pairs().size(), 0u);
      for (std::size_t p = 0; p < b.scaled_pairs().size(); ++p) {
        EXPECT_EQ(moved_term->scaled_pairs()[p].i, b.scaled_pairs()[p].i);
        EXPECT_EQ(moved_term->scaled_pairs()[p].j, b.scaled_pairs()[p].j);
        EXPECT_EQ(moved_term->scaled_pairs()[p].weight, b.scaled_pairs()[p].weight);
      }
      EXPECT_EQ(f_moved, f_built);
      EXPECT_EQ(e_moved, e_built);
      EXPECT_EQ(moved_term->rebuilds(), 2);  // built on each set once
    }
  }
}

TEST(GhostPairs, MoveRefusesATypeOutsideTheCoefficients) {
  const System s = lattice(5, Eigen::Vector3i::Ones(), false, 18);
  const auto term = lj_term(s);
  std::vector<int> types(s.size(), 0);
  types[7] = 1;
  EXPECT_THROW(term->move_to(types, {}, std::span<const SpecialPair>(), {}), std::invalid_argument);
}

}  // namespace
}  // namespace stiffmd
