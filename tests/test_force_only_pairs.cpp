// The force-only pair pass (ForceTerm::add_forces_only, pair_loop.hpp's accumulate_pair_forces_rows)
// against the full one (add_forces, every listed pair evaluated and masked, with the energy): the
// same forces bit for bit, for every pair style, on one and on several threads, with one particle
// type (the coefficients held in registers) and with two, with special pairs scaled and excluded,
// and with rows longer than the loop's chunk (a row split across chunks keeps its f_i sum whole).
// The full pass is the one checked against finite differences (test_pairs.cpp, test_coulomb.cpp);
// equal bits carry that over. ForceField::compute_forces against compute, likewise.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstring>
#include <memory>
#include <random>
#include <string>
#include <vector>

#include "core/parallel.hpp"
#include "force_term_checks.hpp"
#include "forcefields/force_field.hpp"
#include "forcefields/pair_term.hpp"

namespace stiffmd {
namespace {

// A jittered simple-cubic melt of side 12 (1 728 particles, density 1, nearest distance ≥ 0.7),
// chains of 12 along x (bonds between lattice neighbours), charges ±0.5 … ±1, in a periodic box
// with its origin off zero. Positions are unwrapped by whole boxes for every seventh particle.
struct Melt {
  static constexpr int kSide = 12;
  Eigen::Matrix3Xd x;
  Box box;
  std::vector<int> alternating, uniform;
  std::vector<double> charges;
  std::vector<Bond> bonds;
  Melt() {
    const int n = kSide * kSide * kSide;
    box = test::periodic_box(Eigen::Vector3d::Constant(kSide), Eigen::Vector3d(-3.0, 1.5, 0.25));
    x.resize(3, n);
    std::mt19937_64 rng(2024);
    std::uniform_real_distribution<double> jitter(-0.15, 0.15), q(0.5, 1.0);
    for (int i = 0; i < n; ++i) {
      const int a = i % kSide, b = (i / kSide) % kSide, c = i / (kSide * kSide);
      x.col(i) = box.origin + Eigen::Vector3d(a + 0.5 + jitter(rng), b + 0.5 + jitter(rng), c + 0.5 + jitter(rng));
      if (i % 7 == 3) x.col(i) += Eigen::Vector3d(2 * kSide, -kSide, 3 * kSide);
      alternating.push_back(i % 3 == 0 ? 1 : 0);
      uniform.push_back(0);
      charges.push_back((i % 2 == 0 ? 1.0 : -1.0) * q(rng));
      if (a + 1 < kSide) bonds.push_back({i, i + 1, 0});
    }
  }
};

const Melt& melt() {
  static const Melt m;
  return m;
}

// Each style's coefficients for two types in reduced units (σ ≈ 1); the Coulomb cutoffs (5.5, list
// radius 5.8) give rows of ~400 listed pairs, longer than kPairChunk.
template <class K>
typename K::Coeffs coeffs_of(int a, int b);

template <>
LennardJones::Coeffs coeffs_of<LennardJones>(int a, int b) {
  return {1.0 + 0.2 * (a + b), 1.0 - 0.05 * (a + b), 2.5 - 0.2 * (a + b)};
}
template <>
WeeksChandlerAndersen::Coeffs coeffs_of<WeeksChandlerAndersen>(int a, int b) {
  return {1.0 + 0.3 * (a + b), 1.0 + 0.05 * (a + b)};
}
template <>
SoftCosine::Coeffs coeffs_of<SoftCosine>(int a, int b) {
  return {3.0 + a + b, 1.0 + 0.1 * (a + b)};
}
template <>
Yukawa::Coeffs coeffs_of<Yukawa>(int a, int b) {
  return {a == b ? 2.0 : -1.0, 1.0 + 0.25 * (a + b), 2.5 - 0.1 * (a + b)};
}
template <>
CoulombCut::Coeffs coeffs_of<CoulombCut>(int, int) {
  return {5.5};
}
template <>
CoulombDebye::Coeffs coeffs_of<CoulombDebye>(int, int) {
  return {0.4, 5.5};
}
template <>
CoulombLong::Coeffs coeffs_of<CoulombLong>(int, int) {
  return {5.5};
}
LjCoulCoeffs lj_coul(int a, int b, double kappa) {
  LjCoulCoeffs c;
  c.epsilon = 0.5 + 0.25 * (a + b), c.sigma = 1.0 - 0.05 * (a + b), c.rc = 2.5, c.coulomb_cutoff = 5.5;
  c.kappa = kappa;
  return c;
}
template <>
LjCutCoulCut::Coeffs coeffs_of<LjCutCoulCut>(int a, int b) {
  return lj_coul(a, b, 0.0);
}
template <>
LjCutCoulDebye::Coeffs coeffs_of<LjCutCoulDebye>(int a, int b) {
  return lj_coul(a, b, 0.4);
}
template <>
LjCutCoulLong::Coeffs coeffs_of<LjCutCoulLong>(int a, int b) {
  return lj_coul(a, b, 0.0);
}
template <>
LjCharmmCoulLong::Coeffs coeffs_of<LjCharmmCoulLong>(int a, int b) {
  return {0.5 + 0.25 * (a + b), 1.0 - 0.05 * (a + b), 0.3, 0.9, 2.0, 2.5, 5.5};
}

template <class K>
std::unique_ptr<PairTerm<K>> make_term(const std::vector<int>& types) {
  const Melt& m = melt();
  TypePairMatrix<typename K::Coeffs> c(2);
  for (int a = 0; a < 2; ++a)
    for (int b = a; b < 2; ++b) c.set(a, b, coeffs_of<K>(a, b));
  const SpecialWeights lj{0.0, 0.5, 0.8};
  auto term = std::make_unique<PairTerm<K>>(
      "pairs", Level::slow, types, c, m.bonds, lj, m.box, 0.3,
      Electrostatics{ChargedKernel<K> ? m.charges : std::vector<double>{}, 1.0, SpecialWeights{0.0, 0.3, 0.6}});
  if constexpr (EwaldKernel<K>) term->set_ewald_splitting(0.6);
  return term;
}

// f0 + the term's forces, by add_forces and by add_forces_only, from the same non-zero f0 (both add).
template <class K>
void expect_same_bits(const PairTerm<K>& term, const std::string& what) {
  const Melt& m = melt();
  Eigen::Matrix3Xd f0(3, m.x.cols());
  std::mt19937_64 rng(7);
  std::normal_distribution<double> g;
  for (Eigen::Index k = 0; k < f0.size(); ++k) f0.data()[k] = g(rng);
  Eigen::Matrix3Xd full = f0, only = f0;
  term.add_forces(m.x, m.box, full);
  term.add_forces_only(m.x, m.box, only);
  ASSERT_GT((full - f0).cwiseAbs().maxCoeff(), 1e-3) << what << ": the melt must interact";
  EXPECT_EQ(std::memcmp(full.data(), only.data(), sizeof(double) * full.size()), 0)
      << what << ": max |difference| " << (full - only).cwiseAbs().maxCoeff();
}

template <class K>
class ForceOnlyPairs : public ::testing::Test {};
using AllStyles = ::testing::Types<LennardJones, WeeksChandlerAndersen, SoftCosine, Yukawa, CoulombCut, CoulombDebye,
                                   CoulombLong, LjCutCoulCut, LjCutCoulDebye, LjCutCoulLong, LjCharmmCoulLong>;
TYPED_TEST_SUITE(ForceOnlyPairs, AllStyles);

TYPED_TEST(ForceOnlyPairs, SameForcesBitForBitAsTheFullPass) {
  const int threads = max_threads();
  for (const bool one_type : {false, true})
    for (const int t : {1, 2, 3}) {
      set_max_threads(t);
      const auto term = make_term<TypeParam>(one_type ? melt().uniform : melt().alternating);
      expect_same_bits(*term, std::string(TypeParam::kStyle) + (one_type ? ", one type" : ", two types") + ", " +
                                  std::to_string(t) + " thread(s)");
    }
  set_max_threads(threads);
}

// The force-only pass's AVX2 separations (pair_chunk_separations_avx2) against
// its scalar pass and both against the full pass (accumulate_pair_rows, forces alone): the same
// forces bit for bit, in the melt's periodic box (the fold, pairs across every face), in a
// periodic box a few list radii wide (NearestImage's rounding), in open space, and with rows
// longer than the chunk. Where the CPU has no AVX2 both calls take the scalar pass.
template <class K>
void expect_vector_pass_is_scalar_pass(const Eigen::Matrix3Xd& x, const Box& box, const typename K::Coeffs& c,
                                       const std::string& what, double skin = 0.3, bool signed_zeros = false) {
  const int n = static_cast<int>(x.cols());
  NeighborList list(K::cutoff(c), skin);
  list.update(x, box);
  TypePairMatrix<typename K::Params> params(1);
  params.set(0, 0, K::params(c));
  const std::vector<int> type(n, 0);
  const Eigen::Matrix3Xd& xw = box.any_periodic() ? list.wrapped_positions(x) : x;
  const NearestImage near(box, list.cutoff() + list.skin());
  Eigen::Matrix3Xd f0(3, n);
  std::mt19937_64 rng(11);
  std::normal_distribution<double> g;
  for (Eigen::Index k = 0; k < f0.size(); ++k) f0.data()[k] = g(rng);
  // f_k + 0 is f_k but for −0: each f_i += (its row's sum, 0 for no kept pair) as every pass adds
  // it, and a row with no listed pair passed over by every pass (a −0 stays −0).
  if (signed_zeros)
    for (Eigen::Index k = 0; k < f0.size(); k += 3) f0.data()[k] = k % 2 == 0 ? -0.0 : 0.0;
  Eigen::Matrix3Xd scalar = f0, vector = f0, full = f0;
  for (const bool v : {false, true}) {
    double* f = (v ? vector : scalar).data();
    if (box.any_periodic())
      accumulate_pair_forces_rows<K, true, true>(list, 0, n, params, type.data(), 0, xw, near, f, {}, v);
    else
      accumulate_pair_forces_rows<K, false, true>(list, 0, n, params, type.data(), 0, xw, near, f, {}, v);
  }
  if (box.any_periodic())
    accumulate_pair_rows<K, true, true, false>(list, 0, n, params, type.data(), xw, near, full.data());
  else
    accumulate_pair_rows<K, false, true, false>(list, 0, n, params, type.data(), xw, near, full.data());
  ASSERT_GT((scalar - f0).cwiseAbs().maxCoeff(), 1e-3) << what << ": the particles must interact";
  EXPECT_EQ(std::memcmp(scalar.data(), vector.data(), sizeof(double) * scalar.size()), 0)
      << what << ": max |difference| " << (scalar - vector).cwiseAbs().maxCoeff();
  EXPECT_EQ(std::memcmp(scalar.data(), full.data(), sizeof(double) * scalar.size()), 0)
      << what << ": against the full pass, max |difference| " << (scalar - full).cwiseAbs().maxCoeff();
}

TEST(ForceOnlyPairs, VectorSeparationsGiveTheScalarPassBits) {
  const Melt& m = melt();
  // The melt's box: 12 wide, list radius 1.42 (WCA) or 2.8 (LJ) — the fold.
  expect_vector_pass_is_scalar_pass<WeeksChandlerAndersen>(m.x, m.box, {1.0, 1.0}, "wca, periodic");
  expect_vector_pass_is_scalar_pass<LennardJones>(m.x, m.box, {1.0, 1.0, 2.5}, "lj, periodic");
  expect_vector_pass_is_scalar_pass<SoftCosine>(m.x, m.box, {3.0, 1.2}, "soft, periodic");
  expect_vector_pass_is_scalar_pass<Yukawa>(m.x, m.box, {2.0, 1.0, 2.5}, "yukawa, periodic");
  // Rows of ~400 listed pairs: longer than the chunk.
  expect_vector_pass_is_scalar_pass<LennardJones>(m.x, m.box, {1.0, 1.0, 5.5}, "lj 5.5, periodic");
  // Open space: the same particles without the box.
  expect_vector_pass_is_scalar_pass<LennardJones>(m.x, Box{}, {1.0, 1.0, 2.5}, "lj, open");
  // A box under 6 list radii wide: the rounded minimum image (NearestImage::rounded).
  const Box small = test::periodic_box(Eigen::Vector3d::Constant(6.0), Eigen::Vector3d(0.5, -1.0, 2.0));
  Eigen::Matrix3Xd xs(3, 216);
  std::mt19937_64 rng(5);
  std::uniform_real_distribution<double> jitter(-0.1, 0.1);
  for (int i = 0; i < 216; ++i)
    xs.col(i) = small.origin + Eigen::Vector3d(i % 6 + 0.5 + jitter(rng), (i / 6) % 6 + 0.5 + jitter(rng),
                                               i / 36 + 0.5 + jitter(rng) + (i % 5 == 0 ? 12.0 : 0.0));
  ASSERT_TRUE(NearestImage(small, 2.5 + 0.3).rounded);
  expect_vector_pass_is_scalar_pass<LennardJones>(xs, small, {1.0, 1.0, 2.5}, "lj, small periodic box");
}

// Lists shorter than a group of four and than the prefetch's reach (kPairPrefetch), and lists whose
// last group runs past their end (those lanes are given x_i = +∞): a few particles around a corner
// of the box, so that most pairs cross one to three faces, against the scalar pass — in a box wide
// enough for the fold (20 > 6 list radii), where a group with a lane across a face folds and the
// others skip it, and in one where the minimum image rounds (12).
TEST(ForceOnlyPairs, VectorPassOnShortListsAcrossTheFaces) {
  std::mt19937_64 rng(17);
  std::uniform_real_distribution<double> jitter(-0.7, 0.7);
  for (const double side : {20.0, 12.0}) {
    const Box box = test::periodic_box(Eigen::Vector3d::Constant(side), Eigen::Vector3d(-3.0, 1.5, 0.25));
    const Eigen::Vector3d corner = box.origin + box.lengths;
    ASSERT_EQ(NearestImage(box, 2.5 + 0.3).rounded, side < 16.8);
    for (const int n : {2, 3, 5, 9, 14, 40}) {  // 1 to 780 listed pairs
      Eigen::Matrix3Xd x(3, n);
      for (int i = 0; i < n; ++i) x.col(i) = corner + Eigen::Vector3d(jitter(rng), jitter(rng), jitter(rng));
      expect_vector_pass_is_scalar_pass<LennardJones>(
          x, box, {1.0, 1.0, 2.5},
          "lj, " + std::to_string(n) + " particles at a corner of a box " + std::to_string(side));
    }
  }
}

// The AVX2 scatter (pair_chunk_forces_avx2: the f_j in one loop over the kept pairs, the rows' sums
// as a scan, the f_i in a loop over the rows) against the scalar pass's loop per row: a list with a
// wide skin, so that most listed pairs are beyond the cutoff and many rows keep no pair at all —
// rows with none, rows longer than the chunk split where a chunk's part of them keeps none —
// in a cluster across a corner of the box (the fold) and in open space, with forces that start as
// ±0 on one axis in three.
TEST(ForceOnlyPairs, VectorScatterOnSparseRowsGivesTheScalarPassBits) {
  std::mt19937_64 rng(23);
  std::uniform_real_distribution<double> u(-1.0, 1.0);
  const Box box = test::periodic_box(Eigen::Vector3d::Constant(40.0), Eigen::Vector3d(-3.0, 1.5, 0.25));
  const Eigen::Vector3d corner = box.origin + box.lengths;
  for (const int n : {7, 60, 500}) {
    Eigen::Matrix3Xd x(3, n);
    for (int i = 0; i < n; ++i) {
      Eigen::Vector3d d;
      do d = Eigen::Vector3d(u(rng), u(rng), u(rng));
      while (d.squaredNorm() > 1.0);
      x.col(i) = corner + (n == 7 ? 0.8 : 3.0) * d;  // the seven close enough to interact
    }
    const LennardJones::Coeffs c{1.0, 0.9, 1.0};  // r_c = 1 with a skin of 2: a listed pair in 27 within r_c
    NeighborList list(LennardJones::cutoff(c), 2.0);
    list.update(x, box);
    std::int64_t longest = 0;
    for (int i = 0; i < n; ++i) longest = std::max(longest, list.offsets()[i + 1] - list.offsets()[i]);
    if (n == 500) ASSERT_GT(longest, kPairChunk);
    for (const bool zeros : {false, true}) {
      const std::string what = std::to_string(n) + " particles" + (zeros ? ", ±0 forces" : "");
      expect_vector_pass_is_scalar_pass<LennardJones>(x, box, c, what + ", periodic", 2.0, zeros);
      expect_vector_pass_is_scalar_pass<LennardJones>(x, Box{}, c, what + ", open", 2.0, zeros);
    }
  }
}

// The Coulomb styles' rows are longer than the force-only loop's chunk: some rows are split.
TEST(ForceOnlyPairs, CoulombRowsAreLongerThanTheChunk) {
  const auto term = make_term<CoulombCut>(melt().alternating);
  Eigen::Matrix3Xd f = Eigen::Matrix3Xd::Zero(3, melt().x.cols());
  term->add_forces(melt().x, melt().box, f);
  const auto offsets = term->neighbor_list().offsets();
  std::int64_t longest = 0;
  for (std::size_t i = 0; i + 1 < offsets.size(); ++i) longest = std::max(longest, offsets[i + 1] - offsets[i]);
  EXPECT_GT(longest, kPairChunk);
}

// A force field of two pair terms (WCA on one type, screened Coulomb on two): compute_forces gives
// compute's forces, bit for bit, and counts the evaluation the same.
TEST(ForceOnlyPairs, ForceFieldComputeForcesIsComputeWithoutTheEnergy) {
  const Melt& m = melt();
  ForceField a(m.box, static_cast<int>(m.x.cols())), b(m.box, static_cast<int>(m.x.cols()));
  for (ForceField* ff : {&a, &b}) {
    ff->add(make_term<WeeksChandlerAndersen>(m.uniform));
    ff->add(make_term<CoulombDebye>(m.alternating));
  }
  Eigen::Matrix3Xd fa, fb;
  a.compute(m.x, {Level::slow}, fa);
  b.compute_forces(m.x, {Level::slow}, fb);
  ASSERT_EQ(fa.cols(), m.x.cols());
  EXPECT_EQ(std::memcmp(fa.data(), fb.data(), sizeof(double) * fa.size()), 0);
  EXPECT_EQ(a.evaluations(Level::slow), b.evaluations(Level::slow));
  a.compute_unconstrained(m.x, fa);
  b.compute_forces_unconstrained(m.x, fb);
  EXPECT_EQ(std::memcmp(fa.data(), fb.data(), sizeof(double) * fa.size()), 0);
  EXPECT_EQ(a.evaluations(a.outermost()), b.evaluations(b.outermost()));
}

}  // namespace
}  // namespace stiffmd
