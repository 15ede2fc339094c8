// Tests for integrators/modes.hpp: frequencies, actions, correction potential and the
// validity monitor of the effective dynamics (docs/design.md §4; Lubich & Weiss eqs. (CH),
// (actions), (separated), (nonresonant)).

#include "integrators/eigen_dense.hpp"  // first: see the header

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <random>
#include <stdexcept>
#include <vector>
#include "integrators/modes.hpp"

#include "core/errors.hpp"
#include "core/parallel.hpp"

namespace stiffmd {
namespace {

using Eigen::Matrix3Xd;
using Eigen::MatrixXd;
using Eigen::Vector3d;
using Eigen::VectorXd;

constexpr double kPi = 3.14159265358979323846;

struct System {
  std::vector<StiffBond> bonds;
  VectorXd inv_mass;
  Matrix3Xd x;
};

// The paper's stiff spring double pendulum (Example 1, eq. (IV)): pivot 0 fixed at the
// origin, unit masses 1 and 2, l = α = 1, x₁ = (√½, −√½), x₂ = (√2, x2y).
System pendulum(double x2y) {
  System s;
  s.bonds = {{0, 1, 1.0, 1.0}, {1, 2, 1.0, 1.0}};
  s.inv_mass = VectorXd(3);
  s.inv_mass << 0.0, 1.0, 1.0;
  s.x = Matrix3Xd::Zero(3, 3);
  s.x.col(1) << std::sqrt(0.5), -std::sqrt(0.5), 0.0;
  s.x.col(2) << std::sqrt(2.0), x2y, 0.0;
  return s;
}

Vector3d random_unit(std::mt19937& rng) {
  std::normal_distribution<double> n(0.0, 1.0);
  Vector3d d(n(rng), n(rng), n(rng));
  return d.normalized();
}

// A chain of `beads` particles with random masses, α and rest lengths; bond lengths are
// the rest lengths times (1 + stretch·noise), so stretch = 0 puts it on the manifold.
System random_chain(std::mt19937& rng, int beads, double stretch) {
  std::uniform_real_distribution<double> mass(0.5, 3.0), alpha(0.5, 2.0), len(0.8, 1.3), noise(-1.0, 1.0);
  System s;
  s.inv_mass = VectorXd(beads);
  for (int p = 0; p < beads; ++p) s.inv_mass[p] = 1.0 / mass(rng);
  s.x = Matrix3Xd(3, beads);
  s.x.col(0) << 0.3, -0.2, 0.5;
  for (int b = 0; b + 1 < beads; ++b) {
    StiffBond bond{b, b + 1, len(rng), alpha(rng)};
    s.bonds.push_back(bond);
    s.x.col(b + 1) = s.x.col(b) + bond.length * (1.0 + stretch * noise(rng)) * random_unit(rng);
  }
  return s;
}

// Stiff force −ε⁻² Σ_b α_b² g_b ∇g_b (docs/design.md §1), added to f.
void add_stiff_force(const std::vector<StiffBond>& bonds, double eps, const Matrix3Xd& x, Matrix3Xd& f) {
  for (const StiffBond& b : bonds) {
    const Vector3d d = x.col(b.i) - x.col(b.j);
    const double r = d.norm();
    const Vector3d fi = -(b.alpha * b.alpha * (r - b.length) / (eps * eps)) * (d / r);
    f.col(b.i) += fi;
    f.col(b.j) -= fi;
  }
}

// Velocity Verlet on H = ½ vᵀMv + U + ε⁻²V; `slow(x, f)` adds −∇U into f.
template <class Slow>
class Verlet {
 public:
  Verlet(const System& s, double eps, Slow slow) : s_(s), eps_(eps), slow_(slow), f_(3, s.x.cols()) {}
  void force(const Matrix3Xd& x) {
    f_.setZero();
    add_stiff_force(s_.bonds, eps_, x, f_);
    slow_(x, f_);
  }
  void start(const Matrix3Xd& x) { force(x); }
  void step(Matrix3Xd& x, Matrix3Xd& v, double dt) {
    for (int p = 0; p < x.cols(); ++p) v.col(p) += 0.5 * dt * s_.inv_mass[p] * f_.col(p);
    x += dt * v;
    force(x);
    for (int p = 0; p < x.cols(); ++p) v.col(p) += 0.5 * dt * s_.inv_mass[p] * f_.col(p);
  }

 private:
  const System& s_;
  double eps_;
  Slow slow_;
  Matrix3Xd f_;
};
auto no_slow = [](const Matrix3Xd&, Matrix3Xd&) {};

VectorXd freqs(StiffModes& modes, const Matrix3Xd& x) {
  VectorXd om(modes.num_modes());
  modes.frequencies(x, om);
  return om;
}

VectorXd acts(StiffModes& modes, const Matrix3Xd& x, const Matrix3Xd& v) {
  VectorXd I(modes.num_modes());
  modes.actions(x, v, I);
  return I;
}

// max |−∇W − central FD of W| / max |−∇W| over all coordinates (fixed particles included).
double fd_error(StiffModes& modes, const VectorXd& I, const Matrix3Xd& x) {
  Matrix3Xd f, scratch;
  const double W = modes.correction_force(I, x, f);
  EXPECT_NEAR(W, I.dot(freqs(modes, x)), 1e-13 * std::abs(W));
  const double h = 1e-5;
  double err = 0.0;
  for (int p = 0; p < x.cols(); ++p)
    for (int a = 0; a < 3; ++a) {
      Matrix3Xd xp = x, xm = x;
      xp(a, p) += h;
      xm(a, p) -= h;
      const double fd = -(modes.correction_force(I, xp, scratch) - modes.correction_force(I, xm, scratch)) / (2 * h);
      err = std::max(err, std::abs(fd - f(a, p)));
    }
  return err / f.cwiseAbs().maxCoeff();
}

// Brute force over all index triples and signs, exactly as paper eq. (nonresonant) reads.
double brute_resonance(const VectorXd& om) {
  double best = INFINITY;
  for (int j = 0; j < om.size(); ++j)
    for (int k = 0; k < om.size(); ++k)
      for (int l = 0; l < om.size(); ++l)
        for (double s1 : {-1.0, 1.0})
          for (double s2 : {-1.0, 1.0}) best = std::min(best, std::abs(om[j] + s1 * om[k] + s2 * om[l]));
  return best;
}

// ---------------------------------------------------------------------------------------

TEST(StiffModes, SingleBondFrequencyIsAlphaOverSqrtReducedMass) {
  const double alpha = 1.7, mi = 2.0, mj = 3.0;
  Matrix3Xd x(3, 2);
  x.col(0) << 0.1, 0.2, -0.3;
  x.col(1) << 1.0, -0.4, 0.25;  // off its rest length on purpose: ω does not depend on it
  VectorXd im(2);
  im << 1.0 / mi, 1.0 / mj;
  StiffModes modes({{0, 1, 0.9, alpha}}, im, 1e-3);
  ASSERT_EQ(modes.num_modes(), 1);
  const double mu = mi * mj / (mi + mj);
  EXPECT_NEAR(freqs(modes, x)[0], alpha / std::sqrt(mu), 1e-14);

  // Fixed partner (inverse mass 0), on either end: μ = m of the mobile particle.
  for (int fixed : {0, 1}) {
    VectorXd imf(2);
    imf << 1.0 / mi, 1.0 / mi;
    imf[fixed] = 0.0;
    StiffModes fm({{0, 1, 0.9, alpha}}, imf, 1e-3);
    EXPECT_NEAR(freqs(fm, x)[0], alpha / std::sqrt(mi), 1e-14) << "fixed particle " << fixed;
  }
}

// The modes come cluster after cluster in find_clusters' order (integrators/clusters.hpp), which
// the effective dynamics' actions and a decomposed run's share of them are numbered by. A pinned
// core (0) with two one-bond arms, bonds 0 (ω = 1, a unit mass) and 2 (ω = 2, inverse mass 4),
// a free unit dimer's bond 1 (ω = √2) listed between them: three clusters, modes [1, √2, 2]. Had
// the core coupled its arms, their cluster's modes would come first and ascending: [1, 2, √2].
TEST(StiffModes, ModesComeClusterAfterClusterAPinnedBeadSplittingThem) {
  Matrix3Xd x(3, 5);
  x.col(0) << 0.0, 0.0, 0.0;
  x.col(1) << 1.0, 0.0, 0.0;
  x.col(2) << 5.0, 0.0, 0.0;
  x.col(3) << 6.0, 0.0, 0.0;
  x.col(4) << 0.0, 1.0, 0.0;
  VectorXd im(5);
  im << 0.0, 1.0, 1.0, 1.0, 4.0;
  StiffModes modes({{0, 1, 1.0, 1.0}, {2, 3, 1.0, 1.0}, {0, 4, 1.0, 1.0}}, im, 1e-3);
  ASSERT_EQ(modes.num_modes(), 3);
  const VectorXd omega = freqs(modes, x);
  EXPECT_NEAR(omega[0], 1.0, 1e-14);
  EXPECT_NEAR(omega[1], std::sqrt(2.0), 1e-14);
  EXPECT_NEAR(omega[2], 2.0, 1e-14);
}

// Paper eq. (CH): ω_k² are the nonzero eigenvalues of the pencil λM − ∇²V on the manifold.
// Checked against a finite-difference Hessian of V, independently of A = K½ S K½.
TEST(StiffModes, FrequenciesAreTheNonzeroEigenvaluesOfThePencil) {
  std::mt19937 rng(7);
  System s = random_chain(rng, 5, 0.0);
  StiffModes modes(s.bonds, s.inv_mass, 1.0);
  const VectorXd om = freqs(modes, s.x);
  const int n = 3 * static_cast<int>(s.x.cols());
  auto gradV = [&](const Matrix3Xd& x) {
    Matrix3Xd f = Matrix3Xd::Zero(3, x.cols());
    add_stiff_force(s.bonds, 1.0, x, f);
    return VectorXd(-Eigen::Map<const VectorXd>(f.data(), n));
  };
  MatrixXd H(n, n);
  const double h = 1e-6;
  for (int c = 0; c < n; ++c) {
    Matrix3Xd xp = s.x, xm = s.x;
    xp.data()[c] += h;
    xm.data()[c] -= h;
    H.col(c) = (gradV(xp) - gradV(xm)) / (2 * h);
  }
  VectorXd sqrt_im(n);
  for (int c = 0; c < n; ++c) sqrt_im[c] = std::sqrt(s.inv_mass[c / 3]);
  const MatrixXd B = sqrt_im.asDiagonal() * (0.5 * (H + H.transpose())) * sqrt_im.asDiagonal();
  const VectorXd ev = Eigen::SelfAdjointEigenSolver<MatrixXd>(B).eigenvalues();  // ascending
  const int m = static_cast<int>(om.size());
  for (int k = 0; k < n - m; ++k) EXPECT_NEAR(ev[k], 0.0, 1e-6);
  for (int k = 0; k < m; ++k) EXPECT_NEAR(ev[n - m + k], om[k] * om[k], 1e-6 * om[k] * om[k]);
}

TEST(StiffModes, CorrectionForceMatchesFiniteDifferenceOnPendulum) {
  System s = pendulum(0.01);
  StiffModes modes(s.bonds, s.inv_mass, 1e-3);
  std::mt19937 rng(11);
  std::uniform_real_distribution<double> act(0.2, 2.0);
  VectorXd I(2);
  I << act(rng), act(rng);
  const double err = fd_error(modes, I, s.x);
  std::printf("[ measure  ] pendulum: relative FD error of -grad W = %.2e\n", err);
  EXPECT_LT(err, 1e-6);
}

TEST(StiffModes, CorrectionForceMatchesFiniteDifferenceOnRandomChain) {
  std::mt19937 rng(2024);
  System s = random_chain(rng, 6, 0.05);
  StiffModes modes(s.bonds, s.inv_mass, 1e-3);
  ASSERT_EQ(modes.num_modes(), 5);
  // W is smooth only where the frequencies are separated; make sure this sample is.
  ASSERT_GT(modes.validity(s.x).min_gap, 1e-2);
  std::uniform_real_distribution<double> act(0.2, 2.0);
  VectorXd I(5);
  for (int k = 0; k < 5; ++k) I[k] = act(rng);
  const double err = fd_error(modes, I, s.x);
  std::printf("[ measure  ] random 6-bead chain: relative FD error of -grad W = %.2e\n", err);
  EXPECT_LT(err, 1e-6);
}

// A single bond in pure radial vibration (plus uniform translation) is an exact harmonic
// oscillator of frequency Ω = ω/ε: its action must equal J/ε = μ ω A²/(2ε²) (A the
// amplitude; paper eq. (actions)) and stay constant along the motion.
TEST(StiffModes, ActionOfSingleHarmonicBondIsExactAndConstant) {
  const double eps = 1e-3, alpha = 1.3, m0 = 1.0, m1 = 2.5, ell = 1.0;
  const double stretch = 2 * eps, rdot = 1.5;
  std::mt19937 rng(3);
  const Vector3d e = random_unit(rng), V(0.3, -0.2, 0.7);
  System s;
  s.bonds = {{0, 1, ell, alpha}};
  s.inv_mass = VectorXd(2);
  s.inv_mass << 1.0 / m0, 1.0 / m1;
  s.x = Matrix3Xd(3, 2);
  s.x.col(0) << 0.4, 0.1, -0.2;
  s.x.col(1) = s.x.col(0) - (ell + stretch) * e;
  Matrix3Xd v(3, 2);
  v.col(0) = V + (m1 / (m0 + m1)) * rdot * e;
  v.col(1) = V - (m0 / (m0 + m1)) * rdot * e;

  StiffModes modes(s.bonds, s.inv_mass, eps);
  const double mu = m0 * m1 / (m0 + m1), omega = alpha / std::sqrt(mu), Omega = omega / eps;
  const double amp = std::sqrt(stretch * stretch + (rdot / Omega) * (rdot / Omega));
  const double I0 = acts(modes, s.x, v)[0];
  EXPECT_NEAR(I0, mu * omega * amp * amp / (2 * eps * eps), 1e-12 * I0);

  const double period = 2 * kPi / Omega, dt = period / 20000;
  Verlet vv(s, eps, no_slow);
  vv.start(s.x);
  double drift = 0.0, max_g = 0.0;
  for (int n = 0; n < 5 * 20000; ++n) {
    vv.step(s.x, v, dt);
    max_g = std::max(max_g, std::abs((s.x.col(0) - s.x.col(1)).norm() - ell));
    drift = std::max(drift, std::abs(acts(modes, s.x, v)[0] - I0) / I0);
  }
  std::printf("[ measure  ] single harmonic bond, 5 periods: max relative action change = %.2e\n", drift);
  EXPECT_LT(drift, 1e-6);
  EXPECT_NEAR(max_g, amp, 1e-5 * amp);  // the action belongs to the amplitude actually seen
}

// Exciting one normal mode (v along M⁻¹Gᵀ K½ q_k, on the manifold) must give action to that
// mode only: checks that actions are modal (w = Qᵀz), not per bond. The modes are built here
// from dense G and M, independently of the implementation.
TEST(StiffModes, SingleModeExcitationStaysInItsMode) {
  const double eps = 1e-3;
  std::mt19937 rng(5);
  System s = random_chain(rng, 5, 0.0);
  const int m = 4, n = 5;
  MatrixXd G = MatrixXd::Zero(m, 3 * n);
  VectorXd sqrtK(m), im3(3 * n);
  for (int b = 0; b < m; ++b) {
    const Vector3d u = (s.x.col(s.bonds[b].i) - s.x.col(s.bonds[b].j)).normalized();
    G.block<1, 3>(b, 3 * s.bonds[b].i) = u.transpose();
    G.block<1, 3>(b, 3 * s.bonds[b].j) = -u.transpose();
    sqrtK[b] = s.bonds[b].alpha;
  }
  for (int c = 0; c < 3 * n; ++c) im3[c] = s.inv_mass[c / 3];
  const MatrixXd A = sqrtK.asDiagonal() * (G * im3.asDiagonal() * G.transpose()) * sqrtK.asDiagonal();
  Eigen::SelfAdjointEigenSolver<MatrixXd> es(A);
  StiffModes modes(s.bonds, s.inv_mass, eps);

  for (int k = 0; k < m; ++k) {
    const double om = std::sqrt(es.eigenvalues()[k]);
    const double amp = std::sqrt(2.0 / om);  // chosen so that I_k = ½ ω_k amp² = 1
    const VectorXd vflat = amp * (im3.asDiagonal() * G.transpose() * sqrtK.asDiagonal() * es.eigenvectors().col(k));
    Matrix3Xd v = Eigen::Map<const Matrix3Xd>(vflat.data(), 3, n);
    Matrix3Xd x = s.x;
    const VectorXd I0 = acts(modes, x, v);
    for (int j = 0; j < m; ++j) EXPECT_NEAR(I0[j], j == k ? 1.0 : 0.0, 1e-12) << "mode " << k << ", action " << j;

    // A few slowest periods: the other actions stay O(ε), this one constant to O(ε).
    const double dt = eps / (200 * std::sqrt(es.eigenvalues()[m - 1]));
    const int steps = static_cast<int>(3 * 2 * kPi * eps / std::sqrt(es.eigenvalues()[0]) / dt);
    Verlet vv(s, eps, no_slow);
    vv.start(x);
    double leak = 0.0, drift = 0.0;
    for (int t = 1; t <= steps; ++t) {
      vv.step(x, v, dt);
      if (t % 50) continue;
      const VectorXd I = acts(modes, x, v);
      for (int j = 0; j < m; ++j) (j == k ? drift : leak) = std::max(j == k ? drift : leak, std::abs(I[j] - I0[j]));
    }
    std::printf("[ measure  ] mode %d excited: own action drift %.2e, max other action %.2e\n", k, drift, leak);
    EXPECT_LT(drift, 10 * eps);
    EXPECT_LT(leak, 1e-4);
  }
}

// Velocity Verlet at step ε/200 over t ∈ [0, 1] on the stiff pendulum with gravity
// (U = y₁ + y₂), from rest at s.x; returns the actions at t = 0 and the largest absolute
// change of each along the way.
struct Drift {
  VectorXd I0, abs_change;
  Vector3d x1_end;
};
Drift pendulum_action_drift(System s, double eps) {
  Matrix3Xd v = Matrix3Xd::Zero(3, 3);
  StiffModes modes(s.bonds, s.inv_mass, eps);
  Drift d;
  d.I0 = acts(modes, s.x, v);
  d.abs_change = VectorXd::Zero(d.I0.size());
  auto gravity = [](const Matrix3Xd&, Matrix3Xd& f) { f.row(1).array() -= 1.0; };  // pivot is fixed anyway
  Verlet vv(s, eps, gravity);
  vv.start(s.x);
  const double dt = eps / 200;
  const int steps = static_cast<int>(std::lround(1.0 / dt));
  for (int t = 1; t <= steps; ++t) {
    vv.step(s.x, v, dt);
    if (t % 100) continue;
    d.abs_change = d.abs_change.cwiseMax((acts(modes, s.x, v) - d.I0).cwiseAbs());
  }
  d.x1_end = s.x.col(1);
  return d;
}

// Adiabatic invariance (paper eq. (action-inv)): along the full stiff motion the actions
// change by O(ε) only, while the pendulum swings through an O(1) angle.
TEST(StiffModes, ActionsAreAdiabaticInvariantsOnStiffPendulum) {
  const double eps = 1e-3;
  const Vector3d x1_start = pendulum(0).x.col(1);

  // Both bonds stretched (bond 1 by 3ε, bond 2 by ≈3.5ε): both actions are O(1).
  System both = pendulum(5 * eps);
  both.x.col(1) *= 1 + 3 * eps;
  const Drift d = pendulum_action_drift(both, eps);
  const VectorXd rel = d.abs_change.cwiseQuotient(d.I0);
  std::printf("[ measure  ] pendulum, both modes excited: I(0) = %.4f %.4f, max relative drift on [0,1] = %.2e %.2e\n",
              d.I0[0], d.I0[1], rel[0], rel[1]);
  EXPECT_GT(d.I0.minCoeff(), 1e-3);  // not vacuous
  EXPECT_LT(rel.maxCoeff(), 0.05);
  EXPECT_GT((d.x1_end - x1_start).norm(), 0.1);  // the pendulum really swung

  // The paper's initial data (IV), x₂ = (√2, 5ε): the bonds start perpendicular
  // (u₁·u₂ ≈ −3.5ε), so the modes are the bonds up to O(ε) mixing and only bond 2 is
  // stretched; the ω≈1 mode receives an O(ε²) share of the action (≈ 8e-5). A relative
  // drift of that is meaningless: eq. (action-inv) bounds I_k(t) − I_k(0) = O(ε) absolutely.
  const Drift p = pendulum_action_drift(pendulum(5 * eps), eps);
  std::printf("[ measure  ] pendulum, paper data (IV): I(0) = %.3e %.4f, max |I(t) - I(0)| on [0,1] = %.2e %.2e\n",
              p.I0[0], p.I0[1], p.abs_change[0], p.abs_change[1]);
  EXPECT_GT(p.I0[1], 1.0);
  EXPECT_LT(p.abs_change[1], 0.05 * p.I0[1]);
  EXPECT_LT(p.abs_change.maxCoeff(), 10 * eps * p.I0.sum());
}

TEST(StiffModes, FrequenciesActionsAndForceAreRigidMotionCovariant) {
  std::mt19937 rng(99);
  System s = random_chain(rng, 6, 0.03);
  std::normal_distribution<double> nd(0.0, 1.0);
  Matrix3Xd v(3, 6);
  for (int p = 0; p < 6; ++p) v.col(p) << nd(rng), nd(rng), nd(rng);
  StiffModes modes(s.bonds, s.inv_mass, 1e-2);
  const Eigen::Matrix3d R = Eigen::Quaterniond(nd(rng), nd(rng), nd(rng), nd(rng)).normalized().toRotationMatrix();
  const Vector3d t(1.5, -2.0, 0.7), Vcm(0.4, 0.9, -1.1);
  const Matrix3Xd x2 = (R * s.x).colwise() + t;
  const Matrix3Xd v2 = (R * v).colwise() + Vcm;  // no fixed particle: a uniform velocity is invisible

  const VectorXd om1 = freqs(modes, s.x), om2 = freqs(modes, x2);
  EXPECT_LT((om1 - om2).cwiseAbs().maxCoeff(), 1e-13 * om1.maxCoeff());
  const VectorXd I1 = acts(modes, s.x, v), I2 = acts(modes, x2, v2);
  EXPECT_LT((I1 - I2).cwiseAbs().maxCoeff(), 1e-10 * I1.maxCoeff());
  Matrix3Xd f1, f2;
  modes.correction_force(I1, s.x, f1);
  modes.correction_force(I1, x2, f2);
  EXPECT_LT((R * f1 - f2).cwiseAbs().maxCoeff(), 1e-10 * f1.cwiseAbs().maxCoeff());
  // Translation invariance of W means no net correction force.
  EXPECT_LT(f1.rowwise().sum().norm(), 1e-10 * f1.cwiseAbs().maxCoeff());
}

TEST(StiffModes, ValidityMonitorOnPendulumAndChain) {
  System s = pendulum(0.01);
  StiffModes modes(s.bonds, s.inv_mass, 1e-3);
  const VectorXd om = freqs(modes, s.x);
  const StiffModes::Validity val = modes.validity(s.x);
  std::printf("[ measure  ] pendulum: omega = %.6f %.6f, min_gap %.6f, min_resonance %.6f\n", om[0], om[1], val.min_gap,
              val.min_resonance);
  EXPECT_LT(om[0], om[1]);
  EXPECT_NEAR(val.min_gap, std::abs(om[1] - om[0]), 1e-14);
  EXPECT_NEAR(val.min_resonance, brute_resonance(om), 1e-14);
  EXPECT_NEAR(val.min_resonance, std::abs(2 * om[0] - om[1]), 1e-14);  // the near 1:2 resonance

  std::mt19937 rng(19);  // a sample whose closest pair is not the lowest two frequencies
  System c = random_chain(rng, 8, 0.02);
  StiffModes cm(c.bonds, c.inv_mass, 1e-3);
  VectorXd oc = freqs(cm, c.x);
  std::sort(oc.data(), oc.data() + oc.size());
  double gap = INFINITY;
  for (int j = 0; j < oc.size(); ++j)
    for (int k = 0; k < oc.size(); ++k)
      if (j != k) gap = std::min(gap, std::abs(oc[j] - oc[k]));
  ASSERT_LT(gap, oc[1] - oc[0]);
  const StiffModes::Validity vc = cm.validity(c.x);
  EXPECT_NEAR(vc.min_gap, gap, 1e-14);
  EXPECT_NEAR(vc.min_resonance, brute_resonance(oc), 1e-14);

  // One mode: no gap; the only "resonance" is ω itself (|ω − ω + ω|).
  StiffModes one({{0, 1, 1.0, 2.0}}, VectorXd::Ones(2), 1e-3);
  Matrix3Xd x1 = Matrix3Xd::Zero(3, 2);
  x1(0, 1) = 1.0;
  EXPECT_TRUE(std::isinf(one.validity(x1).min_gap));
  EXPECT_NEAR(one.validity(x1).min_resonance, 2.0 * std::sqrt(2.0), 1e-14);
}

TEST(StiffModes, LargeClustersAreSkippedAndCounted) {
  // Clusters in bond order: a 4-bond chain (0..4), a single bond (5,6), a 2-bond chain
  // (7,8,9), and two bonds meeting only at the fixed particle 10 (two 1-bond clusters).
  std::vector<StiffBond> bonds = {{0, 1, 1.0, 1.0}, {1, 2, 1.0, 1.0},   {2, 3, 1.0, 1.0},
                                  {3, 4, 1.0, 1.0}, {5, 6, 1.0, 2.0},   {7, 8, 1.0, 1.0},
                                  {8, 9, 1.0, 1.0}, {10, 11, 1.0, 3.0}, {10, 12, 1.0, 0.5}};
  VectorXd im = VectorXd::Ones(13);
  im[6] = 0.25;
  im[10] = 0.0;
  im[12] = 0.5;
  Matrix3Xd x = Matrix3Xd::Zero(3, 13);
  for (int p = 0; p < 13; ++p) x.col(p) << p, 0.1 * p * p, 0.0;  // no two particles coincide

  StiffModes small(bonds, im, 1e-3, 2);
  EXPECT_EQ(small.num_skipped_clusters(), 1);
  EXPECT_EQ(small.num_modes(), 5);
  const VectorXd om = freqs(small, x);
  EXPECT_NEAR(om[0], 2.0 * std::sqrt(1.0 + 0.25), 1e-14);  // bond (5,6): α/√μ comes first
  EXPECT_NEAR(om[3], 3.0, 1e-14);                          // (10,11), pivot fixed: α/√m
  EXPECT_NEAR(om[4], 0.5 * std::sqrt(0.5), 1e-14);         // (10,12)
  Matrix3Xd f;
  small.correction_force(VectorXd::Ones(5), x, f);
  EXPECT_EQ(f.cols(), 13);
  EXPECT_EQ(f.leftCols(5).cwiseAbs().maxCoeff(), 0.0);  // the skipped chain gets no force
  // A lone bond's ω = α/√μ does not depend on x, so it exerts no correction force; the
  // angle-dependent frequencies of the 2-bond chain do.
  EXPECT_EQ(f.col(6).norm(), 0.0);
  EXPECT_GT(f.middleCols(7, 3).norm(), 0.0);

  StiffModes all(bonds, im, 1e-3, 4);
  EXPECT_EQ(all.num_skipped_clusters(), 0);
  EXPECT_EQ(all.num_modes(), 9);
  StiffModes none(bonds, im, 1e-3, 1);
  EXPECT_EQ(none.num_skipped_clusters(), 2);
  EXPECT_EQ(none.num_modes(), 3);
}

// The chain path (tridiagonal eigenvalues + twisted-factorization eigenvectors, the pair formula
// for −∇W) against the dense path, which shares none of that code: to round-off on random chains,
// free or hanging from a fixed particle, also one split into two chains at a fixed bead.
TEST(StiffModes, ChainPathAgreesWithDensePath) {
  std::mt19937 rng(31);
  std::normal_distribution<double> nd(0.0, 1.0);
  std::uniform_real_distribution<double> act(0.2, 2.0);
  for (int trial = 0; trial < 8; ++trial) {
    const int beads = std::vector<int>{2, 3, 5, 12, 30, 60, 100, 41}[trial];
    System s = random_chain(rng, beads, 0.05);
    if (trial == 3) s.inv_mass[0] = 0.0;          // a pendulum
    if (trial == 7) s.inv_mass[beads / 2] = 0.0;  // two chains sharing a fixed bead
    Matrix3Xd v(3, beads);
    for (int p = 0; p < beads; ++p) v.col(p) << nd(rng), nd(rng), nd(rng);
    StiffModes fast(s.bonds, s.inv_mass, 1e-2, StiffModes::kMaxDenseBonds, StiffModes::Solver::fast);
    StiffModes dense(s.bonds, s.inv_mass, 1e-2, StiffModes::kMaxDenseBonds, StiffModes::Solver::dense);
    const VectorXd om_f = freqs(fast, s.x), om_d = freqs(dense, s.x);
    EXPECT_LT((om_f - om_d).cwiseAbs().maxCoeff(), 1e-14 * om_d.maxCoeff()) << beads << " beads";
    const VectorXd I_f = acts(fast, s.x, v), I_d = acts(dense, s.x, v);
    EXPECT_LT((I_f - I_d).cwiseAbs().maxCoeff(), 1e-10 * I_d.maxCoeff()) << beads << " beads";
    VectorXd I(om_d.size());
    for (int k = 0; k < I.size(); ++k) I[k] = act(rng);
    Matrix3Xd f_f, f_d;
    const double W_f = fast.correction_force(I, s.x, f_f), W_d = dense.correction_force(I, s.x, f_d);
    EXPECT_NEAR(W_f, W_d, 1e-14 * W_d) << beads << " beads";
    // Relative to the force, plus W's round-off (a lone bond has no correction force at all).
    const double f_scale = f_d.cwiseAbs().maxCoeff() + 1e-4 * W_d;
    EXPECT_LT((f_f - f_d).cwiseAbs().maxCoeff(), 1e-10 * f_scale) << beads << " beads";
    std::printf("[ measure  ] %d beads: chain vs dense path: omega %.1e, I %.1e, W %.1e, force %.1e (relative)\n",
                beads, (om_f - om_d).cwiseAbs().maxCoeff() / om_d.maxCoeff(),
                (I_f - I_d).cwiseAbs().maxCoeff() / I_d.maxCoeff(), std::abs(W_f - W_d) / W_d,
                (f_f - f_d).cwiseAbs().maxCoeff() / f_scale);
    const StiffModes::Validity val_f = fast.validity(s.x), val_d = dense.validity(s.x);
    if (std::isinf(val_d.min_gap))
      EXPECT_TRUE(std::isinf(val_f.min_gap));
    else
      EXPECT_NEAR(val_f.min_gap, val_d.min_gap, 1e-13 * om_d.maxCoeff());
    EXPECT_NEAR(val_f.min_resonance, val_d.min_resonance, 1e-13 * om_d.maxCoeff());
  }
}

// Molecules of one and two bonds take closed forms (modes.cpp, small_chain) instead of LAPACK:
// against the dense path on a mixture of dimers, trimers and a longer chain (the mode offsets of
// one object), with masses, α and angles that stress the 2 × 2 formulas: straight (u·u' = ±1),
// nearly perpendicular with equal diagonal (a close pair of eigenvalues), and exactly
// perpendicular with equal diagonal (a double eigenvalue: any basis, so equal actions there).
TEST(StiffModes, SmallMoleculesInClosedFormAgreeWithDensePath) {
  std::mt19937 rng(8);
  std::normal_distribution<double> nd(0.0, 1.0);
  System all;
  all.inv_mass = VectorXd(0);
  auto add = [&](const System& s) {
    const int offset = static_cast<int>(all.inv_mass.size()), n = static_cast<int>(s.inv_mass.size());
    all.inv_mass.conservativeResize(offset + n);
    all.inv_mass.tail(n) = s.inv_mass;
    all.x.conservativeResize(3, offset + n);
    all.x.rightCols(n) = s.x;
    for (StiffBond b : s.bonds) all.bonds.push_back({b.i + offset, b.j + offset, b.length, b.alpha});
  };
  // A trimer of unit masses and α with bond angle cos = c between the two bond vectors.
  auto trimer = [](double c) {
    System s;
    s.bonds = {{0, 1, 1.0, 1.0}, {1, 2, 1.0, 1.0}};
    s.inv_mass = VectorXd::Ones(3);
    s.x = Matrix3Xd::Zero(3, 3);
    s.x.col(1) << 1.02, 0.0, 0.0;
    // u_0 = (x0 − x1)/r, u_1 = (x1 − x2)/r: x2 = x1 − 0.99 (c, √(1 − c²), 0) · sign convention of u_0 = −e_x.
    s.x.col(2) = s.x.col(1) + 0.99 * Vector3d(c, std::sqrt(std::max(0.0, 1.0 - c * c)), 0.0);
    return s;
  };
  for (double c : {1.0, -1.0, 0.3, -0.7, 1e-7}) add(trimer(c));
  add(trimer(0.0));  // the double eigenvalue: last trimer, modes num_modes − 2, num_modes − 1 (see below)
  for (int k = 0; k < 20; ++k) add(random_chain(rng, 2 + k % 2, 0.05));
  add(random_chain(rng, 7, 0.05));
  const int beads = static_cast<int>(all.inv_mass.size());
  Matrix3Xd v(3, beads);
  for (int p = 0; p < beads; ++p) v.col(p) << nd(rng), nd(rng), nd(rng);
  StiffModes fast(all.bonds, all.inv_mass, 1e-2, StiffModes::kMaxDenseBonds, StiffModes::Solver::fast);
  StiffModes dense(all.bonds, all.inv_mass, 1e-2, StiffModes::kMaxDenseBonds, StiffModes::Solver::dense);
  ASSERT_EQ(fast.num_modes(), dense.num_modes());
  const VectorXd om_f = freqs(fast, all.x), om_d = freqs(dense, all.x);
  EXPECT_LT((om_f - om_d).cwiseAbs().maxCoeff(), 1e-14 * om_d.maxCoeff());
  // The exactly perpendicular trimer (modes 10, 11) has a double eigenvalue: its split into
  // actions depends on the basis, so it is left out of the comparison of I.
  const VectorXd I_f = acts(fast, all.x, v), I_d = acts(dense, all.x, v);
  for (int k = 0; k < I_d.size(); ++k) {
    if (k == 10 || k == 11) continue;
    EXPECT_NEAR(I_f[k], I_d[k], 1e-10 * I_d.maxCoeff()) << "mode " << k;
  }
  std::uniform_real_distribution<double> act(0.2, 2.0);
  VectorXd I(om_d.size());
  for (int k = 0; k < I.size(); ++k) I[k] = act(rng);
  I[11] = I[10];  // equal actions on the double eigenvalue: W is then smooth and basis-free
  Matrix3Xd f_f, f_d;
  const double W_f = fast.correction_force(I, all.x, f_f), W_d = dense.correction_force(I, all.x, f_d);
  EXPECT_NEAR(W_f, W_d, 1e-14 * W_d);
  EXPECT_LT((f_f - f_d).cwiseAbs().maxCoeff(), 1e-12 * f_d.cwiseAbs().maxCoeff());
  // And the closed forms' force is the gradient of their W.
  StiffModes one_trimer(trimer(0.3).bonds, VectorXd::Ones(3), 1e-2);
  EXPECT_LT(fd_error(one_trimer, VectorXd::LinSpaced(2, 0.7, 1.3), trimer(0.3).x), 1e-6);
}

TEST(StiffModes, ChainPathForceMatchesFiniteDifferenceOnLongChain) {
  std::mt19937 rng(77);
  System s = random_chain(rng, 25, 0.05);
  StiffModes modes(s.bonds, s.inv_mass, 1e-3);
  ASSERT_GT(modes.validity(s.x).min_gap, 1e-3);  // W smooth here
  std::uniform_real_distribution<double> act(0.2, 2.0);
  VectorXd I(modes.num_modes());
  for (int k = 0; k < I.size(); ++k) I[k] = act(rng);
  const double err = fd_error(modes, I, s.x);
  std::printf("[ measure  ] random 25-bead chain, chain path: relative FD error of -grad W = %.2e\n", err);
  EXPECT_LT(err, 1e-6);
}

// Above the serial threshold the chains are decomposed on the threads: bit-identical results.
TEST(StiffModes, ChainPathDoesNotDependOnTheThreadCount) {
  std::mt19937 rng(5);
  System all;
  all.inv_mass = VectorXd(0);
  for (int c = 0; c < 45; ++c) {
    const System s = random_chain(rng, 101, 0.03);
    const int offset = static_cast<int>(all.inv_mass.size());
    all.inv_mass.conservativeResize(offset + 101);
    all.inv_mass.tail(101) = s.inv_mass;
    all.x.conservativeResize(3, offset + 101);
    all.x.rightCols(101) = s.x;
    for (StiffBond b : s.bonds) all.bonds.push_back({b.i + offset, b.j + offset, b.length, b.alpha});
  }
  const int restore = max_threads();
  set_max_threads(2);  // the workspaces are made for the thread count at construction
  StiffModes modes(all.bonds, all.inv_mass, 1e-2, StiffModes::kMaxDenseBonds);
  const VectorXd I = VectorXd::LinSpaced(modes.num_modes(), 0.5, 1.5);
  Matrix3Xd f1, f2;
  VectorXd om1(modes.num_modes()), om2(modes.num_modes());
  set_max_threads(1);
  const double W1 = modes.correction_force(I, all.x, f1);
  modes.frequencies(all.x, om1);
  set_max_threads(2);
  const double W2 = modes.correction_force(I, all.x, f2);
  modes.frequencies(all.x, om2);
  set_max_threads(restore);
  EXPECT_EQ(W1, W2);
  EXPECT_TRUE(f1 == f2);
  EXPECT_TRUE(om1 == om2);
}

TEST(StiffModes, BadInputAndDegenerateGeometryAreReported) {
  VectorXd im = VectorXd::Ones(3);
  std::vector<StiffBond> b = {{0, 1, 1.0, 1.0}};
  EXPECT_THROW(StiffModes(b, im, 0.0), InputError);
  EXPECT_THROW(StiffModes(b, im, 1e-3, 0), InputError);
  EXPECT_THROW(StiffModes(b, im, 1e-3, StiffModes::kMaxDenseBonds + 1), InputError);
  EXPECT_THROW(StiffModes({{0, 3, 1.0, 1.0}}, im, 1e-3), InputError);
  EXPECT_THROW(StiffModes({{1, 1, 1.0, 1.0}}, im, 1e-3), InputError);
  EXPECT_THROW(StiffModes({{0, 1, 1.0, 0.0}}, im, 1e-3), InputError);
  VectorXd two_fixed = im;
  two_fixed[0] = two_fixed[1] = 0.0;
  EXPECT_THROW(StiffModes(b, two_fixed, 1e-3), InputError);

  StiffModes modes(b, im, 1e-3);
  Matrix3Xd x = Matrix3Xd::Zero(3, 3);
  VectorXd om(1);
  EXPECT_THROW(modes.frequencies(x, om), NumericalError);  // particles 0 and 1 coincide
  x(0, 1) = 1.0;
  VectorXd wrong(2);
  EXPECT_THROW(modes.frequencies(x, wrong), std::invalid_argument);
  EXPECT_THROW(modes.frequencies(Matrix3Xd::Zero(3, 2), om), std::invalid_argument);

  // Rest lengths 1, 1, 2 are refused: only collinear triangles satisfy them (stiff_bond.hpp).
  EXPECT_THROW(StiffModes({{0, 1, 1.0, 1.0}, {1, 2, 1.0, 1.0}, {0, 2, 2.0, 1.0}}, im, 1e-3), InputError);
  // A collinear configuration of a realisable triangle has a redundant constraint: one frequency
  // is zero, so its action is undefined.
  StiffModes tri({{0, 1, 1.0, 1.0}, {1, 2, 1.0, 1.0}, {0, 2, 1.9, 1.0}}, im, 1e-3);
  Matrix3Xd xt = Matrix3Xd::Zero(3, 3);
  xt(0, 1) = 1.0;
  xt(0, 2) = 2.0;
  VectorXd ot(3), It(3);
  tri.frequencies(xt, ot);
  EXPECT_LT(ot[0], 1e-7);
  EXPECT_THROW(tri.actions(xt, Matrix3Xd::Zero(3, 3), It), NumericalError);
}

}  // namespace
}  // namespace stiffmd
