// The all-atom bonded styles (issue 39): the impropers (harmonic, cvff, umbrella), charmm-angle with
// its Urey–Bradley term, charmm-dihedral with its weighted 1-4 pairs, harmonic-bond. Each kernel's
// forces against central differences of its energy, near the degenerate geometries too; each
// style against LAMMPS's energies and forces on small molecules (tests/data/lammps_bonded/: the
// data files, the decks that import them with coefficients = "data", and LAMMPS's numbers in
// CASE.ref, made by tools/lammps_bonded_reference.py — LAMMPS is not needed here); the terms on a
// subset of the particles; the virial.
#include <gtest/gtest.h>

#include <cmath>
#include <fstream>
#include <numbers>
#include <sstream>
#include <string>
#include <vector>

#include "cli_support.hpp"
#include "core/errors.hpp"
#include "core/units.hpp"
#include "engine/io/lammps_data.hpp"
#include "engine/scene/scene.hpp"
#include "force_term_checks.hpp"
#include "forcefields/charmm_terms.hpp"
#include "forcefields/improper_terms.hpp"
#include "test_support.hpp"

namespace stiffmd {
namespace {

using Eigen::Matrix3Xd;
using Eigen::Vector3d;
using test::energy_of;
using test::fd_error;
using test::forces_of;
using test::position_virial;
constexpr double kPi = std::numbers::pi;
constexpr double kDeg = kPi / 180.0;

// A centre 0 with three ligands 1, 2, 3 in the xy plane at 120° (lengths 1.0, 1.1, 0.9), the
// centre lifted by `lift` along z; in degenerate variants a ligand is moved.
Matrix3Xd pyramid(double lift) {
  Matrix3Xd x(3, 4);
  x.col(0) = Vector3d(0.0, 0.0, lift);
  x.col(1) = Vector3d(1.0, 0.0, 0.0);
  x.col(2) = 1.1 * Vector3d(std::cos(2 * kPi / 3), std::sin(2 * kPi / 3), 0.0);
  x.col(3) = 0.9 * Vector3d(std::cos(4 * kPi / 3), std::sin(4 * kPi / 3), 0.0) + Vector3d(0.0, 0.0, 0.05);
  return x;
}

const std::vector<Improper> kThreeImpropers = {{0, 1, 2, 3, 0}, {0, 2, 3, 1, 1}, {0, 3, 1, 2, 0}};

TEST(ImproperKernels, ForcesAreMinusTheGradientOfTheEnergy) {
  const HarmonicImproper harmonic("h", Level::slow, kThreeImpropers, {{120.0, 0.0}, {20.0, 10 * kDeg}});
  const CvffImproper cvff("c", Level::slow, kThreeImpropers, {{2.5, -1, 2}, {1.0, 1, 3}});
  const UmbrellaImproper umbrella("u", Level::slow, kThreeImpropers, {{30.0, 0.0}, {15.0, 35 * kDeg}});
  for (const ForceTerm* term : std::vector<const ForceTerm*>{&harmonic, &cvff, &umbrella})
    for (double lift : {0.0, 1e-7, 0.05, 0.3, 0.6, -0.4}) {
      const Matrix3Xd x = pyramid(lift);
      EXPECT_TRUE(forces_of(*term, x, Box{}).allFinite());
      EXPECT_LT(fd_error(*term, x, Box{}), 1e-6) << term->style() << " lift " << lift;
      const Matrix3Xd f = forces_of(*term, x, Box{});
      EXPECT_LT(f.rowwise().sum().norm(), 1e-10 * std::max(1.0, f.norm())) << term->style();  // Newton
    }
}

// χ near 0 and near 180° (the dihedral angle of i, j, k, l nearly cis or trans), with χ₀ at that
// end (smooth) or away from it, for the harmonic improper: finite forces equal to −∇E.
TEST(ImproperKernels, HarmonicNearZeroAndStraight) {
  const std::vector<Improper> one = {{0, 1, 2, 3, 0}};
  for (const double chi0 : {0.0, 30 * kDeg, kPi}) {
    const HarmonicImproper term("h", Level::slow, one, {{50.0, chi0}});
    for (const double phi : {1e-6, 1e-3, kPi - 1e-3, kPi - 1e-6, -1e-3, -(kPi - 1e-3)}) {
      // 0 at the origin, 1 and 2 along x and y, 3 turned by phi about the 1-2 bond: χ = |phi|.
      Matrix3Xd x(3, 4);
      x.col(1) = Vector3d::Zero();
      x.col(2) = Vector3d(1.2, 0.0, 0.0);
      x.col(0) = Vector3d(-0.4, 1.0, 0.0);
      x.col(3) = x.col(2) + Vector3d(0.5, std::cos(phi), std::sin(phi));
      const auto g = dihedral_detail::geometry(0, 1, 2, 3, x);
      ASSERT_NEAR(std::abs(std::remainder(g.phi - phi, 2 * kPi)), 0.0, 1e-12);
      double e = 0.0, de = 0.0;
      HarmonicImproperKernel::eval(g.phi, {50.0, chi0}, e, de);
      EXPECT_NEAR(energy_of(term, x, Box{}), 50.0 * (std::abs(phi) - chi0) * (std::abs(phi) - chi0), 1e-9);
      EXPECT_TRUE(forces_of(term, x, Box{}).allFinite());
      // A central difference straddles the kink at χ = 0 (χ₀ > 0) or 180° (χ₀ < 180°) when within a step of it.
      const bool kink = (chi0 > 0 && std::abs(phi) < 1e-5) || (chi0 < kPi && kPi - std::abs(phi) < 1e-5);
      if (!kink) {
        EXPECT_LT(fd_error(term, x, Box{}, 1e-8), 1e-6) << "chi0 " << chi0 << " phi " << phi;
      }
    }
  }
}

// Degenerate umbrellas: the ligands j, i, k collinear (no plane), the axis i–l along the normal
// (the cone of cos ω = 0), and near it: finite forces; −∇E away from the cone's tip.
TEST(ImproperKernels, UmbrellaAtDegenerateGeometries) {
  const std::vector<Improper> one = {{0, 1, 2, 3, 0}};
  for (const UmbrellaCoeffs c : {UmbrellaCoeffs{30.0, 0.0}, UmbrellaCoeffs{15.0, 35 * kDeg}}) {
    const UmbrellaImproper term("u", Level::slow, one, {c});
    Matrix3Xd x = pyramid(0.2);
    x.col(2) = 2.0 * x.col(0) - x.col(1);  // 1, 0, 2 collinear
    EXPECT_TRUE(forces_of(term, x, Box{}).allFinite());
    EXPECT_EQ(forces_of(term, x, Box{}).cwiseAbs().maxCoeff(), 0.0);
    x = pyramid(0.0);
    x.col(3) = Vector3d(0.0, 0.0, 1.0);  // the axis along the normal: cos ω = 0
    EXPECT_TRUE(forces_of(term, x, Box{}).allFinite());
    x.col(3) = Vector3d(0.02, -0.01, 1.0);  // near it: large, exact forces
    EXPECT_TRUE(forces_of(term, x, Box{}).allFinite());
    EXPECT_LT(fd_error(term, x, Box{}, 1e-8), 1e-5);
  }
}

// The umbrella's ω as LAMMPS defines it: planar with l away from j and k is ω = 0 (E = 0 for
// ω₀ = 0); the centre lifted by h above the plane of three ligands at 120°: cos ω follows.
TEST(ImproperKernels, UmbrellaAngleIsLammps) {
  const UmbrellaImproper planar("u", Level::slow, {{0, 1, 2, 3, 0}}, {{30.0, 0.0}});
  Matrix3Xd x = pyramid(0.0);
  x.col(3).z() = 0.0;
  EXPECT_NEAR(energy_of(planar, x, Box{}), 0.0, 1e-14);
  // 0, 1, 2 in the plane z = 0, ligand 3 at height 0.3: the i–l axis makes sin ω = 0.3/|h_l|.
  x.col(3).z() = 0.3;
  const double sin_w = 0.3 / (x.col(3) - x.col(0)).norm();
  EXPECT_NEAR(energy_of(planar, x, Box{}), 30.0 * (1.0 - std::sqrt(1.0 - sin_w * sin_w)), 1e-12);
}

TEST(ImproperTerms, RefuseBadCoefficientsAndImpropers) {
  EXPECT_THROW(HarmonicImproper("h", Level::slow, {}, {{-1.0, 0.0}}), std::invalid_argument);
  EXPECT_THROW(HarmonicImproper("h", Level::slow, {}, {{1.0, 4.0}}), std::invalid_argument);
  EXPECT_THROW(UmbrellaImproper("u", Level::slow, {}, {{1.0, 100 * kDeg}}), std::invalid_argument);
  EXPECT_THROW(CvffImproper("c", Level::slow, {}, {{1.0, 2, 1}}), std::invalid_argument);
  for (const Improper bad : {Improper{0, 1, 2, 0, 0}, Improper{0, 1, 2, 3, 1}, Improper{-1, 1, 2, 3, 0}}) {
    EXPECT_THROW(HarmonicImproper("h", Level::slow, {bad}, {{1.0, 0.0}}), std::invalid_argument);
    EXPECT_THROW(UmbrellaImproper("u", Level::slow, {bad}, {{1.0, 0.0}}), std::invalid_argument);
  }
}

// A chain of six (the 1-4 pairs 0-3, 1-4, 2-5) and its charmm terms.
Matrix3Xd chain6() {
  Matrix3Xd x(3, 6);
  x << 0.0, 1.5, 2.0, 3.5, 4.1, 5.6,  //
      0.0, 0.0, 1.4, 1.5, 2.6, 2.5,   //
      0.0, 0.1, 0.0, 0.5, -0.3, -0.2;
  return x;
}
const std::vector<Dihedral> kChainDihedrals = {{0, 1, 2, 3, 0}, {1, 2, 3, 4, 1}, {2, 3, 4, 5, 2}, {0, 1, 2, 3, 3}};
const std::vector<CharmmDihedralKernel::Coeffs> kCharmmTypes = {
    {0.2, 1, 180, 1.0}, {1.6, 3, 0, 0.5}, {0.5, 2, 60, 1.0}, {2.5, 2, 180, 0.0}};
const std::vector<int> kChainTypes = {0, 1, 2, 1, 3, 0};
const std::vector<double> kChainCharges = {-0.3, 0.1, 0.51, -0.47, 0.2, -0.04};

// The 1-4 coefficients of tools/lammps_bonded_reference.py's pair_coeff (eps14, sigma14), mixed
// arithmetically as lj/charmm/coul/charmm does.
TypePairMatrix<Lj14> lj14_of_the_reference() {
  const std::vector<Lj14> own = {{0.01, 3.3854}, {0.055, 3.2}, {0.12, 3.0}, {0.2, 3.296}};
  TypePairMatrix<Lj14> m(4);
  for (int a = 0; a < 4; ++a)
    for (int b = a; b < 4; ++b)
      m.set(a, b, {std::sqrt(own[a].epsilon * own[b].epsilon), 0.5 * (own[a].sigma + own[b].sigma)});
  return m;
}

CharmmDihedral charmm_dihedral(bool charges) {
  return CharmmDihedral("d", Level::slow, kChainDihedrals, kCharmmTypes, kChainTypes, lj14_of_the_reference(),
                        charges ? kChainCharges : std::vector<double>{}, Units::kRealCoulomb);
}

TEST(CharmmTerms, ForcesAreMinusTheGradientOfTheEnergy) {
  const CharmmAngle angle("a", Level::slow, {{0, 1, 2, 0}, {1, 2, 3, 1}, {2, 3, 4, 0}},
                          {{33.0, 109.5 * kDeg, 30.0, 2.163}, {50.0, 120 * kDeg, 0.0, 0.0}});
  const CharmmDihedral plain = charmm_dihedral(false), charged = charmm_dihedral(true);
  const Matrix3Xd x = chain6();
  for (const ForceTerm* term : std::vector<const ForceTerm*>{&angle, &plain, &charged}) {
    const Matrix3Xd f = forces_of(*term, x, Box{});
    ASSERT_GT(f.cwiseAbs().maxCoeff(), 0.1);
    EXPECT_LT(fd_error(*term, x, Box{}), 1e-6) << term->style();
    EXPECT_LT(f.rowwise().sum().norm(), 1e-10 * f.norm());
  }
  // Near the straight angle and cis/trans torsions.
  Matrix3Xd straight = x;
  straight.col(2) = x.col(1) + 1.2 * (x.col(1) - x.col(0)).normalized() + Vector3d(0.0, 1e-7, 0.0);
  EXPECT_TRUE(forces_of(angle, straight, Box{}).allFinite());
  EXPECT_LT(fd_error(angle, straight, Box{}, 1e-9), 1e-5);
  EXPECT_TRUE(forces_of(charged, straight, Box{}).allFinite());
}

// The virial: Σ r·f of the whole term equals Σ x·f in open space; the torsion's share is zero, so
// it is the 1-4 pairs' Σ r·f (and for charmm-angle the Urey–Bradley springs').
TEST(CharmmTerms, VirialIsThePairsSeparationDotForce) {
  const CharmmDihedral term = charmm_dihedral(true);
  const Matrix3Xd x = chain6();
  const double w = term.virial(x, Box{});
  EXPECT_NEAR(w, position_virial(term, x), 1e-10 * std::max(1.0, std::abs(w)));
  double pairs = 0.0;
  for (const Dihedral& d : kChainDihedrals) {
    const auto& c = kCharmmTypes[static_cast<size_t>(d.type)];
    if (c.w == 0.0) continue;
    const Lj14 p = lj14_of_the_reference()(kChainTypes[d.i], kChainTypes[d.l]);
    const double r = (x.col(d.i) - x.col(d.l)).norm(), s6 = std::pow(p.sigma / r, 6);
    // r·f = −r dE/dr
    pairs += c.w * (4 * p.epsilon * (12 * s6 * s6 - 6 * s6) +
                    Units::kRealCoulomb * kChainCharges[d.i] * kChainCharges[d.l] / r);
  }
  EXPECT_NEAR(w, pairs, 1e-10 * std::abs(pairs));
  const CharmmDihedral::Parts parts = term.energy_parts(x, Box{});
  EXPECT_NEAR(parts.torsion + parts.lj14 + parts.coul14, energy_of(term, x, Box{}), 1e-12);
}

TEST(CharmmTerms, RefuseBadCoefficients) {
  const Matrix3Xd x = chain6();
  auto with = [](CharmmDihedralKernel::Coeffs c) {
    return CharmmDihedral("d", Level::slow, {{0, 1, 2, 3, 0}}, {c}, kChainTypes, lj14_of_the_reference(), {},
                          Units::kRealCoulomb);
  };
  EXPECT_THROW(with({1.0, 1, 0, 1.5}), std::invalid_argument);  // w outside [0, 1]
  EXPECT_THROW(with({1.0, 1, 0, -0.1}), std::invalid_argument);
  EXPECT_THROW(with({1.0, -1, 0, 0.5}), std::invalid_argument);  // n < 0
  EXPECT_NO_THROW(with({-1.0, 0, 90, 0.5}));
  // A 1-4 pair without coefficients for its types.
  EXPECT_THROW(CharmmDihedral("d", Level::slow, {{0, 1, 2, 3, 0}}, {{1.0, 1, 0, 1.0}}, kChainTypes,
                              TypePairMatrix<Lj14>(1), {}, Units::kRealCoulomb),
               std::invalid_argument);
  EXPECT_THROW(CharmmAngle("a", Level::slow, {{0, 1, 2, 0}}, {{1.0, 2.0, -1.0, 1.0}}), std::invalid_argument);
  EXPECT_THROW(CharmmAngle("a", Level::slow, {{0, 1, 2, 0}}, {{1.0, 2.0, 1.0, -1.0}}), std::invalid_argument);
}

// ---------------------------------------------------------------------------------------------
// Against LAMMPS. CASE.ref: the LAMMPS input as comments, then the energies pe ebond eangle edihed
// eimp evdwl ecoul and one row "id fx fy fz" per atom.
struct Reference {
  std::vector<double> energy;  // pe ebond eangle edihed eimp evdwl ecoul
  Matrix3Xd f;
};
Reference reference(const std::string& name) {
  std::ifstream in(test::source_path("tests/data/lammps_bonded/" + name + ".ref"));
  Reference r;
  std::vector<std::vector<double>> rows;
  for (std::string line; std::getline(in, line);) {
    if (line.empty() || line[0] == '#') continue;
    std::istringstream s(line);
    std::vector<double> v;
    for (double d; s >> d;) v.push_back(d);
    if (r.energy.empty())
      r.energy = v;
    else
      rows.push_back(v);
  }
  r.f.resize(3, static_cast<Eigen::Index>(rows.size()));
  for (size_t k = 0; k < rows.size(); ++k)
    r.f.col(static_cast<Eigen::Index>(k)) = Vector3d(rows[k][1], rows[k][2], rows[k][3]);
  EXPECT_EQ(r.energy.size(), 7u) << name;
  return r;
}

// Relative agreement: |E − E_L| / max(1, |E_L|) and max |f − f_L| / max|f_L|, recorded.
void expect_agrees(const std::string& name, double e, double e_lammps, const Matrix3Xd& f, const Matrix3Xd& f_lammps) {
  ASSERT_EQ(f.cols(), f_lammps.cols()) << name;
  const double de = std::abs(e - e_lammps) / std::max(1.0, std::abs(e_lammps));
  const double df = (f - f_lammps).cwiseAbs().maxCoeff() / f_lammps.cwiseAbs().maxCoeff();
  char buf[80];
  std::snprintf(buf, sizeof buf, "energy %.2e, forces %.2e", de, df);
  testing::Test::RecordProperty(name, buf);
  EXPECT_LT(de, 1e-8) << name << ": E = " << e << ", LAMMPS " << e_lammps;
  EXPECT_LT(df, 1e-8) << name << ": forces\n" << f << "\nLAMMPS\n" << f_lammps;
}

// Each case's deck imports the data file and takes every coefficient from it (coefficients =
// "data"): the whole road from a LAMMPS data file to the forces, against LAMMPS's numbers.
class LammpsReference : public ::testing::TestWithParam<std::string> {};

TEST_P(LammpsReference, EnergyAndForcesMatch) {
  const std::string name = GetParam();
  const Scene sc =
      test::load(name == "peptide" ? "inputs/peptide_bonded.toml" : "tests/data/lammps_bonded/" + name + ".toml");
  const Reference ref = reference(name);
  Matrix3Xd f = Matrix3Xd::Zero(3, sc.state.size());
  double e = 0.0;
  for (const auto& term : sc.forces->terms()) e += term->add_forces(sc.state.x, sc.box, f);
  // LAMMPS's pe; the 1-4 part of charmm is its evdwl (no charges here: the import refuses them).
  expect_agrees(name, e, ref.energy[0], f, ref.f);
}
INSTANTIATE_TEST_SUITE_P(Styles, LammpsReference,
                         ::testing::Values("improper_harmonic", "improper_cvff", "improper_umbrella", "angle_charmm",
                                           "angle_harmonic", "dihedral_charmm", "peptide"));

// The bundled all-atom deck (the peptide example's bonded part, every coefficient from its data
// file): `stiffmd check` accepts it and lists its impropers and charmm terms.
TEST(PeptideDeck, StiffmdCheckAcceptsIt) {
  const test::CliResult r = test::cli("check " + test::source_path("inputs/peptide_bonded.toml"));
  ASSERT_EQ(r.code, 0) << r.err;
  for (const char* what :
       {"impropers:   12", "[charmm-angle, slow]", "[charmm-dihedral, slow]", "207 weighted 1-4 pairs",
        "[harmonic-improper, slow]", "[harmonic-bond, slow]", "deck is valid"})
    EXPECT_NE(r.out.find(what), std::string::npos) << what << "\n" << r.out;
}

// charmm-dihedral with charges (the constructor's charges; a scene has none yet): LAMMPS's edihed,
// evdwl and ecoul apart, and the forces.
TEST(LammpsReferenceWithCharges, CharmmDihedral) {
  const ImportedSystem in = read_lammps_data(test::source_path("tests/data/lammps_bonded/dihedral_charmm_q.data"));
  const Reference ref = reference("dihedral_charmm_q");
  const CharmmDihedral term = charmm_dihedral(true);
  for (int i = 0; i < 6; ++i) {
    ASSERT_EQ(in.type[i] - 1, kChainTypes[i]);
    ASSERT_EQ(in.charge[i], kChainCharges[i]);
  }
  ASSERT_EQ((in.x - chain6()).cwiseAbs().maxCoeff(), 0.0);
  Matrix3Xd f = Matrix3Xd::Zero(3, 6);
  const double e = term.add_forces(in.x, Box{}, f);
  expect_agrees("dihedral_charmm_q", e, ref.energy[0], f, ref.f);
  const CharmmDihedral::Parts parts = term.energy_parts(in.x, Box{});
  EXPECT_NEAR(parts.torsion, ref.energy[3], 1e-8 * std::abs(ref.energy[3]));
  EXPECT_NEAR(parts.lj14, ref.energy[5], 1e-8 * std::abs(ref.energy[5]));
  EXPECT_NEAR(parts.coul14, ref.energy[6], 1e-8 * std::abs(ref.energy[6]));
}

// ---------------------------------------------------------------------------------------------
// A decomposed run's parts: each term on a subset of whole molecules gives each of their particles
// what the whole term gives it. Two copies of the chain of six, the second shifted.
TEST(AllAtomTermsOnSubset, WholeMoleculesFeelWhatTheyFeelInTheWholeSystem) {
  Matrix3Xd x(3, 12);
  x.leftCols(6) = chain6();
  x.rightCols(6) = chain6().colwise() + Vector3d(0.3, 6.0, -1.0);
  std::vector<Dihedral> dihedrals;
  std::vector<Angle> angles;
  std::vector<Improper> impropers;
  std::vector<int> types;
  std::vector<double> charges;
  for (int m = 0; m < 2; ++m) {
    for (Dihedral d : kChainDihedrals)
      dihedrals.push_back({d.i + 6 * m, d.j + 6 * m, d.k + 6 * m, d.l + 6 * m, d.type});
    for (int a = 0; a < 4; ++a) angles.push_back({a + 6 * m, a + 1 + 6 * m, a + 2 + 6 * m, a % 2});
    impropers.push_back({1 + 6 * m, 0 + 6 * m, 2 + 6 * m, 3 + 6 * m, m});
    for (int k = 0; k < 6; ++k) types.push_back(kChainTypes[k]), charges.push_back(kChainCharges[k]);
  }
  const CharmmDihedral dihedral("d", Level::slow, dihedrals, kCharmmTypes, types, lj14_of_the_reference(), charges,
                                Units::kRealCoulomb);
  const CharmmAngle angle("a", Level::slow, angles, {{33.0, 109.5 * kDeg, 30.0, 2.163}, {50.0, 120 * kDeg, 0.0, 0.0}});
  const HarmonicImproper harmonic("h", Level::slow, impropers, {{120.0, 0.0}, {20.0, 10 * kDeg}});
  const UmbrellaImproper umbrella("u", Level::slow, impropers, {{30.0, 0.0}, {15.0, 35 * kDeg}});
  Topology topology;
  const std::vector<int> first = {0, 1, 2, 3, 4, 5}, second = {6, 7, 8, 9, 10, 11};
  const std::vector<int> first_types(types.begin(), types.begin() + 6), second_types(types.begin() + 6, types.end());
  for (const ForceTerm* term : std::vector<const ForceTerm*>{&dihedral, &angle, &harmonic, &umbrella}) {
    const Matrix3Xd fw = forces_of(*term, x, Box{});
    double e_parts = 0.0;
    for (int m = 0; m < 2; ++m) {
      const ParticleSubset subset{m ? second : first, m ? second_types : first_types, topology};
      const auto part = term->on_subset(subset, Box{});
      const Matrix3Xd xm = m ? Matrix3Xd(x.rightCols(6)) : Matrix3Xd(x.leftCols(6));
      const Matrix3Xd fp = forces_of(*part, xm, Box{});
      for (int k = 0; k < 6; ++k)
        for (int c = 0; c < 3; ++c) EXPECT_EQ(fp(c, k), fw(c, 6 * m + k)) << term->style() << " particle " << 6 * m + k;
      e_parts += energy_of(*part, xm, Box{});
    }
    EXPECT_NEAR(e_parts, energy_of(*term, x, Box{}), 1e-10) << term->style();
  }
  // A subset that cuts a molecule is refused.
  const std::vector<int> cut = {0, 1, 2};
  const std::vector<int> cut_types = {0, 1, 2};
  EXPECT_THROW(dihedral.on_subset(ParticleSubset{cut, cut_types, topology}, Box{}), std::invalid_argument);
}

}  // namespace
}  // namespace stiffmd
