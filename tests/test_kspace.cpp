// The reciprocal-space terms of Ewald summation (forcefields/kspace/): EwaldSum and PPPM against
// the Madelung constant of rock salt, their own energies (forces by central differences, the
// virial by box scaling), a converged Ewald sum (the RMS force error of the parameters chosen for
// an accuracy, LAMMPS's way), a charged system's g-independence, a decomposed evaluation on fake
// ranks, and bad inputs. The real-space part is a plain sum here (real_space below): the pair styles
// that compute it in a run are not these terms'.
#include <gtest/gtest.h>

#include "core/units.hpp"

#include <Eigen/Core>
#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <numbers>
#include <random>
#include <vector>

#include "core/format.hpp"
#include "core/topology.hpp"
#include "fake_processes.hpp"
#include "force_term_checks.hpp"
#include "forcefields/kspace/ewald_parameters.hpp"
#include "forcefields/kspace/ewald_sum.hpp"
#include "forcefields/kspace/pppm.hpp"

namespace stiffmd {
namespace {

using test::energy_of;
using test::forces_of;
using test::periodic_box;

constexpr double kPi = std::numbers::pi;
constexpr double kQqrd2eReal = Units::kRealCoulomb;  // kcal·Å/(mol·e²)

// The real-space Ewald sum, plainly: every pair and every periodic image within `cutoff` (no
// minimum image), C q_i q_j erfc(g r)/r, and each particle with its own images (no force). O(N²)
// times the images.
struct RealSpace {
  double energy = 0.0;
  Eigen::Matrix3Xd f;
};
RealSpace real_space(const Eigen::Matrix3Xd& x, const std::vector<double>& q, const Box& box, double g, double cutoff,
                     double c) {
  const int n = static_cast<int>(x.cols());
  RealSpace r;
  r.f = Eigen::Matrix3Xd::Zero(3, n);
  int images[3];
  for (int a = 0; a < 3; ++a) images[a] = static_cast<int>(std::ceil(cutoff / box.lengths[a]));
  const double rc2 = cutoff * cutoff;
  const double two_over_sqrt_pi = 2.0 / std::sqrt(kPi);
  for (int i = 0; i < n; ++i)
    for (int j = i; j < n; ++j) {
      const Eigen::Vector3d d = box.min_image(x.col(i) - x.col(j));
      const double qq = c * q[i] * q[j];
      for (int ix = -images[0]; ix <= images[0]; ++ix)
        for (int iy = -images[1]; iy <= images[1]; ++iy)
          for (int iz = -images[2]; iz <= images[2]; ++iz) {
            const Eigen::Vector3d rv =
                d + Eigen::Vector3d(ix * box.lengths[0], iy * box.lengths[1], iz * box.lengths[2]);
            const double r2 = rv.squaredNorm();
            if (r2 >= rc2 || r2 == 0.0) continue;
            const double rr = std::sqrt(r2);
            const double e = qq * std::erfc(g * rr) / rr;
            if (i == j) {
              r.energy += 0.5 * e;
              continue;
            }
            r.energy += e;
            const double fpair = (e + qq * two_over_sqrt_pi * g * std::exp(-g * g * r2)) / r2;
            r.f.col(i) += fpair * rv;
            r.f.col(j) -= fpair * rv;
          }
    }
  return r;
}

// Positions and charges of a neutral random system: n particles uniform in the box, charges ±1
// in equal numbers (plus `extra` on the first) shuffled.
struct Charged {
  Eigen::Matrix3Xd x;
  std::vector<double> q;
};
Charged random_charges(int n, const Box& box, unsigned seed, double extra = 0.0) {
  std::mt19937 rng(seed);
  std::uniform_real_distribution<double> u(0.0, 1.0);
  Charged s;
  s.x.resize(3, n);
  for (int i = 0; i < n; ++i)
    for (int a = 0; a < 3; ++a) s.x(a, i) = box.origin[a] + box.lengths[a] * u(rng);
  for (int i = 0; i < n; ++i) s.q.push_back(i % 2 ? -1.0 : 1.0);
  std::shuffle(s.q.begin(), s.q.end(), rng);
  s.q[0] += extra;
  return s;
}

// A molten salt at liquid density: m³ ions (±1, shuffled) on a simple cubic lattice of spacing
// `spacing`, each displaced uniformly by up to ±0.3 spacing per axis.
Charged melt(int m, double spacing, unsigned seed) {
  std::mt19937 rng(seed);
  std::uniform_real_distribution<double> jitter(-0.3 * spacing, 0.3 * spacing);
  Charged s;
  s.x.resize(3, m * m * m);
  int i = 0;
  for (int a = 0; a < m; ++a)
    for (int b = 0; b < m; ++b)
      for (int c = 0; c < m; ++c, ++i) {
        s.x.col(i) = spacing * Eigen::Vector3d(a + 0.5, b + 0.5, c + 0.5);
        for (int k = 0; k < 3; ++k) s.x(k, i) += jitter(rng);
        s.q.push_back(i % 2 ? -1.0 : 1.0);
      }
  std::shuffle(s.q.begin(), s.q.end(), rng);
  return s;
}

// RMS over particles of |a_i − b_i|.
double rms_difference(const Eigen::Matrix3Xd& a, const Eigen::Matrix3Xd& b) {
  return std::sqrt((a - b).colwise().squaredNorm().sum() / static_cast<double>(a.cols()));
}

EwaldParameters ewald_parameters(double g, int kmax) {
  EwaldParameters p;
  p.g_ewald = g;
  p.kmax[0] = p.kmax[1] = p.kmax[2] = kmax;
  return p;
}

MeshParameters mesh_parameters(double g, int mesh, int order) {
  MeshParameters p;
  p.g_ewald = g;
  p.mesh[0] = p.mesh[1] = p.mesh[2] = mesh;
  p.order = order;
  return p;
}

// The k-vector index at which e^{−k²/4g²} < 1e-17 (a converged reciprocal sum).
int converged_kmax(double g, double length) {
  return static_cast<int>(std::ceil(2.0 * g * std::sqrt(17.0 * std::log(10.0)) * length / (2.0 * kPi))) + 1;
}

// The virial's diagonal from add_forces_and_virial_diagonal.
Eigen::Vector3d virial_diagonal(const ForceTerm& term, const Eigen::Matrix3Xd& x, const Box& box) {
  Eigen::Matrix3Xd f = Eigen::Matrix3Xd::Zero(3, x.cols());
  ExactDiagonal w;
  term.add_forces_and_virial_diagonal(x, box, f, w);
  return {w.axis[0].value(), w.axis[1].value(), w.axis[2].value()};
}

// −L_a ∂E/∂L_a at fixed scaled coordinates (the box's origin at 0), by central differences.
double axis_dilation_virial(const ForceTerm& term, const Eigen::Matrix3Xd& x, const Box& box, int a, double d) {
  auto scaled = [&](double lambda) {
    Box b = box;
    b.lengths[a] *= lambda;
    Eigen::Matrix3Xd y = x;
    y.row(a) *= lambda;
    return energy_of(term, y, b);
  };
  return -(scaled(1 + d) - scaled(1 - d)) / (2 * d);
}

TEST(KSpace, MadelungConstantOfRockSalt) {
  // NaCl: a cubic cell of edge 2m with nearest-neighbour distance 1, charge (−1)^{x+y+z}; the
  // total Ewald energy per ion pair is −M/a.
  constexpr double kMadelung = 1.747564594633182;
  for (const int m : {1, 2}) {
    const int side = 2 * m;
    Charged s;
    s.x.resize(3, side * side * side);
    int i = 0;
    for (int a = 0; a < side; ++a)
      for (int b = 0; b < side; ++b)
        for (int c = 0; c < side; ++c, ++i) {
          s.x.col(i) = Eigen::Vector3d(a, b, c);
          s.q.push_back((a + b + c) % 2 ? -1.0 : 1.0);
        }
    const Box box = periodic_box(Eigen::Vector3d::Constant(side), Eigen::Vector3d::Constant(-0.25));
    const double g = 2.5;  // erfc(g r) < 1e-17 beyond r = 2.6
    const EwaldSum ewald("coulomb", Level::slow, s.q, ewald_parameters(g, converged_kmax(g, side)), 1.0, box);
    const double e = energy_of(ewald, s.x, box) + real_space(s.x, s.q, box, g, 2.6, 1.0).energy;
    const double per_pair = e / (s.x.cols() / 2.0);
    std::printf("NaCl %d ions: E per ion pair %.15f, -M %.15f, relative error %.2e\n", static_cast<int>(s.x.cols()),
                per_pair, -kMadelung, std::abs(per_pair + kMadelung) / kMadelung);
    EXPECT_NEAR(per_pair, -kMadelung, 1e-10 * kMadelung);
    // By symmetry every ion's force vanishes.
    EXPECT_LT(forces_of(ewald, s.x, box).cwiseAbs().maxCoeff(), 1e-12);
  }
}

TEST(KSpace, AssignmentWeightsArePartitionsOfUnity) {
  double w[7];
  for (int order = 1; order <= 7; ++order)
    for (const double s : {0.0, 0.25, 0.5, 0.999, 3.3, 7.5}) {
      const int first = assignment_weights(s, order, w);
      double sum = 0.0, moment = 0.0;
      for (int j = 0; j < order; ++j) {
        EXPECT_GE(w[j], 0.0);
        sum += w[j];
        moment += w[j] * (first + j);
      }
      EXPECT_NEAR(sum, 1.0, 1e-14) << "order " << order << " s " << s;
      // The B-splines reproduce linear functions from order 2 on: Σ_j w_j m_j = s.
      if (order >= 2) {
        EXPECT_NEAR(moment, s, 1e-12) << "order " << order << " s " << s;
      }
      EXPECT_LE(first, s + 0.5);
      EXPECT_GE(first + order - 1, s - 0.5);
    }
}

TEST(KSpace, EwaldForcesAndVirialAreTheEnergysDerivatives) {
  const Box box = periodic_box({5.0, 6.0, 7.0}, {0.0, 0.0, 0.0});
  const Charged s = random_charges(24, box, 7);
  const EwaldSum ewald("coulomb", Level::slow, s.q, ewald_parameters(0.9, 7), 1.0, box);
  EXPECT_LT(test::fd_error(ewald, s.x, box, 1e-5), 1e-8);
  const Eigen::Vector3d w = virial_diagonal(ewald, s.x, box);
  for (int a = 0; a < 3; ++a) {
    const double fd = axis_dilation_virial(ewald, s.x, box, a, 1e-5);
    EXPECT_NEAR(w[a], fd, 1e-8 * std::max(1.0, std::abs(fd))) << "axis " << a;
  }
  EXPECT_NEAR(ewald.virial(s.x, box), w.sum(), 1e-12 * std::abs(w.sum()));
  // Internal forces: they sum to zero.
  EXPECT_LT(forces_of(ewald, s.x, box).rowwise().sum().norm(), 1e-12);
  // Unwrapped positions give the same forces.
  Eigen::Matrix3Xd shifted = s.x;
  shifted.col(3) += Eigen::Vector3d(10.0, -12.0, 21.0);
  EXPECT_LT((forces_of(ewald, shifted, box) - forces_of(ewald, s.x, box)).cwiseAbs().maxCoeff(), 1e-11);
}

TEST(KSpace, PppmForcesAndVirialAgreeWithItsEnergyToItsAccuracy) {
  // ik-differentiated forces are not −∇E exactly, nor is LAMMPS's virial −L ∂E/∂L exactly: both
  // agree to the method's accuracy, here about 1e-6 of the typical force.
  const Box box = periodic_box({5.0, 6.0, 7.0}, {0.0, 0.0, 0.0});
  const Charged s = random_charges(24, box, 7);
  MeshParameters p = mesh_parameters(0.9, 32, 7);
  p.mesh[1] = 36, p.mesh[2] = 40;
  const ParticleParticleParticleMesh pppm("coulomb", Level::slow, s.q, p, 1.0, box);
  const EwaldSum ewald("coulomb", Level::slow, s.q, ewald_parameters(0.9, converged_kmax(0.9, 7.0)), 1.0, box);
  const Eigen::Matrix3Xd f = forces_of(pppm, s.x, box);
  const double scale = f.cwiseAbs().maxCoeff();
  const double fd = test::fd_error(pppm, s.x, box, 1e-5) * std::max(1.0, scale) / scale;
  const double to_ewald = (f - forces_of(ewald, s.x, box)).cwiseAbs().maxCoeff() / scale;
  const double energy = std::abs(energy_of(pppm, s.x, box) / energy_of(ewald, s.x, box) - 1.0);
  std::printf("PPPM 32-40 mesh, order 7: |F + dE/dx| %.2e, |F - F_ewald| %.2e of max |F|; energy %.2e relative\n", fd,
              to_ewald, energy);
  EXPECT_LT(fd, 1e-5);
  EXPECT_LT(to_ewald, 1e-5);
  EXPECT_LT(energy, 1e-6);
  const Eigen::Vector3d w = virial_diagonal(pppm, s.x, box);
  for (int a = 0; a < 3; ++a) {
    const double by_dilation = axis_dilation_virial(pppm, s.x, box, a, 1e-5);
    std::printf("  virial axis %d: %.10f, by dilation %.10f\n", a, w[a], by_dilation);
    EXPECT_NEAR(w[a], by_dilation, 1e-5 * std::abs(by_dilation)) << "axis " << a;
  }
  EXPECT_NEAR(pppm.virial(s.x, box), w.sum(), 1e-12 * std::abs(w.sum()));
}

TEST(KSpace, ChargedSystemEnergyDoesNotDependOnG) {
  // Net charge +3: without the background term the total would shift with g.
  const Box box = periodic_box({5.0, 6.0, 7.0}, {0.0, 0.0, 0.0});
  const Charged s = random_charges(20, box, 11, 3.0);
  std::vector<double> totals;
  for (const double g : {0.8, 1.1, 1.5}) {
    const EwaldSum ewald("coulomb", Level::slow, s.q, ewald_parameters(g, converged_kmax(g, 7.0)), 1.0, box);
    const double cutoff = std::sqrt(17.0 * std::log(10.0)) / g;
    totals.push_back(energy_of(ewald, s.x, box) + real_space(s.x, s.q, box, g, cutoff, 1.0).energy);
  }
  for (const double t : totals) EXPECT_NEAR(t, totals[0], 1e-10 * std::abs(totals[0]));
  // The same with PPPM at a fine mesh, to its accuracy; and its virial against the dilation.
  const ParticleParticleParticleMesh pppm("coulomb", Level::slow, s.q, mesh_parameters(1.1, 40, 7), 1.0, box);
  const double cutoff = std::sqrt(17.0 * std::log(10.0)) / 1.1;
  EXPECT_NEAR(energy_of(pppm, s.x, box) + real_space(s.x, s.q, box, 1.1, cutoff, 1.0).energy, totals[0],
              1e-6 * std::abs(totals[0]));
  const EwaldSum ewald("coulomb", Level::slow, s.q, ewald_parameters(1.1, converged_kmax(1.1, 7.0)), 1.0, box);
  const Eigen::Vector3d w = virial_diagonal(ewald, s.x, box);
  for (int a = 0; a < 3; ++a) {
    const double fd = axis_dilation_virial(ewald, s.x, box, a, 1e-5);
    EXPECT_NEAR(w[a], fd, 1e-8 * std::max(1.0, std::abs(fd))) << "axis " << a;
  }
}

// The molten salt of the accuracy tests: 1000 ions in real units, 0.1 ions/Å³, r_c = 10 Å.
struct Melt {
  Charged s = melt(10, 2.15, 2024);
  Box box = periodic_box(Eigen::Vector3d::Constant(21.5), Eigen::Vector3d::Zero());
  double cutoff = 10.0;
  // The converged total Ewald force (real + reciprocal, both to 1e-17 of their terms).
  Eigen::Matrix3Xd reference;
  double reference_energy = 0.0;

  Eigen::Matrix3Xd total(double g, double* energy = nullptr) const {
    const EwaldSum ewald("coulomb", Level::slow, s.q, ewald_parameters(g, converged_kmax(g, 21.5)), kQqrd2eReal, box);
    const RealSpace r = real_space(s.x, s.q, box, g, std::sqrt(17.0 * std::log(10.0)) / g, kQqrd2eReal);
    Eigen::Matrix3Xd f = r.f;
    const double e = ewald.add_forces(s.x, box, f);
    if (energy) *energy = e + r.energy;
    return f;
  }
  Melt() { reference = total(0.32, &reference_energy); }
};

const Melt& the_melt() {
  static const Melt m;
  return m;
}

TEST(KSpace, ConvergedEwaldReferenceDoesNotDependOnG) {
  const Melt& m = the_melt();
  double energy = 0.0;
  const Eigen::Matrix3Xd other = m.total(0.38, &energy);
  const double force_scale = std::sqrt(m.reference.colwise().squaredNorm().mean());
  std::printf("melt: RMS |F| %.4f kcal/(mol Å), reference g 0.32 vs 0.38: RMS |dF| %.2e, dE/E %.2e\n", force_scale,
              rms_difference(other, m.reference), std::abs(energy / m.reference_energy - 1.0));
  EXPECT_LT(rms_difference(other, m.reference), 1e-9 * force_scale);
  EXPECT_NEAR(energy, m.reference_energy, 1e-10 * std::abs(m.reference_energy));
}

TEST(KSpace, EwaldMeetsTheRequestedAccuracy) {
  // LAMMPS's Ewald takes g from the real-space estimate alone, ΔF_real(g) = accuracy, and kmax
  // with ΔF_k ≤ accuracy: the term's own (reciprocal) error meets the accuracy, the total with a
  // real-space cutoff is √(ΔF_real² + ΔF_k²), above it by design. Both are checked: the first
  // against the accuracy, the second against the estimate.
  const Melt& m = the_melt();
  for (const double accuracy : {1e-3, 1e-4, 1e-5, 1e-6}) {
    const EwaldParameters p = choose_ewald(accuracy, m.cutoff, m.s.q, m.box, kQqrd2eReal);
    const EwaldSum ewald("coulomb", Level::slow, m.s.q, p, kQqrd2eReal, m.box);
    const Eigen::Matrix3Xd kspace = forces_of(ewald, m.s.x, m.box);
    const EwaldSum exact("coulomb", Level::slow, m.s.q, ewald_parameters(p.g_ewald, converged_kmax(p.g_ewald, 21.5)),
                         kQqrd2eReal, m.box);
    const double own = rms_difference(kspace, forces_of(exact, m.s.x, m.box));
    const Eigen::Matrix3Xd f = kspace + real_space(m.s.x, m.s.q, m.box, p.g_ewald, m.cutoff, kQqrd2eReal).f;
    const double measured = rms_difference(f, m.reference);
    std::printf(
        "ewald %.0e: g %.5f kmax %d %d %d, requested %.3e, reciprocal alone %.3e; total estimated %.3e, "
        "measured %.3e\n",
        accuracy, p.g_ewald, p.kmax[0], p.kmax[1], p.kmax[2], p.accuracy_absolute, own, p.estimated_error, measured);
    EXPECT_LE(own, p.accuracy_absolute) << ewald.describe();
    EXPECT_LE(measured, 1.25 * p.estimated_error) << ewald.describe();
  }
}

TEST(KSpace, PppmMeetsTheRequestedAccuracy) {
  const Melt& m = the_melt();
  for (const double accuracy : {1e-3, 1e-4, 1e-5, 1e-6}) {
    const MeshParameters p = choose_pppm(accuracy, m.cutoff, m.s.q, m.box, kQqrd2eReal);
    const ParticleParticleParticleMesh pppm("coulomb", Level::slow, m.s.q, p, kQqrd2eReal, m.box);
    Eigen::Matrix3Xd kspace = Eigen::Matrix3Xd::Zero(3, m.s.x.cols());
    const auto start = std::chrono::steady_clock::now();
    pppm.add_forces(m.s.x, m.box, kspace);
    const double seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
    const Eigen::Matrix3Xd f = kspace + real_space(m.s.x, m.s.q, m.box, p.g_ewald, m.cutoff, kQqrd2eReal).f;
    const double measured = rms_difference(f, m.reference);
    // The mesh's own error: against the exact reciprocal sum at the same g.
    const EwaldSum exact("coulomb", Level::slow, m.s.q, ewald_parameters(p.g_ewald, converged_kmax(p.g_ewald, 21.5)),
                         kQqrd2eReal, m.box);
    const double mesh_only = rms_difference(kspace, forces_of(exact, m.s.x, m.box));
    std::printf(
        "pppm %.0e: g %.5f mesh %d %d %d order %d, requested %.3e, estimated %.3e, measured %.3e (mesh alone "
        "%.3e), %.1f ms\n",
        accuracy, p.g_ewald, p.mesh[0], p.mesh[1], p.mesh[2], p.order, p.accuracy_absolute, p.estimated_error, measured,
        mesh_only, 1e3 * seconds);
    EXPECT_LE(measured, p.accuracy_absolute) << pppm.describe();
    EXPECT_LE(mesh_only, p.accuracy_absolute) << pppm.describe();
  }
}

TEST(KSpace, ChosenParametersAreLammps) {
  // Hand-checked against LAMMPS's formulas for this melt (kspace_style pppm 1e-4, pair cutoff 10).
  const Melt& m = the_melt();
  const MeshParameters p = choose_pppm(1e-4, m.cutoff, m.s.q, m.box, kQqrd2eReal);
  EXPECT_DOUBLE_EQ(p.accuracy_absolute, 1e-4 * kQqrd2eReal);
  for (int a = 0; a < 3; ++a) {
    int n = p.mesh[a];
    for (const int factor : {2, 3, 5})
      while (n % factor == 0) n /= factor;
    EXPECT_EQ(n, 1) << "mesh " << p.mesh[a] << " is not 2^a 3^b 5^c";
  }
  // g balances the two error estimates (to LAMMPS's Newton tolerance, 1e-5 force units).
  const double n = 1000.0, q2 = 1000.0 * kQqrd2eReal;
  EXPECT_NEAR(real_space_error(p.g_ewald, m.cutoff, n, q2, m.box.lengths.prod()), pppm_kspace_error(p, m.box, n, q2),
              1e-5);
  // The Ewald kmax is the smallest meeting the accuracy on each axis.
  const EwaldParameters e = choose_ewald(1e-4, m.cutoff, m.s.q, m.box, kQqrd2eReal);
  for (int a = 0; a < 3; ++a) {
    EXPECT_LE(ewald_axis_error(e.kmax[a], 21.5, e.g_ewald, n, q2), e.accuracy_absolute);
    EXPECT_GT(ewald_axis_error(e.kmax[a] - 1, 21.5, e.g_ewald, n, q2), e.accuracy_absolute);
  }
  // g from the real-space estimate: ΔF_real(g) = accuracy.
  EXPECT_NEAR(real_space_error(e.g_ewald, m.cutoff, n, q2, m.box.lengths.prod()), e.accuracy_absolute,
              1e-12 * e.accuracy_absolute);
  const ParticleParticleParticleMesh pppm("long", Level::slow, m.s.q, p, kQqrd2eReal, m.box);
  EXPECT_NE(pppm.describe().find("mesh " + std::to_string(p.mesh[0])), std::string::npos) << pppm.describe();
  EXPECT_NE(pppm.describe().find("estimated"), std::string::npos);
}

template <class Term, class Parameters>
void check_decomposed(const Parameters& parameters) {
  const Box box = periodic_box({5.0, 6.0, 7.0}, {1.0, -2.0, 0.5});
  const Charged s = random_charges(60, box, 5, 0.5);  // charged, so the background term is shared too
  const Term whole("coulomb", Level::slow, s.q, parameters, 1.0, box);
  const Eigen::Matrix3Xd f_whole = forces_of(whole, s.x, box);
  const double e_whole = energy_of(whole, s.x, box);
  const Eigen::Vector3d w_whole = virial_diagonal(whole, s.x, box);
  constexpr int kRanks = 3;
  // Rank r holds particles r, r + 3, …: each subset spread over the box.
  std::vector<std::vector<int>> global(kRanks);
  for (int i = 0; i < s.x.cols(); ++i) global[i % kRanks].push_back(i);
  Eigen::Matrix3Xd f_parts = Eigen::Matrix3Xd::Zero(3, s.x.cols());
  std::vector<double> energies(kRanks);
  std::vector<Eigen::Vector3d> virials(kRanks);
  const Topology topology;
  fake::run_ranks(kRanks, [&](const Communicator& comm) {
    const int r = comm.rank();
    const std::vector<int> types(global[r].size(), 0);
    const ParticleSubset subset{global[r], types, topology};
    std::unique_ptr<ForceTerm> part = whole.on_subset(subset, box);
    part->set_processes(&comm);
    Eigen::Matrix3Xd x(3, subset.size());
    for (int k = 0; k < subset.size(); ++k) x.col(k) = s.x.col(global[r][k]);
    Eigen::Matrix3Xd f = Eigen::Matrix3Xd::Zero(3, subset.size());
    energies[r] = part->add_forces(x, box, f);
    for (int k = 0; k < subset.size(); ++k) f_parts.col(global[r][k]) = f.col(k);
    virials[r] = virial_diagonal(*part, x, box);
  });
  const double scale = f_whole.cwiseAbs().maxCoeff();
  EXPECT_LT((f_parts - f_whole).cwiseAbs().maxCoeff(), 1e-12 * scale);
  double e_sum = 0.0;
  Eigen::Vector3d w_sum = Eigen::Vector3d::Zero();
  for (int r = 0; r < kRanks; ++r) e_sum += energies[r], w_sum += virials[r];
  EXPECT_NEAR(e_sum, e_whole, 1e-12 * std::abs(e_whole));
  for (int a = 0; a < 3; ++a) EXPECT_NEAR(w_sum[a], w_whole[a], 1e-12 * w_whole.cwiseAbs().maxCoeff());
}

TEST(KSpace, EwaldOnSubsetsOfRanksIsTheWholeSystems) {
  check_decomposed<EwaldSum>(ewald_parameters(0.9, 7));
}

TEST(KSpace, PppmOnSubsetsOfRanksIsTheWholeSystems) {
  MeshParameters p = mesh_parameters(0.9, 16, 5);
  p.mesh[1] = 18, p.mesh[2] = 15;  // an odd axis too
  check_decomposed<ParticleParticleParticleMesh>(p);
}

// The distributed mesh (pppm.hpp: slabs of planes along z, the transposes, each rank's window of
// planes) on n = 1 … 4 fake ranks against one process, 80 charges (net +0.5, so the background
// term is shared too, and one of them unwrapped by several box lengths). The particles of the z
// slab that rank k would own are held by rank k + 1 (so every rank's charges lie in planes other
// ranks own), the last rank's by rank 1 (so the last rank holds none and rank 1 two slabs apart:
// a window around an untouched gap); rank 0 holds the top slab, whose window wraps through z = 0.
// Every particle's force and the shares' sums of the energy and virial equal one process's to
// 1e-12 (n = 1: bit for bit), a second evaluation grows no buffer and repeats the first's bits, and
// so does one after release_buffers (the whole term's too).
void check_distributed_mesh(const MeshParameters& p) {
  const Box box = periodic_box({5.0, 6.0, 7.0}, {1.0, -2.0, 0.5});
  Charged s = random_charges(80, box, 9, 0.5);
  s.x.col(3) += Eigen::Vector3d(10.0, -12.0, 21.0);
  const ParticleParticleParticleMesh whole("coulomb", Level::slow, s.q, p, 1.0, box);
  const Eigen::Matrix3Xd f_whole = forces_of(whole, s.x, box);
  const double e_whole = energy_of(whole, s.x, box);
  const Eigen::Vector3d w_whole = virial_diagonal(whole, s.x, box);
  const double scale = f_whole.cwiseAbs().maxCoeff();
  whole.release_buffers();
  EXPECT_EQ(forces_of(whole, s.x, box), f_whole);
  const Topology topology;
  for (int n = 1; n <= 4; ++n) {
    std::vector<std::vector<int>> global(n);
    for (int i = 0; i < s.x.cols(); ++i) {
      double z = (s.x(2, i) - box.origin[2]) / box.lengths[2];
      z -= std::floor(z);
      int holder = (std::min(static_cast<int>(z * n), n - 1) + 1) % n;
      if (n > 1 && holder == n - 1) holder = n > 2 ? 1 : 0;
      global[holder].push_back(i);
    }
    Eigen::Matrix3Xd f_parts = Eigen::Matrix3Xd::Zero(3, s.x.cols());
    std::vector<double> energies(n);
    std::vector<Eigen::Vector3d> virials(n);
    std::vector<ParticleParticleParticleMesh::Traffic> traffic(n);
    std::vector<int> repeated(n, 0);
    fake::run_ranks(n, [&](const Communicator& comm) {
      const int r = comm.rank();
      const std::vector<int> types(global[r].size(), 0);
      const ParticleSubset subset{global[r], types, topology};
      std::unique_ptr<ForceTerm> part = whole.on_subset(subset, box);
      part->set_processes(&comm);
      Eigen::Matrix3Xd x(3, subset.size());
      for (int k = 0; k < subset.size(); ++k) x.col(k) = s.x.col(global[r][k]);
      Eigen::Matrix3Xd f = Eigen::Matrix3Xd::Zero(3, subset.size());
      energies[r] = part->add_forces(x, box, f);
      for (int k = 0; k < subset.size(); ++k) f_parts.col(global[r][k]) = f.col(k);
      virials[r] = virial_diagonal(*part, x, box);
      const auto& mesh = dynamic_cast<const ParticleParticleParticleMesh&>(*part);
      traffic[r] = mesh.traffic();
      Eigen::Matrix3Xd again = Eigen::Matrix3Xd::Zero(3, subset.size());
      const double e_again = part->add_forces(x, box, again);
      repeated[r] = e_again == energies[r] && again == f && mesh.traffic().growths == 0;
      // Its buffers dropped, the term makes them again at the next evaluation: the same bits.
      part->release_buffers();
      again.setZero();
      repeated[r] = repeated[r] && part->add_forces(x, box, again) == energies[r] && again == f;
    });
    double e_sum = 0.0;
    Eigen::Vector3d w_sum = Eigen::Vector3d::Zero();
    for (int r = 0; r < n; ++r) e_sum += energies[r], w_sum += virials[r];
    const double df = (f_parts - f_whole).cwiseAbs().maxCoeff() / scale;
    std::printf("mesh %d×%d×%d order %d on %d ranks: max |dF|/max |F| %.2e, dE/E %.1e, dW/W %.1e;", p.mesh[0],
                p.mesh[1], p.mesh[2], p.order, n, df, std::abs(e_sum / e_whole - 1.0),
                (w_sum - w_whole).cwiseAbs().maxCoeff() / w_whole.cwiseAbs().maxCoeff());
    for (int r = 0; r < n; ++r)
      std::printf(" rank %d: %zu charges, %d window planes, %ld messages, %ld bytes%s", r, global[r].size(),
                  traffic[r].window_planes, traffic[r].messages, traffic[r].bytes, r + 1 < n ? ";" : "\n");
    if (n == 1) {
      EXPECT_EQ(f_parts, f_whole);
      EXPECT_EQ(e_sum, e_whole);
      EXPECT_EQ(w_sum, w_whole);
    }
    EXPECT_LT(df, 1e-12) << n << " ranks";
    EXPECT_NEAR(e_sum, e_whole, 1e-12 * std::abs(e_whole)) << n << " ranks";
    for (int a = 0; a < 3; ++a)
      EXPECT_NEAR(w_sum[a], w_whole[a], 1e-12 * w_whole.cwiseAbs().maxCoeff()) << n << " ranks, axis " << a;
    for (int r = 0; r < n; ++r) EXPECT_TRUE(repeated[r]) << "rank " << r << " of " << n;
    if (n > 1) {
      EXPECT_TRUE(global[n - 1].empty());
      EXPECT_EQ(traffic[n - 1].window_planes, 0);
    }
  }
}

TEST(KSpace, PppmDistributedMeshOnOneToFourRanksIsOneProcesss) {
  MeshParameters p = mesh_parameters(0.9, 16, 5);
  p.mesh[1] = 18, p.mesh[2] = 15;
  check_distributed_mesh(p);
}

TEST(KSpace, PppmMeshWithFewerPlanesOrColumnsThanRanks) {
  // 2 planes for up to 4 ranks (two own none); then 3 planes and 2 columns (n_y (n_x/2 + 1)).
  MeshParameters p = mesh_parameters(0.9, 6, 3);
  p.mesh[1] = 5, p.mesh[2] = 2;
  check_distributed_mesh(p);
  p.mesh[0] = 2, p.mesh[1] = 1, p.mesh[2] = 3, p.order = 2;
  check_distributed_mesh(p);
}

TEST(KSpace, SubsetsKeepTheirCharges) {
  const Box box = periodic_box({5.0, 6.0, 7.0}, {0.0, 0.0, 0.0});
  const Charged s = random_charges(10, box, 3);
  const EwaldSum whole("coulomb", Level::slow, s.q, ewald_parameters(0.9, 5), 1.0, box);
  const std::vector<int> global{1, 4, 7}, types(3, 0);
  const Topology topology;
  const auto part = whole.on_subset(ParticleSubset{global, types, topology}, box);
  const auto& ewald = dynamic_cast<const EwaldSum&>(*part);
  EXPECT_EQ(ewald.charges(), (std::vector<double>{s.q[1], s.q[4], s.q[7]}));
  EXPECT_EQ(ewald.style(), "ewald");
  ParameterRecord a, b;
  whole.define(a);
  part->define(b);
  EXPECT_NE(a.value(), b.value());
}

template <class F>
void expect_invalid(F&& f, const std::string& needle) {
  try {
    f();
    ADD_FAILURE() << "no exception; expected one naming " << needle;
  } catch (const std::invalid_argument& e) {
    EXPECT_NE(std::string(e.what()).find(needle), std::string::npos) << e.what();
  }
}

TEST(KSpace, BadInputsAreRefused) {
  const Box box = periodic_box({5.0, 6.0, 7.0}, {0.0, 0.0, 0.0});
  const Charged s = random_charges(10, box, 3);
  Box open = box;
  open.periodic[2] = 0;
  expect_invalid([&] { choose_ewald(1e-4, 2.0, s.q, open, 1.0); }, "axis z: open");
  expect_invalid([&] { choose_pppm(1e-4, 2.0, s.q, open, 1.0); }, "choose_pppm");
  expect_invalid([&] { EwaldSum("coul", Level::slow, s.q, ewald_parameters(0.9, 5), 1.0, open); }, "'coul' (ewald)");
  expect_invalid([&] { ParticleParticleParticleMesh("coul", Level::slow, s.q, mesh_parameters(0.9, 8, 5), 1.0, open); },
                 "'coul' (pppm)");
  for (const double accuracy : {0.0, -1e-4, 1.0, 2.0})
    expect_invalid([&] { choose_pppm(accuracy, 2.0, s.q, box, 1.0); }, "relative accuracy " + format_number(accuracy));
  expect_invalid([&] { choose_ewald(0.0, 2.0, s.q, box, 1.0); }, "choose_ewald: the relative accuracy 0");
  expect_invalid([&] { choose_pppm(1e-4, 2.0, s.q, box, 1.0, 8); }, "order 8");
  expect_invalid([&] { choose_pppm(1e-4, 2.0, s.q, box, 1.0, 0); }, "order 0");
  expect_invalid([&] { ParticleParticleParticleMesh("coul", Level::slow, s.q, mesh_parameters(0.9, 8, 9), 1.0, box); },
                 "order 9");
  expect_invalid([&] { choose_ewald(1e-4, 0.0, s.q, box, 1.0); }, "cutoff 0");
  expect_invalid([&] { choose_ewald(1e-4, 2.0, std::vector<double>(5, 0.0), box, 1.0); }, "no charges");
  expect_invalid([&] { EwaldSum("coul", Level::slow, s.q, ewald_parameters(0.0, 5), 1.0, box); }, "g_ewald 0");
  expect_invalid([&] { ParticleParticleParticleMesh("coul", Level::slow, s.q, mesh_parameters(0.9, 0, 5), 1.0, box); },
                 "mesh size 0");
  // A charge per particle: the positions' count must match.
  const EwaldSum ewald("coul", Level::slow, s.q, ewald_parameters(0.9, 5), 1.0, box);
  const ParticleParticleParticleMesh pppm("coul", Level::slow, s.q, mesh_parameters(0.9, 8, 5), 1.0, box);
  const Eigen::Matrix3Xd fewer = s.x.leftCols(9);
  expect_invalid([&] { energy_of(ewald, fewer, box); }, "'coul' (ewald): 9 particles, but 10 charges");
  expect_invalid([&] { energy_of(pppm, fewer, box); }, "'coul' (pppm): 9 particles, but 10 charges");
  expect_invalid([&] { energy_of(pppm, s.x, open); }, "'coul' (pppm): needs a box periodic on every axis");
}

// One PPPM evaluation (forces and energy) at 1e-4 for 1000 and 29791 ions of the molten salt: a
// timing to read, not a test (run with --gtest_also_run_disabled_tests).
TEST(KSpace, DISABLED_PppmTiming) {
  for (const int m : {10, 31}) {
    const Charged s = melt(m, 2.15, 1);
    const Box box = periodic_box(Eigen::Vector3d::Constant(2.15 * m), Eigen::Vector3d::Zero());
    const MeshParameters p = choose_pppm(1e-4, 10.0, s.q, box, kQqrd2eReal);
    const ParticleParticleParticleMesh pppm("coulomb", Level::slow, s.q, p, kQqrd2eReal, box);
    Eigen::Matrix3Xd f = Eigen::Matrix3Xd::Zero(3, s.x.cols());
    pppm.add_forces(s.x, box, f);
    const int repeats = 5;
    const auto start = std::chrono::steady_clock::now();
    for (int k = 0; k < repeats; ++k) pppm.add_forces(s.x, box, f);
    const double seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count() / repeats;
    std::printf("pppm 1e-4, %d ions: mesh %d %d %d, %.2f ms per evaluation\n", static_cast<int>(s.x.cols()), p.mesh[0],
                p.mesh[1], p.mesh[2], 1e3 * seconds);
  }
}

}  // namespace
}  // namespace stiffmd
