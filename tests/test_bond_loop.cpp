// The bond loop's paths (forcefields/bond_loop.hpp) against each other and against the bonds
// summed one by one: one thread (chain runs streamed, one set of coefficients read once, the
// FENE logarithms of a block added as the logarithm of their product) and several threads (owner
// computes over work items) give every particle the same force bits; the energies agree to
// round-off. And log_one_minus (core/log_one_minus.hpp), the branch-free ln(1 − s) of the FENE
// kernel, against the long-double log1p.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <numeric>
#include <random>
#include <vector>

#include "core/errors.hpp"
#include "core/log_one_minus.hpp"
#include "core/parallel.hpp"
#include "force_term_checks.hpp"
#include "forcefields/bond_term.hpp"

namespace stiffmd {
namespace {

using Eigen::Matrix3Xd;
using Eigen::Vector3d;

// |computed − exact| in units of the last place of the exact value rounded to double.
double ulps(double computed, long double exact) {
  const double rounded = static_cast<double>(exact);
  const double ulp = std::nextafter(std::abs(rounded), INFINITY) - std::abs(rounded);
  return static_cast<double>(std::abs(static_cast<long double>(computed) - exact)) / ulp;
}

TEST(LogOneMinus, WithinAnUlpOfTheLongDoubleLog1p) {
  std::mt19937_64 rng(5);
  std::uniform_real_distribution<double> unit(0.0, 1.0);
  std::vector<double> s = {0.0,
                           1e-300,
                           1e-17,
                           0x1p-53,
                           0.5,
                           std::nextafter(0.5, 0.0),
                           std::nextafter(1.0, 0.0),
                           -1.0,
                           -0.5,
                           std::sqrt(0.5),
                           1.0 - std::sqrt(0.5)};
  for (int k = 0; k < 300000; ++k) {
    const double t = unit(rng);
    s.push_back(t);                      // uniform on [0, 1): typical FENE stretches
    s.push_back(std::pow(t, 30));        // near 0: short bonds, where ln(1 − s) ≈ −s
    s.push_back(1.0 - std::pow(t, 30));  // near 1: bonds near R₀
  }
  double worst = 0.0, at = 0.0;
  for (double v : s) {
    if (!(v < 1.0)) continue;
    const long double exact = std::log1p(-static_cast<long double>(v));
    const double err = exact == 0.0L ? std::abs(log_one_minus(v)) : ulps(log_one_minus(v), exact);
    if (err > worst) worst = err, at = v;
  }
  EXPECT_LT(worst, 1.0) << "at s = " << at;  // fdlibm's bound; glibc's log1p measures 0.79 here too
  EXPECT_EQ(log_one_minus(0.0), 0.0);
}

// Chains of `length` beads, bonded along the chain, and the beads' positions: a random walk of
// steps in [0.85, 1.2] (inside FENE's domain, R₀ = 1.5, with the WCA core acting on most bonds).
struct Chains {
  std::vector<Bond> bonds;
  Matrix3Xd x;
};
Chains chains(int count, int length, int types, unsigned seed) {
  Chains c;
  c.x.resize(3, count * length);
  for (int m = 0; m < count; ++m) {
    c.x.middleCols(m * length, length) =
        test::random_walk(length, 0.85, 1.2, seed + m, Vector3d(3.0 * m, 0.5 * m, -1.0 * m));
    for (int i = 0; i + 1 < length; ++i) c.bonds.push_back({m * length + i, m * length + i + 1, i % types});
  }
  return c;
}

const std::vector<FeneCoeffs> kTypes = {{30.0, 1.5, 1.0, 1.0}, {20.0, 1.6, 0.5, 0.9}};

struct Result {
  Matrix3Xd f;
  double energy;
};
Result evaluate(const FeneBond& term, const Matrix3Xd& x, int threads) {
  const int restore = max_threads();
  set_max_threads(threads);
  Result r{Matrix3Xd::Zero(3, x.cols()), 0.0};
  r.energy = term.add_forces(x, Box{}, r.f);
  set_max_threads(restore);
  return r;
}

// The bonds one by one through the kernel's r form (Fene::eval), in list order: the definition.
Result bond_by_bond(const std::vector<Bond>& bonds, const std::vector<FeneCoeffs>& types, const Matrix3Xd& x) {
  Result r{Matrix3Xd::Zero(3, x.cols()), 0.0};
  for (const Bond& b : bonds) {
    const Vector3d d = x.col(b.i) - x.col(b.j);
    double e = 0.0, de_dr = 0.0;
    Fene::eval(d.norm(), Fene::params(types[b.type]), e, de_dr);
    r.energy += e;
    r.f.col(b.i) -= de_dr / d.norm() * d;
    r.f.col(b.j) += de_dr / d.norm() * d;
  }
  return r;
}

// Every path of the loop on one list: one thread and 2, 3 threads (work items, kParallelMin bonds
// and more), forces bit for bit, energies to round-off; and all of them the bond-by-bond sums, to
// `tolerance` relative (the reference's r = √(r²) squared again differs from r² in the last bit,
// which 1/(1 − (r/R₀)²) amplifies near R₀).
void expect_paths_agree(const std::vector<Bond>& bonds, const std::vector<FeneCoeffs>& types, const Matrix3Xd& x,
                        double tolerance = 1e-12) {
  ASSERT_GE(static_cast<std::int64_t>(bonds.size()), kParallelMin) << "too few bonds for the threaded path";
  const FeneBond term("fene", Level::slow, bonds, types);
  const Result one = evaluate(term, x, 1);
  const Result ref = bond_by_bond(bonds, types, x);
  const double scale = ref.f.cwiseAbs().maxCoeff();
  ASSERT_GT(scale, 1.0);
  EXPECT_LE((one.f - ref.f).cwiseAbs().maxCoeff(), tolerance * scale);
  EXPECT_NEAR(one.energy, ref.energy, tolerance * std::abs(ref.energy));
  for (int threads : {2, 3}) {
    SCOPED_TRACE(testing::Message() << threads << " threads");
    const Result many = evaluate(term, x, threads);
    EXPECT_EQ(many.f, one.f);  // each bond the same operations, each particle its forces in bond order
    EXPECT_NEAR(many.energy, one.energy, 1e-12 * std::abs(one.energy));
    EXPECT_EQ(evaluate(term, x, threads).energy, many.energy);  // the owners' sums in a fixed order
  }
  EXPECT_EQ(evaluate(term, x, 1).f, one.f);  // and call to call
  EXPECT_EQ(evaluate(term, x, 1).energy, one.energy);
}

TEST(BondLoop, OneTypeChainRunsMatchTheThreadedLoopAndTheBondByBondSums) {
  const Chains c = chains(60, 100, 1, 3);  // 5 940 bonds: chain runs, one type (UniformBonds)
  expect_paths_agree(c.bonds, {kTypes[0]}, c.x);
}

TEST(BondLoop, TwoTypeChainRunsMatchTheThreadedLoopAndTheBondByBondSums) {
  const Chains c = chains(60, 100, 2, 4);  // alternating types: each bond its own coefficients (AllBonds)
  expect_paths_agree(c.bonds, kTypes, c.x);
}

TEST(BondLoop, BondsOutOfChainOrderMatchTheThreadedLoopAndTheBondByBondSums) {
  Chains c = chains(60, 100, 1, 5);
  // Shuffled, and every other bond with its ends swapped: no chain runs, the gathered blocks.
  std::mt19937 rng(6);
  std::shuffle(c.bonds.begin(), c.bonds.end(), rng);
  for (std::size_t k = 0; k < c.bonds.size(); k += 2) std::swap(c.bonds[k].i, c.bonds[k].j);
  expect_paths_agree(c.bonds, {kTypes[0]}, c.x);
  expect_paths_agree(c.bonds, kTypes, c.x);
}

// Bonds near R₀ (1 − (r/R₀)² ≈ 10⁻⁶ each): a block of 64 such factors has a product below
// 2⁻¹⁰⁰⁰, and its logarithms are added one by one instead — the same energy to round-off. There
// (r/R₀)² carries a rounding error of 10⁻¹⁶, 10⁻¹⁰ of 1 − (r/R₀)², so energies and forces are
// known to about that: the tolerance.
TEST(BondLoop, NearlyFullyStretchedChainsKeepTheirEnergy) {
  Chains c;
  const int count = 50, length = 100;
  const double r = 1.5 * std::sqrt(1.0 - 1e-6);
  c.x.resize(3, count * length);
  for (int m = 0; m < count; ++m)
    for (int i = 0; i < length; ++i) {
      c.x.col(m * length + i) = Vector3d(r * i, 2.0 * m, 0.0);
      if (i + 1 < length) c.bonds.push_back({m * length + i, m * length + i + 1, 0});
    }
  expect_paths_agree(c.bonds, {kTypes[0]}, c.x, 1e-9);
  const Result ref = bond_by_bond(c.bonds, {kTypes[0]}, c.x);
  EXPECT_NEAR(ref.energy / static_cast<double>(c.bonds.size()), -0.5 * 30.0 * 2.25 * std::log(1e-6), 1e-3);
}

TEST(BondLoop, AnOverstretchedBondInALongChainIsNamedOnEveryPath) {
  Chains c = chains(60, 100, 1, 7);
  const int i = 1234;  // bond (1234, 1235): stretched to 1.6 > R₀ by moving the rest of its chain
  const Vector3d d = c.x.col(i + 1) - c.x.col(i);
  const Vector3d shift = (1.6 / d.norm() - 1.0) * d;
  for (int p = i + 1; p < 1300; ++p) c.x.col(p) += shift;
  const FeneBond term("chains", Level::slow, c.bonds, {kTypes[0]});
  for (int threads : {1, 2}) {
    try {
      evaluate(term, c.x, threads);
      FAIL() << "no NumericalError at " << threads << " threads";
    } catch (const NumericalError& e) {
      EXPECT_NE(std::string(e.what()).find("particles 1234 and 1235"), std::string::npos) << e.what();
    }
  }
}

}  // namespace
}  // namespace stiffmd
