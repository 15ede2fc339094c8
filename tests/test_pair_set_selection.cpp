// A pair set kept across list rebuilds (engine/domain/ghosted_pairs.cpp, docs/parallel.md): the
// lists rebuild on the pair sets of the last selection while no bead has moved more than
// (R − r_c − skin)/2 since it, and between builds a list counts as stale once a bead may have moved
// (R − r_c)/2 since the selection. If either bound were wrong, some home bead would miss a partner
// within r_c and its force would differ from one process's.
//
// On 2, 3 and 4 fake ranks (tests/fake_processes.hpp), beads that drift at their own speeds (some
// fast) through a periodic melt of trimers: at every evaluation each bead's Lennard-Jones force,
// computed on its home's pair set and sent back to its owner, is one process's bit for bit (one
// thread: the same pairs in the same order), over a walk in which the lists rebuild more often
// than the pair sets are selected, and the pair sets are selected more than once.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <limits>
#include <memory>
#include <random>
#include <string>
#include <vector>

#include "engine/domain/decomposition.hpp"
#include "engine/domain/ghosted_pairs.hpp"
#include "fake_processes.hpp"
#include "forcefields/pair_term.hpp"
#include "test_support.hpp"

namespace stiffmd {
namespace {

using fake::FakeCommunicator;
using fake::run_ranks;

constexpr double kCutoff = 2.5, kSkin = 0.3;
constexpr SpecialWeights kWeights{0.0, 0.5, 1.0};  // 1-2 pairs excluded, 1-3 scaled

// Beads on a periodic box with their positions at each step (unwrapped, as the owners hold them).
struct Walk {
  std::vector<Eigen::Matrix3Xd> x;  // per step
  Box box;
  Topology topology;
  Eigen::VectorXd inv_mass;
  int size() const { return static_cast<int>(x[0].cols()); }
  int steps() const { return static_cast<int>(x.size()); }
};

// A jittered cubic lattice of m³ beads (spacing 1.2), joined into trimers (3k, 3k + 1, 3k + 2) along
// the index order, each bead drifting at its own velocity: most slow, every seventh up to four
// times faster, so that a few beads pass half the skin long before the rest.
Walk drifting_lattice(int m, int steps, unsigned seed) {
  const double a = 1.2;
  std::mt19937 rng(seed);
  std::uniform_real_distribution<double> jitter(-0.2, 0.2), speed(0.0, 1.0);
  std::normal_distribution<double> g;
  const int n = m * m * m;
  Walk w;
  Eigen::Matrix3Xd x(3, n), drift(3, n);
  for (int i = 0; i < n; ++i) {
    const int ix = i / (m * m), iy = (i / m) % m, iz = i % m;
    x.col(i) =
        Eigen::Vector3d((ix + 0.5) * a + jitter(rng), (iy + 0.5) * a + jitter(rng), (iz + 0.5) * a + jitter(rng));
    const Eigen::Vector3d d(g(rng), g(rng), g(rng));
    drift.col(i) = (i % 7 == 0 ? 0.04 : 0.01) * speed(rng) * d.normalized();
  }
  for (int s = 0; s < steps; ++s, x += drift) w.x.push_back(x);
  w.box.lengths = Eigen::Vector3d::Constant(m * a);
  w.box.periodic = Eigen::Vector3i::Ones();
  w.topology.bond_types = {"bond"};
  for (int k = 0; 3 * k + 2 < n; ++k) {
    w.topology.bonds.push_back({3 * k, 3 * k + 1, 0});
    w.topology.bonds.push_back({3 * k + 1, 3 * k + 2, 0});
  }
  w.inv_mass = Eigen::VectorXd::Ones(n);
  return w;
}

std::unique_ptr<LennardJonesPair> lj_term(const Walk& w) {
  TypePairMatrix<LennardJones::Coeffs> c(1);
  c.set(0, 0, {1.0, 1.0, kCutoff});
  return std::make_unique<LennardJonesPair>("lj", Level::slow, std::vector<int>(w.size(), 0), c, w.topology.bonds,
                                            kWeights, w.box, kSkin);
}

// The force so far (the terms before the pair term): the pair forces add onto it.
Eigen::Vector3d force_so_far(int g, int step) {
  return Eigen::Vector3d(0.25 * g, -1.0 * step, 0.5);
}

struct Outcome {
  long selections = 0, rebuilds = 0;
  std::int64_t listed = 0;  // the pairs listed at the end, summed over the ranks
};

// The walk on `ranks` fake ranks of grid `dims` with the halo's `margin`: at every step each
// bead's force (the force so far plus its pair forces, computed at its home and sent back to its
// owner) is one process's, bit for bit, and the ranks' energies add up to one process's (to
// round-off: each rank sums its share). With `once` (the halo pairs once: a pair of a home bead and
// a halo bead computed on one rank, the halo bead's force sent back and added at its owner) the
// forces are one process's to round-off. Returns rank 0's selections and list builds (every rank's
// the same) and the pairs listed on all ranks.
Outcome expect_one_process_forces(const Walk& walk, int ranks, const Eigen::Vector3i& dims, double margin,
                                  bool once = false) {
  const test::ThreadCount one(1);
  const int n = walk.size(), steps = walk.steps();
  std::vector<Eigen::Matrix3Xd> expected;
  std::vector<double> expected_energy;
  {
    const auto whole = lj_term(walk);
    for (int s = 0; s < steps; ++s) {
      Eigen::Matrix3Xd f(3, n);
      for (int g = 0; g < n; ++g) f.col(g) = force_so_far(g, s);
      whole->add_forces(walk.x[s], walk.box, f);
      Eigen::Matrix3Xd scratch;
      expected_energy.push_back(whole->energy_and_virial(walk.x[s], walk.box, scratch).energy);
      expected.push_back(f);
    }
  }
  const auto whole_term = lj_term(walk);
  std::vector<int> every(n);
  for (int g = 0; g < n; ++g) every[g] = g;
  const SpecialPartners special = special_partners(whole_term->special_pairs(), every);
  std::vector<Eigen::Matrix3Xd> got(steps, Eigen::Matrix3Xd::Constant(3, n, -7.0));
  std::vector<Outcome> outcome(ranks);
  std::vector<std::vector<double>> energy(ranks, std::vector<double>(steps, 0.0));
  run_ranks(ranks, [&](const FakeCommunicator& comm) {
    const test::ThreadCount one_here(1);
    Decomposition d(walk.box, comm, kCutoff, margin, &dims);
    d.set_halo_pairs_once(once);
    State whole;
    whole.x = walk.x[0];
    whole.v = Eigen::Matrix3Xd::Zero(3, n);
    whole.inv_mass = walk.inv_mass;
    Eigen::Matrix3Xd x, v;
    d.distribute(walk.topology, whole, x, v);
    // What the owned beads carry to the pair sets: type 0, the whole term's special partners.
    PairBeadData owned;
    owned.type.assign(d.num_owned(), 0);
    owned.special.resize(1);
    for (const int g : d.owned_ids()) {
      SpecialPartners& o = owned.special[0];
      for (int q = special.start[g]; q < special.start[g + 1]; ++q) {
        o.partner.push_back(special.partner[q]);
        o.weight.push_back(special.weight[q]);
        o.weight_coul.push_back(special.weight_coul[q]);
      }
      o.start.push_back(static_cast<int>(o.partner.size()));
    }
    d.set_owned_pair_data(std::move(owned));
    d.select_pair_set(x);
    GhostedPairs pairs(*whole_term, d, 0);
    pairs.update_list(x, walk.box);
    const std::vector<int>& ids = d.owned_ids();
    for (int s = 0; s < steps; ++s) {
      for (int k = 0; k < d.num_owned(); ++k) x.col(k) = walk.x[s].col(ids[k]);
      Eigen::Matrix3Xd f(3, d.num_owned());
      for (int k = 0; k < d.num_owned(); ++k) f.col(k) = force_so_far(ids[k], s);
      pairs.add_forces(x, walk.box, f);
      // The rank's share of the energy (a pair with a halo bead counted half, or with the halo
      // pairs once whole on the one rank that lists it), as the thermo output sums them.
      Eigen::Matrix3Xd scratch;
      energy[comm.rank()][s] = pairs.energy_and_virial(x, walk.box, scratch).energy;
      for (int k = 0; k < d.num_owned(); ++k) got[s].col(ids[k]) = f.col(k);  // disjoint columns per rank
    }
    outcome[comm.rank()] = {d.selections(), pairs.neighbor_list_rebuilds(), pairs.listed_pairs()};
  });
  for (int s = 0; s < steps; ++s) {
    double sum = 0.0;
    for (int r = 0; r < ranks; ++r) sum += energy[r][s];
    EXPECT_NEAR(sum, expected_energy[s], 1e-11 * (1.0 + std::abs(expected_energy[s]))) << "step " << s;
    for (int g = 0; g < n; ++g) {
      if (once) {
        const double scale = 1e-12 * (1.0 + expected[s].col(g).norm());
        EXPECT_LE((got[s].col(g) - expected[s].col(g)).norm(), 10.0 * scale) << "step " << s << ", particle " << g;
        if ((got[s].col(g) - expected[s].col(g)).norm() > 10.0 * scale) return outcome[0];
        continue;
      }
      EXPECT_EQ(got[s].col(g), expected[s].col(g)) << "step " << s << ", particle " << g;
      if (got[s].col(g) != expected[s].col(g)) return outcome[0];
    }
  }
  for (int r = 1; r < ranks; ++r) {
    EXPECT_EQ(outcome[r].selections, outcome[0].selections) << "rank " << r;
    EXPECT_EQ(outcome[r].rebuilds, outcome[0].rebuilds) << "rank " << r;
  }
  Outcome all = outcome[0];
  for (int r = 1; r < ranks; ++r) all.listed += outcome[r].listed;
  return all;
}

struct Case {
  int ranks;
  Eigen::Vector3i dims;
  double margin;  // beyond the cutoff; (margin − skin)/2 is what a kept pair set allows
};

class PairSetKeptAcrossRebuilds : public ::testing::TestWithParam<Case> {};

TEST_P(PairSetKeptAcrossRebuilds, EveryBeadsPairForceIsOneProcesssAtEveryStep) {
  const Case c = GetParam();
  const Outcome o = expect_one_process_forces(drifting_lattice(12, 60, 3), c.ranks, c.dims, c.margin);
  EXPECT_GE(o.selections, 3) << "the walk should need new pair sets";
  EXPECT_GT(o.rebuilds, o.selections) << "a pair set should outlive a list build";
}

// A margin of 2.3 skins keeps a pair set while no bead moved 0.65 skin, 3 skins while none moved
// one skin.
INSTANTIATE_TEST_SUITE_P(Layouts, PairSetKeptAcrossRebuilds,
                         ::testing::Values(Case{2, {2, 1, 1}, 3.0 * kSkin}, Case{3, {1, 3, 1}, 2.3 * kSkin},
                                           Case{4, {2, 2, 1}, 3.0 * kSkin}),
                         [](const ::testing::TestParamInfo<Case>& info) {
                           const Case& c = info.param;
                           return std::to_string(c.ranks) + "_ranks_margin_" +
                                  std::to_string(static_cast<int>(c.margin / kSkin * 10 + 0.5)) + "_tenths_skin";
                         });

// The halo pairs once on the same walks: each bead's force is one process's to round-off at every
// step (a pair missed, or counted on both ranks, or a halo force not sent back, is off by a whole
// pair force), the ranks' energies add up to one process's (each such pair counted whole on one
// rank), and the ranks list fewer pairs than with each home computing its beads' pairs whole.
TEST_P(PairSetKeptAcrossRebuilds, WithTheHaloPairsOnceEveryBeadsForceIsOneProcesssToRoundOff) {
  const Case c = GetParam();
  const Walk walk = drifting_lattice(12, 60, 3);
  const Outcome both = expect_one_process_forces(walk, c.ranks, c.dims, c.margin);
  const Outcome once = expect_one_process_forces(walk, c.ranks, c.dims, c.margin, true);
  EXPECT_GE(once.selections, 3) << "the walk should need new pair sets";
  EXPECT_LT(once.listed, both.listed) << "a pair of a home bead and a halo bead should be listed on one rank";
}

// Where the lists' own tests cannot see a pair: beads i and j, home on slabs A and C on either side
// of a slab B narrower than R, each just over R from the other's slab (in neither's pair set; in
// B's and D's, but as two halo beads, whose pair no list tests), fly at each other while the rest
// stands still. A third bead t, home on B, makes B's list count three fast beads (over its 1/256)
// when i and j have moved 0.28 of the 0.3 a kept pair set allows: the lists rebuild on the pair
// sets as they are. From then on only the displacement limit (R − r_c)/2 − 0.28 = 0.17 since that
// build stops them before they come within r_c of each other: at 0.3 (the skin), where the list
// would stop them by itself, they are 2.47 apart. A pair set kept too long, or a list let run to
// its skin, drops the pair from i's and j's forces.
TEST(PairSetKeptAcrossRebuilds, TwoBeadsFlyingAcrossANarrowSlabMeetInAPairSet) {
  const double margin = 3.0 * kSkin, radius = kCutoff + margin;  // R = 3.4
  // Four slabs of 3.25 along x; a lattice of 11 × 8 × 8 beads, the fliers between its lines.
  Walk w;
  w.box.lengths = Eigen::Vector3d(13.0, 9.6, 9.6);
  w.box.periodic = Eigen::Vector3i::Ones();
  std::vector<Eigen::Vector3d> start;
  for (int ix = 0; ix < 11; ++ix)
    for (int iy = 0; iy < 8; ++iy)
      for (int iz = 0; iz < 8; ++iz) start.emplace_back((ix + 0.5) * 13.0 / 11, (iy + 0.5) * 1.2, (iz + 0.5) * 1.2);
  const int i = static_cast<int>(start.size()), j = i + 1, t = i + 2;
  const double slab = 3.25, past = radius - slab + 0.02;  // i, j: 0.02 beyond R from the other's slab
  start.emplace_back(slab - past, 4.8, 4.8);
  start.emplace_back(2.0 * slab + past, 4.8, 4.8);
  start.emplace_back(1.5 * slab, 0.0, 0.0);
  const int n = static_cast<int>(start.size()), steps = 32;
  for (int s = 0; s < steps; ++s) {
    Eigen::Matrix3Xd x(3, n);
    for (int b = 0; b < n; ++b) x.col(b) = start[b];
    x(0, i) += 0.02 * s, x(0, j) -= 0.02 * s;  // toward each other
    x(2, t) += 0.0115 * std::min(s, 14);       // fast (past 0.15) at step 14, then still
    w.x.push_back(x);
  }
  w.inv_mass = Eigen::VectorXd::Ones(n);
  double closest = std::numeric_limits<double>::infinity();
  for (const Eigen::Matrix3Xd& x : w.x) closest = std::min(closest, (x.col(i) - x.col(j)).norm());
  ASSERT_LT(closest, kCutoff) << "the fliers should meet within the cutoff";
  const Outcome o = expect_one_process_forces(w, 4, {4, 1, 1}, margin);
  EXPECT_GE(o.selections, 2);
  EXPECT_GT(o.rebuilds, o.selections);
}

}  // namespace
}  // namespace stiffmd
