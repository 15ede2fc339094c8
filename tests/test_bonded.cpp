// Soft bonded and external terms (FENE, angles, tether, 9-3 wall) against energies computed here
// by hand, brute-force virials, the singular geometries and their failure modes (docs/design.md §11.8a).
// The checks every bond and angle kernel passes (−∇E open and periodic, Newton's third law) are
// the typed suites of test_bonded_kernels.cpp.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <numbers>
#include <random>
#include <string>

#include "core/errors.hpp"
#include "engine/scene/whole_molecules.hpp"
#include "forcefields/angle_terms.hpp"
#include "forcefields/bond_term.hpp"
#include "forcefields/external_terms.hpp"

namespace stiffmd {
namespace {

using Eigen::Matrix3Xd;
using Eigen::Vector3d;
constexpr double kPi = std::numbers::pi;

Matrix3Xd zeros_like(const Matrix3Xd& x) {
  return Matrix3Xd::Zero(3, x.cols());
}

double energy(const ForceTerm& term, const Matrix3Xd& x, const Box& box) {
  Matrix3Xd f = zeros_like(x);
  return term.add_forces(x, box, f);
}

Matrix3Xd forces(const ForceTerm& term, const Matrix3Xd& x, const Box& box) {
  Matrix3Xd f = zeros_like(x);
  term.add_forces(x, box, f);
  return f;
}

// Max over all coordinates of |f − (−∂E/∂x)| by central differences with step d, relative to
// max(1, max |f|). Recorded as a test property (see --gtest_output) so the errors can be quoted.
double fd_error(const ForceTerm& term, const Matrix3Xd& x, const Box& box, double d = 1e-6) {
  const Matrix3Xd f = forces(term, x, box);
  EXPECT_TRUE(f.allFinite()) << term.describe();
  double worst = 0.0;
  for (int i = 0; i < x.cols(); ++i)
    for (int a = 0; a < 3; ++a) {
      Matrix3Xd xp = x, xm = x;
      xp(a, i) += d;
      xm(a, i) -= d;
      const double fd = -(energy(term, xp, box) - energy(term, xm, box)) / (2 * d);
      worst = std::max(worst, std::abs(fd - f(a, i)));
    }
  const double err = worst / std::max(1.0, f.cwiseAbs().maxCoeff());
  static int n = 0;
  char buf[32];
  std::snprintf(buf, sizeof buf, "%.3e", err);
  testing::Test::RecordProperty("fd_error_" + std::to_string(n++), buf);
  return err;
}

Vector3d random_unit(std::mt19937& rng) {
  std::normal_distribution<double> g;
  Vector3d u(g(rng), g(rng), g(rng));
  return u.normalized();
}

// A random walk with step lengths in [lo, hi]: every consecutive pair is a valid FENE bond.
Matrix3Xd random_chain(int n, double lo, double hi, unsigned seed, Vector3d start = Vector3d::Zero()) {
  std::mt19937 rng(seed);
  std::uniform_real_distribution<double> len(lo, hi);
  Matrix3Xd x(3, n);
  x.col(0) = start;
  for (int i = 1; i < n; ++i) x.col(i) = x.col(i - 1) + len(rng) * random_unit(rng);
  return x;
}

Box periodic_box() {
  Box box;
  box.periodic = Eigen::Vector3i::Ones();
  box.lengths = Vector3d(3.0, 3.5, 4.0);
  box.origin = Vector3d(-1.5, -1.75, -2.0);
  return box;
}

// Positions folded into the primary cell: bonds and angles that cross a face now straddle it.
Matrix3Xd wrapped(Matrix3Xd x, const Box& box) {
  for (int i = 0; i < x.cols(); ++i)
    for (int a = 0; a < 3; ++a) x(a, i) -= box.lengths[a] * std::floor((x(a, i) - box.origin[a]) / box.lengths[a]);
  return x;
}

std::vector<Bond> chain_bond_list(int n, int num_types) {
  std::vector<Bond> b;
  for (int i = 0; i + 1 < n; ++i) b.push_back({i, i + 1, i % num_types});
  return b;
}

std::vector<Angle> chain_angle_list(int n, int num_types) {
  std::vector<Angle> a;
  for (int i = 0; i + 2 < n; ++i) a.push_back({i, i + 1, i + 2, i % num_types});
  return a;
}

const std::vector<FeneCoeffs> kFeneTypes = {{30.0, 1.5, 1.0, 1.0}, {20.0, 1.6, 0.5, 0.9}};

Matrix3Xd two_particles(double r) {
  Matrix3Xd x = Matrix3Xd::Zero(3, 2);
  x(0, 1) = r;
  return x;
}

// Three particles with arms of lengths la, lb at angle theta, vertex at the origin.
Matrix3Xd angle_geometry(double theta, double la = 1.0, double lb = 1.3) {
  Matrix3Xd x = Matrix3Xd::Zero(3, 3);
  x.col(0) = la * Vector3d(1, 0, 0);
  x.col(2) = lb * Vector3d(std::cos(theta), std::sin(theta), 0);
  return x;
}

// ---------------------------------------------------------------------------------------- FENE

std::vector<std::pair<int, int>> pairs(const std::vector<Bond>& bonds) {
  std::vector<std::pair<int, int>> p;
  for (const Bond& b : bonds) p.emplace_back(b.i, b.j);
  return p;
}

TEST(FeneBond, EnergyAndForceAtHandComputedLengths) {
  const FeneBond term("fene", Level::slow, {{0, 1, 0}}, {{30.0, 1.5, 1.0, 1.0}});
  // r = 0.97 < 2^{1/6}: FENE plus the WCA core. 20.24159000794699744 is the same sum in 30-digit
  // arithmetic (mpmath); the std::pow form below is computed independently of the kernel.
  const double r = 0.97;
  const double fene = -0.5 * 30.0 * 1.5 * 1.5 * std::log(1.0 - (r / 1.5) * (r / 1.5));
  const double wca = 4.0 * (std::pow(1.0 / r, 12) - std::pow(1.0 / r, 6)) + 1.0;
  Matrix3Xd f = Matrix3Xd::Zero(3, 2);
  const double e = term.add_forces(two_particles(r), Box{}, f);
  EXPECT_NEAR(e, fene + wca, 1e-12);
  EXPECT_NEAR(e, 20.24159000794699744, 1e-12);
  // dE/dr = K r/(1 − (r/R0)²) − 24/r [2 (1/r)¹² − (1/r)⁶] = 8.39931259245631823 (mpmath):
  // particle 1, at +r, is pulled back towards particle 0.
  EXPECT_NEAR(f(0, 1), -8.39931259245631823, 1e-11);
  EXPECT_NEAR(f(0, 0), 8.39931259245631823, 1e-11);

  // σ < r < 2^{1/6} σ: the core still acts (its cutoff is the LJ minimum, not σ).
  const double r2 = 1.05;
  EXPECT_NEAR(energy(term, two_particles(r2), Box{}),
              -0.5 * 30.0 * 2.25 * std::log(1.0 - r2 * r2 / 2.25) + 4.0 * (std::pow(r2, -12) - std::pow(r2, -6)) + 1.0,
              1e-12);
  // Beyond the WCA cutoff only the FENE part remains.
  EXPECT_NEAR(energy(term, two_particles(1.2), Box{}), -0.5 * 30.0 * 2.25 * std::log(1.0 - 1.44 / 2.25), 1e-12);
  // epsilon = 0 disables the core.
  const FeneBond bare("fene", Level::slow, {{0, 1, 0}}, {{30.0, 1.5, 0.0, 1.0}});
  EXPECT_NEAR(energy(bare, two_particles(r), Box{}), fene, 1e-12);
  // The shifted WCA core vanishes continuously at r_c = 2^{1/6} σ.
  const double rc = std::pow(2.0, 1.0 / 6.0);
  EXPECT_NEAR(energy(term, two_particles(rc - 1e-7), Box{}) - energy(bare, two_particles(rc - 1e-7), Box{}), 0.0,
              1e-12);
  EXPECT_EQ(energy(term, two_particles(rc + 1e-7), Box{}), energy(bare, two_particles(rc + 1e-7), Box{}));
}

TEST(FeneBond, VirialMatchesBruteForce) {
  const Box box = periodic_box();
  const std::vector<Bond> bonds = chain_bond_list(12, 2);
  const FeneBond term("fene", Level::slow, bonds, kFeneTypes);
  const Matrix3Xd x = random_chain(12, 0.8, 1.35, 21, Vector3d(1.2, 1.5, 1.8));
  Matrix3Xd xw = wrapped(x, box);
  ASSERT_FALSE(make_molecules_whole(xw, pairs(bonds), box));
  // Definition: Σ_b r_ij · f_i^(b), r_ij = x_i − x_j (the bond vector), f^(b) from that bond alone.
  double w = 0.0;
  for (const Bond& b : bonds) {
    const FeneBond one("one", Level::slow, {{b.i, b.j, b.type}}, kFeneTypes);
    w += bond_vector(xw, b.i, b.j).dot(forces(one, xw, box).col(b.i));
  }
  EXPECT_NEAR(term.virial(xw, box), w, 1e-10 * std::abs(w));
  // And the virial theorem's form: W = −dE(λx)/dλ at λ = 1 (open box, unwrapped chain).
  const double d = 1e-6;
  const double dilation = -(energy(term, (1 + d) * x, Box{}) - energy(term, (1 - d) * x, Box{})) / (2 * d);
  EXPECT_NEAR(term.virial(x, Box{}), dilation, 1e-6 * std::max(1.0, std::abs(dilation)));
}

TEST(FeneBond, OverstretchedBondThrowsNumericalErrorNamingTheBond) {
  const FeneBond term("chain", Level::slow, chain_bond_list(4, 1), {{30.0, 1.5, 1.0, 1.0}});
  Matrix3Xd x = Matrix3Xd::Zero(3, 4);
  x.row(0) << 0.0, 0.97, 1.94, 3.54;  // bond 2–3 stretched to 1.6 > R0
  Matrix3Xd f = zeros_like(x);
  try {
    term.add_forces(x, Box{}, f);
    FAIL() << "no NumericalError";
  } catch (const NumericalError& e) {
    const std::string msg = e.what();
    EXPECT_NE(msg.find("particles 2 and 3"), std::string::npos) << msg;
    EXPECT_NE(msg.find("r = 1.6"), std::string::npos) << msg;
    EXPECT_NE(msg.find("chain"), std::string::npos) << msg;
  }
  EXPECT_THROW(term.virial(x, Box{}), NumericalError);
  x(0, 3) = 1.94 + 1.5;  // exactly R0: the energy is already infinite
  EXPECT_THROW(energy(term, x, Box{}), NumericalError);
  x(0, 3) = 1.94;  // coincident particles: no direction for the force
  EXPECT_THROW(energy(term, x, Box{}), NumericalError);
  // Across a periodic face, once made whole: 1.49 is fine, the same pair at 1.51 is not.
  Box box;
  box.periodic = Eigen::Vector3i(1, 0, 0);
  box.lengths = Vector3d(10.0, 0.0, 0.0);
  const FeneBond pair("pair", Level::slow, {{0, 1, 0}}, {{30.0, 1.5, 0.0, 1.0}});
  for (const auto& [gap, ok] : {std::pair{1.49, true}, std::pair{1.51, false}}) {
    Matrix3Xd p = two_particles(10.0 - gap);
    ASSERT_FALSE(make_molecules_whole(p, {{0, 1}}, box));
    if (ok)
      EXPECT_NO_THROW(energy(pair, p, box));
    else
      EXPECT_THROW(energy(pair, p, box), NumericalError);
  }
}

TEST(FeneBond, RejectsInvalidParameters) {
  const std::vector<Bond> one = {{0, 1, 0}};
  EXPECT_THROW(FeneBond("f", Level::slow, one, {{-1.0, 1.5, 1.0, 1.0}}), std::invalid_argument);   // K < 0
  EXPECT_THROW(FeneBond("f", Level::slow, one, {{30.0, 0.0, 1.0, 1.0}}), std::invalid_argument);   // R0 = 0
  EXPECT_THROW(FeneBond("f", Level::slow, one, {{30.0, 1.5, -1.0, 1.0}}), std::invalid_argument);  // ε < 0
  EXPECT_THROW(FeneBond("f", Level::slow, one, {{30.0, 1.5, 1.0, 0.0}}), std::invalid_argument);   // σ = 0
  EXPECT_THROW(FeneBond("f", Level::slow, one, {{NAN, 1.5, 1.0, 1.0}}), std::invalid_argument);
  EXPECT_NO_THROW(FeneBond("f", Level::slow, one, {{30.0, 1.5, 0.0, 0.0}}));  // no core, σ unused
  EXPECT_THROW(FeneBond("f", Level::slow, {{1, 1, 0}}, kFeneTypes), std::invalid_argument);
  EXPECT_THROW(FeneBond("f", Level::slow, {{-1, 1, 0}}, kFeneTypes), std::invalid_argument);
  EXPECT_THROW(FeneBond("f", Level::slow, {{0, 1, 2}}, kFeneTypes), std::invalid_argument);  // 2 types
  try {
    FeneBond("named", Level::slow, one, {{30.0, -2.0, 1.0, 1.0}});
  } catch (const std::invalid_argument& e) {
    EXPECT_NE(std::string(e.what()).find("R0"), std::string::npos) << e.what();
    EXPECT_NE(std::string(e.what()).find("named"), std::string::npos) << e.what();
  }
}

// -------------------------------------------------------------------------------------- angles

TEST(AngleTerms, EnergiesAtHandComputedGeometries) {
  const double k = 3.0;
  for (const double theta : {kPi / 2, kPi / 3, 2.5, kPi}) {
    const Matrix3Xd x = angle_geometry(theta);
    const HarmonicAngle h("h", Level::slow, {{0, 1, 2, 0}}, {{k, 2.0}});
    EXPECT_NEAR(energy(h, x, Box{}), 0.5 * k * (theta - 2.0) * (theta - 2.0), 1e-12) << theta;
    // θ₀ = π is LAMMPS's angle_style cosine, E = K (1 + cos θ).
    const CosineAngle c("c", Level::slow, {{0, 1, 2, 0}}, {{k, kPi}});
    EXPECT_NEAR(energy(c, x, Box{}), k * (1.0 + std::cos(theta)), 1e-12) << theta;
    const CosineAngle c1("c", Level::slow, {{0, 1, 2, 0}}, {{k, 1.9}});
    EXPECT_NEAR(energy(c1, x, Box{}), k * (1.0 - std::cos(theta - 1.9)), 1e-12) << theta;
  }
  // Right angle, θ₀ = 2π/3: E = ½ k (π/6)², and f = −E'(θ) ∇θ = k (π/6) ∇θ opens the angle.
  // Moving i (on x̂) towards k (on ŷ) closes it: ∂θ/∂x_i = −ŷ/|a|; likewise ∂θ/∂x_k = −x̂/|b|.
  const HarmonicAngle h("h", Level::slow, {{0, 1, 2, 0}}, {{k, 2 * kPi / 3}});
  Matrix3Xd f = Matrix3Xd::Zero(3, 3);
  const double e = h.add_forces(angle_geometry(kPi / 2, 2.0, 1.0), Box{}, f);
  EXPECT_NEAR(e, 0.5 * k * (kPi / 6) * (kPi / 6), 1e-12);
  EXPECT_NEAR(f(1, 0), -k * (kPi / 6) / 2.0, 1e-12);
  EXPECT_NEAR(f(0, 2), -k * (kPi / 6) / 1.0, 1e-12);
  EXPECT_NEAR(f(0, 0), 0.0, 1e-12);
}

// The straight chain, θ = π exactly. The arms are along x, so a × b = 0 exactly.
TEST(AngleTerms, ExactlyStraightGivesFiniteForcesMatchingFiniteDifferences) {
  Matrix3Xd xs = Matrix3Xd::Zero(3, 3);  // not angle_geometry(π): sin(π) ≠ 0 in floating point
  xs(0, 0) = 1.1;
  xs(0, 2) = -0.9;
  for (const double theta0 : {kPi, 2.0}) {
    const HarmonicAngle h("h", Level::slow, {{0, 1, 2, 0}}, {{3.0, theta0}});
    const CosineAngle c("c", Level::slow, {{0, 1, 2, 0}}, {{3.0, theta0}});
    for (const ForceTerm* t : {static_cast<const ForceTerm*>(&h), static_cast<const ForceTerm*>(&c)}) {
      Matrix3Xd f = Matrix3Xd::Zero(3, 3);
      const double e = t->add_forces(xs, Box{}, f);
      EXPECT_TRUE(std::isfinite(e));
      EXPECT_TRUE(f.allFinite());
      EXPECT_EQ(f.cwiseAbs().maxCoeff(), 0.0);  // a ridge (θ₀ < π) or a minimum (θ₀ = π): symmetric
      EXPECT_LT(fd_error(*t, xs, Box{}), 1e-9) << t->describe();
    }
  }
  // A straight chain in a generic direction: a × b is round-off, not 0. The θ₀ = π terms are
  // smooth there and must give (almost) zero, finite forces, not 0/0.
  std::mt19937 rng(3);
  for (int rep = 0; rep < 5; ++rep) {
    const Vector3d u = random_unit(rng), o(0.3, -0.2, 0.7);
    Matrix3Xd xl(3, 4);
    xl << o - 1.1 * u, o, o + 0.9 * u, o + 1.7 * u;
    const HarmonicAngle h("h", Level::slow, chain_angle_list(4, 1), {{3.0, kPi}});
    const CosineAngle c("c", Level::slow, chain_angle_list(4, 1), {{3.0, kPi}});
    for (const ForceTerm* t : {static_cast<const ForceTerm*>(&h), static_cast<const ForceTerm*>(&c)}) {
      const Matrix3Xd f = forces(*t, xl, Box{});
      EXPECT_TRUE(f.allFinite());
      EXPECT_LT(f.cwiseAbs().maxCoeff(), 1e-12);
      EXPECT_LT(fd_error(*t, xl, Box{}), 1e-9);
    }
  }
}

TEST(AngleTerms, NearlyStraightMatchesFiniteDifferences) {
  for (const double bend : {1e-7, 1e-5, 1e-3, 1e-1}) {
    const Matrix3Xd x = angle_geometry(kPi - bend, 1.1, 0.9);
    const HarmonicAngle h("h", Level::slow, {{0, 1, 2, 0}}, {{3.0, kPi}});
    const CosineAngle c("c", Level::slow, {{0, 1, 2, 0}}, {{3.0, kPi}});
    EXPECT_LT(fd_error(h, x, Box{}), 1e-8) << bend;
    EXPECT_LT(fd_error(c, x, Box{}), 1e-8) << bend;
    // The restoring force has the size k·bend/|a|, not k·bend·(something/sin θ).
    EXPECT_NEAR(forces(h, x, Box{}).col(0).norm(), 3.0 * bend / 1.1, 1e-6 * 3.0 * bend);
  }
  // θ₀ < π: a cone at θ = π, smooth at any bend ≫ the FD step.
  const HarmonicAngle h2("h", Level::slow, {{0, 1, 2, 0}}, {{3.0, 2.0}});
  const CosineAngle c2("c", Level::slow, {{0, 1, 2, 0}}, {{3.0, 2.0}});
  for (const double bend : {1e-2, 1e-1}) {
    EXPECT_LT(fd_error(h2, angle_geometry(kPi - bend, 1.1, 0.9), Box{}, 1e-7), 1e-6) << bend;
    EXPECT_LT(fd_error(c2, angle_geometry(kPi - bend, 1.1, 0.9), Box{}, 1e-7), 1e-6) << bend;
  }
}

TEST(AngleTerms, NearZeroAngleMatchesFiniteDifferences) {
  const HarmonicAngle h0("h", Level::slow, {{0, 1, 2, 0}}, {{3.0, 0.0}});
  const HarmonicAngle h1("h", Level::slow, {{0, 1, 2, 0}}, {{3.0, 1.0}});
  const CosineAngle c1("c", Level::slow, {{0, 1, 2, 0}}, {{3.0, 0.5}});
  // θ = 0 exactly: i and k on the same ray from j.
  const Matrix3Xd x0 = angle_geometry(0.0, 1.1, 0.6);
  for (const ForceTerm* t :
       {static_cast<const ForceTerm*>(&h0), static_cast<const ForceTerm*>(&h1), static_cast<const ForceTerm*>(&c1)}) {
    EXPECT_TRUE(forces(*t, x0, Box{}).allFinite());
    EXPECT_LT(fd_error(*t, x0, Box{}), 1e-9);
  }
  EXPECT_NEAR(energy(h1, x0, Box{}), 1.5, 1e-15);
  for (const double theta : {1e-7, 1e-4, 1e-2}) EXPECT_LT(fd_error(h0, angle_geometry(theta, 1.1, 0.6), Box{}), 1e-8);
  EXPECT_LT(fd_error(h1, angle_geometry(1e-2, 1.1, 0.6), Box{}, 1e-7), 1e-6);
  EXPECT_LT(fd_error(c1, angle_geometry(1e-2, 1.1, 0.6), Box{}, 1e-7), 1e-6);
}

// acos(cos(π − 10⁻⁸)) = π exactly (the cosine rounds to −1); the energy must still see the bend.
TEST(AngleTerms, EnergyIsAccurateNearPiAndZero) {
  const HarmonicAngle h("h", Level::slow, {{0, 1, 2, 0}}, {{2.0, kPi}});
  Matrix3Xd x = Matrix3Xd::Zero(3, 3);
  x(0, 0) = -1.0;
  x(0, 2) = 1.0;
  x(1, 2) = 1e-8;  // θ = π − atan(10⁻⁸)
  EXPECT_NEAR(energy(h, x, Box{}), 1e-16, 1e-22);
  const HarmonicAngle h0("h", Level::slow, {{0, 1, 2, 0}}, {{2.0, 0.0}});
  x(0, 0) = 1.0;
  EXPECT_NEAR(energy(h0, x, Box{}), 1e-16, 1e-22);
}

TEST(AngleTerms, VirialMatchesBruteForce) {
  const Box box = periodic_box();
  const std::vector<AngleCoeffs> types = {{2.0, 1.9}, {5.0, kPi}};
  const std::vector<Angle> angles = chain_angle_list(12, 2);
  const HarmonicAngle h("h", Level::slow, angles, types);
  const CosineAngle c("c", Level::slow, angles, types);
  const Matrix3Xd x = random_chain(12, 0.7, 1.3, 41, Vector3d(1.2, 1.5, 1.8));
  // The chain reaches the term whole (unwrapped, ARCHITECTURE.md), reaching past the cell.
  const Matrix3Xd xw = x;
  ASSERT_GT((wrapped(x, box) - x).cwiseAbs().maxCoeff(), 0.0);
  // Definition: per angle, Σ_a r_a · f_a over its three atoms with r relative to the vertex
  // (r_j = 0), f from that angle alone. Each is 0 analytically (E(λx) = E(x)), so
  // compare with the scale of the individual terms |r_a||f_a|.
  double w = 0.0, scale = 0.0;
  for (const Angle& a : angles) {
    const HarmonicAngle one("one", Level::slow, {a}, types);
    const Matrix3Xd f = forces(one, xw, box);
    const Vector3d ra = xw.col(a.i) - xw.col(a.j), rb = xw.col(a.k) - xw.col(a.j);
    w += ra.dot(f.col(a.i)) + rb.dot(f.col(a.k));
    scale += ra.norm() * f.col(a.i).norm() + rb.norm() * f.col(a.k).norm();
  }
  ASSERT_GT(scale, 1.0);
  EXPECT_NEAR(h.virial(xw, box), w, 1e-13 * scale);
  EXPECT_NEAR(h.virial(xw, box), 0.0, 1e-13 * scale);
  EXPECT_NEAR(c.virial(xw, box), 0.0, 1e-13 * scale);
  const double d = 1e-6;
  const double dilation = -(energy(h, (1 + d) * x, Box{}) - energy(h, (1 - d) * x, Box{})) / (2 * d);
  EXPECT_NEAR(dilation, 0.0, 1e-8);
}

TEST(AngleTerms, CoincidentParticlesThrowNumericalError) {
  const HarmonicAngle h("h", Level::slow, {{0, 1, 2, 0}}, {{3.0, 2.0}});
  Matrix3Xd x = angle_geometry(1.0);
  x.col(2) = x.col(1);
  try {
    energy(h, x, Box{});
    FAIL() << "no NumericalError";
  } catch (const NumericalError& e) {
    EXPECT_NE(std::string(e.what()).find("angle (0, 1, 2)"), std::string::npos) << e.what();
  }
  x = angle_geometry(1.0);
  x(0, 0) = NAN;
  EXPECT_THROW(energy(h, x, Box{}), NumericalError);
}

TEST(AngleTerms, RejectInvalidParameters) {
  const std::vector<Angle> one = {{0, 1, 2, 0}};
  for (const AngleCoeffs bad : {AngleCoeffs{-1.0, 2.0}, AngleCoeffs{1.0, -0.1}, AngleCoeffs{1.0, 3.2},
                                AngleCoeffs{NAN, 2.0}, AngleCoeffs{1.0, NAN}}) {
    EXPECT_THROW(HarmonicAngle("h", Level::slow, one, {bad}), std::invalid_argument);
    EXPECT_THROW(CosineAngle("c", Level::slow, one, {bad}), std::invalid_argument);
  }
  EXPECT_NO_THROW(HarmonicAngle("h", Level::slow, one, {{0.0, 0.0}}));
  EXPECT_NO_THROW(CosineAngle("c", Level::slow, one, {{1.0, kPi}}));
  for (const Angle bad : {Angle{0, 0, 2, 0}, Angle{0, 1, 1, 0}, Angle{2, 1, 2, 0}, Angle{-1, 1, 2, 0},
                          Angle{0, 1, 2, 1}, Angle{0, 1, 2, -1}}) {
    EXPECT_THROW(HarmonicAngle("h", Level::slow, {bad}, {{1.0, 2.0}}), std::invalid_argument);
    EXPECT_THROW(CosineAngle("c", Level::slow, {bad}, {{1.0, 2.0}}), std::invalid_argument);
  }
}

// A kernel E = θ makes the loop return −∇θ, checked against the textbook formula
// ∂θ/∂x_i = (â cos θ − b̂)/(|a| sin θ) away from the singular angles.
struct ThetaKernel {
  static void eval(double theta, const int&, double& e, double& de_dtheta) {
    e = theta;
    de_dtheta = 1.0;
  }
};

TEST(AngleLoop, GradientOfThetaMatchesTextbookFormula) {
  const Matrix3Xd x = random_chain(3, 0.7, 1.3, 9);
  const std::vector<AngleInstance<int>> angles = {{0, 1, 2, 0}};
  Matrix3Xd f = zeros_like(x);
  const double theta = accumulate_angle_forces<ThetaKernel>(angles, x, Box{}, f);
  const Vector3d a = x.col(0) - x.col(1), b = x.col(2) - x.col(1);
  EXPECT_NEAR(theta, std::acos(a.normalized().dot(b.normalized())), 1e-12);
  const Vector3d gi = (a.normalized() * std::cos(theta) - b.normalized()) / (a.norm() * std::sin(theta));
  const Vector3d gk = (b.normalized() * std::cos(theta) - a.normalized()) / (b.norm() * std::sin(theta));
  EXPECT_LT((Vector3d(f.col(0)) + gi).norm(), 1e-12);
  EXPECT_LT((Vector3d(f.col(2)) + gk).norm(), 1e-12);
  EXPECT_LT((Vector3d(f.col(1)) - gi - gk).norm(), 1e-12);
}

// ------------------------------------------------------------------------------------ external

TEST(HarmonicTether, EnergyAndForceAtHandComputedPositions) {
  const Vector3d c(0.5, -1.0, 2.0);
  const HarmonicTether term("t", Level::slow, {0, 2}, c, 4.0);
  Matrix3Xd x(3, 3);
  x << 1.5, 7.0, 0.5,  //
      -1.0, 7.0, 1.0,  //
      2.0, 7.0, 2.5;
  Matrix3Xd f = zeros_like(x);
  const double e = term.add_forces(x, Box{}, f);
  EXPECT_NEAR(e, 0.5 * 4.0 * (1.0 + (4.0 + 0.25)), 1e-14);  // |x0 − c|² = 1, |x2 − c|² = 4.25
  EXPECT_NEAR(f(0, 0), -4.0, 1e-14);
  EXPECT_NEAR(f(1, 2), -8.0, 1e-14);
  EXPECT_NEAR(f(2, 2), -2.0, 1e-14);
  EXPECT_EQ(f.col(1).norm(), 0.0);  // not tethered
  EXPECT_EQ(term.virial(x, Box{}), 0.0);
}

TEST(HarmonicTether, ForceIsMinusGradientOpenAndPeriodic) {
  const HarmonicTether term("t", Level::slow, {0, 1, 3, 4}, Vector3d(1.4, -1.6, 0.1), 2.5);
  const Matrix3Xd x = random_chain(5, 0.7, 1.3, 51);
  EXPECT_LT(fd_error(term, x, Box{}), 1e-8);
  // Centre near the +x, −y faces: particles near the opposite faces see its nearer image.
  const Box box = periodic_box();
  Matrix3Xd xw = Matrix3Xd::Zero(3, 5);
  xw.col(0) = Vector3d(-1.3, 1.6, 0.0);
  xw.col(1) = Vector3d(-1.0, -1.5, 0.5);
  xw.col(3) = Vector3d(1.0, 1.0, -1.7);  // (not −1.9: 2.0 from c in z is half the box, a cusp)
  xw.col(4) = Vector3d(0.2, 0.3, 0.4);
  EXPECT_LT(fd_error(term, xw, box), 1e-8);
  // Particle 0: x0 − c = (−2.7, 3.2, −0.1), by minimum image (0.3, −0.3, −0.1).
  const HarmonicTether one("t", Level::slow, {0}, Vector3d(1.4, -1.6, 0.1), 2.5);
  EXPECT_NEAR(energy(one, xw, box), 0.5 * 2.5 * (0.09 + 0.09 + 0.01), 1e-14);
  EXPECT_NEAR(forces(one, xw, box)(1, 0), 2.5 * 0.3, 1e-14);
}

TEST(HarmonicTether, RejectsInvalidParameters) {
  EXPECT_THROW(HarmonicTether("t", Level::slow, {0}, Vector3d::Zero(), -1.0), std::invalid_argument);
  EXPECT_THROW(HarmonicTether("t", Level::slow, {0}, Vector3d(NAN, 0, 0), 1.0), std::invalid_argument);
  EXPECT_THROW(HarmonicTether("t", Level::slow, {}, Vector3d::Zero(), 1.0), std::invalid_argument);
  EXPECT_THROW(HarmonicTether("t", Level::slow, {0, 2, 0}, Vector3d::Zero(), 1.0), std::invalid_argument);
  EXPECT_THROW(HarmonicTether("t", Level::slow, {-1}, Vector3d::Zero(), 1.0), std::invalid_argument);
}

TEST(LJ93Wall, EnergyAtHandComputedDistances) {
  const LJ93WallParams p{.axis = 1, .position = 0.5, .side = +1, .epsilon = 2.0, .sigma = 1.0, .cutoff = 2.5};
  const LJ93Wall wall("w", Level::slow, p, {0});
  Matrix3Xd x = Matrix3Xd::Zero(3, 1);
  auto at = [&](double r) {
    x(1, 0) = 0.5 + r;
    return energy(wall, x, Box{});
  };
  const double shift = 2.0 * (2.0 / 15.0 * std::pow(2.5, -9) - std::pow(2.5, -3));
  EXPECT_NEAR(at(1.0), 2.0 * (2.0 / 15.0 - 1.0) - shift, 1e-14);
  EXPECT_NEAR(at(1.7), 2.0 * (2.0 / 15.0 * std::pow(1.7, -9) - std::pow(1.7, -3)) - shift, 1e-14);
  EXPECT_NEAR(at(2.5 - 1e-9), 0.0, 1e-9);  // shifted: continuous at the cutoff
  EXPECT_EQ(at(3.0), 0.0);
  // The minimum, at r = (2/5)^{1/6} σ: no force; closer in it pushes away (+y), further it pulls.
  const double rmin = std::pow(0.4, 1.0 / 6.0);
  x(1, 0) = 0.5 + rmin;
  EXPECT_NEAR(forces(wall, x, Box{})(1, 0), 0.0, 1e-12);
  x(1, 0) = 0.5 + 0.8;
  EXPECT_GT(forces(wall, x, Box{})(1, 0), 0.0);
  x(1, 0) = 0.5 + 1.2;
  EXPECT_LT(forces(wall, x, Box{})(1, 0), 0.0);
  EXPECT_EQ(wall.virial(x, Box{}), 0.0);
}

TEST(LJ93Wall, ForceIsMinusGradientOnBothSides) {
  Box box;  // periodic across the wall's plane, open along its axis
  box.periodic = Eigen::Vector3i(1, 1, 0);
  box.lengths = Vector3d(3.0, 3.0, 0.0);
  for (const int side : {+1, -1}) {
    const LJ93WallParams p{.axis = 2, .position = -0.3, .side = side, .epsilon = 1.5, .sigma = 0.8, .cutoff = 1.7};
    const LJ93Wall wall("w", Level::slow, p, {0, 1, 2, 3});
    Matrix3Xd x = random_chain(4, 0.5, 1.0, 61);
    for (int i = 0; i < 4; ++i) x(2, i) = -0.3 + side * (0.5 + 0.45 * i);  // r = 0.5 … 1.85: last beyond r_c
    EXPECT_LT(fd_error(wall, x, box), 1e-6) << side;
    EXPECT_GT(side * forces(wall, x, box)(2, 0), 0.0);  // the closest particle is pushed away
  }
}

TEST(LJ93Wall, WrongSideOrPeriodicAxisThrows) {
  const LJ93WallParams p{.axis = 0, .position = 1.0, .side = -1, .epsilon = 1.0, .sigma = 1.0, .cutoff = 2.5};
  const LJ93Wall wall("floor", Level::slow, p, {0, 1});
  Matrix3Xd x = Matrix3Xd::Zero(3, 2);
  x(0, 1) = 1.2;  // side −1 wants x < 1
  try {
    energy(wall, x, Box{});
    FAIL() << "no NumericalError";
  } catch (const NumericalError& e) {
    EXPECT_NE(std::string(e.what()).find("particle 1"), std::string::npos) << e.what();
    EXPECT_NE(std::string(e.what()).find("floor"), std::string::npos) << e.what();
  }
  x(0, 1) = 1.0;  // on the wall, r = 0
  EXPECT_THROW(energy(wall, x, Box{}), NumericalError);
  x(0, 1) = 0.0;
  EXPECT_NO_THROW(energy(wall, x, Box{}));
  Box box;
  box.periodic = Eigen::Vector3i(1, 0, 0);
  box.lengths = Vector3d(5.0, 0.0, 0.0);
  EXPECT_THROW(energy(wall, x, box), std::invalid_argument);
}

TEST(LJ93Wall, RejectsInvalidParameters) {
  const LJ93WallParams ok{.axis = 2, .position = 0.0, .side = 1, .epsilon = 1.0, .sigma = 1.0, .cutoff = 2.5};
  EXPECT_NO_THROW(LJ93Wall("w", Level::slow, ok, {0}));
  auto with = [&](auto change) {
    LJ93WallParams p = ok;
    change(p);
    return p;
  };
  for (const LJ93WallParams& bad : {with([](auto& p) { p.axis = 3; }), with([](auto& p) { p.side = 0; }),
                                    with([](auto& p) { p.epsilon = -1; }), with([](auto& p) { p.sigma = 0; }),
                                    with([](auto& p) { p.cutoff = 0; }), with([](auto& p) { p.position = NAN; })})
    EXPECT_THROW(LJ93Wall("w", Level::slow, bad, {0}), std::invalid_argument);
  EXPECT_THROW(LJ93Wall("w", Level::slow, ok, {}), std::invalid_argument);
  EXPECT_THROW(LJ93Wall("w", Level::slow, ok, {1, 1}), std::invalid_argument);
}

}  // namespace
}  // namespace stiffmd
