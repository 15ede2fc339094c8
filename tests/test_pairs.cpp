// Pair styles (lj, wca, soft), the Verlet neighbour list and special bonds, against
// definitions: forces = −∇E by central finite differences, Newton's third law, the virial
// Σ r_ij·f_ij, and every list against an all-pairs O(N²) search with the minimum image
// (docs/design.md §11.8a).
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <map>
#include <numbers>
#include <random>
#include <set>
#include <utility>
#include <vector>

#include "force_term_checks.hpp"
#include "forcefields/neighbor_list.hpp"
#include "forcefields/pair_term.hpp"

namespace stiffmd {
namespace {

using PairSet = std::set<std::pair<int, int>>;
using WeightMap = std::map<std::pair<int, int>, double>;  // (i < j) → special weight ≠ 1

Box periodic_box(const Eigen::Vector3d& lengths, const Eigen::Vector3d& origin = Eigen::Vector3d::Zero(),
                 const Eigen::Vector3i& periodic = Eigen::Vector3i::Ones()) {
  Box b;
  b.lengths = lengths;
  b.origin = origin;
  b.periodic = periodic;
  return b;
}

Eigen::Vector3d separation(const Eigen::Matrix3Xd& x, const Box& box, int i, int j) {
  return box.min_image(x.col(i) - x.col(j));  // Box's own std::nearbyint: independent of MinimumImage
}

// Uniform positions in the box [origin, origin + L) (open axes: in [0, L)), optionally keeping
// every pair at least d_min apart (random sequential addition). The columns of `first`, if
// given, are placed as they are, before the random ones.
Eigen::Matrix3Xd random_in_box(int n, const Box& box, unsigned seed, double d_min = 0.0,
                               const Eigen::Matrix3Xd& first = Eigen::Matrix3Xd(3, 0)) {
  std::mt19937 rng(seed);
  std::uniform_real_distribution<double> u(0.0, 1.0);
  Eigen::Matrix3Xd x(3, n);
  x.leftCols(first.cols()) = first;
  for (int i = static_cast<int>(first.cols()); i < n; ++i) {
    for (int attempt = 0;; ++attempt) {
      for (int a = 0; a < 3; ++a) x(a, i) = box.origin[a] + box.lengths[a] * u(rng);
      bool ok = true;
      for (int j = 0; j < i && ok; ++j) ok = separation(x, box, i, j).norm() >= d_min;
      if (ok) break;
      if (attempt > 10000) throw std::runtime_error("random_in_box: too dense for d_min");
    }
  }
  return x;
}

// Chains of random-walk steps of length `step`, started uniformly in the box and left unwrapped
// (they wander out of it, as the engine's positions do). Beads farther than one bond along the
// chain keep at least d_min apart (within the chain and from the other chains).
Eigen::Matrix3Xd random_chains(int chains, int beads, const Box& box, double step, unsigned seed, double d_min = 0.0) {
  std::mt19937 rng(seed);
  std::uniform_real_distribution<double> u(0.0, 1.0);
  std::normal_distribution<double> g;
  const int n = chains * beads;
  Eigen::Matrix3Xd x(3, n);
  for (int c = 0; c < chains; ++c)
    for (int k = 0; k < beads; ++k) {
      const int i = c * beads + k;
      for (int attempt = 0;; ++attempt) {
        if (k == 0) {
          for (int a = 0; a < 3; ++a) x(a, i) = box.origin[a] + box.lengths[a] * u(rng);
        } else {
          Eigen::Vector3d dir(g(rng), g(rng), g(rng));
          x.col(i) = x.col(i - 1) + step * dir.normalized();
        }
        bool ok = true;
        for (int j = 0; j < i - (k > 0 ? 1 : 0) && ok; ++j) ok = separation(x, box, i, j).norm() >= d_min;
        if (ok || attempt > 1000) break;  // give up on avoidance rather than loop forever
      }
    }
  return x;
}

std::vector<Bond> chain_bonds(int chains, int beads) {
  std::vector<Bond> b;
  for (int c = 0; c < chains; ++c)
    for (int k = 0; k + 1 < beads; ++k) b.push_back({c * beads + k, c * beads + k + 1, 0});
  return b;
}

// The special weights of linear chains, written down directly (not through special_pairs).
WeightMap chain_weights(int chains, int beads, SpecialWeights w) {
  WeightMap m;
  for (int c = 0; c < chains; ++c)
    for (int k = 0; k < beads; ++k) {
      const int i = c * beads + k;
      if (k + 1 < beads && w.w12 != 1.0) m[{i, i + 1}] = w.w12;
      if (k + 2 < beads && w.w13 != 1.0) m[{i, i + 2}] = w.w13;
    }
  return m;
}

// All pairs i < j with minimum-image distance < r, by brute force, leaving out `excluded`.
PairSet all_pairs_within(const Eigen::Matrix3Xd& x, const Box& box, double r, const WeightMap& excluded = {}) {
  PairSet s;
  for (int i = 0; i < x.cols(); ++i)
    for (int j = i + 1; j < x.cols(); ++j)
      if (separation(x, box, i, j).squaredNorm() < r * r && !excluded.count({i, j})) s.insert({i, j});
  return s;
}

// The list's pairs; fails the test on a duplicate or a j ≤ i entry.
PairSet listed_pairs(const NeighborList& nl) {
  PairSet s;
  const auto off = nl.offsets();
  const auto nb = nl.neighbors();
  for (int i = 0; i < nl.num_particles(); ++i)
    for (auto k = off[i]; k < off[i + 1]; ++k) {
      EXPECT_GT(nb[k], i) << "half list must hold j > i only";
      EXPECT_TRUE(s.insert({i, nb[k]}).second) << "pair (" << i << ", " << nb[k] << ") listed twice";
    }
  return s;
}

PairSet within(const PairSet& pairs, const Eigen::Matrix3Xd& x, const Box& box, double r) {
  PairSet s;
  for (const auto& [i, j] : pairs)
    if (separation(x, box, i, j).squaredNorm() < r * r) s.insert({i, j});
  return s;
}

// Energy, forces and virial by brute force over all pairs, minimum image, special weights.
struct AllPairs {
  double energy = 0.0;
  double virial = 0.0;
  Eigen::Matrix3Xd f;
};

template <class Kernel>
AllPairs all_pairs(const Eigen::Matrix3Xd& x, const Box& box, const std::vector<int>& types,
                   const TypePairMatrix<typename Kernel::Coeffs>& coeffs, const WeightMap& weights = {}) {
  const auto params = coeffs.transform([](const typename Kernel::Coeffs& c) { return Kernel::params(c); });
  AllPairs out;
  out.f = Eigen::Matrix3Xd::Zero(3, x.cols());
  for (int i = 0; i < x.cols(); ++i)
    for (int j = i + 1; j < x.cols(); ++j) {
      const Eigen::Vector3d d = separation(x, box, i, j);
      const double r2 = d.squaredNorm();
      const auto& p = params(types[i], types[j]);
      if (!(r2 < p.rc2)) continue;
      const auto w = weights.find({i, j});
      const double weight = w == weights.end() ? 1.0 : w->second;
      double e = 0.0, fpair = 0.0;
      Kernel::eval(r2, p, e, fpair);
      out.energy += weight * e;
      out.virial += weight * fpair * r2;  // r_ij · f_ij with f_ij = fpair r_ij
      out.f.col(i) += weight * fpair * d;
      out.f.col(j) -= weight * fpair * d;
    }
  return out;
}

// Max over coordinates of |f − (−∂E/∂x)| by central differences, relative to max(1, max |f|).
double fd_mismatch(const ForceTerm& term, const Eigen::Matrix3Xd& x, const Box& box) {
  Eigen::Matrix3Xd f = Eigen::Matrix3Xd::Zero(3, x.cols()), scratch = f;
  term.add_forces(x, box, f);
  double worst = 0.0;
  const double h = 1e-6;
  for (int i = 0; i < x.cols(); ++i)
    for (int a = 0; a < 3; ++a) {
      Eigen::Matrix3Xd xp = x, xm = x;
      xp(a, i) += h;
      xm(a, i) -= h;
      const double fd = -(term.add_forces(xp, box, scratch) - term.add_forces(xm, box, scratch)) / (2 * h);
      worst = std::max(worst, std::abs(fd - f(a, i)));
    }
  return worst / std::max(1.0, f.cwiseAbs().maxCoeff());
}

double max_abs(const Eigen::Matrix3Xd& m) {
  return m.cwiseAbs().maxCoeff();
}

template <class Kernel>
double kernel_energy(double r, const typename Kernel::Params& p) {
  double e = 0.0, fpair = 0.0;
  Kernel::eval(r * r, p, e, fpair);
  return e;
}
template <class Kernel>
double kernel_force(double r, const typename Kernel::Params& p) {  // −dE/dr
  double e = 0.0, fpair = 0.0;
  Kernel::eval(r * r, p, e, fpair);
  return fpair * r;
}

// ---------------------------------------------------------------------------------------
// Kernels: −dE/dr, values at known points, continuity at the cutoff, the WCA minimum.

TEST(PairKernels, ForceIsMinusDerivativeOfEnergy) {
  const auto lj = LennardJones::params({1.3, 0.9, 2.5});
  const auto wca = WeeksChandlerAndersen::params({1.3, 0.9});
  const auto soft = SoftCosine::params({2.0, 1.2});
  const double h = 1e-6;
  for (double r = 0.8; r < 2.5; r += 0.0137) {
    const double fd_lj = -(kernel_energy<LennardJones>(r + h, lj) - kernel_energy<LennardJones>(r - h, lj)) / (2 * h);
    EXPECT_NEAR(kernel_force<LennardJones>(r, lj), fd_lj, 1e-6 * std::max(1.0, std::abs(fd_lj))) << "lj r = " << r;
    if (r + h < std::sqrt(wca.rc2)) {
      const double fd =
          -(kernel_energy<WeeksChandlerAndersen>(r + h, wca) - kernel_energy<WeeksChandlerAndersen>(r - h, wca)) /
          (2 * h);
      EXPECT_NEAR(kernel_force<WeeksChandlerAndersen>(r, wca), fd, 1e-6 * std::max(1.0, std::abs(fd)))
          << "wca r = " << r;
    }
  }
  for (double r = 0.001; r + h < 1.2; r += 0.0113) {
    const double fd = -(kernel_energy<SoftCosine>(r + h, soft) - kernel_energy<SoftCosine>(r - h, soft)) / (2 * h);
    EXPECT_NEAR(kernel_force<SoftCosine>(r, soft), fd, 1e-7) << "soft r = " << r;
  }
}

TEST(PairKernels, KnownValues) {
  const double eps = 1.7, sigma = 1.1, rc = 2.5;
  const auto lj = LennardJones::params({eps, sigma, rc});
  const double e_rc = 4 * eps * (std::pow(sigma / rc, 12) - std::pow(sigma / rc, 6));  // the shift
  EXPECT_NEAR(kernel_energy<LennardJones>(sigma, lj), -e_rc, 1e-14);
  const double rmin = std::pow(2.0, 1.0 / 6.0) * sigma;
  EXPECT_NEAR(kernel_energy<LennardJones>(rmin, lj), -eps - e_rc, 1e-13);
  EXPECT_NEAR(kernel_force<LennardJones>(sigma, lj), 24 * eps / sigma, 1e-12);  // −dE/dr at r = σ

  const auto soft = SoftCosine::params({3.0, 1.5});
  EXPECT_DOUBLE_EQ(kernel_energy<SoftCosine>(0.0, soft), 6.0);  // 2A at full overlap
  double e = 0.0, fpair = 1.0;
  SoftCosine::eval(0.0, soft, e, fpair);
  EXPECT_EQ(fpair, 0.0);  // no direction at r = 0: no force, not NaN
  EXPECT_NEAR(kernel_energy<SoftCosine>(0.75, soft), 3.0, 1e-14);
  EXPECT_NEAR(kernel_force<SoftCosine>(0.75, soft), 3.0 * std::numbers::pi / 1.5, 1e-13);
}

TEST(PairKernels, EnergyIsContinuousAndZeroAtCutoff) {
  const auto lj = LennardJones::params({1.0, 1.0, 2.5});
  const auto wca = WeeksChandlerAndersen::params({1.0, 1.0});
  const auto soft = SoftCosine::params({1.0, 1.0});
  EXPECT_NEAR(kernel_energy<LennardJones>(2.5, lj), 0.0, 1e-15);
  EXPECT_NEAR(kernel_energy<LennardJones>(2.5 * (1 - 1e-9), lj), 0.0, 1e-10);
  const double rc_wca = std::sqrt(wca.rc2);
  EXPECT_NEAR(rc_wca, std::pow(2.0, 1.0 / 6.0), 1e-15);
  EXPECT_NEAR(kernel_energy<WeeksChandlerAndersen>(rc_wca, wca), 0.0, 1e-13);
  EXPECT_NEAR(kernel_energy<WeeksChandlerAndersen>(rc_wca * (1 - 1e-9), wca), 0.0, 1e-12);
  EXPECT_NEAR(kernel_energy<SoftCosine>(1.0 - 1e-9, soft), 0.0, 1e-15);

  // Through the term: the energy just inside the cutoff tends to the 0 just outside.
  const Box open;
  for (const double r : {2.5 - 1e-9, 2.5, 2.5 + 1e-9}) {
    Eigen::Matrix3Xd x = Eigen::Matrix3Xd::Zero(3, 2), f = x;
    x(0, 1) = r;
    TypePairMatrix<LennardJones::Coeffs> c(1);
    c.set(0, 0, {1.0, 1.0, 2.5});
    const LennardJonesPair term("lj", Level::slow, {0, 0}, c, {}, {}, open);
    EXPECT_NEAR(term.add_forces(x, open, f), 0.0, 1e-10) << "r = " << r;
    if (r >= 2.5) {
      EXPECT_EQ(max_abs(f), 0.0) << "no force at or beyond rc";
    }
  }
}

TEST(PairKernels, WcaIsPurelyRepulsiveWithItsMinimumAtTwoToTheSixthSigma) {
  const double sigma = 0.8, eps = 2.0, rmin = std::pow(2.0, 1.0 / 6.0) * sigma;
  const auto wca = WeeksChandlerAndersen::params({eps, sigma});
  EXPECT_NEAR(std::sqrt(wca.rc2), rmin, 1e-15);
  // The force vanishes at the cutoff (rc is the LJ minimum), so the cut costs no impulse.
  EXPECT_NEAR(kernel_force<WeeksChandlerAndersen>(rmin, wca), 0.0, 1e-12);
  // E = 4ε[(σ/r)¹² − (σ/r)⁶] + ε: positive and decreasing up to rc, repulsive throughout.
  double previous = INFINITY;
  for (double r = 0.7 * sigma; r < rmin; r += 0.01 * sigma) {
    const double e = kernel_energy<WeeksChandlerAndersen>(r, wca);
    EXPECT_GT(e, 0.0);
    EXPECT_LT(e, previous);
    EXPECT_GT(kernel_force<WeeksChandlerAndersen>(r, wca), 0.0);
    EXPECT_NEAR(e, 4 * eps * (std::pow(sigma / r, 12) - std::pow(sigma / r, 6)) + eps, 1e-11 * std::max(1.0, e));
    previous = e;
  }
  // The same point is the minimum of the full LJ potential.
  const auto lj = LennardJones::params({eps, sigma, 3.0 * sigma});
  const double e_min = kernel_energy<LennardJones>(rmin, lj);
  EXPECT_LT(e_min, kernel_energy<LennardJones>(rmin * (1 - 1e-3), lj));
  EXPECT_LT(e_min, kernel_energy<LennardJones>(rmin * (1 + 1e-3), lj));
}

// ---------------------------------------------------------------------------------------
// Each style as a force term: −∇E, Newton's third law, the virial, unwrapped positions.
// Two particle types with different coefficients, so the type-pair lookup is exercised.

struct LjCase {
  using Term = LennardJonesPair;
  using Kernel = LennardJones;
  static TypePairMatrix<Kernel::Coeffs> coeffs() {
    TypePairMatrix<Kernel::Coeffs> c(2);
    c.set(0, 0, {1.0, 1.0, 2.5});
    c.set(0, 1, {0.7, 0.95, 2.0});
    c.set(1, 1, {1.3, 0.9, 1.8});
    return c;
  }
  static constexpr double kMinDistance = 0.85;
};
struct WcaCase {
  using Term = WcaPair;
  using Kernel = WeeksChandlerAndersen;
  static TypePairMatrix<Kernel::Coeffs> coeffs() {
    TypePairMatrix<Kernel::Coeffs> c(2);
    c.set(0, 0, {1.0, 1.0});
    c.set(0, 1, {1.5, 0.9});
    c.set(1, 1, {0.8, 1.1});
    return c;
  }
  static constexpr double kMinDistance = 0.8;
};
struct SoftCase {
  using Term = SoftPair;
  using Kernel = SoftCosine;
  static TypePairMatrix<Kernel::Coeffs> coeffs() {
    TypePairMatrix<Kernel::Coeffs> c(2);
    c.set(0, 0, {3.0, 1.0});
    c.set(0, 1, {5.0, 1.3});
    c.set(1, 1, {2.0, 1.1});
    return c;
  }
  static constexpr double kMinDistance = 0.0;  // soft cores may overlap
};
struct YukawaCase {
  using Term = PairTerm<Yukawa>;
  using Kernel = Yukawa;
  static TypePairMatrix<Kernel::Coeffs> coeffs() {
    TypePairMatrix<Kernel::Coeffs> c(2);
    c.set(0, 0, {2.0, 1.0, 2.5});
    c.set(0, 1, {-1.0, 1.5, 2.0});  // A < 0: attraction
    c.set(1, 1, {3.0, 0.5, 2.2});
    return c;
  }
  static constexpr double kMinDistance = 0.6;
};

template <class Case>
class PairStyle : public ::testing::Test {
 protected:
  using Term = typename Case::Term;
  using Kernel = typename Case::Kernel;

  static std::vector<int> alternating_types(int n) {
    std::vector<int> t(n);
    for (int i = 0; i < n; ++i) t[i] = (i % 3 == 0) ? 1 : 0;
    return t;
  }
  // A periodic box of a few list radii per side (2.5: two cells per axis, so every cell is a
  // neighbour of every other) with a non-zero origin.
  static Box small_periodic_box(double radii_per_side = 2.5) {
    const Term probe("probe", Level::slow, {0}, Case::coeffs(), {}, {}, Box{});
    const double l = radii_per_side * (probe.cutoff() + probe.skin());
    return periodic_box(Eigen::Vector3d(l, 1.1 * l, 1.2 * l), Eigen::Vector3d(-1.0, 0.5, 2.0));
  }
};

using Styles = ::testing::Types<LjCase, WcaCase, SoftCase, YukawaCase>;
TYPED_TEST_SUITE(PairStyle, Styles);

TYPED_TEST(PairStyle, ForceIsMinusGradientOfEnergyInOpenSpace) {
  using Term = typename TestFixture::Term;
  const int n = 40;
  const Box open;
  Box sampling = periodic_box(Eigen::Vector3d::Constant(4.0), Eigen::Vector3d::Zero(), Eigen::Vector3i::Zero());
  const Eigen::Matrix3Xd x = random_in_box(n, sampling, 11, TypeParam::kMinDistance);
  const Term term("pairs", Level::slow, TestFixture::alternating_types(n), TypeParam::coeffs(), {}, {}, open);
  Eigen::Matrix3Xd f = Eigen::Matrix3Xd::Zero(3, n);
  term.add_forces(x, open, f);
  ASSERT_GT(max_abs(f), 0.1) << "the configuration must interact";
  EXPECT_LT(fd_mismatch(term, x, open), 1e-6);
}

TYPED_TEST(PairStyle, ForceIsMinusGradientAcrossPeriodicBoundaries) {
  using Term = typename TestFixture::Term;
  const Box box = TestFixture::small_periodic_box();
  const int n = 30;
  // Particles 0 and 1 are 0.95 apart through the x boundary only.
  Eigen::Matrix3Xd first(3, 2);
  first.col(0) = box.origin + Eigen::Vector3d(0.3, 1.0, 1.0);
  first.col(1) = box.origin + Eigen::Vector3d(box.lengths.x() - 0.65, 1.0, 1.0);
  Eigen::Matrix3Xd x = random_in_box(n, box, 12, TypeParam::kMinDistance, first);
  // Unwrapped positions several boxes away.
  x.col(2) += Eigen::Vector3d(2 * box.lengths.x(), -3 * box.lengths.y(), box.lengths.z());
  x.col(3) -= Eigen::Vector3d(5 * box.lengths.x(), 0.0, 7 * box.lengths.z());
  const Term term("pairs", Level::slow, TestFixture::alternating_types(n), TypeParam::coeffs(), {}, {}, box);
  Eigen::Matrix3Xd f = Eigen::Matrix3Xd::Zero(3, n);
  term.add_forces(x, box, f);
  EXPECT_TRUE(listed_pairs(term.neighbor_list()).count({0, 1})) << "the pair across the boundary must be listed";
  EXPECT_LT(fd_mismatch(term, x, box), 1e-6);
}

TYPED_TEST(PairStyle, NewtonsThirdLawAndVirialAgainstAllPairs) {
  using Term = typename TestFixture::Term;
  using Kernel = typename TestFixture::Kernel;
  const Box box = TestFixture::small_periodic_box();
  const int n = 60;
  const Eigen::Matrix3Xd x = random_in_box(n, box, 13, TypeParam::kMinDistance);
  const auto types = TestFixture::alternating_types(n);
  const Term term("pairs", Level::slow, types, TypeParam::coeffs(), {}, {}, box);
  Eigen::Matrix3Xd f = Eigen::Matrix3Xd::Zero(3, n);
  const double e = term.add_forces(x, box, f);
  const AllPairs ref = all_pairs<Kernel>(x, box, types, TypeParam::coeffs());
  const double scale = max_abs(ref.f);
  ASSERT_GT(scale, 0.1);
  EXPECT_LT((f.rowwise().sum()).cwiseAbs().maxCoeff(), 1e-12 * n * scale) << "Σ f = 0";
  EXPECT_LT(max_abs(f - ref.f), 1e-12 * scale);
  EXPECT_NEAR(e, ref.energy, 1e-12 * std::max(1.0, std::abs(ref.energy)));
  const double w = term.virial(x, box);
  EXPECT_NEAR(w, ref.virial, 1e-12 * std::max(1.0, std::abs(ref.virial)));
}

// For pair forces W = Σ r_ij·f_ij = −Σ r dE/dr = −dE(λx, λL)/dλ at λ = 1: a check of the
// virial through the energy alone, independent of the force kernel.
TYPED_TEST(PairStyle, VirialIsMinusDerivativeOfEnergyUnderUniformScaling) {
  using Term = typename TestFixture::Term;
  const Box box = TestFixture::small_periodic_box();
  const int n = 50;
  const Eigen::Matrix3Xd x = random_in_box(n, box, 14, TypeParam::kMinDistance);
  const Term term("pairs", Level::slow, TestFixture::alternating_types(n), TypeParam::coeffs(), {}, {}, box);
  auto energy_scaled = [&](double lambda) {
    Box b = box;
    b.lengths *= lambda;
    b.origin *= lambda;
    Eigen::Matrix3Xd f = Eigen::Matrix3Xd::Zero(3, n);
    return term.add_forces(lambda * x, b, f);
  };
  const double h = 1e-6;
  const double w_fd = -(energy_scaled(1 + h) - energy_scaled(1 - h)) / (2 * h);
  const double w = term.virial(x, box);
  ASSERT_GT(std::abs(w), 0.1);
  EXPECT_NEAR(w, w_fd, 1e-6 * std::max(1.0, std::abs(w)));
}

// The kernel alone: fpair·r = −dE/dr by central differences, for every type pair, from the
// case's closest distance to the cutoff.
TYPED_TEST(PairStyle, KernelForceIsMinusDerivativeOfEnergy) {
  using Kernel = typename TestFixture::Kernel;
  const auto coeffs = TypeParam::coeffs();
  const double h = 1e-6;
  for (int a = 0; a < coeffs.num_types(); ++a)
    for (int b = a; b < coeffs.num_types(); ++b) {
      const auto p = Kernel::params(coeffs(a, b));
      const double rc = Kernel::cutoff(coeffs(a, b));
      for (double r = std::max(TypeParam::kMinDistance, 0.01); r + h < rc; r += 0.0137) {
        const double fd = -(kernel_energy<Kernel>(r + h, p) - kernel_energy<Kernel>(r - h, p)) / (2 * h);
        EXPECT_NEAR(kernel_force<Kernel>(r, p), fd, 1e-6 * std::max(1.0, std::abs(fd)))
            << "types (" << a << ", " << b << "), r = " << r;
      }
    }
}

// Every pair style is cut and shifted: E → 0 as r → rc from below, so that a pair crossing
// the cutoff does not change the energy.
TYPED_TEST(PairStyle, EnergyVanishesAtTheCutoff) {
  using Kernel = typename TestFixture::Kernel;
  const auto coeffs = TypeParam::coeffs();
  for (int a = 0; a < coeffs.num_types(); ++a)
    for (int b = a; b < coeffs.num_types(); ++b) {
      const auto p = Kernel::params(coeffs(a, b));
      const double rc = Kernel::cutoff(coeffs(a, b));
      EXPECT_NEAR(kernel_energy<Kernel>(rc, p), 0.0, 1e-14) << "types (" << a << ", " << b << ")";
      EXPECT_NEAR(kernel_energy<Kernel>(rc * (1 - 1e-9), p), 0.0, 1e-7) << "types (" << a << ", " << b << ")";
    }
}

// In open space the virial's definition Σ r_ij · f_ij is Σ_i x_i · f_i (Σ f = 0).
TYPED_TEST(PairStyle, OpenSpaceVirialIsSumOfPositionDotForce) {
  using Term = typename TestFixture::Term;
  const int n = 40;
  Box sampling = periodic_box(Eigen::Vector3d::Constant(4.0), Eigen::Vector3d::Zero(), Eigen::Vector3i::Zero());
  const Eigen::Matrix3Xd x = random_in_box(n, sampling, 16, TypeParam::kMinDistance);
  const Term term("pairs", Level::slow, TestFixture::alternating_types(n), TypeParam::coeffs(), {}, {}, Box{});
  const double w = term.virial(x, Box{});
  ASSERT_GT(std::abs(w), 0.1);
  EXPECT_NEAR(w, test::position_virial(term, x), 1e-12 * std::max(1.0, std::abs(w)));
}

TYPED_TEST(PairStyle, UnwrappedPositionsGiveTheSameForces) {
  using Term = typename TestFixture::Term;
  const Box box = TestFixture::small_periodic_box(4.5);  // 4 cells per axis: binning must wrap
  const int n = 150;
  const Eigen::Matrix3Xd x = random_in_box(n, box, 15, TypeParam::kMinDistance);
  Eigen::Matrix3Xd shifted = x;
  std::mt19937 rng(3);
  std::uniform_int_distribution<int> image(-4, 4);
  for (int i = 0; i < n; ++i)
    for (int a = 0; a < 3; ++a) shifted(a, i) += image(rng) * box.lengths[a];
  const Term term("pairs", Level::slow, TestFixture::alternating_types(n), TypeParam::coeffs(), {}, {}, box);
  Eigen::Matrix3Xd f0 = Eigen::Matrix3Xd::Zero(3, n), f1 = f0;
  const double e0 = term.add_forces(x, box, f0);
  const double e1 = term.add_forces(shifted, box, f1);
  EXPECT_NEAR(e0, e1, 1e-10 * std::max(1.0, std::abs(e0)));
  EXPECT_LT(max_abs(f0 - f1), 1e-9 * std::max(1.0, max_abs(f0)));
}

// Yukawa against LAMMPS's pair_yukawa.cpp, term by term: screening = exp(−kappa r),
// forceyukawa = a screening (kappa + 1/r), fpair = forceyukawa / r², evdwl = a screening / r −
// offset with offset = a exp(−kappa rc) / rc (pair_modify shift yes) — and against 30-digit
// values (mpmath) at four distances.
TEST(PairKernels, YukawaMatchesLammpsFormula) {
  const double a = 3.0, kappa = 1.5, rc = 2.5;
  const auto p = Yukawa::params({a, kappa, rc});
  const struct {
    double r, energy, force;  // force: −dE/dr (mpmath)
  } golden[] = {{0.5, 2.8059780214188773129, 9.9196976075613088499},
                {1.0, 0.64116918541807855692, 1.673476201113223717},
                {2.0, 0.046459307524584984586, 0.14936120510359182894},
                {2.49, 0.00054156168212284258272, 0.054695633140038318324}};
  const double offset = a * std::exp(-kappa * rc) / rc;
  for (const auto& g : golden) {
    double e = 0.0, fpair = 0.0;
    Yukawa::eval(g.r * g.r, p, e, fpair);
    const double screening = std::exp(-kappa * g.r);
    EXPECT_NEAR(e, a * screening / g.r - offset, 1e-14) << g.r;
    EXPECT_NEAR(fpair, a * screening * (kappa + 1 / g.r) / (g.r * g.r), 1e-13) << g.r;
    EXPECT_NEAR(e, g.energy, 1e-14) << g.r;
    EXPECT_NEAR(fpair * g.r, g.force, 1e-13) << g.r;
  }
  // Through the term: two particles at r = 1 across a periodic face, 1-2 bonded pair excluded.
  TypePairMatrix<Yukawa::Coeffs> c(1);
  c.set(0, 0, {a, kappa, rc});
  const Box box = periodic_box(Eigen::Vector3d::Constant(6.0));
  Eigen::Matrix3Xd x = Eigen::Matrix3Xd::Zero(3, 3), f = x;
  x(0, 0) = 0.4;
  x(0, 1) = 5.4;  // 1.0 from particle 0 by minimum image
  x(1, 2) = 3.0;  // 3.0 from both: beyond the cutoff
  const PairTerm<Yukawa> term("y", Level::slow, {0, 0, 0}, c, {}, {}, box);
  EXPECT_NEAR(term.add_forces(x, box, f), golden[1].energy, 1e-14);
  EXPECT_NEAR(f(0, 0), golden[1].force, 1e-13);
  EXPECT_EQ(term.style(), "yukawa");
  const PairTerm<Yukawa> bonded("y", Level::slow, {0, 0, 0}, c, {{0, 1, 0}}, {0.0, 1.0}, box);
  EXPECT_EQ(bonded.add_forces(x, box, f), 0.0);
}

// ---------------------------------------------------------------------------------------
// The neighbour list against the all-pairs search.

struct ListCase {
  const char* name;
  int cutoffs_per_side;  // box edge in units of the cutoff (0: open space)
  bool chains;
};

void PrintTo(const ListCase& c, std::ostream* os) {
  *os << c.name;
}

class NeighborListVsAllPairs : public ::testing::TestWithParam<ListCase> {};

// At build time the list is exactly the pairs within cutoff + skin; it must then keep every
// pair within the cutoff while particles move, rebuilding when (and only when) needed.
TEST_P(NeighborListVsAllPairs, SamePairsAsBruteForce) {
  const ListCase c = GetParam();
  const int n = 1000;
  const double density = 0.85, skin = 0.3;
  const double side = std::cbrt(n / density);
  Box box = periodic_box(Eigen::Vector3d::Constant(side), Eigen::Vector3d(0.3, -2.0, 1.0));
  const double cutoff = c.cutoffs_per_side > 0 ? side / c.cutoffs_per_side : 2.0;
  const Box sampling = box;
  if (c.cutoffs_per_side == 0) box = Box{};
  Eigen::Matrix3Xd x = c.chains ? random_chains(20, 50, sampling, 0.97, 21) : random_in_box(n, sampling, 22);

  NeighborList nl(cutoff, skin);
  ASSERT_TRUE(nl.update(x, box));
  EXPECT_EQ(listed_pairs(nl), all_pairs_within(x, box, cutoff + skin));

  std::mt19937 rng(5);
  std::uniform_real_distribution<double> u(-0.02, 0.02);
  const int updates = 60;
  int rebuilt = 0;
  for (int s = 0; s < updates; ++s) {
    for (int i = 0; i < n; ++i)
      for (int a = 0; a < 3; ++a) x(a, i) += u(rng);
    if (nl.update(x, box)) {
      ++rebuilt;
      EXPECT_EQ(listed_pairs(nl), all_pairs_within(x, box, cutoff + skin)) << "after rebuild at update " << s;
    }
    if (s % 10 == 0 || s == updates - 1) {
      EXPECT_EQ(within(listed_pairs(nl), x, box, cutoff), all_pairs_within(x, box, cutoff)) << "update " << s;
    }
  }
  EXPECT_GT(rebuilt, 0);
  EXPECT_LT(rebuilt, updates);
  EXPECT_EQ(nl.rebuilds(), rebuilt + 1);
}

INSTANTIATE_TEST_SUITE_P(Configurations, NeighborListVsAllPairs,
                         ::testing::Values(ListCase{"liquid_3_cutoffs", 3, false},
                                           ListCase{"liquid_4_cutoffs", 4, false},
                                           ListCase{"liquid_6_cutoffs", 6, false},
                                           ListCase{"chains_3_cutoffs", 3, true}, ListCase{"chains_4_cutoffs", 4, true},
                                           ListCase{"chains_6_cutoffs", 6, true}, ListCase{"liquid_open", 0, false},
                                           ListCase{"chains_open", 0, true}),
                         [](const auto& info) { return std::string(info.param.name); });

TEST(NeighborList, FewerThanThreeCellsPerAxisAndMixedPeriodicity) {
  // 2 cells on the periodic x and y axes (the −1 and +1 neighbours are the same cell), z open:
  // every pair must still appear exactly once.
  const double cutoff = 1.2, skin = 0.3, w = cutoff + skin;
  const Box box =
      periodic_box(Eigen::Vector3d(2.05 * w, 2.9 * w, 5.0), Eigen::Vector3d(-1, -1, -1), Eigen::Vector3i(1, 1, 0));
  const Box sampling = periodic_box(box.lengths, box.origin, Eigen::Vector3i::Zero());
  const Eigen::Matrix3Xd x = random_in_box(200, sampling, 31);
  NeighborList nl(cutoff, skin);
  nl.update(x, box);
  EXPECT_EQ(nl.cells_per_axis().x(), 2);
  EXPECT_EQ(nl.cells_per_axis().y(), 2);
  EXPECT_EQ(listed_pairs(nl), all_pairs_within(x, box, w));
}

// At most 2 cells on every axis (a box under two list radii wide, as LAMMPS's peptide example):
// the search takes all j > i in index order (search_all_pairs). Every pair within the list radius
// once, none excluded (every 1-2 and 1-3 pair of chains left out), and each row in increasing j —
// the order the pair loop's sums depend on (neighbor_list.hpp).
TEST(NeighborList, AtMostTwoCellsPerAxisListsRowsInIncreasingOrderWithoutExclusions) {
  const double cutoff = 1.2, skin = 0.3, w = cutoff + skin;
  const Box box = periodic_box(Eigen::Vector3d(2.6 * w, 2.3 * w, 2.9 * w), Eigen::Vector3d(-1, 0.5, 2));
  const Eigen::Matrix3Xd x = random_chains(10, 12, box, 0.97, 33);
  const WeightMap excluded = chain_weights(10, 12, {0.0, 0.0, 1.0});
  std::vector<SpecialPair> pairs;
  for (const auto& [ij, weight] : excluded) pairs.push_back({ij.first, ij.second, weight, weight});
  NeighborList nl(cutoff, skin);
  nl.set_exclusions(static_cast<int>(x.cols()), pairs);
  nl.update(x, box);
  ASSERT_EQ(nl.cells_per_axis(), Eigen::Vector3i(2, 2, 2));
  EXPECT_EQ(listed_pairs(nl), all_pairs_within(x, box, w, excluded));
  const auto off = nl.offsets();
  const auto nb = nl.neighbors();
  for (int i = 0; i < nl.num_particles(); ++i)
    EXPECT_TRUE(std::is_sorted(nb.begin() + off[i], nb.begin() + off[i + 1])) << "row " << i;
}

// The list, array for array, against the all-pairs search: row i holds every j > i within the list
// radius (minimum image) that is not excluded, in increasing j, and nothing else — so a search that
// missed, added or reordered a pair fails. Uniform and clustered particles (clusters of a few
// dozen within one cell: long rows and crowded cells), chains with 1-2 and 1-3 exclusions, periodic,
// mixed and open boxes from under 3 list radii (fewer than 3 cells: the small-box searches) to many,
// on one thread and on two (above the size where the search splits into parts).
TEST(NeighborList, RowsAreTheAllPairsRowsInIncreasingOrder) {
  const double cutoff = 1.1, skin = 0.35, w = cutoff + skin;
  const int restore = max_threads();
  struct Shape {
    Eigen::Vector3d lists;  // box edges in list radii
    Eigen::Vector3i periodic;
  };
  const Shape shapes[] = {{{3.2, 4.5, 6.1}, {1, 1, 1}},   {{2.6, 3.3, 7.9}, {1, 1, 1}}, {{5.0, 3.1, 4.2}, {1, 0, 1}},
                          {{4.4, 5.7, 3.6}, {0, 0, 0}},   {{2.3, 2.8, 2.9}, {1, 1, 1}}, {{3.0, 3.0, 3.0}, {1, 1, 1}},
                          {{14.5, 12.2, 11.3}, {1, 1, 1}}};
  int checked = 0;
  for (const Shape& shape : shapes)
    for (int layout = 0; layout < 3; ++layout) {  // uniform, clustered, chains with exclusions
      const Box box = periodic_box(shape.lists * w, Eigen::Vector3d(-0.7, 2.3, 0.4), shape.periodic);
      const Box sampling = periodic_box(box.lengths, box.origin);
      const double volume = box.lengths.prod();
      const int n = std::max(40, static_cast<int>(0.85 * volume));
      Eigen::Matrix3Xd x;
      WeightMap excluded;
      if (layout == 0) {
        x = random_in_box(n, sampling, 61 + checked);
      } else if (layout == 1) {  // clusters of 40 within 0.3 list radii, around uniform centres
        x = random_in_box(n, sampling, 71 + checked);
        std::mt19937 rng(81 + checked);
        std::uniform_real_distribution<double> u(-0.15 * w, 0.15 * w);
        for (int i = 0; i < n; ++i)
          for (int a = 0; a < 3; ++a) x(a, i) = x(a, i - i % 40) + u(rng);
      } else {
        const int beads = 20, chains = std::max(2, n / beads);
        x = random_chains(chains, beads, sampling, 0.97, 91 + checked);
        excluded = chain_weights(chains, beads, {0.0, 0.0, 1.0});
      }
      if (shape.periodic.x() != 0 && layout != 2)  // some images far from the box: unwrapped positions
        for (int i = 0; i < x.cols(); i += 3) x(0, i) += box.lengths.x() * ((i % 7) - 3);
      std::vector<SpecialPair> pairs;
      for (const auto& [ij, weight] : excluded) pairs.push_back({ij.first, ij.second, weight, weight});
      const int m = static_cast<int>(x.cols());
      std::vector<std::int64_t> offsets(1, 0);
      std::vector<int> neighbors;
      const PairSet expected = all_pairs_within(x, box, w, excluded);
      auto next = expected.begin();
      for (int i = 0; i < m; ++i) {
        for (; next != expected.end() && next->first == i; ++next) neighbors.push_back(next->second);
        offsets.push_back(static_cast<std::int64_t>(neighbors.size()));
      }
      for (const int threads : {1, 2}) {
        set_max_threads(threads);
        NeighborList nl(cutoff, skin);
        if (!pairs.empty()) nl.set_exclusions(m, pairs);
        nl.build(x, box);
        const auto off = nl.offsets();
        const auto nb = nl.neighbors();
        EXPECT_TRUE(std::equal(off.begin(), off.end(), offsets.begin(), offsets.end()))
            << "row lengths, shape " << shape.lists.transpose() << ", layout " << layout << ", " << threads
            << " thread(s)";
        EXPECT_TRUE(std::equal(nb.begin(), nb.end(), neighbors.begin(), neighbors.end()))
            << "partners, shape " << shape.lists.transpose() << ", layout " << layout << ", " << threads
            << " thread(s)";
      }
      ++checked;
    }
  set_max_threads(restore);
}

// In a box a few list radii wide the pair loop rounds d/L instead of folding (NearestImage::rounded):
// the same separation, bit for bit, for every |d| < 1.5 L away from ±L/2 (and at ±0 and on an open
// axis), and at ±L/2 one at distance L/2, as the fold's.
TEST(NearestImage, RoundingGivesTheFoldsSeparation) {
  const double len = 27.371367;
  const Box box = periodic_box(Eigen::Vector3d(len, 80.0, 80.0));
  const NearestImage rounding(box, 12.0), folding(box);
  ASSERT_TRUE(rounding.rounded);
  ASSERT_FALSE(folding.rounded);
  ASSERT_FALSE(NearestImage(box, 2.0).rounded);  // data.chain's proportions
  std::vector<double> ds = {0.0, -0.0, 1.49 * len, -1.49 * len, 0.4999 * len, -0.5001 * len};
  std::mt19937 rng(41);
  std::uniform_real_distribution<double> u(-1.5 * len, 1.5 * len);
  for (int k = 0; k < 10000; ++k) ds.push_back(u(rng));
  auto bits = [](double v) {
    std::uint64_t b;
    std::memcpy(&b, &v, sizeof b);
    return b;
  };
  for (const double d : ds) {
    double rx = d, ry = 0.5 * d, rz = 0.0, fx = d, fy = 0.5 * d, fz = 0.0;
    rounding.apply(rx, ry, rz);
    folding.apply(fx, fy, fz);
    EXPECT_EQ(bits(rx), bits(fx)) << d;
    EXPECT_EQ(bits(ry), bits(fy)) << d;  // an open-like long axis: no fold either way
    EXPECT_EQ(bits(rz), bits(fz)) << d;
  }
  for (const double d : {0.5 * len, -0.5 * len, std::nextafter(0.5 * len, 0.0), std::nextafter(0.5 * len, len)}) {
    double rx = d, ry = 0.0, rz = 0.0;
    rounding.apply(rx, ry, rz);
    EXPECT_NEAR(std::abs(rx), 0.5 * len, 1e-12) << d;
  }
}

// BoxWrap::wrap_particles (four particles at a time where the CPU has AVX2) gives each coordinate
// as BoxWrap's one-coordinate form, bit for bit: positions in the box, images several boxes away,
// on faces and at ±0, a box with an open axis and an origin off zero, and block ends that cut the
// groups of four.
TEST(BoxWrap, WrapParticlesIsTheCoordinateWrapBitForBit) {
  Box box = periodic_box(Eigen::Vector3d(7.3, 5.1, 9.7), Eigen::Vector3d(-1.25, 0.5, 3.0));
  box.periodic[1] = 0;  // an open axis: its coordinates stay as they are
  const BoxWrap wrap(box);
  std::mt19937_64 rng(17);
  std::uniform_real_distribution<double> u(-40.0, 40.0);
  const int n = 1003;
  Eigen::Matrix3Xd x(3, n);
  for (Eigen::Index k = 0; k < x.size(); ++k) x.data()[k] = u(rng);
  const double special[] = {0.0, -0.0, -1.25, -1.25 + 7.3, 3.0, 3.0 + 9.7, -1.25 - 7.3, 1e-300, -1e-300};
  for (int k = 0; k < 9; ++k) x(0, k) = x(1, k) = x(2, k) = special[k];
  auto bits = [](double v) {
    std::uint64_t b;
    std::memcpy(&b, &v, sizeof b);
    return b;
  };
  for (const auto& [first, last] : {std::pair{0, n}, std::pair{1, 6}, std::pair{3, 3}, std::pair{5, 1002}}) {
    Eigen::Matrix3Xd out = Eigen::Matrix3Xd::Constant(3, n, 123.0);
    wrap.wrap_particles(x.data(), out.data(), first, last);
    for (int i = 0; i < n; ++i)
      for (int a = 0; a < 3; ++a) {
        const double want = i >= first && i < last ? wrap(x(a, i), a) : 123.0;
        ASSERT_EQ(bits(out(a, i)), bits(want)) << "particle " << i << " axis " << a << " of " << first << " … " << last;
      }
  }
}

TEST(NeighborList, RebuildsWhenSomeParticleMovedMoreThanTheSkinOrHalfOfItTooOften) {
  const Box box = periodic_box(Eigen::Vector3d::Constant(8.0));
  Eigen::Matrix3Xd x = random_in_box(300, box, 41);
  NeighborList nl(2.0, 0.4);
  EXPECT_TRUE(nl.update(x, box));
  EXPECT_FALSE(nl.update(x, box));
  x(1, 17) += 0.199;
  EXPECT_FALSE(nl.update(x, box)) << "0.199 < skin/2";
  x(1, 17) += 0.202;
  EXPECT_TRUE(nl.update(x, box)) << "0.401 > skin: rebuilt whatever the pairs";
  EXPECT_EQ(nl.rebuilds(), 2);
  // More than 1/256 of the particles past skin/2 (here all of them): rebuilt without the check.
  x.array() += 0.21;
  EXPECT_TRUE(nl.update(x, box));
  EXPECT_FALSE(nl.update(x, box));
  // A changed box (a barostat's cell move) keeps the list while it stays complete
  // (NeighborList::deformed_needs_rebuild): here the particles did not follow the box, so a
  // particle at x is U = |x|·(1 − μ) from its build position mapped into the new box.
  Box other = box;
  other.lengths.x() += 1e-9;
  EXPECT_FALSE(nl.update(x, other)) << "2U ≈ 2e-9 ≤ μ(cutoff + skin) − cutoff: kept";
  other.lengths.x() = 0.99 * box.lengths.x();
  EXPECT_FALSE(nl.update(x, other)) << "U ≤ 0.01 × 8 = 0.08, 2U ≤ 0.99 × 2.4 − 2 = 0.376: kept";
  other.lengths.x() = 0.9 * box.lengths.x();
  EXPECT_TRUE(nl.update(x, other)) << "U up to 0.1 × 8 = 0.8, 2U > 0.9 × 2.4 − 2 = 0.16: rebuilt";
  Box open_z = box;
  open_z.periodic.z() = 0;
  EXPECT_TRUE(nl.update(x, open_z)) << "other periodic axes: rebuilt";
}

// Past skin/2 and within the skin, the list is kept exactly while no unlisted pair is within the
// cutoff. A and B start 1.45 apart (beyond cutoff + skin = 1.4: not listed); 600 particles far
// away keep the fast ones at most 1/256 of all.
TEST(NeighborList, KeepsTheListWhileNoUnlistedPairIsWithinTheCutoff) {
  for (const bool periodic : {false, true}) {
    SCOPED_TRACE(periodic ? "periodic" : "open");
    const Box box = periodic ? periodic_box(Eigen::Vector3d::Constant(40.0), Eigen::Vector3d::Constant(-5.0)) : Box{};
    Eigen::Matrix3Xd x = Eigen::Matrix3Xd::Zero(3, 602);
    x.col(1) = Eigen::Vector3d(1.45, 0.0, 0.0);
    for (int k = 0; k < 600; ++k)
      x.col(2 + k) = Eigen::Vector3d(10.0 + 2.0 * (k % 10), 2.0 * (k / 10 % 10), 12.0 + 3.0 * (k / 100));
    NeighborList nl(1.0, 0.4);
    ASSERT_TRUE(nl.update(x, box));
    ASSERT_TRUE(listed_pairs(nl).empty() || !listed_pairs(nl).count({0, 1}));
    const Eigen::Matrix3Xd start = x;
    x(1, 0) += 0.3;  // A sideways: 1.48 from B
    EXPECT_FALSE(nl.update(x, box)) << "A moved 0.3 > skin/2, but nothing unlisted is within the cutoff";
    x = start;
    x(0, 0) += 0.3;  // A towards B: 1.15
    EXPECT_FALSE(nl.update(x, box));
    x(0, 1) -= 0.3;  // and B towards A: 0.85 < cutoff, not listed
    EXPECT_TRUE(nl.update(x, box));
    EXPECT_TRUE(listed_pairs(nl).count({0, 1}));
  }
}

// A displacement limit (a decomposed run's pair set: complete while no bead moved half the halo's
// margin) makes the list stale past it, where the fast particles' test alone would keep it; and a
// verdict given ahead (set_next_verdict, the ranks' agreed one) is what the next update does,
// once.
TEST(NeighborList, DisplacementLimitAndAGivenVerdict) {
  const Box box = periodic_box(Eigen::Vector3d::Constant(40.0), Eigen::Vector3d::Constant(-5.0));
  Eigen::Matrix3Xd x = Eigen::Matrix3Xd::Zero(3, 602);
  x.col(1) = Eigen::Vector3d(1.45, 0.0, 0.0);
  for (int k = 0; k < 600; ++k)
    x.col(2 + k) = Eigen::Vector3d(10.0 + 2.0 * (k % 10), 2.0 * (k / 10 % 10), 12.0 + 3.0 * (k / 100));
  NeighborList nl(1.0, 0.4);
  ASSERT_TRUE(nl.update(x, box));
  const Eigen::Matrix3Xd start = x;
  x(1, 0) += 0.3;  // A sideways: past skin/2, no unlisted pair within the cutoff
  EXPECT_FALSE(nl.needs_rebuild(x, box));
  nl.set_displacement_limit(0.29);
  EXPECT_TRUE(nl.needs_rebuild(x, box)) << "0.3 past the limit 0.29";
  nl.set_displacement_limit(0.31);
  EXPECT_FALSE(nl.needs_rebuild(x, box)) << "0.3 within the limit 0.31: the fast particles' test decides";
  nl.set_displacement_limit(0.1);
  x = start;
  x(1, 0) += 0.15;  // below skin/2, past the limit
  EXPECT_TRUE(nl.needs_rebuild(x, box)) << "a limit below skin/2 holds too";
  // The verdict given: the next update follows it, the one after tests again.
  const long rebuilds = nl.rebuilds();
  nl.set_next_verdict(false);
  EXPECT_FALSE(nl.update(x, box));
  EXPECT_EQ(nl.rebuilds(), rebuilds);
  EXPECT_TRUE(nl.update(x, box)) << "the given verdict holds for one update only";
  nl.set_next_verdict(true);
  EXPECT_TRUE(nl.update(x, box)) << "a rebuild asked for is made";
}

// Heterogeneous motion checked at every update against the all-pairs search: most particles creep,
// a few jump, and every fourth update an unlisted pair just beyond cutoff + skin is pulled
// together, each of its particles by 0.2 (> skin/2, < skin), to 0.4 closer: within the cutoff, so
// the list must be rebuilt or it would miss that pair. Every pair within the cutoff is listed
// after every update, and the list is rebuilt less often than the rule "any particle moved more
// than skin/2" would rebuild it. (A check that never finds a missing pair fails this test.)
TEST(NeighborList, FastParticlesNeverHideAPairWithinTheCutoff) {
  for (const bool periodic : {true, false}) {
    SCOPED_TRACE(periodic ? "periodic" : "open");
    const int n = 1000;
    const double side = std::cbrt(n / 0.85), cutoff = 1.12, skin = 0.3;
    const Box sampling = periodic_box(Eigen::Vector3d::Constant(side));
    const Box box = periodic ? sampling : Box{};
    Eigen::Matrix3Xd x = random_in_box(n, sampling, 71, 0.8);
    NeighborList nl(cutoff, skin);
    nl.update(x, box);
    Eigen::Matrix3Xd at_build = x;
    std::mt19937 rng(72);
    std::uniform_real_distribution<double> creep(-0.01, 0.01);
    std::uniform_int_distribution<int> pick(0, n - 1);
    std::normal_distribution<double> jump(0.0, 0.07);
    int classic = 0, pulled = 0;
    for (int s = 0; s < 120; ++s) {
      for (int i = 0; i < n; ++i)
        for (int a = 0; a < 3; ++a) x(a, i) += creep(rng);
      for (int k = 0; k < 2; ++k) {
        const int i = pick(rng);
        for (int a = 0; a < 3; ++a) x(a, i) += jump(rng);
      }
      if (s % 4 == 3) {  // an unlisted pair of slow particles just beyond the list radius, pulled together
        const PairSet listed = listed_pairs(nl);
        const Eigen::VectorXd moved = (x - nl.positions_at_build()).colwise().norm();
        for (const auto& [i, j] : all_pairs_within(x, box, cutoff + skin + 0.1)) {
          const Eigen::Vector3d d = separation(x, box, i, j);
          if (listed.count({i, j}) || d.norm() < cutoff + skin + 0.02 || moved[i] > 0.05 || moved[j] > 0.05) continue;
          x.col(i) -= 0.2 * d.normalized();
          x.col(j) += 0.2 * d.normalized();
          ++pulled;
          break;
        }
      }
      if ((x - at_build).colwise().norm().maxCoeff() > 0.5 * skin) {
        ++classic;
        at_build = x;
      }
      if (nl.update(x, box)) at_build = x;
      EXPECT_EQ(within(listed_pairs(nl), x, box, cutoff), all_pairs_within(x, box, cutoff)) << "update " << s;
    }
    EXPECT_GE(pulled, 20);
    RecordProperty(
        periodic ? "rebuilds_periodic" : "rebuilds_open",
        std::to_string(nl.rebuilds() - 1) + " (the skin/2 rule alone: about " + std::to_string(classic) + ")");
    EXPECT_LT(nl.rebuilds() - 1, classic) << "the check should keep the list longer than the skin/2 rule";
  }
}

TEST(NeighborList, RebuildReusesStorageOnceCapacityIsReached) {
  const Box box = periodic_box(Eigen::Vector3d::Constant(9.0));
  const Eigen::Matrix3Xd a = random_in_box(600, box, 51), b = random_in_box(600, box, 52);
  NeighborList nl(2.2, 0.3);
  nl.update(a, box);
  nl.update(b, box);
  const int* storage = nl.neighbors().data();
  const std::int64_t* offsets = nl.offsets().data();
  for (int k = 0; k < 6; ++k) {
    EXPECT_TRUE(nl.update(k % 2 ? b : a, box));
    EXPECT_EQ(nl.neighbors().data(), storage);
    EXPECT_EQ(nl.offsets().data(), offsets);
  }
}

TEST(NeighborList, BoxShorterThanTwiceCutoffPlusSkinIsRejected) {
  const double cutoff = 2.5, skin = 0.3;
  NeighborList nl(cutoff, skin);
  const Eigen::Matrix3Xd x = Eigen::Matrix3Xd::Zero(3, 4);
  Box box = periodic_box(Eigen::Vector3d(10.0, 2 * (cutoff + skin) - 0.01, 10.0));
  try {
    nl.update(x, box);
    FAIL() << "expected std::invalid_argument";
  } catch (const std::invalid_argument& e) {
    EXPECT_NE(std::string(e.what()).find("box length L < 2 × (cutoff + skin)"), std::string::npos) << e.what();
    EXPECT_NE(std::string(e.what()).find("axis y"), std::string::npos) << e.what();
  }
  box.lengths.y() = 2 * (cutoff + skin);  // exactly twice: the minimum image is unique within the radius
  EXPECT_NO_THROW(nl.update(x, box));
  box.periodic.y() = 0;  // an open axis has no such limit
  box.lengths.y() = 0.1;
  EXPECT_NO_THROW(nl.update(x, box));
}

// ---------------------------------------------------------------------------------------
// Forces through the list equal all pairs while the configuration evolves, with rebuilds
// happening when needed and not every step.

struct DriftCase {
  const char* name;
  bool periodic;
  SpecialWeights weights;
};

void PrintTo(const DriftCase& c, std::ostream* os) {
  *os << c.name;
}

class ListForcesVsAllPairs : public ::testing::TestWithParam<DriftCase> {};

TEST_P(ListForcesVsAllPairs, AfterManySmallRandomDisplacements) {
  const DriftCase c = GetParam();
  const int chains = 20, beads = 50, n = chains * beads;
  const double side = std::cbrt(n / 0.85);
  const Box sampling = periodic_box(Eigen::Vector3d::Constant(side));
  const Box box = c.periodic ? sampling : Box{};
  Eigen::Matrix3Xd x = random_chains(chains, beads, sampling, 0.97, 61, 0.8);
  const std::vector<int> types(n, 0);
  TypePairMatrix<LennardJones::Coeffs> coeffs(1);
  coeffs.set(0, 0, {1.0, 1.0, 2.5});
  const auto bonds = chain_bonds(chains, beads);
  const LennardJonesPair term("lj", Level::slow, types, coeffs, bonds, c.weights, box, 0.3);
  const WeightMap weights = chain_weights(chains, beads, c.weights);

  std::mt19937 rng(7);
  std::uniform_real_distribution<double> u(-0.015, 0.015);
  const int updates = 80;
  Eigen::Matrix3Xd f(3, n);
  for (int s = 0; s < updates; ++s) {
    for (int i = 0; i < n; ++i)
      for (int a = 0; a < 3; ++a) x(a, i) += u(rng);
    f.setZero();
    const double e = term.add_forces(x, box, f);
    if (s % 4 != 0 && s != updates - 1) continue;  // the O(N²) reference on every fourth step
    const AllPairs ref = all_pairs<LennardJones>(x, box, types, coeffs, weights);
    EXPECT_LT(max_abs(f - ref.f), 1e-12 * max_abs(ref.f)) << "update " << s;
    EXPECT_NEAR(e, ref.energy, 1e-12 * std::abs(ref.energy)) << "update " << s;
    if (s == updates - 1) {
      EXPECT_NEAR(term.virial(x, box), ref.virial, 1e-12 * std::abs(ref.virial));
    }
  }
  EXPECT_GT(term.rebuilds(), 1);
  EXPECT_LT(term.rebuilds(), updates / 2) << "the list is rebuilt when needed, not every step";
}

INSTANTIATE_TEST_SUITE_P(Chains, ListForcesVsAllPairs,
                         ::testing::Values(DriftCase{"periodic_fene_convention", true, {0.0, 1.0}},
                                           DriftCase{"periodic_scaled", true, {0.5, 0.25}},
                                           DriftCase{"open_all_pairs", false, {1.0, 1.0}},
                                           DriftCase{"open_w13_zero", false, {0.0, 0.0}}),
                         [](const auto& info) { return std::string(info.param.name); });

// ---------------------------------------------------------------------------------------
// Special bonds.

// Three beads, 0–1–2, bent so that the 1-3 distance is inside the cutoff.
Eigen::Matrix3Xd bent_trimer(double bond, double r13) {
  Eigen::Matrix3Xd x = Eigen::Matrix3Xd::Zero(3, 3);
  const double half = 0.5 * r13, height = std::sqrt(bond * bond - half * half);
  x.col(0) = Eigen::Vector3d(-half, 0, 0);
  x.col(1) = Eigen::Vector3d(0, height, 0);
  x.col(2) = Eigen::Vector3d(half, 0, 0);
  return x;
}

TEST(SpecialBonds, W12ZeroRemovesBondedPairs) {
  // Bonds at 0.6σ would repel with E ≈ 4(0.6⁻¹² − 0.6⁻⁶) ≈ 1800 each if they counted.
  const Eigen::Matrix3Xd x = bent_trimer(0.6, 1.05);
  const std::vector<Bond> bonds = {{0, 1, 0}, {1, 2, 0}};
  TypePairMatrix<WeeksChandlerAndersen::Coeffs> c(1);
  c.set(0, 0, {1.0, 1.0});
  const Box open;
  const WcaPair term("wca", Level::slow, {0, 0, 0}, c, bonds, {0.0, 1.0}, open);
  Eigen::Matrix3Xd f = Eigen::Matrix3Xd::Zero(3, 3);
  const double e = term.add_forces(x, open, f);
  const auto p = WeeksChandlerAndersen::params({1.0, 1.0});
  EXPECT_NEAR(e, kernel_energy<WeeksChandlerAndersen>(1.05, p), 1e-12);  // the 1-3 pair only
  EXPECT_EQ(f(0, 1), 0.0);                                               // the middle bead feels nothing
  EXPECT_EQ(f(1, 1), 0.0);
  EXPECT_EQ(term.excluded_pairs(), 2u);
  EXPECT_EQ(listed_pairs(term.neighbor_list()), (PairSet{{0, 2}}));
}

TEST(SpecialBonds, W13HalfHalvesTheOneThreeEnergy) {
  const Eigen::Matrix3Xd x = bent_trimer(0.97, 1.3);
  const std::vector<Bond> bonds = {{1, 0, 0}, {1, 2, 0}};  // either orientation
  TypePairMatrix<LennardJones::Coeffs> c(1);
  c.set(0, 0, {1.0, 1.0, 2.5});
  const Box open;
  auto energy = [&](SpecialWeights w) {
    const LennardJonesPair term("lj", Level::slow, {0, 0, 0}, c, bonds, w, open);
    Eigen::Matrix3Xd f = Eigen::Matrix3Xd::Zero(3, 3);
    return term.add_forces(x, open, f);
  };
  const double e13 = kernel_energy<LennardJones>(1.3, LennardJones::params({1.0, 1.0, 2.5}));
  ASSERT_GT(std::abs(e13), 0.1);
  EXPECT_NEAR(energy({0.0, 1.0}), e13, 1e-14);
  EXPECT_NEAR(energy({0.0, 0.5}), 0.5 * e13, 1e-14);
  EXPECT_NEAR(energy({0.0, 0.0}), 0.0, 1e-14);
  const double e12 = kernel_energy<LennardJones>(0.97, LennardJones::params({1.0, 1.0, 2.5}));
  EXPECT_NEAR(energy({0.25, 0.5}), 0.25 * 2 * e12 + 0.5 * e13, 1e-13);
  EXPECT_NEAR(energy({1.0, 1.0}), 2 * e12 + e13, 1e-13);

  // Scaled forces are the gradient of the scaled energy, and the scaled pair is not listed.
  const LennardJonesPair term("lj", Level::slow, {0, 0, 0}, c, bonds, {0.3, 0.5}, open);
  EXPECT_LT(fd_mismatch(term, x, open), 1e-6);
  EXPECT_EQ(term.scaled_pairs().size(), 3u);
  EXPECT_TRUE(listed_pairs(term.neighbor_list()).empty());
}

TEST(SpecialBonds, PairsFromBondsWithOneTwoPrecedence) {
  // A triangle 0–1–2–0 (every pair is both 1-2 and 1-3: 1-2 wins), a tail 2–3, a branch 1–4,
  // and a duplicated bond.
  const std::vector<Bond> bonds = {{0, 1, 0}, {1, 2, 0}, {2, 0, 0}, {2, 3, 0}, {1, 4, 0}, {3, 2, 0}};
  const auto sp = special_pairs(6, bonds, {0.0, 0.5});
  std::map<std::pair<int, int>, double> got;
  for (const SpecialPair& p : sp) {
    EXPECT_LT(p.i, p.j);
    EXPECT_TRUE(got.emplace(std::pair{p.i, p.j}, p.weight).second) << "duplicate pair";
  }
  const std::map<std::pair<int, int>, double> expected = {
      {{0, 1}, 0.0}, {{1, 2}, 0.0}, {{0, 2}, 0.0}, {{2, 3}, 0.0}, {{1, 4}, 0.0},  // 1-2
      {{0, 3}, 0.5}, {{1, 3}, 0.5}, {{0, 4}, 0.5}, {{2, 4}, 0.5}};                // 1-3
  EXPECT_EQ(got, expected);
  // w12 = 1 leaves bonded pairs ordinary even where they are also 1-3 (the triangle).
  const auto sp1 = special_pairs(6, bonds, {1.0, 0.0});
  for (const SpecialPair& p : sp1) {
    EXPECT_FALSE((p.i == 0 && p.j == 2)) << "bonded pair scaled as 1-3";
    EXPECT_EQ(p.weight, 0.0);
  }
  EXPECT_EQ(sp1.size(), 4u);
  EXPECT_THROW(special_pairs(3, {{0, 3, 0}}, {}), std::invalid_argument);
  EXPECT_THROW(special_pairs(3, {{1, 1, 0}}, {}), std::invalid_argument);
}

// 1-4 pairs (the ends of each dihedral) take w14 unless they are also closer: a chain 0–1–2–3–4
// and a 4-ring 5–6–7–8–5, where every 1-4 relation is also 1-2 (the closing bond).
TEST(SpecialBonds, OneFourPairsTakeTheirWeight) {
  const std::vector<Bond> bonds = {{0, 1, 0}, {1, 2, 0}, {2, 3, 0}, {3, 4, 0},
                                   {5, 6, 0}, {6, 7, 0}, {7, 8, 0}, {8, 5, 0}};
  std::map<std::pair<int, int>, double> got;
  for (const SpecialPair& p : special_pairs(9, bonds, {0.0, 0.0, 0.5})) got[{p.i, p.j}] = p.weight;
  const std::map<std::pair<int, int>, double> expected = {
      {{0, 1}, 0.0}, {{1, 2}, 0.0}, {{2, 3}, 0.0}, {{3, 4}, 0.0}, {{0, 2}, 0.0}, {{1, 3}, 0.0},
      {{2, 4}, 0.0}, {{0, 3}, 0.5}, {{1, 4}, 0.5},                                                // 1-4 along the chain
      {{5, 6}, 0.0}, {{6, 7}, 0.0}, {{7, 8}, 0.0}, {{5, 8}, 0.0}, {{5, 7}, 0.0}, {{6, 8}, 0.0}};  // the ring
  EXPECT_EQ(got, expected);
  // w14 = 1 (the default) lists no 1-4 pair: the result is the two-weight one.
  EXPECT_EQ(special_pairs(9, bonds, {0.0, 0.5, 1.0}).size(), special_pairs(9, bonds, {0.0, 0.5}).size());
}

TEST(SpecialBonds, ChainsInAPeriodicBoxMatchAllPairs) {
  const int chains = 8, beads = 25, n = chains * beads;
  const Box box = periodic_box(Eigen::Vector3d::Constant(std::cbrt(n / 0.6)));
  const Eigen::Matrix3Xd x = random_chains(chains, beads, box, 0.97, 71, 0.8);
  const std::vector<int> types(n, 0);
  TypePairMatrix<WeeksChandlerAndersen::Coeffs> c(1);
  c.set(0, 0, {1.0, 1.0});
  for (const SpecialWeights w : {SpecialWeights{0.0, 1.0}, SpecialWeights{0.0, 0.5}, SpecialWeights{0.5, 0.0}}) {
    const WcaPair term("wca", Level::slow, types, c, chain_bonds(chains, beads), w, box);
    Eigen::Matrix3Xd f = Eigen::Matrix3Xd::Zero(3, n);
    const double e = term.add_forces(x, box, f);
    const AllPairs ref = all_pairs<WeeksChandlerAndersen>(x, box, types, c, chain_weights(chains, beads, w));
    EXPECT_NEAR(e, ref.energy, 1e-12 * std::abs(ref.energy));
    EXPECT_LT(max_abs(f - ref.f), 1e-12 * max_abs(ref.f));
    // No pair with weight ≠ 1 is in the Verlet list.
    for (const auto& pr : listed_pairs(term.neighbor_list()))
      EXPECT_FALSE(chain_weights(chains, beads, w).count(pr)) << pr.first << "–" << pr.second;
  }
}

// ---------------------------------------------------------------------------------------
// Validation.

template <class F>
void expect_invalid(F make, const std::string& fragment) {
  try {
    make();
    ADD_FAILURE() << "expected std::invalid_argument mentioning '" << fragment << "'";
  } catch (const std::invalid_argument& e) {
    EXPECT_NE(std::string(e.what()).find(fragment), std::string::npos) << e.what();
  }
}

TEST(PairTermValidation, RejectsBadCoefficientsWeightsTypesAndBonds) {
  const Box open;
  auto lj = [&](LennardJones::Coeffs c, std::vector<int> types = {0, 0}, SpecialWeights w = {},
                std::vector<Bond> b = {}, double skin = 0.3) {
    TypePairMatrix<LennardJones::Coeffs> m(1);
    m.set(0, 0, c);
    return LennardJonesPair("lj-term", Level::slow, types, m, b, w, open, skin);
  };
  expect_invalid([&] { lj({-1.0, 1.0, 2.5}); }, "epsilon");
  expect_invalid([&] { lj({1.0, 0.0, 2.5}); }, "sigma");
  expect_invalid([&] { lj({1.0, 1.0, 0.0}); }, "cutoff rc");
  expect_invalid([&] { lj({1.0, 1.0, NAN}); }, "cutoff rc");
  expect_invalid([&] { lj({1.0, 1.0, 2.5}, {0, 1}); }, "particle 1 has type 1");
  expect_invalid([&] { lj({1.0, 1.0, 2.5}, {0, -1}); }, "type -1");
  expect_invalid([&] { lj({1.0, 1.0, 2.5}, {0, 0}, {-0.1, 1.0}); }, "w12");
  expect_invalid([&] { lj({1.0, 1.0, 2.5}, {0, 0}, {0.0, 1.5}); }, "w13");
  expect_invalid([&] { lj({1.0, 1.0, 2.5}, {0, 0}, {NAN, 1.0}); }, "w12");
  expect_invalid([&] { lj({1.0, 1.0, 2.5}, {0, 0}, {}, {{0, 2, 0}}); }, "bond (0, 2)");
  expect_invalid([&] { lj({1.0, 1.0, 2.5}, {0, 0}, {}, {}, -0.1); }, "skin");
  expect_invalid([&] { lj({-1.0, 1.0, 2.5}); }, "pair term 'lj-term' (lj)");
  EXPECT_NO_THROW(lj({0.0, 1.0, 2.5}));  // ε = 0: a type pair that does not interact

  TypePairMatrix<WeeksChandlerAndersen::Coeffs> partial(2);
  partial.set(0, 0, {1.0, 1.0});
  partial.set(1, 1, {1.0, 1.0});
  expect_invalid(
      [&] {
        WcaPair("w", Level::slow, {0, 1}, partial, {}, {}, open);
      },
      "types (0, 1): pair coefficients not given");
  TypePairMatrix<WeeksChandlerAndersen::Coeffs> bad_sigma(1);
  bad_sigma.set(0, 0, {1.0, -1.0});
  expect_invalid([&] { WcaPair("w", Level::slow, {0}, bad_sigma, {}, {}, open); }, "sigma");
  TypePairMatrix<SoftCosine::Coeffs> bad_a(1);
  bad_a.set(0, 0, {-1.0, 1.0});
  expect_invalid([&] { SoftPair("s", Level::slow, {0}, bad_a, {}, {}, open); }, "prefactor A");
}

TEST(PairTermValidation, BoxTooSmallThrows) {
  TypePairMatrix<LennardJones::Coeffs> c(1);
  c.set(0, 0, {1.0, 1.0, 2.5});
  const Box small = periodic_box(Eigen::Vector3d(5.5, 8.0, 8.0));  // < 2 × (2.5 + 0.3) = 5.6
  expect_invalid(
      [&] {
        LennardJonesPair("lj", Level::slow, {0, 0}, c, {}, {}, small);
      },
      "box length L < 2 × (cutoff + skin)");
  // A smaller skin fits the same box.
  EXPECT_NO_THROW(LennardJonesPair("lj", Level::slow, {0, 0}, c, {}, {}, small, 0.2));
  // A box that shrinks later is caught when the forces are asked for.
  const Box big = periodic_box(Eigen::Vector3d::Constant(8.0));
  const LennardJonesPair term("lj", Level::slow, {0, 0}, c, {}, {}, big);
  Eigen::Matrix3Xd x = Eigen::Matrix3Xd::Zero(3, 2), f = x;
  x(0, 1) = 1.0;
  EXPECT_NO_THROW(term.add_forces(x, big, f));
  EXPECT_THROW(term.add_forces(x, small, f), std::invalid_argument);
}

TEST(PairTermValidation, DescribeNamesStyleCutoffSkinAndRebuilds) {
  TypePairMatrix<WeeksChandlerAndersen::Coeffs> c(1);
  c.set(0, 0, {1.0, 1.0});
  const Box box = periodic_box(Eigen::Vector3d::Constant(6.0));
  const WcaPair term("wca", Level::slow, std::vector<int>(50, 0), c, {}, {}, box, 0.4);
  EXPECT_EQ(term.style(), "wca");
  EXPECT_NEAR(term.cutoff(), std::pow(2.0, 1.0 / 6.0), 1e-15);
  EXPECT_EQ(term.rebuilds(), 0);
  Eigen::Matrix3Xd x = random_in_box(50, box, 81), f = Eigen::Matrix3Xd::Zero(3, 50);
  term.add_forces(x, box, f);
  term.add_forces(x, box, f);
  EXPECT_EQ(term.rebuilds(), 1);
  const std::string d = term.describe();
  for (const char* fragment : {"wca", "cutoff 1.12246", "skin 0.4", "1 neighbour-list rebuilds"})
    EXPECT_NE(d.find(fragment), std::string::npos) << d;
  // The wrong number of particles is an error, not a silent out-of-bounds read or write.
  Eigen::Matrix3Xd x3 = Eigen::Matrix3Xd::Zero(3, 3), f3 = x3;
  EXPECT_THROW(term.add_forces(x3, box, f3), std::invalid_argument);
  EXPECT_THROW(term.add_forces(x, box, f3), std::invalid_argument);
}

TEST(PairTermValidation, NoParticlesAndOneParticle) {
  TypePairMatrix<LennardJones::Coeffs> c(1);
  c.set(0, 0, {1.0, 1.0, 2.5});
  for (const Box& box : {Box{}, periodic_box(Eigen::Vector3d::Constant(6.0))})
    for (const int n : {0, 1}) {
      const LennardJonesPair term("lj", Level::slow, std::vector<int>(n, 0), c, {}, {}, box);
      Eigen::Matrix3Xd x = Eigen::Matrix3Xd::Constant(3, n, 0.5), f = Eigen::Matrix3Xd::Zero(3, n);
      EXPECT_EQ(term.add_forces(x, box, f), 0.0);
      EXPECT_EQ(term.virial(x, box), 0.0);
      EXPECT_EQ(term.neighbor_list().num_pairs(), 0u);
    }
}

}  // namespace
}  // namespace stiffmd
