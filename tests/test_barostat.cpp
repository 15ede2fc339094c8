// The barostat's numerics (integrators/barostat.hpp): the molecular virial against finite
// differences of the energy under a scaling of the molecules' centres, its independence of the
// intramolecular forces, the neighbour list under a cell move, and the cell move's groups.
#include <gtest/gtest.h>

#include <Eigen/Core>
#include <cmath>
#include <random>
#include <stdexcept>

#include "core/topology.hpp"
#include "forcefields/bond_term.hpp"
#include "forcefields/force_field.hpp"
#include "forcefields/pair_term.hpp"
#include "integrators/barostat.hpp"

namespace stiffmd {
namespace {

Box cube(double l) {
  Box b;
  b.lengths = Eigen::Vector3d::Constant(l);
  b.periodic = Eigen::Vector3i::Ones();
  return b;
}

// Dimers (bonded pairs 2k, 2k+1 at distance 1) with random centres and orientations in the box,
// left unwrapped as the engine's molecules are; every pair of beads at least 0.95 apart (minimum
// image) so that LJ stays moderate.
Eigen::Matrix3Xd dimers(int count, const Box& box, unsigned seed) {
  std::mt19937 rng(seed);
  std::uniform_real_distribution<double> u(0.0, 1.0);
  std::normal_distribution<double> g;
  Eigen::Matrix3Xd x(3, 2 * count);
  for (int k = 0; k < count; ++k)
    for (int attempt = 0;; ++attempt) {
      Eigen::Vector3d c(u(rng), u(rng), u(rng));
      c = c.cwiseProduct(box.lengths) + Eigen::Vector3d(0.3, -0.2, 0.1) * box.lengths[0];  // some centres outside
      const Eigen::Vector3d d = Eigen::Vector3d(g(rng), g(rng), g(rng)).normalized() * 0.5;
      x.col(2 * k) = c + d;
      x.col(2 * k + 1) = c - d;
      bool ok = true;
      for (int j = 0; j < 2 * k && ok; ++j)
        for (int i : {2 * k, 2 * k + 1}) ok = ok && box.min_image(x.col(i) - x.col(j)).norm() > 0.95;
      if (ok) break;
      if (attempt > 100000) throw std::runtime_error("dimers: too dense");
    }
  return x;
}

struct DimerScene {
  Box box = cube(9.0);  // three cells of cutoff + skin per axis: the list's cell search
  int molecules = 80;
  Eigen::Matrix3Xd x;
  Eigen::VectorXd inv_mass;
  std::vector<Bond> bonds;
  std::vector<int> molecule;
  ForceField forces;

  // spring > 0: a FENE spring in each dimer; bonded_lj: LJ between the two beads of a dimer too.
  explicit DimerScene(double spring = 0.0, bool bonded_lj = false) : forces(box, 2 * 80) {
    x = dimers(molecules, box, 7);
    inv_mass = Eigen::VectorXd::Ones(2 * molecules);
    for (int k = 0; k < molecules; ++k) inv_mass[2 * k + 1] = 0.5;  // mass 2: the centres are not the midpoints
    Topology top;
    for (int k = 0; k < molecules; ++k) top.bonds.push_back({2 * k, 2 * k + 1, 0});
    bonds = top.bonds;
    molecule = bonded_molecules(top, 2 * molecules);
    TypePairMatrix<LennardJones::Coeffs> c(1);
    c.set(0, 0, {1.0, 1.0, 2.5});
    // Intramolecular pairs excluded as bonded 1-2 pairs are (special_bonds 0): LJ acts between
    // the molecules only, plus each dimer's bond when `spring` > 0.
    forces.add(std::make_unique<LennardJonesPair>("lj", Level::slow, std::vector<int>(2 * molecules, 0), c, bonds,
                                                  SpecialWeights{bonded_lj ? 1.0 : 0.0, 1.0}, box, 0.3));
    if (spring > 0.0) {
      FeneCoeffs fene;
      fene.K = spring, fene.R0 = 1.5, fene.epsilon = 0.0;
      forces.add(std::make_unique<FeneBond>("spring", Level::fast, bonds, std::vector<FeneCoeffs>{fene}));
    }
  }
  State state() const {
    State s;
    s.x = x;
    s.v = Eigen::Matrix3Xd::Zero(3, x.cols());
    s.inv_mass = inv_mass;
    return s;
  }
  // The energy after scaling the centres and the box by exp(δ) along axis a.
  double scaled_energy(int a, double delta) {
    MolecularPressure mp(molecule, inv_mass);
    State s = state();
    mp.locate(s);
    const double mu = std::exp(delta);
    for (int i = 0; i < s.size(); ++i) s.x(a, i) += (mu - 1.0) * (mp.centres()(a, molecule[i]) - box.origin[a]);
    Box moved = box;
    moved.lengths[a] *= mu;
    forces.set_box(moved);
    Eigen::Matrix3Xd f = Eigen::Matrix3Xd::Zero(3, s.size());
    double e = 0.0;
    for (const auto& t : forces.terms()) e += t->add_forces(s.x, moved, f);
    forces.set_box(box);
    return e;
  }
};

// W_aa = −dU/dλ_a, U as a function of the log box length λ_a with the molecules' centres scaled
// and each molecule moved rigidly (the molecular virial, docs/design.md "Constant pressure").
TEST(MolecularVirial, IsMinusTheDerivativeOfTheEnergyUnderCentreScaling) {
  DimerScene sc;
  MolecularPressure mp(sc.molecule, sc.inv_mass);
  State s = sc.state();
  Eigen::Matrix3Xd scratch;
  mp.locate(s);
  const Eigen::Vector3d w = mp.virial_and_kinetic(s, sc.forces, scratch);  // v = 0: W alone
  const double h = 1e-6;
  for (int a = 0; a < 3; ++a) {
    const double fd = -(sc.scaled_energy(a, h) - sc.scaled_energy(a, -h)) / (2.0 * h);
    EXPECT_NEAR(w[a], fd, 1e-5 * (1.0 + std::abs(fd))) << "axis " << a;
  }
  EXPECT_GT(w.cwiseAbs().maxCoeff(), 1.0);  // the test means something: the virial is not small
}

// Forces inside each molecule — a spring, or LJ between its two beads (a pair term's
// intramolecular pairs, which enter the pair virial and cancel against Σ δ·f) — change the atomic
// virial but not the molecular one.
TEST(MolecularVirial, IntramolecularForcesDropOut) {
  DimerScene plain, sprung(30.0, true);
  MolecularPressure mp(plain.molecule, plain.inv_mass);
  Eigen::Matrix3Xd scratch;
  State s = plain.state();
  mp.locate(s);
  const Eigen::Vector3d w0 = mp.virial_and_kinetic(s, plain.forces, scratch);
  const Eigen::Vector3d w1 = mp.virial_and_kinetic(s, sprung.forces, scratch);
  for (int a = 0; a < 3; ++a) EXPECT_NEAR(w0[a], w1[a], 1e-10 * w0.cwiseAbs().maxCoeff()) << "axis " << a;
  double atomic0 = 0.0, atomic1 = 0.0;
  for (const auto& t : plain.forces.terms()) atomic0 += t->virial(s.x, plain.box);
  for (const auto& t : sprung.forces.terms()) atomic1 += t->virial(s.x, sprung.box);
  EXPECT_GT(std::abs(atomic1 - atomic0), 1.0);  // the intramolecular LJ is there
}

// 2K_a of the centres: a molecule moving as one gives M V_a², internal motion nothing.
TEST(MolecularVirial, KineticPartIsTheCentresOfMass) {
  DimerScene sc;
  sc.forces = ForceField(sc.box, 2 * sc.molecules);  // no terms: W = 0
  MolecularPressure mp(sc.molecule, sc.inv_mass);
  State s = sc.state();
  for (int k = 0; k < sc.molecules; ++k) {
    s.v.col(2 * k) = Eigen::Vector3d(1.0, 0.0, 0.0) + Eigen::Vector3d(0.0, 3.0, 0.0);
    s.v.col(2 * k + 1) =
        Eigen::Vector3d(1.0, 0.0, 0.0) - Eigen::Vector3d(0.0, 1.5, 0.0);  // mass 2: centre at rest in y
  }
  Eigen::Matrix3Xd scratch;
  mp.locate(s);
  const Eigen::Vector3d k2 = mp.virial_and_kinetic(s, sc.forces, scratch);
  EXPECT_NEAR(k2[0], sc.molecules * 3.0, 1e-12);  // M = 3, V_x = 1
  EXPECT_NEAR(k2[1], 0.0, 1e-12);
  EXPECT_EQ(k2[2], 0.0);
}

// After a cell move that scales the centres by a small factor the list is not rebuilt, and the
// forces equal those of a term built afresh on the moved scene; a large move rebuilds.
TEST(NeighborListUnderCellMove, StaysCompleteWithoutRebuildForSmallMoves) {
  DimerScene sc;
  MolecularPressure mp(sc.molecule, sc.inv_mass);
  State s = sc.state();
  const auto& term = *sc.forces.terms().front();
  Eigen::Matrix3Xd f0 = Eigen::Matrix3Xd::Zero(3, s.size());
  term.add_forces(s.x, sc.box, f0);
  const long built = term.neighbor_list_rebuilds();
  for (const double mu : {1.004, 0.996}) {
    State moved = s;
    mp.locate(moved);
    for (int i = 0; i < s.size(); ++i)
      moved.x.col(i) += (mu - 1.0) * (mp.centres().col(sc.molecule[i]) - sc.box.origin);
    Box box = sc.box;
    box.lengths *= mu;
    Eigen::Matrix3Xd f = Eigen::Matrix3Xd::Zero(3, s.size()), fresh = f;
    const double e = term.add_forces(moved.x, box, f);
    EXPECT_EQ(term.neighbor_list_rebuilds(), built) << "mu = " << mu;
    TypePairMatrix<LennardJones::Coeffs> c(1);
    c.set(0, 0, {1.0, 1.0, 2.5});
    const LennardJonesPair again("lj", Level::slow, std::vector<int>(s.size(), 0), c, sc.bonds,
                                 SpecialWeights{0.0, 1.0}, box, 0.3);
    const double e_fresh = again.add_forces(moved.x, box, fresh);
    EXPECT_NEAR(e, e_fresh, 1e-10 * std::abs(e_fresh));
    EXPECT_LT((f - fresh).cwiseAbs().maxCoeff(), 1e-10 * fresh.cwiseAbs().maxCoeff());
  }
  Box big = sc.box;
  big.lengths *= 1.2;  // (cutoff + skin)·1.2 − cutoff > skin, but the centres did not move: rebuild
  Eigen::Matrix3Xd f = Eigen::Matrix3Xd::Zero(3, s.size());
  term.add_forces(s.x, big, f);
  EXPECT_GT(term.neighbor_list_rebuilds(), built);
}

// The coupled groups: one factor for all axes (isotropic), x with y (semi-isotropic), each alone.
TEST(CellScaling, GroupsMoveTogether) {
  BarostatSettings b;
  b.pressure = Eigen::Vector3d::Constant(1.0);
  b.tau = 1.0, b.compressibility = 1.0, b.temperature = 1.0;
  const Eigen::Vector3d p(1.5, 0.5, 2.0);
  b.coupling = BarostatSettings::Coupling::isotropic;
  Eigen::Vector3d mu = cell_scaling(b, p, 100.0, 0.01, 7);
  EXPECT_EQ(mu[0], mu[1]);
  EXPECT_EQ(mu[1], mu[2]);
  b.coupling = BarostatSettings::Coupling::semi_isotropic;
  mu = cell_scaling(b, p, 100.0, 0.01, 7);
  EXPECT_EQ(mu[0], mu[1]);
  EXPECT_NE(mu[1], mu[2]);
  b.coupling = BarostatSettings::Coupling::anisotropic;
  mu = cell_scaling(b, p, 100.0, 0.01, 7);
  EXPECT_NE(mu[0], mu[1]);
  EXPECT_NE(mu[1], mu[2]);
  // The drift alone (kT → 0): isotropic Δε = β_T (P − P₀) dt / τ_p with P the mean of P_aa.
  b.temperature = 0.0;
  b.coupling = BarostatSettings::Coupling::isotropic;
  mu = cell_scaling(b, p, 100.0, 0.01, 7);
  EXPECT_NEAR(3.0 * std::log(mu[0]), (p.mean() - 1.0) * 0.01, 1e-15);
}

}  // namespace
}  // namespace stiffmd
