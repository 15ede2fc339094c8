// The decomposition's ownership, migration, gather, pair sets, forward and reverse
// (engine/domain/decomposition.hpp) on
// 2, 3 and 4 fake ranks in one process (tests/fake_processes.hpp), on a periodic melt whose
// molecules straddle the domain faces and the periodic faces (tests/decomposition_fixtures.hpp).
//
// What must hold: every molecule is owned whole by exactly one rank, the rank of the domain of its
// anchor (its centre of mass wrapped into the box); a rank's owned particles come in increasing
// global index; a molecule whose anchor has gone far into another domain moves there whole with
// x, v and the carried columns, one that has gone less than the margin past its domain's face
// stays, and so does every other; rank 0 gathers every array by global index; the pair sets are
// the beads within R of each domain, each bead home on one rank; forward and reverse move
// positions out and forces back.
#include <gtest/gtest.h>

#include <algorithm>
#include <bit>
#include <cmath>
#include <cstdint>
#include <limits>
#include <memory>
#include <numeric>
#include <string>
#include <vector>

#include "decomposition_fixtures.hpp"
#include "engine/domain/decomposition.hpp"
#include "fake_processes.hpp"
#include "forcefields/neighbor_list.hpp"  // BoxWrap

namespace stiffmd {
namespace {

using fake::FakeCommunicator;
using fake::Melt;
using fake::run_ranks;

constexpr double kCutoff = 2.5, kMargin = 0.8;

struct Layout {
  int ranks;
  Eigen::Vector3i dims;   // zero: the decomposition chooses
  bool balanced = false;  // the domains recut at the start (any imbalance: unequal slabs)
  bool given() const { return dims.prod() > 0; }
};

std::string layout_name(const ::testing::TestParamInfo<Layout>& info) {
  const Layout& l = info.param;
  const std::string cut = l.balanced ? "_balanced" : "";
  if (!l.given()) return std::to_string(l.ranks) + "_ranks_grid_chosen" + cut;
  return std::to_string(l.ranks) + "_ranks_grid_" + std::to_string(l.dims[0]) + "x" + std::to_string(l.dims[1]) + "x" +
         std::to_string(l.dims[2]) + cut;
}

// One rank's decomposition as seen through its public queries, taken on its own thread.
struct Snapshot {
  std::vector<int> ids;
  std::vector<int> owned_index;  // per global particle
  std::vector<char> owns;        // per global particle: whether its molecule (by its name) is owned here
  std::vector<int> molecule_of;  // per global particle: its molecule's name where owned here, else −1
  DomainGrid grid;
  Eigen::Matrix3Xd x, v;
  std::vector<Eigen::Matrix3Xd> carried;
};

// A molecule's name, as the decomposition gives it: the first global index of its particles.
std::vector<int> molecule_names(const Melt& melt) {
  std::vector<int> name(static_cast<size_t>(melt.size()));
  for (int m = 0; m < melt.molecules; ++m) {
    const std::vector<int> members = melt.members(m);
    for (int g : members) name[g] = members.front();
  }
  return name;
}

Snapshot snapshot(const Decomposition& d, const Melt& melt, const Eigen::Matrix3Xd& x, const Eigen::Matrix3Xd& v,
                  std::vector<Eigen::Matrix3Xd> carried = {}) {
  Snapshot s;
  const int n = melt.size();
  const std::vector<int> name = molecule_names(melt);
  s.ids = d.owned_ids();
  s.molecule_of.assign(static_cast<size_t>(n), -1);
  for (int i = 0; i < n; ++i) s.owned_index.push_back(d.owned_index(i)), s.owns.push_back(d.owns_molecule(name[i]));
  for (int k = 0; k < d.num_owned(); ++k) s.molecule_of[s.ids[k]] = d.owned_molecule(k);
  s.grid = d.grid();
  s.x = x, s.v = v, s.carried = std::move(carried);
  return s;
}

std::unique_ptr<Decomposition> make(const Melt& melt, const Communicator& comm, const Layout& layout) {
  auto d = std::make_unique<Decomposition>(melt.box, comm, kCutoff, kMargin, layout.given() ? &layout.dims : nullptr);
  if (layout.balanced) d->set_balance({BalanceSettings::When::start, 1.0});
  return d;
}

// The melt's molecule anchors' ranks on grid g, for positions x (by global index).
std::vector<int> anchor_ranks(const Melt& melt, const DomainGrid& g, const Eigen::Matrix3Xd& x) {
  std::vector<int> rank(melt.molecules);
  for (int m = 0; m < melt.molecules; ++m)
    rank[m] = fake::rank_of_point(g, fake::centre_of_mass(melt, x, melt.members(m)));
  return rank;
}

// The invariants of an ownership: the grid the same on every rank, each particle owned by exactly
// one rank at its owned index, owned ids increasing, the decomposition's molecules the melt's,
// each owned whole by `owner[label]`, and the owned columns those of x, v (by global index).
void expect_ownership(const Melt& melt, const std::vector<Snapshot>& ranks, const std::vector<int>& owner,
                      const Eigen::Matrix3Xd& x, const Eigen::Matrix3Xd& v) {
  const int n = melt.size(), size = static_cast<int>(ranks.size());
  for (const Snapshot& s : ranks) {
    EXPECT_EQ(s.grid.dims, ranks[0].grid.dims);
    EXPECT_EQ(s.grid.origin, ranks[0].grid.origin);
    EXPECT_EQ(s.grid.length, ranks[0].grid.length);
  }
  // The decomposition's molecules are the melt's, each named by its first particle, on its owner.
  const std::vector<int> name = molecule_names(melt);
  for (const Snapshot& s : ranks)
    for (int g : s.ids) EXPECT_EQ(s.molecule_of[g], name[g]) << "particle " << g;
  std::vector<int> owner_of(n, -1);
  for (int r = 0; r < size; ++r) {
    const Snapshot& s = ranks[r];
    EXPECT_TRUE(std::is_sorted(s.ids.begin(), s.ids.end()) &&
                std::adjacent_find(s.ids.begin(), s.ids.end()) == s.ids.end())
        << "rank " << r << ": owned ids not increasing";
    ASSERT_EQ(s.x.cols(), static_cast<long>(s.ids.size()));
    ASSERT_EQ(s.v.cols(), static_cast<long>(s.ids.size()));
    for (int k = 0; k < static_cast<int>(s.ids.size()); ++k) {
      const int g = s.ids[k];
      EXPECT_EQ(owner_of[g], -1) << "particle " << g << " owned by ranks " << owner_of[g] << " and " << r;
      owner_of[g] = r;
      EXPECT_EQ(s.owned_index[g], k);
      EXPECT_EQ(s.x.col(k), x.col(g)) << "rank " << r << ", particle " << g;
      EXPECT_EQ(s.v.col(k), v.col(g)) << "rank " << r << ", particle " << g;
    }
    // owned_index is −1 for every particle not owned here.
    int indexed = 0;
    for (int g = 0; g < n; ++g) indexed += s.owned_index[g] >= 0;
    EXPECT_EQ(indexed, static_cast<int>(s.ids.size())) << "rank " << r;
  }
  for (int g = 0; g < n; ++g) {
    ASSERT_GE(owner_of[g], 0) << "particle " << g << " owned by no rank";
    EXPECT_EQ(owner_of[g], owner[melt.label[g]])
        << "particle " << g << " of molecule " << melt.label[g] << ": not on the rank of its anchor's domain";
    for (int r = 0; r < size; ++r)
      EXPECT_EQ(ranks[r].owns[g] != 0, owner_of[g] == r) << "rank " << r << ", particle " << g;
  }
}

// Equal sizes and equal values (Eigen's == assumes equal sizes).
bool same(const Eigen::Matrix3Xd& a, const Eigen::Matrix3Xd& b) {
  return a.cols() == b.cols() && a == b;
}

class DecompositionOnFakeRanks : public ::testing::TestWithParam<Layout> {};

TEST_P(DecompositionOnFakeRanks, DistributeGivesEachMoleculeWholeToTheRankOfItsAnchorsDomain) {
  const Layout layout = GetParam();
  const Melt melt = fake::straddling_melt();
  const int n = melt.size();
  std::vector<Snapshot> ranks(layout.ranks);
  std::vector<long> collectives(layout.ranks, -1);
  run_ranks(layout.ranks, [&](const FakeCommunicator& comm) {
    auto d = make(melt, comm, layout);
    Eigen::Matrix3Xd x, v;
    d->distribute(melt.topology, melt.state, x, v);
    // The start's collectives: the counts, the anchors' extent, the loads (with a recut also the
    // histograms and the cut's loads), the molecules' exchange.
    collectives[comm.rank()] = comm.collectives();
    ranks[comm.rank()] = snapshot(*d, melt, x, v);
    std::vector<Eigen::Matrix3Xd> whole;
    d->gather_columns({x, v}, whole, n);
    ASSERT_EQ(whole.size(), 2u);
    if (!comm.root()) {
      EXPECT_EQ(whole[0].cols(), 0);
      return;
    }
    EXPECT_TRUE(same(whole[0], melt.state.x));
    EXPECT_TRUE(same(whole[1], melt.state.v));
  });
  for (long c : collectives) EXPECT_EQ(c, layout.balanced ? 6 : 4);
  const DomainGrid& grid = ranks[0].grid;
  EXPECT_EQ(grid.dims.prod(), layout.ranks);
  if (layout.given()) {
    EXPECT_EQ(grid.dims, layout.dims);
  }
  EXPECT_EQ(grid.origin, melt.box.origin);
  EXPECT_EQ(grid.length, melt.box.lengths);
  // Balanced layouts test unequal slabs: every cut axis recut.
  for (int a = 0; a < 3; ++a) {
    EXPECT_EQ(!grid.cut[a].empty(), layout.balanced && grid.dims[a] > 1) << "axis " << a;
    if (grid.cut[a].empty()) continue;
    bool unequal = false;
    for (int c = 0; c <= grid.dims[a]; ++c)
      unequal |= std::abs(grid.cut[a][c] - static_cast<double>(c) / grid.dims[a]) > 1e-3;
    EXPECT_TRUE(unequal) << "axis " << a << ": the balanced cuts are the equal slabs'";
  }
  const std::vector<int> owner = anchor_ranks(melt, grid, melt.state.x);
  expect_ownership(melt, ranks, owner, melt.state.x, melt.state.v);

  // The melt tests what it should: molecules across the domains' faces and across the box's, and
  // every rank owning some.
  int across_domains = 0, across_box = 0;
  for (int m = 0; m < melt.molecules; ++m) {
    std::vector<int> domains;
    bool inside = false, outside = false;
    for (int g : melt.members(m)) {
      const Eigen::Vector3d p = melt.state.x.col(g);
      domains.push_back(fake::rank_of_point(grid, p));
      const bool in = ((p - melt.box.origin).array() >= 0.0).all() &&
                      ((p - melt.box.origin - melt.box.lengths).array() < 0.0).all();
      (in ? inside : outside) = true;
    }
    across_domains += std::any_of(domains.begin(), domains.end(), [&](int r) { return r != domains[0]; });
    across_box += inside && outside;
  }
  EXPECT_GE(across_domains, 5);
  EXPECT_GE(across_box, 5);
  for (int r = 0; r < layout.ranks; ++r) EXPECT_FALSE(ranks[r].ids.empty()) << "rank " << r << " owns nothing";
}

// Where each molecule goes and where it ends: x moved per molecule, and its owner after migrate.
struct Moves {
  Eigen::Matrix3Xd x;
  std::vector<int> owner_before, owner_after;
  int far = 0, near_face_stays = 0, past_slack = 0;
};

// Molecule m by m % 4: 0 to the centre of another rank's domain (every second one a box length
// further along x: unwrapped, outside the box); 1 its anchor half the slack past its domain's
// upper face along a cut axis (it stays); 2 one and a half slacks past it (it moves on); 3 not at
// all. The slack: a quarter of its owner's domain's narrowest width.
Moves plan_moves(const Melt& melt, const DomainGrid& g) {
  Moves p;
  p.x = melt.state.x;
  p.owner_before = anchor_ranks(melt, g, melt.state.x);
  const int ranks = g.size();
  int cut = 0;
  while (g.dims[cut] == 1) ++cut;
  for (int m = 0; m < melt.molecules; ++m) {
    const std::vector<int> members = melt.members(m);
    const Eigen::Vector3d c = fake::centre_of_mass(melt, melt.state.x, members);
    const int from = p.owner_before[m];
    const double slack = 0.25 * (fake::domain_upper_corner(g, from) - fake::domain_corner(g, from)).minCoeff();
    Eigen::Vector3d shift = Eigen::Vector3d::Zero();
    if (m % 4 == 0) {
      const int to = (from + 1 + m / 4 % (ranks - 1)) % ranks;
      // The centre of `to`'s domain at the image of the box nearest c.
      Eigen::Vector3d target = fake::domain_centre(g, to);
      target += melt.box.lengths.cwiseProduct(((c - target).cwiseQuotient(melt.box.lengths)).array().round().matrix());
      shift = target - c;
      if (m % 8 == 0) shift[0] += melt.box.lengths[0];
      ++p.far;
    } else if (m % 4 == 1 || m % 4 == 2) {
      // c wrapped into the box, then to slack/2 or 3 slack/2 past its domain's upper face.
      double q = c[cut] - melt.box.lengths[cut] * std::floor((c[cut] - g.origin[cut]) / g.length[cut]);
      const double face = fake::domain_upper_corner(g, from)[cut];
      shift[cut] = face + (m % 4 == 1 ? 0.5 : 1.5) * slack - q;
      ++(m % 4 == 1 ? p.near_face_stays : p.past_slack);
    }
    for (int i : members) p.x.col(i) += shift;
  }
  p.owner_after = anchor_ranks(melt, g, p.x);
  for (int m = 0; m < melt.molecules; ++m)
    if (m % 4 == 1) {
      EXPECT_NE(p.owner_after[m], p.owner_before[m]) << "molecule " << m << ": its anchor did not cross the face";
      p.owner_after[m] = p.owner_before[m];
    }
  return p;
}

TEST_P(DecompositionOnFakeRanks, MigrateMovesFarMoleculesWholeWithTheirColumnsAndKeepsTheRest) {
  const Layout layout = GetParam();
  const Melt melt = fake::straddling_melt();
  const int n = melt.size();
  // Two carried columns per particle, distinct by global index.
  Eigen::Matrix3Xd c1(3, n), c2(3, n);
  for (int g = 0; g < n; ++g)
    for (int a = 0; a < 3; ++a) c1(a, g) = 10.0 * g + a, c2(a, g) = -0.5 * g - 0.25 * a;
  std::vector<Snapshot> before(layout.ranks), after(layout.ranks);
  std::vector<char> changed(layout.ranks), changed_again(layout.ranks, 1);
  std::vector<char> leave_at_start(layout.ranks, 1), leave(layout.ranks), leave_again(layout.ranks, 1);
  std::vector<Moves> moves(layout.ranks);
  run_ranks(layout.ranks, [&](const FakeCommunicator& comm) {
    const int me = comm.rank();
    auto d = make(melt, comm, layout);
    Eigen::Matrix3Xd x, v;
    d->distribute(melt.topology, melt.state, x, v);
    before[me] = snapshot(*d, melt, x, v);
    leave_at_start[me] = d->molecules_leave(x);  // each molecule on its anchor's rank
    moves[me] = plan_moves(melt, d->grid());     // the same on every rank
    Eigen::Matrix3Xd mine1(3, d->num_owned()), mine2(3, d->num_owned());
    for (int k = 0; k < d->num_owned(); ++k) {
      const int g = d->owned_ids()[k];
      x.col(k) = moves[me].x.col(g);
      mine1.col(k) = c1.col(g), mine2.col(k) = c2.col(g);
    }
    leave[me] = d->molecules_leave(x);  // the test alone: nothing moves
    EXPECT_EQ(d->owned_ids(), before[me].ids);
    changed[me] = d->migrate(x, v, {&mine1, &mine2});
    after[me] = snapshot(*d, melt, x, v, {mine1, mine2});
    // Nothing moved since: nothing leaves, nothing changes.
    leave_again[me] = d->molecules_leave(x);
    changed_again[me] = d->migrate(x, v, {&mine1, &mine2});
    EXPECT_EQ(d->owned_ids(), after[me].ids);
    EXPECT_TRUE(same(x, after[me].x));
    EXPECT_TRUE(same(mine1, after[me].carried[0]));
    // Rank 0 gathers the moved arrays by global index.
    std::vector<Eigen::Matrix3Xd> whole;
    d->gather_columns({x, v, mine1, mine2}, whole, n);
    std::vector<Eigen::Matrix3Xd> by_sevens;  // the same, one gather per 7 global indices
    d->gather_columns({x, v, mine1, mine2}, by_sevens, n, 7);
    ASSERT_EQ(whole.size(), 4u);
    ASSERT_EQ(by_sevens.size(), 4u);
    for (size_t a = 0; a < whole.size(); ++a) EXPECT_TRUE(same(by_sevens[a], whole[a])) << "array " << a;
    if (!comm.root()) {
      for (const Eigen::Matrix3Xd& w : whole) EXPECT_EQ(w.cols(), 0);
      return;
    }
    EXPECT_TRUE(same(whole[0], moves[me].x));
    EXPECT_TRUE(same(whole[1], melt.state.v));
    EXPECT_TRUE(same(whole[2], c1));
    EXPECT_TRUE(same(whole[3], c2));
  });
  const Moves& p = moves[0];
  ASSERT_GE(p.far, 3);
  ASSERT_GE(p.near_face_stays, 3);
  ASSERT_GE(p.past_slack, 3);
  expect_ownership(melt, before, p.owner_before, melt.state.x, melt.state.v);
  expect_ownership(melt, after, p.owner_after, p.x, melt.state.v);
  for (int r = 0; r < layout.ranks; ++r) {
    ASSERT_EQ(after[r].carried.size(), 2u);
    for (int k = 0; k < static_cast<int>(after[r].ids.size()); ++k) {
      EXPECT_EQ(after[r].carried[0].col(k), c1.col(after[r].ids[k])) << "rank " << r;
      EXPECT_EQ(after[r].carried[1].col(k), c2.col(after[r].ids[k])) << "rank " << r;
    }
    EXPECT_EQ(changed[r] != 0, before[r].ids != after[r].ids) << "rank " << r;
    // The same answer on every rank: whether any rank's molecules moved.
    EXPECT_FALSE(leave_at_start[r]) << "rank " << r;
    EXPECT_EQ(leave[r] != 0, std::any_of(changed.begin(), changed.end(), [](char c) { return c != 0; }))
        << "rank " << r;
    EXPECT_FALSE(leave_again[r]) << "rank " << r;
    EXPECT_FALSE(changed_again[r]) << "rank " << r;
  }
  int moved = 0;
  for (int m = 0; m < melt.molecules; ++m) moved += p.owner_after[m] != p.owner_before[m];
  EXPECT_GE(moved, p.far + p.past_slack);
}

TEST_P(DecompositionOnFakeRanks, FirstNonFiniteIsTheFirstOwnedBeadWithANonFiniteXOrV) {
  const Layout layout = GetParam();
  const Melt melt = fake::straddling_melt();
  run_ranks(layout.ranks, [&](const FakeCommunicator& comm) {
    auto d = make(melt, comm, layout);
    Eigen::Matrix3Xd x, v;
    d->distribute(melt.topology, melt.state, x, v);
    const int owned = d->num_owned();
    EXPECT_EQ(d->first_non_finite(x, v), -1);
    if (owned < 3) return;
    const int first = owned / 2;
    v(0, owned - 1) = std::numeric_limits<double>::infinity();
    EXPECT_EQ(d->first_non_finite(x, v), owned - 1);
    x(1, first) = std::nan("");
    EXPECT_EQ(d->first_non_finite(x, v), first);
  });
}

// The distance from p to rank r's domain (per axis the gap to its slab, over the periodic images),
// computed here from the grid's numbers.
double distance_to_domain(const DomainGrid& g, const Box& box, int r, const Eigen::Vector3d& p) {
  const Eigen::Vector3d lo = fake::domain_corner(g, r), hi = fake::domain_upper_corner(g, r);
  double d2 = 0.0;
  for (int a = 0; a < 3; ++a) {
    double gap = std::numeric_limits<double>::infinity();
    for (int image = -2; image <= 2; ++image) {
      const double q = p[a] + image * box.lengths[a];
      gap = std::min(gap, std::max({0.0, lo[a] - q, q - hi[a]}));
    }
    d2 += gap * gap;
  }
  return std::sqrt(d2);
}

// p wrapped into the box (every axis periodic here).
Eigen::Vector3d wrapped(const Box& box, const Eigen::Vector3d& p) {
  Eigen::Vector3d q;
  for (int a = 0; a < 3; ++a) q[a] = p[a] - box.lengths[a] * std::floor((p[a] - box.origin[a]) / box.lengths[a]);
  return q;
}

// The pair sets (two ownerships, one halo): each bead is home on exactly one rank, the one whose
// domain holds it; a rank's pair set is exactly the beads within R = r_c + margin of its domain
// (up to rounding at R), in increasing global index, its halo the beads not home there; forward
// gives every slot its bead's position wrapped into the box and each home bead the force its owner
// holds (0 on the halo); reverse gives each owner its beads' forces as their homes hold them.
// (When they are selected again is the lists' test: NeighborList.DisplacementLimit*.)
TEST_P(DecompositionOnFakeRanks, PairSetsHoldTheBeadsNearTheirDomainAndMoveXOutAndForcesBack) {
  const Layout layout = GetParam();
  const Melt melt = fake::straddling_melt();
  const int n = melt.size();
  const double radius = kCutoff + kMargin;
  struct PairSet {
    std::vector<int> ids;
    std::vector<char> halo;
    int home = 0;
  };
  std::vector<PairSet> sets(layout.ranks);
  DomainGrid grid;
  run_ranks(layout.ranks, [&](const FakeCommunicator& comm) {
    const int me = comm.rank();
    auto d = make(melt, comm, layout);
    Eigen::Matrix3Xd x, v;
    d->distribute(melt.topology, melt.state, x, v);
    d->select_pair_set(x);
    PairSet& s = sets[me];
    s.ids = d->pair_ids(), s.halo = d->halo_flags(), s.home = d->num_home();
    if (me == 0) grid = d->grid();
    for (int e = 0; e < static_cast<int>(s.ids.size()); ++e) EXPECT_EQ(d->pair_slot(s.ids[e]), e);
    // Forward: positions wrapped, the owners' forces on the home beads, 0 on the halo.
    Eigen::Matrix3Xd f(3, d->num_owned()), pair_x, pair_f;
    for (int k = 0; k < d->num_owned(); ++k) f.col(k) = Eigen::Vector3d(d->owned_ids()[k], -1.0, 0.5);
    d->forward(x, pair_x, &f, &pair_f);
    ASSERT_EQ(pair_x.cols(), static_cast<long>(s.ids.size()));
    ASSERT_EQ(pair_f.cols(), static_cast<long>(s.ids.size()));
    for (int e = 0; e < static_cast<int>(s.ids.size()); ++e) {
      const int g = s.ids[e];
      EXPECT_TRUE(pair_x.col(e).isApprox(wrapped(melt.box, melt.state.x.col(g)), 1e-14)) << "rank " << me << ", " << g;
      const Eigen::Vector3d want = s.halo[e] ? Eigen::Vector3d::Zero() : Eigen::Vector3d(g, -1.0, 0.5);
      EXPECT_EQ(pair_f.col(e), want) << "rank " << me << ", particle " << g;
    }
    // Positions alone: the same positions.
    Eigen::Matrix3Xd again;
    d->forward(x, again);
    EXPECT_TRUE(same(again, pair_x));
    // Reverse: each home bead's force, as its home set it, reaches its owner.
    for (int e = 0; e < static_cast<int>(s.ids.size()); ++e)
      pair_f.col(e) = s.halo[e] ? Eigen::Vector3d(1e9, 1e9, 1e9) : Eigen::Vector3d(2.0 * s.ids[e], me, 7.0);
    f.setConstant(-3.0);
    d->reverse(pair_f, f);
    for (int k = 0; k < d->num_owned(); ++k) {
      const int g = d->owned_ids()[k];
      EXPECT_EQ(f(0, k), 2.0 * g) << "particle " << g;
      EXPECT_EQ(f(1, k), fake::rank_of_point(d->grid(), melt.state.x.col(g))) << "particle " << g << ": not its home's";
      EXPECT_EQ(f(2, k), 7.0);
    }
  });
  // Every bead home on exactly one rank: the one whose domain holds it.
  std::vector<int> home_of(n, -1);
  int homes = 0;
  for (int r = 0; r < layout.ranks; ++r) {
    const PairSet& s = sets[r];
    EXPECT_TRUE(std::is_sorted(s.ids.begin(), s.ids.end()) &&
                std::adjacent_find(s.ids.begin(), s.ids.end()) == s.ids.end());
    int home = 0;
    for (size_t e = 0; e < s.ids.size(); ++e) {
      if (s.halo[e]) continue;
      ++home;
      EXPECT_EQ(home_of[s.ids[e]], -1) << "particle " << s.ids[e] << " home on two ranks";
      home_of[s.ids[e]] = r;
    }
    EXPECT_EQ(home, s.home);
    homes += home;
  }
  EXPECT_EQ(homes, n);
  for (int g = 0; g < n; ++g) EXPECT_EQ(home_of[g], fake::rank_of_point(grid, melt.state.x.col(g))) << "particle " << g;
  // A rank's pair set: the beads within R of its domain (either side of R by more than rounding).
  int halo_beads = 0;
  for (int r = 0; r < layout.ranks; ++r) {
    const PairSet& s = sets[r];
    for (int g = 0; g < n; ++g) {
      const double dist = distance_to_domain(grid, melt.box, r, melt.state.x.col(g));
      const bool in = std::binary_search(s.ids.begin(), s.ids.end(), g);
      if (dist < radius - 1e-9) {
        EXPECT_TRUE(in) << "rank " << r << " misses particle " << g << " at " << dist;
      }
      if (dist > radius + 1e-9) {
        EXPECT_FALSE(in) << "rank " << r << " holds particle " << g << " at " << dist;
      }
    }
    halo_beads += static_cast<int>(s.ids.size()) - s.home;
  }
  EXPECT_GT(halo_beads, 0);
}

// DomainGrid::slab_of on cut slabs counts the inner faces at or below a coordinate's fraction of
// the axis (up to 32 slabs) or bisects them (more): either way the slab whose low face is the last
// at or below it, on the faces themselves too; equal slabs floor the fraction, clamped to the edge
// slabs.
TEST(DomainGridSlabs, SlabOfIsTheSlabWhoseLowFaceIsTheLastAtOrBelow) {
  for (const int n : {2, 5, 32, 33, 64}) {
    SCOPED_TRACE(testing::Message() << n << " slabs");
    DomainGrid g;
    g.dims = Eigen::Vector3i(n, 1, 1);
    g.origin = Eigen::Vector3d(-2.0, 0.0, 0.0);
    g.length = Eigen::Vector3d(7.0, 1.0, 1.0);
    g.periodic = Eigen::Vector3i::Ones();
    std::vector<double> cut(n + 1);
    for (int c = 0; c <= n; ++c) cut[c] = std::pow(static_cast<double>(c) / n, 1.3);  // unequal
    g.cut[0] = cut;
    const auto expected = [&](double q) {
      const double f = (q - g.origin[0]) / g.length[0];
      int slab = 0;
      for (int c = 1; c < n; ++c)
        if (cut[c] <= f) slab = c;
      return slab;
    };
    for (int k = -10; k <= 7010; ++k) {
      const double q = g.origin[0] + 1e-3 * k;
      ASSERT_EQ(g.slab_of(0, q), expected(q)) << "q = " << q;
    }
    for (int c = 1; c < n; ++c) {  // a coordinate whose fraction is a face exactly
      const double q = g.origin[0] + cut[c] * g.length[0];
      EXPECT_EQ(g.slab_of(0, q), expected(q)) << "face " << c;
    }
    g.cut[0].clear();  // equal slabs
    EXPECT_EQ(g.slab_of(0, g.origin[0] - 0.5), 0);
    EXPECT_EQ(g.slab_of(0, g.origin[0] + g.length[0] + 0.5), n - 1);
    EXPECT_EQ(g.slab_of(0, g.origin[0] + (n - 0.5) * g.length[0] / n), n - 1);
    EXPECT_EQ(g.slab_of(0, g.origin[0] + 0.5 * g.length[0] / n), 0);
    EXPECT_EQ(g.slab_of(0, std::nan("")), 0);
  }
}

// The load balance (docs/parallel.md, "Load balance").

// Cuts at equal shares of a histogram's total: exact where a share ends at a bin's edge, linear
// inside a bin, an empty stretch of the axis given to the slab below it.
TEST(LoadBalance, QuantileCutsGiveEachSlabAnEqualShare) {
  const std::vector<double> even(8, 1.0);
  EXPECT_EQ(quantile_cuts(even, 4), (std::vector<double>{0.0, 0.25, 0.5, 0.75, 1.0}));
  // All the work in the upper half: the cut at three quarters of the axis, the empty half below.
  EXPECT_EQ(quantile_cuts(std::vector<double>{0.0, 0.0, 4.0, 4.0}, 2), (std::vector<double>{0.0, 0.75, 1.0}));
  // Half of a bin's work: half way through the bin.
  EXPECT_EQ(quantile_cuts(std::vector<double>{2.0, 0.0, 0.0, 2.0}, 4),
            (std::vector<double>{0.0, 0.125, 0.25, 0.875, 1.0}));
  // No work: equal slabs.
  EXPECT_EQ(quantile_cuts(std::vector<double>(6, 0.0), 3), (std::vector<double>{0.0, 1.0 / 3.0, 2.0 / 3.0, 1.0}));
}

// A melt filling half a periodic box (x < L/2 of a box 2L × L × L, short chains built in an L
// cube, many of them, so that the beads fill it evenly enough for a grid of slabs to share out):
// on 4 ranks the least cut surface is 2 × 1 × 2, and the equal slabs give the two domains at
// low x every bead.
Melt half_box_melt() {
  Box cube;
  cube.lengths = Eigen::Vector3d(12.0, 12.0, 12.0);
  cube.periodic = Eigen::Vector3i::Ones();
  ChainSpec spec;
  spec.chains = 400, spec.beads = 5, spec.min_distance = 0.0, spec.seed = 11;
  const Polymer built = build_linear_chains(spec, cube);
  Melt melt;
  melt.box = cube;
  melt.box.lengths[0] *= 2.0;
  const int n = static_cast<int>(built.x.cols());
  melt.molecules = spec.chains;
  melt.label = built.molecule;
  melt.state.x = built.x;
  melt.state.v = Eigen::Matrix3Xd::Zero(3, n);
  melt.state.inv_mass = Eigen::VectorXd::Ones(n);
  melt.topology.bond_types = {"bond"};
  for (const auto& [i, j] : built.bonds) melt.topology.bonds.push_back({i, j, 0});
  return melt;
}

// Each rank's home beads after a selection of the pair sets, and their max/mean.
double home_imbalance(const std::vector<int>& home) {
  const double total = std::accumulate(home.begin(), home.end(), 0.0);
  return *std::max_element(home.begin(), home.end()) / (total / static_cast<double>(home.size()));
}

TEST(LoadBalance, AHalfBoxMeltOnFourRanksIsCutIntoEqualSharesAtTheStart) {
  const Melt melt = half_box_melt();
  for (const auto when : {BalanceSettings::When::off, BalanceSettings::When::start}) {
    std::vector<int> home(4);
    std::vector<double> before(4), after(4);
    std::vector<long> recuts(4), collectives(4);
    DomainGrid grid;
    run_ranks(4, [&](const FakeCommunicator& comm) {
      auto d = make(melt, comm, Layout{4, {0, 0, 0}});
      d->set_balance({when, 1.1});
      Eigen::Matrix3Xd x, v;
      d->distribute(melt.topology, melt.state, x, v);
      collectives[comm.rank()] = comm.collectives();  // the recut from the counts summed over the ranks
      d->select_pair_set(x);
      home[comm.rank()] = d->num_home();
      before[comm.rank()] = d->imbalance_before(), after[comm.rank()] = d->imbalance(x);
      recuts[comm.rank()] = d->recuts();
      if (comm.root()) grid = d->grid();
    });
    const bool cut = when == BalanceSettings::When::start;
    EXPECT_EQ(grid.dims, Eigen::Vector3i(2, 1, 2));
    for (int r = 0; r < 4; ++r) {
      EXPECT_EQ(collectives[r], cut ? 6 : 4);
      EXPECT_GT(before[r], 1.5) << "the equal slabs: two domains hold the melt";
      EXPECT_EQ(after[r], after[0]);
      EXPECT_EQ(recuts[r], cut ? 1 : 0);
    }
    // The measure is the ranks' home beads.
    EXPECT_DOUBLE_EQ(after[0], home_imbalance(home));
    if (cut) {
      EXPECT_LE(after[0], 1.1);
      EXPECT_LT(grid.cut[0][1], 0.4) << "the x cut inside the melt";
    } else {
      EXPECT_EQ(after[0], before[0]);
    }
  }
}

// The dynamic balance: on equal slabs the melt's home beads exceed the threshold at a selection;
// every rank recuts alike, the molecules migrate whole to the new domains, and the next selection
// finds each rank's share within the threshold (and no recut follows).
TEST(LoadBalance, DynamicRecutAtASelectionMovesTheMoleculesToTheNewDomains) {
  const Melt melt = half_box_melt();
  std::vector<int> home_before(4), home_after(4);
  std::vector<char> recut(4), again(4);
  std::vector<Snapshot> after(4);
  DomainGrid grid;
  run_ranks(4, [&](const FakeCommunicator& comm) {
    const int me = comm.rank();
    auto d = make(melt, comm, Layout{4, {0, 0, 0}});
    Eigen::Matrix3Xd x, v;
    d->distribute(melt.topology, melt.state, x, v);  // the balance off: equal slabs
    d->set_balance({BalanceSettings::When::dynamic, 1.1});
    d->select_pair_set(x);
    home_before[me] = d->num_home();
    recut[me] = d->rebalance(x);
    d->migrate(x, v, {});
    d->select_pair_set(x);
    home_after[me] = d->num_home();
    again[me] = d->rebalance(x);
    after[me] = snapshot(*d, melt, x, v);
    if (comm.root()) grid = d->grid();
  });
  EXPECT_GT(home_imbalance(home_before), 1.5);
  EXPECT_LE(home_imbalance(home_after), 1.1);
  for (int r = 0; r < 4; ++r) {
    EXPECT_TRUE(recut[r]) << "rank " << r;
    EXPECT_FALSE(again[r]) << "rank " << r;
  }
  // Each molecule whole on one rank, its columns the melt's; owned by its anchor's domain or, within
  // the migration's slack, its old owner's.
  std::vector<int> owner(melt.molecules, -1);
  for (int r = 0; r < 4; ++r)
    for (int g : after[r].ids) {
      const int m = melt.label[g];
      EXPECT_TRUE(owner[m] == -1 || owner[m] == r) << "molecule " << m << " on ranks " << owner[m] << " and " << r;
      owner[m] = r;
    }
  int at_anchor = 0;
  for (int m = 0; m < melt.molecules; ++m) {
    ASSERT_GE(owner[m], 0) << "molecule " << m << " owned by no rank";
    at_anchor += owner[m] == fake::rank_of_point(grid, fake::centre_of_mass(melt, melt.state.x, melt.members(m)));
  }
  EXPECT_GE(at_anchor, melt.molecules * 3 / 4);
}

// A melt of long chains numbered along each chain (no permutation), so that a pair set holds runs
// of many consecutive owned columns, of every length modulo 4, beside the halo's short ones.
Melt chain_melt() {
  Melt melt;
  melt.box.origin = Eigen::Vector3d(0.5, -1.0, 2.0);
  melt.box.lengths = Eigen::Vector3d(14.0, 13.0, 12.0);
  melt.box.periodic = Eigen::Vector3i::Ones();
  ChainSpec spec;
  spec.chains = 30, spec.beads = 40, spec.min_distance = 0.0, spec.seed = 11;
  const Polymer built = build_linear_chains(spec, melt.box);
  const int n = static_cast<int>(built.x.cols());
  melt.molecules = spec.chains;
  melt.label = built.molecule;
  melt.state.x = built.x;
  melt.state.v.resize(3, n);
  for (int i = 0; i < n; ++i)
    for (int a = 0; a < 3; ++a) melt.state.v(a, i) = std::cos(2.0 + 5 * i + a);
  melt.state.inv_mass = Eigen::VectorXd::Ones(n);
  melt.topology.bond_types = {"bond"};
  for (const auto& [i, j] : built.bonds) melt.topology.bonds.push_back({i, j, 0});
  return melt;
}

// The bits of a double (−0 is not +0).
std::uint64_t bits(double v) {
  return std::bit_cast<std::uint64_t>(v);
}

// forward writes each pair-set bead's position as BoxWrap gives it from its owner's coordinates,
// bit for bit (the owner wraps its array once and the copies move bits), at every evaluation with
// the beads moved since the selection (some across a periodic face); the home beads' forces so far
// exactly, the halo's cleared whatever the last evaluation left there; reverse hands each owner its
// beads' forces from their home, reading no halo column.
void expect_forward_and_reverse_exact(const Melt& melt, const Layout& layout) {
  const int n = melt.size();
  // Per global index: a displacement since the selection (up to 0.45 per axis).
  const auto moved = [](int g, int pass) {
    return Eigen::Vector3d(0.45 * std::sin(1.0 + g + pass), 0.45 * std::cos(0.5 * g - pass), 0.45 * std::sin(2.0 * g));
  };
  std::vector<int> home_beads(layout.ranks, 0);
  run_ranks(layout.ranks, [&](const FakeCommunicator& comm) {
    const int me = comm.rank();
    auto d = make(melt, comm, layout);
    Eigen::Matrix3Xd x, v;
    d->distribute(melt.topology, melt.state, x, v);
    d->select_pair_set(x);
    const BoxWrap into_box(melt.box);
    const std::vector<int>& ids = d->pair_ids();
    const std::vector<char>& halo = d->halo_flags();
    const int owned = d->num_owned();
    Eigen::Matrix3Xd y(3, owned), f(3, owned), pair_x, pair_f, positions_only;
    for (int pass = 0; pass < 3; ++pass) {
      for (int k = 0; k < owned; ++k) {
        const int g = d->owned_ids()[k];
        y.col(k) = x.col(k) + moved(g, pass);
        f.col(k) = Eigen::Vector3d(g + 0.25, -g, pass);
      }
      if (pass > 0) pair_f.setConstant(1e300);  // what a pair loop may leave on the halo
      d->forward(y, pair_x, &f, &pair_f);
      ASSERT_EQ(pair_x.cols(), static_cast<long>(ids.size()));
      ASSERT_EQ(pair_f.cols(), static_cast<long>(ids.size()));
      for (int e = 0; e < static_cast<int>(ids.size()); ++e) {
        const int g = ids[e];
        const Eigen::Vector3d at = melt.state.x.col(g) + moved(g, pass);
        for (int a = 0; a < 3; ++a)
          ASSERT_EQ(bits(pair_x(a, e)), bits(into_box(at[a], a)))
              << "rank " << me << ", particle " << g << ", axis " << a << ", pass " << pass;
        const Eigen::Vector3d want = halo[e] ? Eigen::Vector3d::Zero() : Eigen::Vector3d(g + 0.25, -g, pass);
        ASSERT_EQ(pair_f.col(e), want) << "rank " << me << ", particle " << g << ", pass " << pass;
      }
      d->forward(y, positions_only);
      EXPECT_TRUE(same(positions_only, pair_x));
      // Reverse: the home's force, never a halo column's (NaN there).
      for (int e = 0; e < static_cast<int>(ids.size()); ++e)
        pair_f.col(e) = halo[e] ? Eigen::Vector3d::Constant(std::numeric_limits<double>::quiet_NaN())
                                : Eigen::Vector3d(3.0 * ids[e], me, ids[e] - pass);
      f.setConstant(-7.0);
      d->reverse(pair_f, f);
      for (int k = 0; k < owned; ++k) {
        const int g = d->owned_ids()[k];
        ASSERT_EQ(f(0, k), 3.0 * g) << "rank " << me << ", particle " << g;
        ASSERT_EQ(f(1, k), fake::rank_of_point(d->grid(), melt.state.x.col(g))) << "particle " << g;
        ASSERT_EQ(f(2, k), g - pass) << "particle " << g;
      }
    }
    home_beads[me] = d->num_home();
  });
  EXPECT_EQ(std::accumulate(home_beads.begin(), home_beads.end(), 0), n);
}

TEST_P(DecompositionOnFakeRanks, ForwardGivesBoxWrapsBitsAndReverseTheHomesForces) {
  expect_forward_and_reverse_exact(fake::straddling_melt(), GetParam());
  expect_forward_and_reverse_exact(chain_melt(), GetParam());
}

// The same on many ranks: slabs wider than R on every axis (the selection's slabs beside a bead's
// own), and slabs narrower than R along one axis (its walk over the slabs within R).
TEST(DecompositionOnManyFakeRanks, ForwardGivesBoxWrapsBitsAndReverseTheHomesForces) {
  const Melt melt = chain_melt();
  for (const Layout& layout :
       {Layout{16, {4, 2, 2}}, Layout{16, {0, 0, 0}}, Layout{8, {8, 1, 1}}, Layout{6, {1, 1, 6}}})
    expect_forward_and_reverse_exact(melt, layout);
}

// What a bead carries to the pair sets (set_owned_pair_data), made up from its global index g and a
// salt that each part build changes: a type, a charge and two terms' special partners — the first
// the chain's neighbours beside it, the second 0–3 beads after it (every count, so that the beads'
// words differ in length along a run) — with weights that name the pair.
struct MadeUpPairData {
  int salt;
  int beads;
  int type(int g) const { return (g * 7 + salt) % 11; }
  double charge(int g) const { return 0.25 * g - salt; }
  std::vector<int> partners(int t, int g) const {
    std::vector<int> p;
    if (t == 0) {
      if (g > 0) p.push_back(g - 1);
      if (g + 1 < beads) p.push_back(g + 1);
    } else {
      for (int q = 1; q <= (g + salt) % 4 && g + q < beads; ++q) p.push_back(g + q);
    }
    return p;
  }
  double weight(int t, int g, int h) const { return 0.5 * t + 1e-3 * g + 1e-7 * h + salt; }
  PairBeadData owned(const std::vector<int>& ids) const {
    PairBeadData d;
    d.charged = true;
    d.special.resize(2);
    for (const int g : ids) {
      d.type.push_back(type(g));
      d.charge.push_back(charge(g));
      for (int t = 0; t < 2; ++t) {
        SpecialPartners& s = d.special[t];
        for (const int h : partners(t, g))
          s.partner.push_back(h), s.weight.push_back(weight(t, g, h)), s.weight_coul.push_back(-weight(t, h, g));
        s.start.push_back(static_cast<int>(s.partner.size()));
      }
    }
    return d;
  }
};

// Every pair-set slot holds what its bead carried, sized exactly (partners as many as the rows
// name), after a selection, after one with the beads moved, and after a part build that changed
// what the beads carry (set_owned_pair_data again: its words packed afresh).
void expect_carried_data_exact(const Melt& melt, const Layout& layout) {
  const int n = melt.size();
  std::vector<long> arrived(layout.ranks, 0);
  run_ranks(layout.ranks, [&](const FakeCommunicator& comm) {
    const int me = comm.rank();
    auto d = make(melt, comm, layout);
    Eigen::Matrix3Xd x, v;
    d->distribute(melt.topology, melt.state, x, v);
    for (int pass = 0; pass < 3; ++pass) {
      const MadeUpPairData made{pass == 2 ? 5 : 0, n};
      if (pass != 1) d->set_owned_pair_data(made.owned(d->owned_ids()));
      if (pass == 1) x.array() += 0.7;
      d->select_pair_set(x);
      const std::vector<int>& ids = d->pair_ids();
      const PairBeadData& p = d->pair_data();
      const int m = static_cast<int>(ids.size());
      ASSERT_EQ(p.type.size(), ids.size());
      ASSERT_EQ(p.charge.size(), ids.size());
      ASSERT_EQ(p.special.size(), 2u);
      for (int t = 0; t < 2; ++t) {
        const SpecialPartners& s = p.special[t];
        ASSERT_EQ(s.size(), m);
        ASSERT_EQ(s.start[0], 0);
        ASSERT_EQ(static_cast<int>(s.partner.size()), s.start[m]) << "rank " << me << ", term " << t;
        ASSERT_EQ(static_cast<int>(s.weight.size()), s.start[m]);
        ASSERT_EQ(static_cast<int>(s.weight_coul.size()), s.start[m]);
      }
      long others = 0;
      for (int e = 0; e < m; ++e) {
        const int g = ids[e];
        others += d->owned_index(g) < 0;
        const std::string where =
            "rank " + std::to_string(me) + ", pass " + std::to_string(pass) + ", particle " + std::to_string(g);
        ASSERT_EQ(p.type[e], made.type(g)) << where;
        ASSERT_EQ(p.charge[e], made.charge(g)) << where;
        for (int t = 0; t < 2; ++t) {
          const SpecialPartners& s = p.special[t];
          const std::vector<int> want = made.partners(t, g);
          ASSERT_EQ(s.start[e + 1] - s.start[e], static_cast<int>(want.size())) << where << ", term " << t;
          for (std::size_t q = 0; q < want.size(); ++q) {
            const int at = s.start[e] + static_cast<int>(q);
            ASSERT_EQ(s.partner[at], want[q]) << where;
            ASSERT_EQ(s.weight[at], made.weight(t, g, want[q])) << where;
            ASSERT_EQ(s.weight_coul[at], -made.weight(t, want[q], g)) << where;
          }
        }
      }
      arrived[me] = others;
    }
  });
  if (layout.ranks > 1) {
    for (int r = 0; r < layout.ranks; ++r) EXPECT_GT(arrived[r], 0) << "rank " << r << ": no bead from another owner";
  }
}

TEST_P(DecompositionOnFakeRanks, EveryPairSetSlotHoldsWhatItsBeadCarried) {
  expect_carried_data_exact(fake::straddling_melt(), GetParam());
  expect_carried_data_exact(chain_melt(), GetParam());
}

TEST(DecompositionOnManyFakeRanks, EveryPairSetSlotHoldsWhatItsBeadCarried) {
  const Melt melt = chain_melt();
  for (const Layout& layout : {Layout{16, {4, 2, 2}}, Layout{8, {8, 1, 1}}, Layout{6, {1, 1, 6}}})
    expect_carried_data_exact(melt, layout);
}

INSTANTIATE_TEST_SUITE_P(Layouts, DecompositionOnFakeRanks,
                         ::testing::Values(Layout{2, {2, 1, 1}}, Layout{3, {1, 3, 1}}, Layout{4, {2, 1, 2}},
                                           Layout{2, {0, 0, 0}}, Layout{3, {0, 0, 0}}, Layout{4, {0, 0, 0}},
                                           Layout{3, {1, 3, 1}, true}, Layout{4, {2, 1, 2}, true},
                                           Layout{4, {0, 0, 0}, true}, Layout{9, {3, 3, 1}}),
                         layout_name);

}  // namespace
}  // namespace stiffmd
