// The OpenMP paths (core/parallel.hpp): bond forces (owner computes), pair forces
// (per-thread buffers), the fused kick–drift. For a system above kParallelMin they must give
// the serial forces to rounding for any thread count, the same bits on every call with a given
// count, and an exception from a kernel must surface as the kernel's exception, not terminate().
#include <gtest/gtest.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <limits>
#include <numeric>
#include <random>
#include <stdexcept>
#include <thread>

#include "core/errors.hpp"
#include "core/parallel.hpp"
#include "engine/run/run.hpp"
#include "forcefields/angle_terms.hpp"
#include "forcefields/bond_term.hpp"
#include "forcefields/counting_sort.hpp"
#include "forcefields/dihedral_terms.hpp"
#include "forcefields/pair_term.hpp"
#include "forcefields/stiff_harmonic_bond.hpp"
#include "integrators/constraints.hpp"
#include "integrators/primitives.hpp"
#include "integrators/thermostat.hpp"

namespace stiffmd {
namespace {

// 20³ particles on a jittered cubic lattice (spacing 1.06) in a periodic box; chains are the
// lattice rows along x (19 bonds each, 7600 in all). With `shuffle`, particle indices are a
// random permutation, so bonds join particles far apart in index (many thread-boundary bonds).
struct Melt {
  Eigen::Matrix3Xd x;
  std::vector<Bond> bonds;
  Box box;
};

Melt melt(bool shuffle) {
  const int n = 20;
  const double a = 1.06;
  std::mt19937 rng(11);
  std::uniform_real_distribution<double> jitter(-0.04, 0.04);
  std::vector<int> index(n * n * n);
  std::iota(index.begin(), index.end(), 0);
  if (shuffle) std::shuffle(index.begin(), index.end(), rng);
  Melt m;
  m.x.resize(3, n * n * n);
  for (int iz = 0; iz < n; ++iz)
    for (int iy = 0; iy < n; ++iy)
      for (int ix = 0; ix < n; ++ix) {
        const int site = ix + n * (iy + n * iz);
        m.x.col(index[site]) = Eigen::Vector3d(ix * a + jitter(rng), iy * a + jitter(rng), iz * a + jitter(rng));
        if (ix > 0) m.bonds.push_back({index[site - 1], index[site], 0});
      }
  m.box.lengths = Eigen::Vector3d::Constant(n * a);
  m.box.periodic = Eigen::Vector3i::Ones();
  return m;
}

struct Forces {
  Eigen::Matrix3Xd f;
  double energy;
};

Forces evaluate(const ForceTerm& term, const Melt& m, int threads) {
  set_max_threads(threads);
  Forces out{Eigen::Matrix3Xd::Zero(3, m.x.cols()), 0.0};
  out.energy = term.add_forces(m.x, m.box, out.f);
  return out;
}

void expect_thread_independent(const ForceTerm& term, const Melt& m) {
  const int restore = max_threads();
  const Forces serial = evaluate(term, m, 1);
  const double scale = serial.f.cwiseAbs().maxCoeff();
  ASSERT_GT(scale, 0.0);
  for (int threads : {2, 3, 4}) {
    SCOPED_TRACE(testing::Message() << threads << " threads");
    const Forces a = evaluate(term, m, threads), b = evaluate(term, m, threads);
    EXPECT_EQ(a.f, b.f);  // bit for bit, call to call
    EXPECT_EQ(a.energy, b.energy);
    EXPECT_LE((a.f - serial.f).cwiseAbs().maxCoeff(), 1e-13 * scale);
    EXPECT_NEAR(a.energy, serial.energy, 1e-12 * std::abs(serial.energy));
  }
  set_max_threads(restore);
}

TEST(Parallel, SystemIsAboveTheSerialThreshold) {
  const Melt m = melt(false);
  EXPECT_GE(static_cast<std::int64_t>(m.bonds.size()), kParallelMin);
  EXPECT_GE(m.x.cols(), kParallelMin);
}

StiffBonds stiff(const std::vector<Bond>& bonds) {
  StiffBonds s;
  s.epsilon = 0.05;
  for (const Bond& b : bonds) s.bonds.push_back({b.i, b.j, 1.0, 1.0});
  return s;
}

TEST(Parallel, StiffBondForcesDoNotDependOnTheThreadCount) {
  for (bool shuffle : {false, true}) {
    SCOPED_TRACE(shuffle ? "shuffled indices" : "chains in index order");
    const Melt m = melt(shuffle);
    expect_thread_independent(StiffHarmonicBond("bonds", Level::fast, stiff(m.bonds)), m);
  }
}

TEST(Parallel, WcaForcesDoNotDependOnTheThreadCount) {
  for (bool shuffle : {false, true}) {
    const Melt m = melt(shuffle);
    TypePairMatrix<WeeksChandlerAndersen::Coeffs> c(1);
    c.set(0, 0, {1.0, 1.0});
    const WcaPair wca("wca", Level::slow, std::vector<int>(m.x.cols(), 0), c, m.bonds, {0.0, 1.0}, m.box, 0.3);
    Eigen::Matrix3Xd f = Eigen::Matrix3Xd::Zero(3, m.x.cols());
    wca.add_forces(m.x, m.box, f);
    ASSERT_GE(static_cast<std::int64_t>(wca.neighbor_list().num_pairs()), kParallelMin);
    expect_thread_independent(wca, m);
  }
}

// The charged pair loop on the threads: lj/cut/coul/long (the real-space table and the exact erfc
// of the special pairs) over the lattice melt with charges ±0.4 alternating along the chains and
// the bonded neighbours' Coulomb scaled (special_coul 0.5): the forces and energy the serial ones.
TEST(Parallel, ChargedEwaldPairForcesDoNotDependOnTheThreadCount) {
  for (bool shuffle : {false, true}) {
    const Melt m = melt(shuffle);
    std::vector<double> q(static_cast<std::size_t>(m.x.cols()), 0.4);
    for (const Bond& b : m.bonds) q[static_cast<std::size_t>(b.j)] = -q[static_cast<std::size_t>(b.i)];
    TypePairMatrix<LjCoulCoeffs> c(1);
    LjCoulCoeffs lj;
    lj.epsilon = 1.0, lj.sigma = 1.0, lj.rc = 1.122462048309373, lj.coulomb_cutoff = 3.0, lj.shift = true;
    c.set(0, 0, lj);
    PairTerm<LjCutCoulLong> term("coul", Level::slow, std::vector<int>(m.x.cols(), 0), c, m.bonds, {0.0, 1.0}, m.box,
                                 0.3, Electrostatics{q, 1.0, {0.5, 1.0}});
    term.set_ewald_splitting(1.0);
    expect_thread_independent(term, m);
  }
}

// The parallel pair loop itself (accumulate_pair_rows_parallel): for 1, 2, 3 and 7 parts the
// serial loop's forces (added into what f held), energy and virial to round-off, 1 part bit for
// bit, and a given part count the same bits on every call — with its touched runs cached, from a
// fresh scratch, and after the list is rebuilt for moved particles (the cache must follow the
// build). LJ at rc = 2.5 over the lattice melt: ~40 neighbours a row, most in other parts' rows.
struct PairRowsResult {
  Eigen::Matrix3Xd f;
  PairSums sums;
  std::array<int, kMaxParts + 1> first_row;
};

PairRowsResult pair_rows(NeighborList& list, const Eigen::Matrix3Xd& x, const Box& box,
                         const Eigen::Matrix3Xd& f_before, int parts, PairScratch& scratch) {
  TypePairMatrix<LennardJonesParams> params(1);
  params.set(0, 0, LennardJonesParams::make(1.0, 1.0, list.cutoff()));
  const std::vector<int> type(x.cols(), 0);
  const Eigen::Matrix3Xd& xl = list.wrapped_positions(x);
  PairRowsResult out{f_before, {}, {}};
  if (parts == 0)  // the serial loop
    out.sums = accumulate_pair_rows<LennardJones, true, true, true>(list, 0, list.num_particles(), params, type.data(),
                                                                    xl, NearestImage(box), out.f.data());
  else
    out.sums = accumulate_pair_rows_parallel<LennardJones, true, true, true>(list, parts, params, type.data(), xl,
                                                                             NearestImage(box), out.f.data(), scratch);
  out.first_row = scratch.first_row;
  return out;
}

void expect_pair_rows_match_serial(NeighborList& list, const Eigen::Matrix3Xd& x, const Box& box,
                                   std::initializer_list<int> part_counts, bool want_empty_part) {
  std::mt19937 rng(3);
  std::uniform_real_distribution<double> any(-1.0, 1.0);
  const Eigen::Matrix3Xd before = Eigen::Matrix3Xd::NullaryExpr(3, x.cols(), [&] { return any(rng); });
  PairScratch none;
  const PairRowsResult serial = pair_rows(list, x, box, before, 0, none);
  const Eigen::Matrix3Xd force = serial.f - before;
  const double scale = force.cwiseAbs().maxCoeff();
  ASSERT_GT(scale, 0.0);
  bool some_part_empty = false;
  for (int parts : part_counts) {
    SCOPED_TRACE(testing::Message() << parts << " parts");
    PairScratch scratch, fresh;
    const PairRowsResult a = pair_rows(list, x, box, before, parts, scratch);
    const PairRowsResult b = pair_rows(list, x, box, before, parts, scratch);  // cached touched runs
    const PairRowsResult c = pair_rows(list, x, box, before, parts, fresh);
    EXPECT_TRUE(a.f == b.f);
    EXPECT_TRUE(a.f == c.f);
    EXPECT_EQ(a.sums.energy, b.sums.energy);
    EXPECT_EQ(a.sums.virial, c.sums.virial);
    if (parts == 1) {
      EXPECT_TRUE(a.f == serial.f);
      EXPECT_EQ(a.sums.energy, serial.sums.energy);
      EXPECT_EQ(a.sums.virial, serial.sums.virial);
    }
    EXPECT_LE(((a.f - before) - force).cwiseAbs().maxCoeff(), 1e-12 * scale);
    EXPECT_NEAR(a.sums.energy, serial.sums.energy, 1e-12 * std::abs(serial.sums.energy));
    EXPECT_NEAR(a.sums.virial, serial.sums.virial, 1e-12 * std::abs(serial.sums.virial));
    for (int u = 0; u < parts; ++u) some_part_empty |= a.first_row[u] >= a.first_row[u + 1];
  }
  if (want_empty_part) {
    EXPECT_TRUE(some_part_empty) << "no part had an empty range of rows";
  }
}

TEST(Parallel, PairRowsOnPartsAreTheSerialLoopsSums) {
  for (bool shuffle : {false, true}) {
    SCOPED_TRACE(shuffle ? "shuffled indices" : "chains in index order");
    Melt m = melt(shuffle);
    m.x.array() -= 0.5;  // some particles below the origin: wrapped
    NeighborList list(2.5, 0.3);
    list.set_exclusions(m.x.cols(), special_pairs(m.x.cols(), m.bonds, SpecialWeights{}));
    list.build(m.x, m.box);
    expect_pair_rows_match_serial(list, m.x, m.box, {1, 2, 3, 7}, false);

    // The same scratch after a rebuild for moved particles: the touched runs must be found again.
    PairScratch scratch;
    const Eigen::Matrix3Xd zero = Eigen::Matrix3Xd::Zero(3, m.x.cols());
    pair_rows(list, m.x, m.box, zero, 7, scratch);
    std::mt19937 rng(8);
    std::uniform_real_distribution<double> move(-0.6, 0.6);
    Eigen::Matrix3Xd moved = m.x;
    for (Eigen::Index i = 0; i < moved.cols(); i += 3) moved(0, i) += move(rng);
    list.build(moved, m.box);
    PairScratch fresh;
    EXPECT_TRUE(pair_rows(list, moved, m.box, zero, 7, scratch).f == pair_rows(list, moved, m.box, zero, 7, fresh).f);
  }
}

// Parts with no rows: a row holding more than a part's share of the pairs takes the blocks that
// fall in it. A periodic box of scattered beads with one tight cluster at the lowest indices,
// whose first bead lists every other bead of it.
TEST(Parallel, PairRowsWithEmptyPartsAreTheSerialLoopsSums) {
  Box box;
  box.lengths = Eigen::Vector3d::Constant(12.0);
  box.periodic = Eigen::Vector3i::Ones();
  const int cluster = 6, n = 6 * 6 * 6;
  Eigen::Matrix3Xd x(3, n);
  std::mt19937 rng(4);
  std::uniform_real_distribution<double> jitter(-0.1, 0.1);
  for (int k = 0; k < n; ++k)  // a 6³ lattice of spacing 2 beyond the cutoff + skin of 1.5
    x.col(k) =
        Eigen::Vector3d(2.0 * (k % 6) + jitter(rng), 2.0 * (k / 6 % 6) + jitter(rng), 2.0 * (k / 36) + jitter(rng));
  for (int k = 1; k < cluster; ++k)  // beads 1 … 5 around bead 0 (at the box's corner: across its faces)
    x.col(k) = x.col(0) + Eigen::Vector3d(0.6 * std::cos(1.2 * k), 0.6 * std::sin(1.2 * k), 0.3 * (k - 3)) +
               Eigen::Vector3d::Constant(jitter(rng));
  NeighborList list(1.2, 0.3);
  list.build(x, box);
  ASSERT_GT(list.num_pairs(), 0u);
  expect_pair_rows_match_serial(list, x, box, {2, 3, 7}, true);
}

// The parallel pair loop against the sum it stands for, written out plainly: the rows whose pairs
// start in [u, u + 1)·pairs/parts are part u's; each part's rows summed by the serial loop into a
// whole buffer of zeros (part 0's into f itself), and the buffers added into f in part order. Bit
// for bit, for 1 … 5 parts (threads), on every one of repeated calls with one scratch: across list
// rebuilds that move which particles a part touches, changes of the part count, a pass without
// forces between them, and a list of fewer particles. A part's write to a neighbour in another
// part's rows (a far write) that the sum lost or added twice, or left in its buffer for the next
// call to add again, fails it; and the forces are the serial loop's to rounding.
Eigen::Matrix3Xd pair_rows_by_whole_buffers(const NeighborList& list, const Eigen::Matrix3Xd& xl, const Box& box,
                                            const Eigen::Matrix3Xd& f_before, int parts) {
  const int n = list.num_particles();
  TypePairMatrix<LennardJonesParams> params(1);
  params.set(0, 0, LennardJonesParams::make(1.0, 1.0, list.cutoff()));
  const std::vector<int> type(n, 0);
  const std::int64_t pairs = list.offsets()[n];
  std::vector<int> first(parts + 1, n);
  for (int u = 1; u < parts; ++u)
    first[u] =
        static_cast<int>(std::lower_bound(list.offsets().begin(), list.offsets().end(), block_begin(pairs, parts, u)) -
                         list.offsets().begin());
  first[0] = 0;
  Eigen::Matrix3Xd f = f_before;
  std::vector<Eigen::Matrix3Xd> buffer(parts, Eigen::Matrix3Xd::Zero(3, n));
  for (int u = 0; u < parts; ++u)
    accumulate_pair_rows<LennardJones, true, true, true>(list, first[u], std::max(first[u], first[u + 1]), params,
                                                         type.data(), xl, NearestImage(box),
                                                         u == 0 ? f.data() : buffer[u].data());
  for (int u = 1; u < parts; ++u) f += buffer[u];
  return f;
}

TEST(Parallel, PairRowsOnPartsAddEveryFarWriteOnceInPartOrder) {
  for (bool shuffle : {false, true}) {
    SCOPED_TRACE(shuffle ? "shuffled indices" : "chains in index order");
    const Melt m = melt(shuffle);
    std::mt19937 rng(5);
    std::uniform_real_distribution<double> any(-1.0, 1.0), move(-0.5, 0.5);
    PairScratch scratch;          // one scratch for every call below
    for (int n : {8000, 6100}) {  // then a list of fewer particles (the first 6 100)
      Eigen::Matrix3Xd x = m.x.leftCols(n);
      const Eigen::Matrix3Xd before = Eigen::Matrix3Xd::NullaryExpr(3, n, [&] { return any(rng); });
      NeighborList list(1.12, 0.4);  // in.chain's reach: ≈ 8 neighbours a row
      for (int build = 0; build < 3; ++build) {
        SCOPED_TRACE(testing::Message() << n << " particles, build " << build);
        if (build > 0)  // every third particle moved: other neighbours, other touched particles
          for (int k = 0; k < n; k += 3) x.col(k) += Eigen::Vector3d(move(rng), move(rng), move(rng));
        list.build(x, m.box);
        const Eigen::Matrix3Xd& xl = list.wrapped_positions(x);
        TypePairMatrix<LennardJonesParams> params(1);
        params.set(0, 0, LennardJonesParams::make(1.0, 1.0, list.cutoff()));
        const std::vector<int> type(n, 0);
        const Eigen::Matrix3Xd serial = pair_rows_by_whole_buffers(list, xl, m.box, before, 1);
        const double scale = (serial - before).cwiseAbs().maxCoeff();
        ASSERT_GT(scale, 0.0);
        for (int parts : {1, 2, 3, 4, 5, 3}) {
          SCOPED_TRACE(testing::Message() << parts << " parts");
          const Eigen::Matrix3Xd expected = pair_rows_by_whole_buffers(list, xl, m.box, before, parts);
          for (int call = 0; call < 3; ++call) {
            Eigen::Matrix3Xd f = before;
            accumulate_pair_rows_parallel<LennardJones, true, true, true>(list, parts, params, type.data(), xl,
                                                                          NearestImage(m.box), f.data(), scratch);
            EXPECT_TRUE(f == expected) << "call " << call;
            EXPECT_LE(((f - before) - (serial - before)).cwiseAbs().maxCoeff(), 1e-12 * scale);
            // A pass without forces (the energy alone) between two with: it writes no buffer.
            accumulate_pair_rows_parallel<LennardJones, true, false, false>(list, parts, params, type.data(), xl,
                                                                            NearestImage(m.box), nullptr, scratch);
          }
        }
      }
    }
  }
}

// The list's rows and the order within each row (which fixes the order of the force sums) must
// be the same for any thread count: the threads search runs of cell columns, and their buffers taken in
// order are the pairs in the order one thread finds them. Also across the periodic faces
// (the jitter puts particles on both sides) and with exclusions.
TEST(Parallel, NeighborListDoesNotDependOnTheThreadCount) {
  for (bool shuffle : {false, true}) {
    SCOPED_TRACE(shuffle ? "shuffled indices" : "chains in index order");
    Melt m = melt(shuffle);
    m.x.array() -= 0.5;  // some particles below the origin: binned through their periodic image
    const std::vector<SpecialPair> excluded = special_pairs(m.x.cols(), m.bonds, SpecialWeights{});
    auto build = [&](int threads) {
      set_max_threads(threads);
      NeighborList list(1.12, 0.3);
      list.set_exclusions(m.x.cols(), excluded);
      list.build(m.x, m.box);
      return std::make_pair(std::vector<std::int64_t>(list.offsets().begin(), list.offsets().end()),
                            std::vector<int>(list.neighbors().begin(), list.neighbors().end()));
    };
    const int restore = max_threads();
    const auto serial = build(1);
    ASSERT_GE(static_cast<std::int64_t>(serial.second.size()), kParallelMin);
    for (int threads : {2, 3, 4}) {
      SCOPED_TRACE(testing::Message() << threads << " threads");
      const auto parallel = build(threads);
      EXPECT_EQ(parallel.first, serial.first);
      EXPECT_EQ(parallel.second, serial.second);
    }
    set_max_threads(restore);
  }
}

// The list's keep-or-rebuild decision past skin/2 (the fast particles' check, run in particle
// blocks) is the same sequence with 1, 2 and 3 threads: 8 000 beads, each update every bead creeps
// and a few jump, and the lists built match the serial ones.
TEST(Parallel, NeighborListRebuildDecisionsDoNotDependOnTheThreadCount) {
  Melt m = melt(true);
  const std::vector<SpecialPair> excluded = special_pairs(m.x.cols(), m.bonds, SpecialWeights{});
  auto decisions = [&](int threads) {
    set_max_threads(threads);
    NeighborList list(1.12, 0.3);
    list.set_exclusions(m.x.cols(), excluded);
    Eigen::Matrix3Xd x = m.x;
    std::mt19937 rng(5);
    std::uniform_real_distribution<double> creep(-0.012, 0.012);
    std::uniform_int_distribution<int> pick(0, static_cast<int>(x.cols()) - 1);
    std::normal_distribution<double> jump(0.0, 0.09);
    std::vector<int> rebuilt;
    std::vector<std::int64_t> last_offsets;
    for (int s = 0; s < 60; ++s) {
      for (Eigen::Index i = 0; i < x.cols(); ++i)
        for (int a = 0; a < 3; ++a) x(a, i) += creep(rng);
      for (int k = 0; k < 10; ++k) {
        const int i = pick(rng);
        for (int a = 0; a < 3; ++a) x(a, i) += jump(rng);
      }
      if (list.update(x, m.box)) rebuilt.push_back(s);
    }
    last_offsets.assign(list.offsets().begin(), list.offsets().end());
    return std::make_pair(rebuilt, last_offsets);
  };
  const int restore = max_threads();
  const auto serial = decisions(1);
  RecordProperty("rebuilds", static_cast<int>(serial.first.size()));
  ASSERT_GE(serial.first.size(), 3u);
  ASSERT_LT(serial.first.size(), 40u) << "the fast particles' check should keep the list between some updates";
  for (int threads : {2, 3}) {
    SCOPED_TRACE(testing::Message() << threads << " threads");
    const auto parallel = decisions(threads);
    EXPECT_EQ(parallel.first, serial.first);
    EXPECT_EQ(parallel.second, serial.second);
  }
  set_max_threads(restore);
}

TEST(Parallel, FeneForcesDoNotDependOnTheThreadCountAndOverstretchStillThrows) {
  Melt m = melt(true);
  const FeneBond fene("fene", Level::slow, m.bonds, {{30.0, 1.5, 1.0, 1.0}});
  expect_thread_independent(fene, m);
  m.x.col(m.bonds.back().j) += Eigen::Vector3d(0.0, 0.0, 3.0);  // r ≥ R0: FENE is undefined
  const int restore = max_threads();
  set_max_threads(2);
  Eigen::Matrix3Xd f = Eigen::Matrix3Xd::Zero(3, m.x.cols());
  EXPECT_THROW(fene.add_forces(m.x, m.box, f), NumericalError);
  set_max_threads(restore);
}

TEST(Parallel, KickDriftIsTheSerialUpdate) {
  const Melt m = melt(false);
  const Eigen::Index n = m.x.cols();
  const Eigen::Matrix3Xd f = Eigen::Matrix3Xd::Random(3, n), v0 = Eigen::Matrix3Xd::Random(3, n);
  const Eigen::VectorXd inv_mass = Eigen::VectorXd::Random(n).cwiseAbs();
  Eigen::Matrix3Xd x = m.x, v = v0;
  const int restore = max_threads();
  set_max_threads(2);
  kick_drift(x, v, inv_mass, f, 0.25, 0.5);
  set_max_threads(restore);
  const Eigen::Matrix3Xd v_expected = v0 + 0.25 * f * inv_mass.asDiagonal();
  EXPECT_EQ(v, v_expected);
  EXPECT_LE((x - (m.x + 0.5 * v_expected)).cwiseAbs().maxCoeff(), 1e-15 * m.x.cwiseAbs().maxCoeff());
}

// The run loop's check that x and v are finite after a step runs in the threads' particle blocks
// (engine/run/run.cpp, check_finite): a NaN or an infinity in any block, in x or in v, with 1 to 3
// threads, stops the run naming the first bad particle, its step and its time.
TEST(Parallel, FiniteCheckFindsABadValueInEveryBlock) {
  const Melt m = melt(false);
  State s;
  s.x = m.x;
  s.v = Eigen::Matrix3Xd::Zero(3, m.x.cols());
  s.inv_mass = Eigen::VectorXd::Ones(m.x.cols());
  s.step = 12;
  s.t = 0.06;
  const int restore = max_threads();
  for (int threads : {1, 2, 3}) {
    set_max_threads(threads);
    EXPECT_NO_THROW(check_finite(s));
    for (const int bad : {0, 2999, 4000, 7999}) {
      for (const bool in_v : {false, true}) {
        SCOPED_TRACE(testing::Message() << threads << " threads, particle " << bad << (in_v ? " v" : " x"));
        State t = s;
        (in_v ? t.v : t.x)(1, bad) = in_v ? std::numeric_limits<double>::infinity() : std::nan("");
        if (bad != 0) t.x(2, bad + (bad < 7999 ? 1 : -1)) = std::nan("");  // a later (or earlier) one too
        try {
          check_finite(t);
          ADD_FAILURE() << "no NumericalError";
        } catch (const NumericalError& e) {
          const int first = bad == 7999 ? 7998 : bad;
          EXPECT_NE(std::string(e.what()).find("particle " + std::to_string(first) + " at step 12"), std::string::npos)
              << e.what();
        }
      }
    }
  }
  set_max_threads(restore);
}

// Clusters are solved independently, so any thread count gives the serial bits.
TEST(Parallel, ConstraintSolvesAreTheSerialOnes) {
  const Melt m = melt(true);
  StiffBonds sb = stiff(m.bonds);
  std::mt19937 rng(5);  // off the manifold by ±1 % per bond (a uniform shrink of these straight chains
  std::uniform_real_distribution<double> off(-0.01, 0.01);  // would need a large tension: SHAKE diverges)
  for (StiffBond& b : sb.bonds) b.length = (m.x.col(b.i) - m.x.col(b.j)).norm() * (1.0 + off(rng));
  ConstraintToolbox toolbox(sb.bonds, Eigen::VectorXd::Ones(m.x.cols()));
  ASSERT_GT(toolbox.clusters().size(), 100u);
  const Eigen::Matrix3Xd f0 = Eigen::Matrix3Xd::Random(3, m.x.cols());
  auto slow = [&](const Eigen::Matrix3Xd& X, Eigen::Matrix3Xd& out) { out = f0 + 0.1 * X; };
  struct Result {
    Eigen::Matrix3Xd projected, shaken, mollified, alpha, velocity, constraint_force;
  };
  auto run = [&](int threads) {
    set_max_threads(threads);
    Result r{f0, m.x, Eigen::Matrix3Xd(), Eigen::Matrix3Xd(), f0, Eigen::Matrix3Xd::Zero(3, m.x.cols())};
    toolbox.project_force(m.x, r.projected);
    toolbox.project_velocity(m.x, r.velocity, &r.constraint_force, 4.0);  // and the constraint force it adds
    toolbox.shake(m.x, r.shaken);
    toolbox.mollified_force(m.x, slow, r.alpha, r.mollified);
    return r;
  };
  const int restore = max_threads();
  const Result serial = run(1);
  for (int threads : {2, 3}) {
    const Result r = run(threads);
    EXPECT_EQ(r.projected, serial.projected);
    EXPECT_EQ(r.shaken, serial.shaken);
    EXPECT_EQ(r.alpha, serial.alpha);
    EXPECT_EQ(r.mollified, serial.mollified);
    EXPECT_EQ(r.velocity, serial.velocity);
    EXPECT_EQ(r.constraint_force, serial.constraint_force);
  }
  set_max_threads(restore);
  Eigen::Matrix3Xd twice = serial.projected;  // and it is a projection: P² = P
  toolbox.project_force(m.x, twice);
  EXPECT_LE((twice - serial.projected).cwiseAbs().maxCoeff(), 1e-12);
  EXPECT_LE(toolbox.max_violation(serial.shaken), 1e-12);
}

// Angles and dihedrals by owner computes (tuple_partition.hpp): with 2 to 4 threads each particle
// gets its forces from the tuples in list order, so the forces are the one-thread bits (tuples
// across owners are evaluated twice, each owner adding to its own particles); the energy and the
// virial are summed per owner (to rounding). The melt's chains, indices shuffled: most tuples span
// owners.
TEST(Parallel, AngleAndDihedralForcesAreTheSerialBits) {
  const Melt m = melt(true);
  std::vector<Angle> angles;
  std::vector<Dihedral> dihedrals;
  for (std::size_t b = 0; b + 1 < m.bonds.size(); ++b) {  // a row's bonds are consecutive, joined end to start
    if (m.bonds[b].j != m.bonds[b + 1].i) continue;
    angles.push_back({m.bonds[b].i, m.bonds[b].j, m.bonds[b + 1].j, 0});
    if (b + 2 < m.bonds.size() && m.bonds[b + 1].j == m.bonds[b + 2].i)
      dihedrals.push_back({m.bonds[b].i, m.bonds[b].j, m.bonds[b + 1].j, m.bonds[b + 2].j, 0});
  }
  ASSERT_GE(static_cast<std::int64_t>(dihedrals.size()), kParallelMin);
  const HarmonicAngle bend("bend", Level::slow, angles, {{3.0, 2.0}});
  const OplsDihedral torsion("torsion", Level::slow, dihedrals, {{{1.0, -0.5, 0.3, 0.1}}});
  const int restore = max_threads();
  for (const ForceTerm* term : std::initializer_list<const ForceTerm*>{&bend, &torsion}) {
    SCOPED_TRACE(term->name());
    const Forces serial = evaluate(*term, m, 1);
    const double virial = term->virial(m.x, m.box);
    ASSERT_GT(serial.f.cwiseAbs().maxCoeff(), 0.0);
    for (int threads : {2, 3, 4}) {
      SCOPED_TRACE(testing::Message() << threads << " threads");
      const Forces a = evaluate(*term, m, threads), b = evaluate(*term, m, threads);
      EXPECT_EQ(a.f, serial.f);
      EXPECT_EQ(a.energy, b.energy);
      EXPECT_NEAR(a.energy, serial.energy, 1e-12 * std::abs(serial.energy));
      EXPECT_NEAR(term->virial(m.x, m.box), virial, 1e-9 * serial.f.cwiseAbs().maxCoeff());
    }
  }
  set_max_threads(restore);
}

// The pressure's and the thermo's sums over bonds on the threads: the bond virial summed per block
// (to rounding, the same bits call to call) and the largest constraint violation (a maximum: the
// serial value exactly, for any thread count).
TEST(Parallel, BondVirialAndMaxViolationOnTheThreads) {
  const Melt m = melt(true);
  const FeneBond fene("fene", Level::slow, m.bonds, {{30.0, 1.5, 1.0, 1.0}});
  StiffBonds sb = stiff(m.bonds);
  const int restore = max_threads();
  set_max_threads(1);
  const double virial = fene.virial(m.x, m.box), worst = max_violation(sb.bonds, m.x);
  ASSERT_GT(worst, 0.0);
  for (int threads : {2, 3, 4}) {
    SCOPED_TRACE(testing::Message() << threads << " threads");
    set_max_threads(threads);
    EXPECT_NEAR(fene.virial(m.x, m.box), virial, 1e-12 * std::abs(virial));
    EXPECT_EQ(fene.virial(m.x, m.box), fene.virial(m.x, m.box));
    EXPECT_EQ(max_violation(sb.bonds, m.x), worst);
  }
  set_max_threads(restore);
}

// The neighbour list's sorts (counting_sort.hpp): items in parts, sorted by key then part then
// place, for 1 to 5 parts, are the stable sort of the concatenated items (keys with no item, keys
// with many, a part with none included), and the starts are the keys' first slots.
TEST(Parallel, CountingSortIsTheStableSortForAnyNumberOfParts) {
  std::mt19937 rng(3);
  const int keys = 9000, items = 60000;
  std::vector<int> key(items);
  std::uniform_int_distribution<int> any_key(0, keys - 1);
  for (int& k : key) k = any_key(rng) % 3 == 0 ? 17 : any_key(rng);  // key 17 crowded, some keys empty
  std::vector<int> expected(items);
  std::iota(expected.begin(), expected.end(), 0);
  std::stable_sort(expected.begin(), expected.end(), [&](int a, int b) { return key[a] < key[b]; });
  const int restore = max_threads();
  for (int parts : {1, 2, 3, 5}) {
    SCOPED_TRACE(testing::Message() << parts << " parts");
    set_max_threads(parts);
    std::vector<std::int64_t> bound(parts + 1);  // part u: items bound[u] … bound[u+1] − 1
    for (int u = 0; u <= parts; ++u) bound[u] = u == parts ? items : u == 1 ? 0 : block_begin(items, parts, u);
    CountingSort<std::int64_t> sort;
    sort.begin(parts, keys);
    run_parts(parts, [&](int u) {
      int* count = sort.clear(u);
      for (std::int64_t i = bound[u]; i < std::max(bound[u], bound[u + 1]); ++i) ++count[key[i]];
    });
    std::vector<std::int64_t> start(keys + 1);
    sort.starts(start.data());
    std::vector<int> sorted(items, -1);
    run_parts(parts, [&](int u) {
      auto cursor = sort.cursor(u);
      for (std::int64_t i = bound[u]; i < std::max(bound[u], bound[u + 1]); ++i) sorted[cursor.slot(key[i])] = i;
    });
    EXPECT_EQ(sorted, expected);
    for (int k = 0; k < keys; ++k)
      ASSERT_EQ(start[k], std::lower_bound(expected.begin(), expected.end(), k, [&](int a, int kk) {
                            return key[a] < kk;
                          }) - expected.begin());
    EXPECT_EQ(start[keys], items);
  }
  set_max_threads(restore);
}

// The kinetic energies the integrators keep (primitives.hpp kinetic_energy, the O step's
// LangevinNoise::apply_and_measure, before and after): with one thread the bits of
// State::kinetic_energy, with more its value to rounding and the same bits call to call; the O
// step's the same as kinetic_energy before and after its plain step. Fixed particles count nothing.
TEST(Parallel, KineticEnergiesAreTheStatesSummedInBlocks) {
  const Melt m = melt(true);
  const Eigen::Index n = m.x.cols();
  State s;
  s.x = m.x;
  s.v = Eigen::Matrix3Xd::Random(3, n);
  s.inv_mass = Eigen::VectorXd::Random(n).cwiseAbs() + Eigen::VectorXd::Constant(n, 0.5);
  s.inv_mass[7] = s.inv_mass[5000] = 0.0;
  s.v.col(7).setZero();
  s.v.col(5000).setZero();
  ThermostatSettings t;
  t.style = ThermostatSettings::Style::langevin;
  t.temperature = 1.5;
  t.friction = Eigen::VectorXd::Constant(n, 2.0);
  t.seed = 9;
  const int restore = max_threads();
  for (int threads : {1, 2, 3}) {
    SCOPED_TRACE(testing::Message() << threads << " threads");
    set_max_threads(threads);
    const double k = kinetic_energy(s.v, s.inv_mass);
    if (threads == 1)
      EXPECT_EQ(k, s.kinetic_energy());
    else
      EXPECT_NEAR(k, s.kinetic_energy(), 1e-13 * k);
    EXPECT_EQ(kinetic_energy(s.v, s.inv_mass), k);
    LangevinNoise plain(t, s.inv_mass), measured(t, s.inv_mass);
    Eigen::Matrix3Xd v_plain = s.v, v_measured = s.v;
    plain.apply(v_plain, 0.01, 4, 1);
    const KineticChange change = measured.apply_and_measure(v_measured, 0.01, 4, 1);
    EXPECT_EQ(v_measured, v_plain);
    EXPECT_EQ(change.before, k);
    EXPECT_EQ(change.after, kinetic_energy(v_plain, s.inv_mass));
    EXPECT_NE(change.after, k);
  }
  set_max_threads(restore);
}

// parallel_seconds: the wall time inside the outermost parallel loops since the last reset, one
// thread or several. Bounds from the test's own clock (no timing thresholds): work of a known least
// duration inside a loop is counted, work outside is not, and a loop nested in another is counted
// once — the count never exceeds the wall time around the outer call.
void busy_for(std::chrono::steady_clock::duration d) {
  const auto until = std::chrono::steady_clock::now() + d;
  while (std::chrono::steady_clock::now() < until) {
  }
}

double seconds_of(std::chrono::steady_clock::duration d) {
  return std::chrono::duration<double>(d).count();
}

TEST(ParallelSeconds, CountsTheOutermostParallelLoopsOnly) {
  using std::chrono::milliseconds;
  const int restore = max_threads();
  for (int threads : {1, 2}) {
    SCOPED_TRACE(testing::Message() << threads << " threads");
    set_max_threads(threads);
    reset_parallel_seconds();
    EXPECT_EQ(parallel_seconds(), 0.0);
    busy_for(milliseconds(30));  // serial: not counted
    EXPECT_EQ(parallel_seconds(), 0.0);

    // One part and several: each part's work is inside.
    for (int parts : {1, threads}) {
      reset_parallel_seconds();
      const auto start = std::chrono::steady_clock::now();
      run_parts(parts, [](int) { busy_for(milliseconds(20)); });
      const double wall = seconds_of(std::chrono::steady_clock::now() - start);
      EXPECT_GE(parallel_seconds(), 0.020);
      EXPECT_LE(parallel_seconds(), wall);
    }

    // Nested: the inner loop's time is already inside the outer one.
    reset_parallel_seconds();
    const auto start = std::chrono::steady_clock::now();
    run_parts(1, [](int) {
      busy_for(milliseconds(10));
      run_parts(1, [](int) { busy_for(milliseconds(10)); });
      parallel_blocks(kParallelMin, 1, [](std::int64_t, std::int64_t) { busy_for(milliseconds(10)); });
    });
    const double wall = seconds_of(std::chrono::steady_clock::now() - start);
    EXPECT_GE(parallel_seconds(), 0.030);
    EXPECT_LE(parallel_seconds(), wall);

    // Blocks: a loop of kParallelMin items is parallel work even when one thread runs it; a
    // shorter one is serial at every thread count.
    reset_parallel_seconds();
    parallel_blocks(kParallelMin - 1, threads_for(kParallelMin - 1),
                    [](std::int64_t, std::int64_t) { busy_for(milliseconds(10)); });
    EXPECT_EQ(parallel_seconds(), 0.0);
    parallel_blocks(kParallelMin, threads_for(kParallelMin),
                    [](std::int64_t, std::int64_t) { busy_for(milliseconds(10)); });
    EXPECT_GE(parallel_seconds(), 0.010);

    // A part that throws still closes its interval: the next loop is counted as outermost.
    reset_parallel_seconds();
    EXPECT_THROW(run_parts(threads,
                           [](int) {
                             busy_for(milliseconds(5));
                             throw std::runtime_error("part");
                           }),
                 std::runtime_error);
    const double after_throw = parallel_seconds();
    EXPECT_GE(after_throw, 0.005);
    run_parts(1, [](int) { busy_for(milliseconds(10)); });
    EXPECT_GE(parallel_seconds(), after_throw + 0.010);
  }
  set_max_threads(restore);
}

// Opt-in: a thread that never reset its count counts nothing (the loops of a test binary or of
// the Python module pay one branch, not two clock reads).
TEST(ParallelSeconds, CountsNothingBeforeAReset) {
  double counted = -1.0;
  std::thread other([&] {
    run_parts(1, [](int) { busy_for(std::chrono::milliseconds(5)); });
    counted = parallel_seconds();
  });
  other.join();
  EXPECT_EQ(counted, 0.0);
}

}  // namespace
}  // namespace stiffmd
