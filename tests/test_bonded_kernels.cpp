// Typed suites for the bond kernels (BondTerm, bond_potentials.hpp) and the angle kernels
// (AngleTerm, angle_terms.hpp): every kernel gets the same checks — the kernel's derivative
// against finite differences of its energy, the term's forces against −∇E in open and periodic
// boxes, Newton's third law and zero torque, the virial against Σ r·f — and a new kernel joins
// by one case line (its example coefficients) and one entry in the type list. Hand-computed
// values per style are in test_bonded.cpp; the LAMMPS formulas for Morse are checked here.
#include <gtest/gtest.h>

#include <numbers>

#include "core/errors.hpp"
#include "engine/scene/whole_molecules.hpp"
#include "force_term_checks.hpp"
#include "forcefields/angle_terms.hpp"
#include "forcefields/bond_term.hpp"
#include "forcefields/dihedral_terms.hpp"

namespace stiffmd {
namespace {

using Eigen::Matrix3Xd;
using Eigen::Vector3d;
using test::dilation_virial;
using test::energy_of;
using test::fd_error;
using test::forces_of;
using test::position_virial;
using test::random_walk;
using test::wrapped;
constexpr double kPi = std::numbers::pi;

const Box kCell = test::periodic_box(Vector3d(3.0, 3.5, 4.0), Vector3d(-1.5, -1.75, -2.0));

// Counts coordinates that moved by a whole box length, so a test can assert it really straddles.
int straddling(const Matrix3Xd& x, const Matrix3Xd& xw) {
  return ((x - xw).cwiseAbs().array() > 1.0).count();
}

Vector3d net(const Matrix3Xd& f) {
  return f.rowwise().sum();
}
Vector3d torque(const Matrix3Xd& x, const Matrix3Xd& f) {
  Vector3d t = Vector3d::Zero();
  for (int i = 0; i < x.cols(); ++i) t += Vector3d(x.col(i)).cross(Vector3d(f.col(i)));
  return t;
}

// =========================================================================================
// Bonds. A case: the kernel, two bond types' example coefficients and a range of bond lengths
// [kMin, kMax] inside the kernel's domain where the forces are not small (kMax < 1.5, half the
// periodic test cell, so that every bond is its own minimum image).

template <class K, double kMinLength, double kMaxLength>
struct BondCase {
  using Kernel = K;
  static constexpr double kMin = kMinLength, kMax = kMaxLength;
};
struct FeneCase : BondCase<Fene, 0.8, 1.35> {
  static std::vector<Fene::Coeffs> types() { return {{30.0, 1.5, 1.0, 1.0}, {20.0, 1.6, 0.5, 0.9}}; }
};
struct MorseCase : BondCase<Morse, 0.6, 1.45> {
  static std::vector<Morse::Coeffs> types() { return {{2.5, 1.7, 1.1}, {0.8, 3.0, 0.9}}; }
};
using BondKernels = ::testing::Types<FeneCase, MorseCase>;

template <class Case>
class BondKernel : public ::testing::Test {
 protected:
  using Kernel = typename Case::Kernel;
  using Term = BondTerm<Kernel>;
  // A chain of n beads, bond types alternating, bond lengths in the case's range.
  static std::vector<Bond> chain(int n) {
    std::vector<Bond> b;
    for (int i = 0; i + 1 < n; ++i) b.push_back({i, i + 1, i % 2});
    return b;
  }
  static Term term(int n) { return Term("bonds", Level::slow, chain(n), Case::types()); }
  static Matrix3Xd configuration(int n, unsigned seed, const Vector3d& start = Vector3d::Zero()) {
    return random_walk(n, Case::kMin, Case::kMax, seed, start);
  }
};
TYPED_TEST_SUITE(BondKernel, BondKernels);

TYPED_TEST(BondKernel, KernelDerivativeIsTheDerivativeOfItsEnergy) {
  using Kernel = typename TestFixture::Kernel;
  const double h = 1e-6;
  for (const auto& c : TypeParam::types()) {
    const auto p = Kernel::params(c);
    auto energy = [&](double r) {
      double e = 0.0, de_dr = 0.0;
      Kernel::eval(r, p, e, de_dr);
      return e;
    };
    for (double r = TypeParam::kMin; r <= TypeParam::kMax; r += 0.0173) {
      double e = 0.0, de_dr = 0.0;
      Kernel::eval(r, p, e, de_dr);
      const double fd = (energy(r + h) - energy(r - h)) / (2 * h);
      EXPECT_NEAR(de_dr, fd, 1e-6 * std::max(1.0, std::abs(fd))) << "r = " << r;
    }
  }
}

TYPED_TEST(BondKernel, ForceIsMinusGradientInOpenSpace) {
  const auto term = TestFixture::term(10);
  for (unsigned seed = 1; seed <= 3; ++seed) {
    const Matrix3Xd x = TestFixture::configuration(10, seed);
    ASSERT_GT(forces_of(term, x, Box{}).cwiseAbs().maxCoeff(), 0.1) << "the configuration must be strained";
    EXPECT_LT(fd_error(term, x, Box{}), 1e-6) << "seed " << seed;
  }
}

// Positions reach a bond term whole (core/state.hpp): a chain folded into the cell is made whole
// again by whole box vectors, and then gives the open-space energy and forces.
Matrix3Xd made_whole(Matrix3Xd xw, int n) {
  std::vector<std::pair<int, int>> pairs;
  for (int i = 0; i + 1 < n; ++i) pairs.emplace_back(i, i + 1);
  EXPECT_FALSE(make_molecules_whole(xw, pairs, kCell));
  return xw;
}

TYPED_TEST(BondKernel, WrappedChainMadeWholeGivesTheOpenSpaceResult) {
  const auto term = TestFixture::term(12);
  for (unsigned seed = 11; seed <= 13; ++seed) {
    const Matrix3Xd x = TestFixture::configuration(12, seed, Vector3d(1.2, 1.5, 1.8));
    ASSERT_GT(straddling(x, wrapped(x, kCell)), 0);
    const Matrix3Xd xw = made_whole(wrapped(x, kCell), 12);
    EXPECT_LT(fd_error(term, xw, kCell), 1e-6);
    EXPECT_NEAR(energy_of(term, xw, kCell), energy_of(term, x, Box{}), 1e-10);
    EXPECT_LT((forces_of(term, xw, kCell) - forces_of(term, x, Box{})).cwiseAbs().maxCoeff(), 1e-9);
  }
}

TYPED_TEST(BondKernel, NewtonsThirdLawAndNoTorque) {
  const auto term = TestFixture::term(10);
  const Matrix3Xd x = TestFixture::configuration(10, 7);
  const Matrix3Xd f = forces_of(term, x, Box{});
  const double scale = f.cwiseAbs().maxCoeff();
  ASSERT_GT(scale, 0.1);
  EXPECT_LT(net(f).cwiseAbs().maxCoeff(), 1e-12 * scale);
  EXPECT_LT(torque(x, f).cwiseAbs().maxCoeff(), 1e-12 * scale * x.cwiseAbs().maxCoeff());  // central forces
}

// W = Σ_b r_ij · f_ij: in open space it is Σ x_i · f_i; in a periodic box, with every bond by
// minimum image, −dE(λx, λL)/dλ.
TYPED_TEST(BondKernel, VirialIsSumOfSeparationDotForce) {
  const auto term = TestFixture::term(12);
  const Matrix3Xd x = TestFixture::configuration(12, 21, Vector3d(1.2, 1.5, 1.8));
  const double w_open = term.virial(x, Box{});
  ASSERT_GT(std::abs(w_open), 0.1);
  EXPECT_NEAR(w_open, position_virial(term, x), 1e-12 * std::max(1.0, std::abs(w_open)));
  const Matrix3Xd xw = made_whole(wrapped(x, kCell), 12);
  const double w = term.virial(xw, kCell);
  EXPECT_NEAR(w, w_open, 1e-10 * std::abs(w_open));
  EXPECT_NEAR(w, dilation_virial(term, xw, kCell), 1e-6 * std::max(1.0, std::abs(w)));
}

TYPED_TEST(BondKernel, RejectsBadBondsNamingTheTerm) {
  using Term = typename TestFixture::Term;
  const auto types = TypeParam::types();
  for (const Bond bad : {Bond{1, 1, 0}, Bond{-1, 1, 0}, Bond{0, 1, 2}, Bond{0, 1, -1}}) {
    try {
      Term("named", Level::slow, {bad}, types);
      ADD_FAILURE() << "bond (" << bad.i << ", " << bad.j << ") of type " << bad.type << " accepted";
    } catch (const std::invalid_argument& e) {
      const std::string msg = e.what();
      EXPECT_NE(msg.find(std::string(Term::Kernel::kStyle) + " 'named'"), std::string::npos) << msg;
    }
  }
}

TYPED_TEST(BondKernel, DescribeNamesStyleCountAndCoefficients) {
  const auto term = TestFixture::term(5);
  const std::string d = term.describe();
  EXPECT_EQ(term.style(), TypeParam::Kernel::kStyle);
  EXPECT_NE(d.find("4 " + std::string(TypeParam::Kernel::kStyle) + " bonds"), std::string::npos) << d;
  EXPECT_NE(d.find("type 1: "), std::string::npos) << d;
}

// Morse against LAMMPS's bond_morse.cpp, term by term: dr = r − r0, ralpha = exp(−alpha dr),
// E = d0 (1 − ralpha)², fbond = −2 d0 alpha (1 − ralpha) ralpha / r (the force on i is
// fbond·(x_i − x_j), so −dE/dr = fbond·r) — and against 30-digit values (mpmath) at four lengths.
TEST(MorseBond, MatchesLammpsFormula) {
  const double d0 = 2.5, alpha = 1.7, r0 = 1.1;
  const BondTerm<Morse> term("m", Level::slow, {{0, 1, 0}}, {{d0, alpha, r0}});
  const struct {
    double r, energy, force;  // force: −dE/dr (mpmath)
  } golden[] = {{0.8, 1.1065309351813132499, 9.4171803366564986711},
                {1.1, 0.0, 0.0},
                {1.4, 0.39900945637136603171, -2.0391554284330949784},
                {3.0, 2.3061244953339917947, -0.32293797616303874125}};
  for (const auto& g : golden) {
    Matrix3Xd x = Matrix3Xd::Zero(3, 2);
    x(0, 0) = g.r;  // x_i − x_j = r x̂
    Matrix3Xd f = Matrix3Xd::Zero(3, 2);
    const double e = term.add_forces(x, Box{}, f);
    const double ralpha = std::exp(-alpha * (g.r - r0));
    const double fbond = -2.0 * d0 * alpha * (1 - ralpha) * ralpha / g.r;
    EXPECT_NEAR(e, d0 * (1 - ralpha) * (1 - ralpha), 1e-14) << g.r;
    EXPECT_NEAR(f(0, 0), fbond * g.r, 1e-13) << g.r;
    EXPECT_NEAR(e, g.energy, 1e-14) << g.r;
    EXPECT_NEAR(f(0, 0), g.force, 1e-13) << g.r;
    EXPECT_EQ(f(0, 1), -f(0, 0));
  }
  // Dissociation: E → D0 far out, the curvature at r0 is 2 D0 α².
  Matrix3Xd far = Matrix3Xd::Zero(3, 2);
  far(0, 0) = 40.0;
  EXPECT_NEAR(energy_of(term, far, Box{}), d0, 1e-12);
  double e = 0.0, dm = 0.0, dp = 0.0;
  Morse::eval(r0 - 1e-5, Morse::params({d0, alpha, r0}), e, dm);
  Morse::eval(r0 + 1e-5, Morse::params({d0, alpha, r0}), e, dp);
  EXPECT_NEAR((dp - dm) / 2e-5, 2 * d0 * alpha * alpha, 1e-6);
}

TEST(MorseBond, RejectsCoefficientsOutsideTheirRanges) {
  const std::vector<Bond> one = {{0, 1, 0}};
  for (const auto& [bad, key] :
       {std::pair{Morse::Coeffs{-1.0, 1.0, 1.0}, "D0"}, std::pair{Morse::Coeffs{1.0, -1.0, 1.0}, "alpha"},
        std::pair{Morse::Coeffs{1.0, 1.0, 0.0}, "r0"}}) {
    try {
      BondTerm<Morse>("m", Level::slow, one, {bad});
      ADD_FAILURE() << key;
    } catch (const std::invalid_argument& e) {
      EXPECT_NE(std::string(e.what()).find(std::string("bond type 0: ") + key + ": expected"), std::string::npos)
          << e.what();
    }
  }
  EXPECT_NO_THROW(BondTerm<Morse>("m", Level::slow, one, {{0.0, 0.0, 1.0}}));  // D0 = 0, α = 0: no force
}

// =========================================================================================
// Angles. A case: the kernel and two angle types' example coefficients (the second with
// θ₀ = π, the straight chain).

template <class K>
struct AngleCase {
  using Kernel = K;
  static std::vector<AngleCoeffs> types() { return {{2.0, 1.9}, {5.0, kPi}}; }
};
using AngleKernels = ::testing::Types<AngleCase<HarmonicAngleKernel>, AngleCase<CosineAngleKernel>>;

template <class Case>
class AngleKernel : public ::testing::Test {
 protected:
  using Kernel = typename Case::Kernel;
  using Term = AngleTerm<Kernel>;
  // The angles of a chain of n beads, types alternating, and (in open space) a branch at bead
  // 3, whose long arm would not be its own minimum image in the periodic test cell.
  static std::vector<Angle> angles(int n, bool branch) {
    std::vector<Angle> a;
    for (int i = 0; i + 2 < n; ++i) a.push_back({i, i + 1, i + 2, i % 2});
    if (branch) a.push_back({n - 1, 3, 0, 1});
    return a;
  }
  static Term term(int n, bool branch = true) { return Term("angles", Level::slow, angles(n, branch), Case::types()); }
};
TYPED_TEST_SUITE(AngleKernel, AngleKernels);

TYPED_TEST(AngleKernel, KernelDerivativeIsTheDerivativeOfItsEnergy) {
  using Kernel = typename TestFixture::Kernel;
  const double h = 1e-6;
  for (const AngleCoeffs& c : TypeParam::types())
    for (double theta = 0.01; theta < kPi - 0.01; theta += 0.0371) {
      double e = 0.0, de = 0.0, ep = 0.0, em = 0.0, unused = 0.0;
      Kernel::eval(theta, c, e, de);
      Kernel::eval(theta + h, c, ep, unused);
      Kernel::eval(theta - h, c, em, unused);
      EXPECT_NEAR(de, (ep - em) / (2 * h), 1e-7 * std::max(1.0, std::abs(de))) << "theta = " << theta;
    }
}

TYPED_TEST(AngleKernel, ForceIsMinusGradientInOpenSpace) {
  const auto term = TestFixture::term(9);
  for (unsigned seed = 1; seed <= 3; ++seed) {
    const Matrix3Xd x = random_walk(9, 0.7, 1.3, seed);
    ASSERT_GT(forces_of(term, x, Box{}).cwiseAbs().maxCoeff(), 0.1);
    EXPECT_LT(fd_error(term, x, Box{}), 1e-6) << "seed " << seed;
  }
}

// Bonded terms take the raw differences of whole molecules (ARCHITECTURE.md): a chain folded into
// the cell and made whole again gives the open-space energy and forces.
TYPED_TEST(AngleKernel, WrappedChainMadeWholeGivesTheOpenSpaceResult) {
  const auto term = TestFixture::term(12, false);
  for (unsigned seed = 31; seed <= 33; ++seed) {
    const Matrix3Xd x = random_walk(12, 0.7, 1.3, seed, Vector3d(1.2, 1.5, 1.8));
    ASSERT_GT(straddling(x, wrapped(x, kCell)), 0);
    const Matrix3Xd xw = made_whole(wrapped(x, kCell), 12);
    EXPECT_LT(fd_error(term, xw, kCell), 1e-6);
    EXPECT_NEAR(energy_of(term, xw, kCell), energy_of(term, x, Box{}), 1e-10);
    EXPECT_LT((forces_of(term, xw, kCell) - forces_of(term, x, Box{})).cwiseAbs().maxCoeff(), 1e-9);
  }
}

TYPED_TEST(AngleKernel, NewtonsThirdLawAndNoTorque) {
  const auto term = TestFixture::term(9);
  const Matrix3Xd x = random_walk(9, 0.7, 1.3, 5);
  const Matrix3Xd f = forces_of(term, x, Box{});
  const double scale = f.cwiseAbs().maxCoeff();
  ASSERT_GT(scale, 0.1);
  EXPECT_LT(net(f).cwiseAbs().maxCoeff(), 1e-12 * scale);
  // E depends on θ alone, which is rotation invariant: Σ x × f = 0 as well.
  EXPECT_LT(torque(x, f).cwiseAbs().maxCoeff(), 1e-12 * scale * x.cwiseAbs().maxCoeff());
}

// θ is invariant under x → λx, so the angle virial vanishes (Euler, degree 0): in open space
// Σ x_i · f_i, in a periodic box −dE(λx, λL)/dλ, and virial() must all be zero to round-off,
// measured against the size of the individual terms |x_i||f_i|.
TYPED_TEST(AngleKernel, VirialIsSumOfSeparationDotForce) {
  const auto term = TestFixture::term(12, false);
  const Matrix3Xd x = random_walk(12, 0.7, 1.3, 41, Vector3d(1.2, 1.5, 1.8));
  const Matrix3Xd f = forces_of(term, x, Box{});
  const double scale = (x.colwise().norm().array() * f.colwise().norm().array()).sum();
  ASSERT_GT(scale, 1.0);
  EXPECT_NEAR(term.virial(x, Box{}), position_virial(term, x), 1e-13 * scale);
  EXPECT_NEAR(term.virial(x, Box{}), 0.0, 1e-13 * scale);
  const Matrix3Xd xw = wrapped(x, kCell);
  EXPECT_NEAR(term.virial(xw, kCell), 0.0, 1e-13 * scale);
  EXPECT_NEAR(dilation_virial(term, xw, kCell), 0.0, 1e-7 * scale);
}

// A straight chain, θ = π exactly: finite forces, zero for the θ₀ = π type (a minimum).
TYPED_TEST(AngleKernel, StraightChainGivesFiniteForces) {
  using Term = typename TestFixture::Term;
  Matrix3Xd x = Matrix3Xd::Zero(3, 3);
  x(0, 0) = 1.1;
  x(0, 2) = -0.9;
  for (const AngleCoeffs& c : TypeParam::types()) {
    const Term term("a", Level::slow, {{0, 1, 2, 0}}, {c});
    const Matrix3Xd f = forces_of(term, x, Box{});
    EXPECT_TRUE(f.allFinite());
    EXPECT_EQ(f.cwiseAbs().maxCoeff(), 0.0);
    EXPECT_LT(fd_error(term, x, Box{}), 1e-9);
  }
}

TYPED_TEST(AngleKernel, RejectsBadAnglesAndCoefficients) {
  using Term = typename TestFixture::Term;
  for (const Angle bad : {Angle{0, 0, 2, 0}, Angle{2, 1, 2, 0}, Angle{-1, 1, 2, 0}, Angle{0, 1, 2, 2}})
    EXPECT_THROW(Term("a", Level::slow, {bad}, TypeParam::types()), std::invalid_argument);
  for (const AngleCoeffs bad : {AngleCoeffs{-1.0, 2.0}, AngleCoeffs{1.0, 3.2}, AngleCoeffs{NAN, 2.0}})
    EXPECT_THROW(Term("a", Level::slow, {{0, 1, 2, 0}}, {bad}), std::invalid_argument);
}

// =========================================================================================
// Dihedrals. A case: the kernel and two dihedral types' example coefficients, with forces that
// are not small at generic torsions.

template <class K>
struct DihedralCase {
  using Kernel = K;
};
struct HarmonicDihedralCase : DihedralCase<HarmonicDihedralKernel> {
  static std::vector<HarmonicDihedralKernel::Coeffs> types() { return {{1.5, 1, 3}, {-0.8, -1, 2}}; }
};
struct MultiHarmonicDihedralCase : DihedralCase<MultiHarmonicDihedralKernel> {
  static std::vector<MultiHarmonicDihedralKernel::Coeffs> types() {
    return {{{1.0, -0.5, 0.8, 1.2, -0.3}}, {{0.2, 1.1, -0.6, 0.0, 0.9}}};
  }
};
struct OplsDihedralCase : DihedralCase<OplsDihedralKernel> {
  static std::vector<OplsDihedralKernel::Coeffs> types() { return {{{1.4, -0.3, 0.9, 0.2}}, {{-0.5, 0.7, 0.1, -0.4}}}; }
};
using DihedralKernels = ::testing::Types<HarmonicDihedralCase, MultiHarmonicDihedralCase, OplsDihedralCase>;

template <class Case>
class DihedralKernel : public ::testing::Test {
 protected:
  using Kernel = typename Case::Kernel;
  using Term = DihedralTerm<Kernel>;
  // The dihedrals of a chain of n beads, types alternating, and (in open space) one about a
  // bond in the middle to a distant bead, whose arm would not be its own minimum image.
  static std::vector<Dihedral> dihedrals(int n, bool branch) {
    std::vector<Dihedral> d;
    for (int i = 0; i + 3 < n; ++i) d.push_back({i, i + 1, i + 2, i + 3, i % 2});
    if (branch) d.push_back({n - 1, 3, 4, 0, 1});
    return d;
  }
  static Term term(int n, bool branch = true) {
    return Term("dihedrals", Level::slow, dihedrals(n, branch), Case::types());
  }

 public:
  // Four beads with bond lengths 1.0, 1.1, 0.9, bond angles 110° and 100°, at torsion φ.
  static Matrix3Xd quadruple(double phi) {
    const double t1 = 110.0 * kPi / 180.0, t2 = 100.0 * kPi / 180.0;
    Matrix3Xd x(3, 4);
    x.col(1) = Vector3d::Zero();
    x.col(2) = Vector3d(1.1, 0.0, 0.0);
    x.col(0) = Vector3d(std::cos(t1), std::sin(t1), 0.0);  // on +y
    // l: at angle t2 at k, rotated by φ about the x axis from the cis position (φ = 0: same side
    // as i); φ > 0 turns it towards +z, clockwise seen along j → k: IUPAC's positive sense.
    const Vector3d arm(-std::cos(t2), std::sin(t2) * std::cos(phi), std::sin(t2) * std::sin(phi));
    x.col(3) = x.col(2) + 0.9 * arm;
    return x;
  }
};
TYPED_TEST_SUITE(DihedralKernel, DihedralKernels);

TYPED_TEST(DihedralKernel, KernelDerivativeIsTheDerivativeOfItsEnergy) {
  using Kernel = typename TestFixture::Kernel;
  const double h = 1e-6;
  for (const auto& c : TypeParam::types())
    for (double phi = -kPi + 0.01; phi < kPi; phi += 0.0371) {
      double e = 0.0, de = 0.0, ep = 0.0, em = 0.0, unused = 0.0;
      Kernel::eval(phi, c, e, de);
      Kernel::eval(phi + h, c, ep, unused);
      Kernel::eval(phi - h, c, em, unused);
      EXPECT_NEAR(de, (ep - em) / (2 * h), 1e-7 * std::max(1.0, std::abs(de))) << "phi = " << phi;
    }
}

// The geometry's φ: the quadruple built at torsion φ reads back as φ (trans = ±π, cis = 0, IUPAC's
// sign), and
// the energy is even in φ (every LAMMPS style here is).
TYPED_TEST(DihedralKernel, TorsionAngleFollowsTheIupacConvention) {
  for (double phi : {0.0, 0.3, 1.2, 2.0, 3.0, kPi, -0.7, -2.9}) {
    const Matrix3Xd x = TestFixture::quadruple(phi);
    const auto g = dihedral_detail::geometry(0, 1, 2, 3, x);
    EXPECT_NEAR(std::remainder(g.phi - phi, 2 * kPi), 0.0, 1e-13) << "phi = " << phi;
    const typename TestFixture::Term one("d", Level::slow, {{0, 1, 2, 3, 0}}, TypeParam::types());
    EXPECT_NEAR(energy_of(one, x, Box{}), energy_of(one, TestFixture::quadruple(-phi), Box{}), 1e-13);
  }
}

TYPED_TEST(DihedralKernel, ForceIsMinusGradientInOpenSpace) {
  const auto term = TestFixture::term(9);
  for (unsigned seed = 1; seed <= 3; ++seed) {
    const Matrix3Xd x = random_walk(9, 0.7, 1.3, seed);
    ASSERT_GT(forces_of(term, x, Box{}).cwiseAbs().maxCoeff(), 0.1);
    EXPECT_LT(fd_error(term, x, Box{}), 1e-6) << "seed " << seed;
  }
}

// Near cis and trans (φ = 0, π ± 10⁻⁹ and exactly), where a cos φ route divides by sin φ ≈ 0:
// finite forces equal to −∇E.
TYPED_TEST(DihedralKernel, ForceIsMinusGradientNearCisAndTrans) {
  const typename TestFixture::Term one("d", Level::slow, {{0, 1, 2, 3, 0}, {3, 2, 1, 0, 1}}, TypeParam::types());
  for (double phi : {0.0, 1e-9, -1e-9, kPi, kPi - 1e-9, -kPi + 1e-9, 1e-4, kPi - 1e-4}) {
    const Matrix3Xd x = TestFixture::quadruple(phi);
    const Matrix3Xd f = forces_of(one, x, Box{});
    EXPECT_TRUE(f.allFinite());
    EXPECT_LT(fd_error(one, x, Box{}), 1e-6) << "phi = " << phi;
  }
}

// Bonded terms take the raw differences of whole molecules (ARCHITECTURE.md): a chain folded into
// the cell and made whole again gives the open-space energy and forces.
TYPED_TEST(DihedralKernel, WrappedChainMadeWholeGivesTheOpenSpaceResult) {
  const auto term = TestFixture::term(12, false);
  for (unsigned seed = 31; seed <= 33; ++seed) {
    const Matrix3Xd x = random_walk(12, 0.7, 1.3, seed, Vector3d(1.2, 1.5, 1.8));
    ASSERT_GT(straddling(x, wrapped(x, kCell)), 0);
    const Matrix3Xd xw = made_whole(wrapped(x, kCell), 12);
    EXPECT_LT(fd_error(term, xw, kCell), 1e-6);
    EXPECT_NEAR(energy_of(term, xw, kCell), energy_of(term, x, Box{}), 1e-10);
    EXPECT_LT((forces_of(term, xw, kCell) - forces_of(term, x, Box{})).cwiseAbs().maxCoeff(), 1e-9);
  }
}

TYPED_TEST(DihedralKernel, NewtonsThirdLawAndNoTorque) {
  const auto term = TestFixture::term(9);
  const Matrix3Xd x = random_walk(9, 0.7, 1.3, 5);
  const Matrix3Xd f = forces_of(term, x, Box{});
  const double scale = f.cwiseAbs().maxCoeff();
  ASSERT_GT(scale, 0.1);
  EXPECT_LT(net(f).cwiseAbs().maxCoeff(), 1e-12 * scale);
  EXPECT_LT(torque(x, f).cwiseAbs().maxCoeff(), 1e-12 * scale * x.cwiseAbs().maxCoeff());
}

// φ is invariant under x → λx: the virial vanishes (Euler, degree 0), computed three ways.
TYPED_TEST(DihedralKernel, VirialIsSumOfSeparationDotForce) {
  const auto term = TestFixture::term(12, false);
  const Matrix3Xd x = random_walk(12, 0.7, 1.3, 41, Vector3d(1.2, 1.5, 1.8));
  const Matrix3Xd f = forces_of(term, x, Box{});
  const double scale = (x.colwise().norm().array() * f.colwise().norm().array()).sum();
  ASSERT_GT(scale, 1.0);
  EXPECT_NEAR(term.virial(x, Box{}), position_virial(term, x), 1e-13 * scale);
  EXPECT_NEAR(term.virial(x, Box{}), 0.0, 1e-13 * scale);
  const Matrix3Xd xw = wrapped(x, kCell);
  EXPECT_NEAR(term.virial(xw, kCell), 0.0, 1e-13 * scale);
  EXPECT_NEAR(dilation_virial(term, xw, kCell), 0.0, 1e-7 * scale);
}

TYPED_TEST(DihedralKernel, RejectsBadDihedrals) {
  using Term = typename TestFixture::Term;
  for (const Dihedral bad :
       {Dihedral{0, 1, 2, 0, 0}, Dihedral{0, 1, 1, 3, 0}, Dihedral{-1, 1, 2, 3, 0}, Dihedral{0, 1, 2, 3, 2}})
    EXPECT_THROW(Term("d", Level::slow, {bad}, TypeParam::types()), std::invalid_argument);
  // A zero-length central bond leaves φ undefined: a numerical error naming the dihedral.
  Matrix3Xd x = TestFixture::quadruple(1.0);
  x.col(2) = x.col(1);
  const Term one("d", Level::slow, {{0, 1, 2, 3, 0}}, TypeParam::types());
  EXPECT_THROW(forces_of(one, x, Box{}), NumericalError);
}

// LAMMPS's energies (dihedral_style harmonic, multi/harmonic, opls; `run 0`, thermo edihed with
// norm no, %.17g) on the quadruples of DihedralKernel::quadruple at five torsions, computed by
// tools/lammps_dihedral_reference.py (LAMMPS 29 Sep 2021, update 2) with, per style and torsion, the input
//     units lj / atom_style molecular / boundary f f f / read_data q.data (the 4 atoms, 1 dihedral 1 2 3 4)
//     dihedral_style STYLE / dihedral_coeff 1 COEFFS / pair_style zero 1.0 / pair_coeff * *
//     thermo_style custom step edihed / thermo_modify norm no format float %.17g / run 0
// Same coefficients, same energies: the styles match LAMMPS's formulas and its φ convention.
TEST(DihedralStyles, MatchLammpsEnergies) {
  const std::vector<double> phis = {0.3, 1.2, 2.0, kPi - 0.05, -2.6};
  auto check = [&](const ForceTerm& term, const std::vector<double>& lammps) {
    for (size_t m = 0; m < phis.size(); ++m) {
      const Matrix3Xd x = DihedralKernel<HarmonicDihedralCase>::quadruple(phis[m]);
      EXPECT_NEAR(energy_of(term, x, Box{}), lammps[m], 1e-13 * std::max(1.0, std::abs(lammps[m])))
          << term.style() << " at phi = " << phis[m];
    }
  };
  const std::vector<Dihedral> one = {{0, 1, 2, 3, 0}};
  check(HarmonicDihedral("d", Level::slow, one, {{1.5, 1, 3}}),
        {2.4324149524059964, 0.15486237549877985, 2.9402554299755486, 0.016843383095936471, 1.5809331308439738});
  check(HarmonicDihedral("d", Level::slow, one, {{-0.8, -1, 2}}),
        {-0.13973150807225743, -1.3899149724329962, -1.3229148966908895, -0.0039966677775793436, -0.42518666295969842});
  check(MultiHarmonicDihedral("d", Level::slow, one, {{{1.0, -0.5, 0.8, 1.2, -0.3}}}),
        {2.048863074065987, 0.97578593612613485, 1.2511376974281729, 0.80336711711166031, 1.0990972022998311});
  check(OplsDihedral("d", Level::slow, one, {{{1.4, -0.3, 0.9, 0.2}}}),
        {2.1360245948985082, 0.830750185108174, 1.1572773036609845, 0.0071717996598833541, 0.65083373833270786});
}

TEST(DihedralCoefficients, RefuseWhatLammpsRefuses) {
  using H = HarmonicDihedralKernel;
  for (const H::Coeffs bad : {H::Coeffs{1.0, 0, 1}, H::Coeffs{1.0, 2, 1}, H::Coeffs{1.0, 1, -1}, H::Coeffs{NAN, 1, 1}})
    EXPECT_THROW(HarmonicDihedral("d", Level::slow, {}, {bad}), std::invalid_argument);
  EXPECT_NO_THROW(HarmonicDihedral("d", Level::slow, {}, {{-2.0, -1, 0}}));  // K < 0 and n = 0 are allowed
  EXPECT_THROW(MultiHarmonicDihedral("d", Level::slow, {}, {{{1, 2, INFINITY, 0, 0}}}), std::invalid_argument);
  EXPECT_THROW(OplsDihedral("d", Level::slow, {}, {{{NAN, 0, 0, 0}}}), std::invalid_argument);
}

}  // namespace
}  // namespace stiffmd
