// Tests for integrators/fixman.hpp: Fixman's potential U_F = (kT/2) log det A and its force
// (docs/design.md §5).
#include "integrators/eigen_dense.hpp"  // first: see the header

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <random>
#include <stdexcept>
#include <vector>

#include "core/errors.hpp"
#include "core/parallel.hpp"
#include "integrators/constraints.hpp"
#include "integrators/fixman.hpp"

namespace stiffmd {
namespace {

using Eigen::Matrix3d;
using Eigen::Matrix3Xd;
using Eigen::MatrixXd;
using Eigen::Vector3d;
using Eigen::VectorXd;

struct System {
  std::vector<StiffBond> bonds;
  VectorXd inv_mass;
  Matrix3Xd x;
};

Vector3d random_unit(std::mt19937& rng) {
  std::normal_distribution<double> n(0.0, 1.0);
  return Vector3d(n(rng), n(rng), n(rng)).normalized();
}

// Random masses (one in `fixed_every` particles fixed, counting from 0, if > 0), α and lengths.
System particles(std::mt19937& rng, int n, int fixed_every = 0) {
  std::uniform_real_distribution<double> mass(0.5, 3.0);
  System s;
  s.inv_mass = VectorXd(n);
  for (int p = 0; p < n; ++p) s.inv_mass[p] = (fixed_every > 0 && p % fixed_every == 0) ? 0.0 : 1.0 / mass(rng);
  s.x = Matrix3Xd::Zero(3, n);
  return s;
}

// Bond from particle i to a new particle j at a random direction, length ≈ ℓ (off the manifold).
void grow(std::mt19937& rng, System& s, int i, int j) {
  std::uniform_real_distribution<double> alpha(0.5, 2.0), len(0.8, 1.3), stretch(0.9, 1.1);
  StiffBond bond{i, j, len(rng), alpha(rng)};
  s.x.col(j) = s.x.col(i) + bond.length * stretch(rng) * random_unit(rng);
  s.bonds.push_back(bond);
}

System chain(std::mt19937& rng, int beads, int fixed_every = 0) {
  System s = particles(rng, beads, fixed_every);
  s.x.col(0) << 0.3, -0.2, 0.5;
  for (int p = 1; p < beads; ++p) grow(rng, s, p - 1, p);
  return s;
}

// A closed ring: beads on a perturbed circle, the last bond back to particle 0.
System ring(std::mt19937& rng, int beads) {
  System s = particles(rng, beads);
  std::uniform_real_distribution<double> noise(-0.15, 0.15), alpha(0.5, 2.0), len(0.8, 1.3);
  const double radius = beads / (2.0 * M_PI);
  for (int p = 0; p < beads; ++p) {
    const double phi = 2.0 * M_PI * p / beads;
    s.x.col(p) << radius * std::cos(phi) + noise(rng), radius * std::sin(phi) + noise(rng), noise(rng);
  }
  for (int p = 0; p < beads; ++p) {
    // Bonds in scrambled direction and order, so the ring order is found, not assumed.
    const int q = (p + 1) % beads;
    s.bonds.push_back(p % 3 == 0 ? StiffBond{q, p, len(rng), alpha(rng)} : StiffBond{p, q, len(rng), alpha(rng)});
  }
  std::shuffle(s.bonds.begin(), s.bonds.end(), rng);
  return s;
}

// `arms` arms of `length` bonds around particle 0 (fixed if center_fixed: the arms are then
// separate clusters sharing that particle).
System star(std::mt19937& rng, int arms, int length, bool center_fixed = false) {
  System s = particles(rng, 1 + arms * length);
  if (center_fixed) s.inv_mass[0] = 0.0;
  int next = 1;
  for (int a = 0; a < arms; ++a)
    for (int k = 0; k < length; ++k, ++next) grow(rng, s, k == 0 ? 0 : next - 1, next);
  return s;
}

// A backbone of `backbone` bonds with a side chain of `side` bonds at every second bead.
System branched(std::mt19937& rng, int backbone, int side) {
  const int n = 1 + backbone + (backbone / 2 + 1) * side;
  System s = particles(rng, n);
  int next = 1;
  for (int k = 0; k < backbone; ++k, ++next) grow(rng, s, next - 1, next);
  for (int bead = 0; bead <= backbone; bead += 2)
    for (int k = 0; k < side; ++k, ++next) grow(rng, s, k == 0 ? bead : next - 1, next);
  EXPECT_EQ(next, n);
  return s;
}

double energy(FixmanPotential& fp, const Matrix3Xd& x, double kT) {
  Matrix3Xd scratch;
  return fp.force(x, kT, scratch);
}

// max |f − (−central FD of U_F)| / max |f| over every coordinate, fixed particles included.
double fd_error(const System& s, double kT) {
  FixmanPotential fp(s.bonds, s.inv_mass);
  Matrix3Xd f;
  fp.force(s.x, kT, f);
  const double h = 1e-6;
  double err = 0.0;
  for (int p = 0; p < s.x.cols(); ++p)
    for (int a = 0; a < 3; ++a) {
      Matrix3Xd xp = s.x, xm = s.x;
      xp(a, p) += h;
      xm(a, p) -= h;
      const double fd = -(energy(fp, xp, kT) - energy(fp, xm, kT)) / (2 * h);
      err = std::max(err, std::abs(fd - f(a, p)));
    }
  EXPECT_GT(f.cwiseAbs().maxCoeff(), 0.0);
  return err / f.cwiseAbs().maxCoeff();
}

// U_F by its definition: (kT/2) log det(K^{1/2} G M⁻¹ Gᵀ K^{1/2}) with G assembled densely.
// All clusters at once (the log det of a block-diagonal matrix is the sum over blocks).
// K^{1/2} G: row b has α_b u_b in the columns of particle i and −α_b u_b in those of j.
MatrixXd scaled_jacobian(const System& s) {
  const int m = static_cast<int>(s.bonds.size());
  const int n = static_cast<int>(s.x.cols());
  MatrixXd G = MatrixXd::Zero(m, 3 * n);
  for (int b = 0; b < m; ++b) {
    const StiffBond& bond = s.bonds[b];
    const Vector3d u = (s.x.col(bond.i) - s.x.col(bond.j)).normalized();
    G.block<1, 3>(b, 3 * bond.i) = bond.alpha * u.transpose();
    G.block<1, 3>(b, 3 * bond.j) = -bond.alpha * u.transpose();
  }
  return G;
}

double reference_energy(const System& s, double kT) {
  const int n = static_cast<int>(s.x.cols());
  const MatrixXd G = scaled_jacobian(s);
  VectorXd minv(3 * n);
  for (int p = 0; p < n; ++p) minv.segment<3>(3 * p).setConstant(s.inv_mass[p]);
  const MatrixXd A = G * minv.asDiagonal() * G.transpose();
  return 0.5 * kT * std::log(A.determinant());
}

// Several systems side by side in one (particles renumbered).
System empty_system() {
  System s;
  s.inv_mass = VectorXd(0);
  return s;
}
void append(System& all, const System& s) {
  const int offset = static_cast<int>(all.inv_mass.size());
  all.inv_mass.conservativeResize(offset + s.inv_mass.size());
  all.inv_mass.tail(s.inv_mass.size()) = s.inv_mass;
  all.x.conservativeResize(3, offset + s.x.cols());
  all.x.rightCols(s.x.cols()) = s.x;
  for (StiffBond b : s.bonds) all.bonds.push_back({b.i + offset, b.j + offset, b.length, b.alpha});
}

std::vector<System> shapes(std::mt19937& rng) {
  return {chain(rng, 12),  chain(rng, 9, 4),      ring(rng, 3),        ring(rng, 11),
          star(rng, 4, 2), star(rng, 3, 3, true), branched(rng, 6, 2), chain(rng, 3)};
}

TEST(FixmanPotential, EnergyIsHalfKTLogDetA) {
  std::mt19937 rng(11);
  for (const System& s : shapes(rng)) {
    FixmanPotential fp(s.bonds, s.inv_mass);
    const double kT = 1.7;
    EXPECT_NEAR(energy(fp, s.x, kT), reference_energy(s, kT), 1e-11 * (1.0 + std::abs(reference_energy(s, kT))));
  }
}

// log det S is summed as the logarithm of running products of the pivots, banked before they
// leave [2^−500, 2^500]: a 300-bond chain of light beads (m = 1e−3: det A ≈ e^+1900) and one of
// heavy beads (m = 1e3: ≈ e^−1800) must still give the dense log det — computed here from a
// Cholesky factor, as det A itself is out of range.
TEST(FixmanPotential, LogDetOfLongChainsOfLightAndHeavyBeadsDoesNotOverflow) {
  for (const double mass : {1e-3, 1e3}) {
    SCOPED_TRACE(testing::Message() << "mass " << mass);
    std::mt19937 rng(19);
    System s = chain(rng, 301);
    s.inv_mass.setConstant(1.0 / mass);
    const MatrixXd G = scaled_jacobian(s);
    const MatrixXd A = G * G.transpose() / mass;
    const Eigen::LLT<MatrixXd> llt(A);
    ASSERT_EQ(llt.info(), Eigen::Success);
    const double log_det = 2.0 * llt.matrixLLT().diagonal().array().log().sum();
    ASSERT_GT(std::abs(log_det), 745.0);  // det A itself over- or underflows (e^±745)
    FixmanPotential fp(s.bonds, s.inv_mass);
    const double kT = 0.8;
    const double u_f = energy(fp, s.x, kT);
    EXPECT_NEAR(u_f, 0.5 * kT * log_det, 1e-11 * std::abs(0.5 * kT * log_det));
  }
}

TEST(FixmanPotential, ForceIsMinusGradientOfEnergy) {
  std::mt19937 rng(12);
  for (int trial = 0; trial < 3; ++trial)
    for (const System& s : shapes(rng)) EXPECT_LT(fd_error(s, 0.8), 3e-8) << "bonds " << s.bonds.size();
}

// The shapes that select the O(bonds) paths are recognised whatever the bond order and direction.
TEST(FixmanPotential, ClusterShapesAreRecognised) {
  std::mt19937 rng(16);
  auto shape_of = [](const System& s) {
    const std::vector<ConstraintCluster> found = find_clusters(s.bonds, s.inv_mass);
    EXPECT_EQ(found.size(), 1u);
    const ClusterPath path = cluster_path(found[0], s.bonds, s.inv_mass);
    EXPECT_EQ(path.bonds.size(), s.bonds.size());
    if (path.shape != ClusterShape::other)  // consecutive bonds share a particle
      for (size_t k = 0; k < path.bonds.size(); ++k) {
        if (k + 1 == path.bonds.size() && path.shape == ClusterShape::chain) break;
        const StiffBond& a = s.bonds[path.bonds[k]];
        const StiffBond& b = s.bonds[path.bonds[(k + 1) % path.bonds.size()]];
        EXPECT_TRUE(a.i == b.i || a.i == b.j || a.j == b.i || a.j == b.j);
      }
    return path.shape;
  };
  EXPECT_EQ(shape_of(chain(rng, 2)), ClusterShape::chain);
  EXPECT_EQ(shape_of(chain(rng, 20)), ClusterShape::chain);
  EXPECT_EQ(shape_of(ring(rng, 3)), ClusterShape::ring);
  EXPECT_EQ(shape_of(ring(rng, 17)), ClusterShape::ring);
  EXPECT_EQ(shape_of(star(rng, 3, 2)), ClusterShape::other);
  EXPECT_EQ(shape_of(branched(rng, 4, 1)), ClusterShape::other);
  System opened = ring(rng, 9);  // a fixed bead breaks the ring's coupling: a chain
  opened.inv_mass[4] = 0.0;
  EXPECT_EQ(shape_of(opened), ClusterShape::chain);
}

// The O(bonds) chain and ring recurrences against the dense inverse, to round-off.
TEST(FixmanPotential, ChainAndRingPathsAgreeWithDensePath) {
  std::mt19937 rng(13);
  std::vector<System> systems = {chain(rng, 2), chain(rng, 3), chain(rng, 40), chain(rng, 30, 7),
                                 ring(rng, 3),  ring(rng, 4),  ring(rng, 37)};
  for (const System& s : systems) {
    FixmanPotential fast(s.bonds, s.inv_mass, FixmanPotential::Path::fast);
    FixmanPotential dense(s.bonds, s.inv_mass, FixmanPotential::Path::dense);
    Matrix3Xd ff, fd;
    const double uf = fast.force(s.x, 1.3, ff);
    const double ud = dense.force(s.x, 1.3, fd);
    EXPECT_NEAR(uf, ud, 1e-13 * (1.0 + std::abs(ud)));
    EXPECT_LE((ff - fd).cwiseAbs().maxCoeff(), 1e-13 * fd.cwiseAbs().maxCoeff()) << "bonds " << s.bonds.size();
  }
}

// docs/design.md §5: the freely jointed trimer, equal masses m, unit bonds, c = cos θ at the middle
// particle: det(G M⁻¹ Gᵀ) = (4 − c²)/m², so U_F = (kT/2) log((4 − c²)/m²) + kT Σ log α_b, and
// the torque dU_F/dθ = kT c sin θ/(4 − c²); no force along the bonds (U_F depends on directions).
TEST(FixmanPotential, FreelyJointedTrimerKnownValues) {
  const double m = 2.5, kT = 0.7;
  for (const double alpha : {1.0, 3.0})
    for (const double theta : {0.3, 1.0, M_PI / 2, 2.0, 2.9}) {
      const double c = std::cos(theta), s = std::sin(theta);
      Matrix3Xd x = Matrix3Xd::Zero(3, 3);
      x.col(0) << 1.0, 0.0, 0.0;  // the middle particle 1 at the origin
      x.col(2) << c, s, 0.0;
      FixmanPotential fp({{0, 1, 1.0, alpha}, {1, 2, 1.0, alpha}}, VectorXd::Constant(3, 1.0 / m));
      Matrix3Xd f;
      const double u = fp.force(x, kT, f);
      EXPECT_NEAR(u, 0.5 * kT * std::log((4.0 - c * c) / (m * m)) + 2.0 * kT * std::log(alpha), 1e-14);
      const Vector3d e_theta(-s, c, 0.0);  // direction in which θ grows at particle 2
      EXPECT_NEAR(f.col(2).dot(e_theta), -kT * c * s / (4.0 - c * c), 1e-14);
      EXPECT_NEAR(f.col(2).dot(x.col(2)), 0.0, 1e-14);
      EXPECT_NEAR(f.col(0).dot(Vector3d(0.0, -1.0, 0.0)), -kT * c * s / (4.0 - c * c), 1e-14);  // θ grows
      EXPECT_NEAR(f.col(0).x(), 0.0, 1e-14);
      EXPECT_NEAR(f.col(2)(2), 0.0, 1e-14);  // in the plane
    }
}

// U_F depends on bond directions only: Σ f = 0, Σ x × f = 0; a rigid motion rotates f.
TEST(FixmanPotential, TranslationAndRotationInvariant) {
  std::mt19937 rng(14);
  const Matrix3d R = Eigen::AngleAxisd(0.7, Vector3d(1.0, -2.0, 0.5).normalized()).toRotationMatrix();
  for (const System& s : shapes(rng)) {
    FixmanPotential fp(s.bonds, s.inv_mass);
    Matrix3Xd f, g;
    const double u = fp.force(s.x, 1.1, f);
    const double scale = f.cwiseAbs().maxCoeff() * s.x.cols();
    EXPECT_LT(f.rowwise().sum().cwiseAbs().maxCoeff(), 1e-13 * scale);
    Vector3d torque = Vector3d::Zero();
    for (int p = 0; p < s.x.cols(); ++p) torque += Vector3d(s.x.col(p)).cross(Vector3d(f.col(p)));
    EXPECT_LT(torque.cwiseAbs().maxCoeff(), 1e-12 * scale * s.x.cwiseAbs().maxCoeff());
    const Matrix3Xd y = (R * s.x).colwise() + Vector3d(3.0, -1.0, 2.0);
    EXPECT_NEAR(fp.force(y, 1.1, g), u, 1e-12 * (1.0 + std::abs(u)));
    EXPECT_LT((g - R * f).cwiseAbs().maxCoeff(), 1e-12 * f.cwiseAbs().maxCoeff());
  }
}

// With the integrator's constraint toolbox (use_toolbox) open chains take G and the band of S⁻¹
// from the toolbox's twisted factorization instead of this object's measure and LDLᵀ: the same
// energy and force to round-off, on every shape (the others keep their own path), at a first x
// and at a moved one (the toolbox must not serve the factors of the first), with chains numbered
// against their path and fixed beads, and with several chains of one length (their bands formed
// in lockstep); and a toolbox built from other bonds is refused.
TEST(FixmanPotential, ToolboxFactorsGiveTheSameForce) {
  std::mt19937 rng(23);
  std::vector<System> systems = shapes(rng);
  systems.push_back(chain(rng, 40, 7));
  {  // seven chains of one length and two of another: the toolbox forms their bands in lockstep
    System all = empty_system();
    for (int k = 0; k < 9; ++k) append(all, chain(rng, k < 7 ? 21 : 13));
    systems.push_back(all);
  }
  {  // a chain numbered backwards, half its bonds reversed
    System s = chain(rng, 15);
    const int n = static_cast<int>(s.x.cols());
    System r = s;
    for (int p = 0; p < n; ++p) {
      r.x.col(n - 1 - p) = s.x.col(p);
      r.inv_mass[n - 1 - p] = s.inv_mass[p];
    }
    for (std::size_t b = 0; b < s.bonds.size(); ++b) {
      r.bonds[b] = s.bonds[b];
      r.bonds[b].i = n - 1 - s.bonds[b].i;
      r.bonds[b].j = n - 1 - s.bonds[b].j;
      if (b % 2 == 0) std::swap(r.bonds[b].i, r.bonds[b].j);
    }
    systems.push_back(r);
  }
  const double kT = 1.3;
  for (const System& s : systems) {
    FixmanPotential own(s.bonds, s.inv_mass), shared(s.bonds, s.inv_mass);
    ConstraintToolbox toolbox(s.bonds, s.inv_mass);
    shared.use_toolbox(&toolbox);
    Matrix3Xd x = s.x;
    for (int move = 0; move < 2; ++move) {
      Matrix3Xd f_own, f_shared;
      const double u_own = own.force(x, kT, f_own);
      const double u_shared = shared.force(x, kT, f_shared);
      EXPECT_NEAR(u_shared, u_own, 1e-12 * (1.0 + std::abs(u_own)));
      EXPECT_LE((f_shared - f_own).cwiseAbs().maxCoeff(), 1e-11 * (1.0 + f_own.cwiseAbs().maxCoeff()));
      x += 0.05 * Matrix3Xd::Random(3, x.cols());
    }
  }
  const System a = chain(rng, 10), b = chain(rng, 10);
  ConstraintToolbox other(b.bonds, b.inv_mass);
  FixmanPotential fp(a.bonds, a.inv_mass);
  EXPECT_THROW(fp.use_toolbox(&other), std::invalid_argument);
  FixmanPotential dense(a.bonds, a.inv_mass, FixmanPotential::Path::dense);
  ConstraintToolbox same(a.bonds, a.inv_mass);
  EXPECT_THROW(dense.use_toolbox(&same), std::invalid_argument);
}

// add_force (what RATTLE's force evaluation calls: U_F's force added to the slow force in place)
// adds exactly what force() writes, to round-off, on every shape, with and without the toolbox's
// factors, and with two chains that share a fixed bead (added serially, in cluster order).
TEST(FixmanPotential, AddForceAddsTheForce) {
  std::mt19937 rng(31);
  std::vector<System> systems = shapes(rng);
  systems.push_back(chain(rng, 40, 7));  // fixed beads split it into clusters sharing them
  const double kT = 0.7;
  for (const System& s : systems)
    for (bool with_toolbox : {false, true}) {
      FixmanPotential fp(s.bonds, s.inv_mass);
      ConstraintToolbox toolbox(s.bonds, s.inv_mass);
      if (with_toolbox) fp.use_toolbox(&toolbox);
      const Matrix3Xd f0 = Matrix3Xd::Random(3, s.x.cols());
      Matrix3Xd f_alone, f = f0;
      const double u_alone = fp.force(s.x, kT, f_alone);
      EXPECT_EQ(fp.add_force(s.x, kT, f), u_alone);
      EXPECT_LE((f - (f0 + f_alone)).cwiseAbs().maxCoeff(), 1e-14 * (1.0 + f_alone.cwiseAbs().maxCoeff()));
      EXPECT_GT(f_alone.cwiseAbs().maxCoeff(), 0.0);
    }
  const System s = chain(rng, 5);
  FixmanPotential fp(s.bonds, s.inv_mass);
  Matrix3Xd wrong = Matrix3Xd::Zero(3, 4);
  EXPECT_THROW(fp.add_force(s.x, kT, wrong), std::invalid_argument);
}

// Above the serial threshold clusters run on the threads: the result is the serial one, bit for bit.
TEST(FixmanPotential, ThreadCountDoesNotChangeTheResult) {
  std::mt19937 rng(15);
  System all = empty_system();
  for (int k = 0; k < 45; ++k) append(all, k % 5 == 4 ? ring(rng, 100) : chain(rng, 101));
  ASSERT_GE(static_cast<std::int64_t>(all.bonds.size()), kParallelMin);
  FixmanPotential fp(all.bonds, all.inv_mass);
  const int restore = max_threads();
  Matrix3Xd f1, f2;
  set_max_threads(1);
  const double u1 = fp.force(all.x, 1.0, f1);
  set_max_threads(2);
  const double u2 = fp.force(all.x, 1.0, f2);
  set_max_threads(restore);
  EXPECT_EQ(u1, u2);
  EXPECT_TRUE(f1 == f2);
  ConstraintToolbox toolbox(all.bonds, all.inv_mass);  // and through the toolbox's factors
  fp.use_toolbox(&toolbox);
  set_max_threads(1);
  const double u3 = fp.force(all.x, 1.0, f1);
  ConstraintToolbox toolbox2(all.bonds, all.inv_mass);
  fp.use_toolbox(&toolbox2);
  set_max_threads(2);
  const double u4 = fp.force(all.x, 1.0, f2);
  set_max_threads(restore);
  EXPECT_EQ(u3, u4);
  EXPECT_TRUE(f1 == f2);
}

TEST(FixmanPotential, BadInputAndDegenerateGeometryAreReported) {
  const VectorXd w = VectorXd::Ones(3);
  EXPECT_THROW(FixmanPotential({{0, 3, 1.0, 1.0}}, w), std::invalid_argument);
  EXPECT_THROW(FixmanPotential({{1, 1, 1.0, 1.0}}, w), std::invalid_argument);
  EXPECT_THROW(FixmanPotential({{0, 1, 0.0, 1.0}}, w), std::invalid_argument);
  EXPECT_THROW(FixmanPotential({{0, 1, 1.0, 0.0}}, w), std::invalid_argument);
  EXPECT_THROW(FixmanPotential({{0, 1, 1.0, 1.0}, {1, 0, 1.0, 1.0}}, w), std::invalid_argument);
  EXPECT_THROW(FixmanPotential({{0, 1, 1.0, 1.0}}, Eigen::Vector3d(0.0, 0.0, 1.0)), std::invalid_argument);
  EXPECT_THROW(FixmanPotential({{0, 1, 1.0, 1.0}}, Eigen::Vector3d(-1.0, 1.0, 1.0)), std::invalid_argument);

  Matrix3Xd x = Matrix3Xd::Zero(3, 3), f;
  x.col(1) << 1.0, 0.0, 0.0;
  x.col(2) << 2.0, 0.0, 0.0;
  FixmanPotential pair({{0, 1, 1.0, 1.0}}, w);
  EXPECT_THROW(pair.force(Matrix3Xd::Zero(3, 3), 1.0, f), NumericalError);  // zero length
  EXPECT_THROW(pair.force(Matrix3Xd::Zero(3, 2), 1.0, f), std::invalid_argument);
  // Lengths that only a collinear triangle realises are refused with the shared rules
  // (find_stiff_bond_problem); a realisable triangle placed collinear (x: three bond directions
  // in a line span one dimension) has a singular S at x.
  EXPECT_THROW(FixmanPotential({{0, 1, 1.0, 1.0}, {1, 2, 1.0, 1.0}, {2, 0, 2.0, 1.0}}, w), std::invalid_argument);
  for (auto path : {FixmanPotential::Path::fast, FixmanPotential::Path::dense}) {
    FixmanPotential triangle({{0, 1, 1.0, 1.0}, {1, 2, 1.0, 1.0}, {2, 0, 1.5, 1.0}}, w, path);
    EXPECT_THROW(triangle.force(x, 1.0, f), NumericalError);
  }
}

}  // namespace
}  // namespace stiffmd
