// The charged pair styles (forcefields/coulomb_potentials.hpp on PairTerm): each kernel's force
// against its energy, the special-bond weights and the Ewald exclusion correction, the terms' forces
// and virials, and LAMMPS's `run 0` on one charged system (tools/lammps_coulomb_reference.py).
#include <gtest/gtest.h>

#include <array>
#include <bit>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <limits>
#include <map>
#include <string>
#include <vector>

#include "engine/io/lammps_data.hpp"
#include "force_term_checks.hpp"
#include "forcefields/ewald_table.hpp"
#include "forcefields/pair_term.hpp"

namespace stiffmd {
namespace {

constexpr double kQqrd2eReal = 332.06371;  // LAMMPS real units
constexpr double kG = 0.28;                // the Ewald splitting of the LAMMPS runs

// One kernel value: evdwl, ecoul, fpair at r² for qq and the factors.
struct KernelValue {
  double evdwl, ecoul, fpair;
};
template <class K>
KernelValue kernel_at(const typename K::Params& p, double r2, double qq, double flj, double fcoul) {
  KernelValue v{};
  K::eval(r2, p, qq, flj, fcoul, v.evdwl, v.ecoul, v.fpair);
  return v;
}

// With `table`, a coul/long kernel's Params carry the real-space table for (kG, its Coulomb cutoff),
// as the term sets them (PairTerm::set_splitting); without, the exact form alone.
template <class K>
typename K::Params kernel_params(const typename K::Coeffs& c, bool table = false) {
  typename K::Params p = K::params(c);
  if constexpr (EwaldKernel<K>) {
    p.g_ewald = kG;
    static const EwaldRealSpaceTable shared(kG, 8.0);
    if (table) {
      EXPECT_EQ(K::coulomb_cutoff(c), 8.0);
      p.table = &shared;
    }
  }
  return p;
}

// −dE/dr / r against central differences of E = evdwl + ecoul, away from the cutoffs.
template <class K>
void expect_force_is_minus_derivative(const typename K::Coeffs& c, std::initializer_list<double> cutoffs,
                                      bool table = false) {
  const typename K::Params p = kernel_params<K>(c, table);
  for (const auto& [flj, fcoul] : {std::pair{1.0, 1.0}, std::pair{0.5, 0.3}, std::pair{0.0, 0.0}})
    for (double r = 1.2; r < 9.5; r += 0.137) {
      bool near_cut = false;
      for (double rc : cutoffs) near_cut |= std::abs(r - rc) < 1e-3;
      if (near_cut) continue;
      const double h = 1e-6 * r, qq = -0.3 * kQqrd2eReal;
      const auto e = [&](double s) {
        const KernelValue v = kernel_at<K>(p, s * s, qq, flj, fcoul);
        return v.evdwl + v.ecoul;
      };
      const double fd = -(e(r + h) - e(r - h)) / (2 * h) / r;
      const double fpair = kernel_at<K>(p, r * r, qq, flj, fcoul).fpair;
      EXPECT_NEAR(fpair, fd, 1e-6 * std::max(1.0, std::abs(fd)))
          << K::kStyle << " r = " << r << " w = " << flj << ", " << fcoul;
    }
}

LjCoulCoeffs lj_coul(double kappa, bool shift) {
  LjCoulCoeffs c;
  c.epsilon = 0.15, c.sigma = 3.2, c.rc = 7.0, c.coulomb_cutoff = 8.0, c.kappa = kappa, c.shift = shift;
  return c;
}
LjCharmmCoulLong::Coeffs charmm() {
  return {0.15, 3.2, 0.07, 3.0, 6.0, 7.0, 8.0};
}

TEST(CoulombKernels, ForceIsMinusDerivativeOfEnergy) {
  expect_force_is_minus_derivative<CoulombCut>({8.0}, {8.0});
  expect_force_is_minus_derivative<CoulombDebye>({0.2, 8.0}, {8.0});
  expect_force_is_minus_derivative<CoulombLong>({8.0}, {8.0});
  expect_force_is_minus_derivative<LjCutCoulCut>(lj_coul(0, false), {7.0, 8.0});
  expect_force_is_minus_derivative<LjCutCoulDebye>(lj_coul(0.2, true), {7.0, 8.0});
  expect_force_is_minus_derivative<LjCutCoulLong>(lj_coul(0, false), {7.0, 8.0});
  expect_force_is_minus_derivative<LjCharmmCoulLong>(charmm(), {6.0, 7.0, 8.0});
  // The coul/long family on its real-space table (E and G interpolated apart).
  expect_force_is_minus_derivative<CoulombLong>({8.0}, {8.0}, true);
  expect_force_is_minus_derivative<LjCutCoulLong>(lj_coul(0, false), {7.0, 8.0}, true);
  expect_force_is_minus_derivative<LjCharmmCoulLong>(charmm(), {6.0, 7.0, 8.0}, true);
}

// The real-space table (forcefields/ewald_table.hpp) against the exact form (coulomb_long: erfc to
// round-off) at 20 000 points spread over its 13 octaves, for the g r_c of LAMMPS's accuracies 1e-4
// … 1e-8 at a 10 Å cutoff: relative error of E and G at most the header's figures.
TEST(EwaldTable, MatchesTheExactFormToItsStatedAccuracy) {
  const double rc = 10.0;
  for (const auto& [g_rc, bound] :
       {std::pair{2.0, 1e-13}, std::pair{3.1, 1e-13}, std::pair{3.5, 1e-13}, std::pair{4.8, 1e-11}}) {
    const EwaldRealSpaceTable table(g_rc / rc, rc);
    EXPECT_LE(table.s_max(), 2.0 * rc * rc);
    EXPECT_GE(table.s_max(), rc * rc);
    double worst_e = 0.0, worst_f = 0.0;
    for (int k = 0; k < 20000; ++k) {
      const double s = table.s_min() * std::pow(rc * rc / table.s_min(), (k + 0.5) / 20000.0);
      ASSERT_TRUE(table.covers(s));
      double e = 0.0, f = 0.0, exact_e = 0.0, exact_f = 0.0;
      table.eval(s, e, f);
      coulomb_detail::coulomb_long(1.0, table.g(), std::sqrt(s), 1.0, exact_f, exact_e);
      worst_e = std::max(worst_e, std::abs(e - exact_e) / exact_e);
      worst_f = std::max(worst_f, std::abs(f - exact_f) / exact_f);
    }
    std::printf("g rc = %.1f: max relative error E %.2e, G %.2e (bound %.0e)\n", g_rc, worst_e, worst_f, bound);
    EXPECT_LE(worst_e, bound);
    EXPECT_LE(worst_f, bound);
  }
}

// At every interval's start the polynomials on both sides meet (to the interpolation's accuracy):
// the table is continuous where its pieces join, so a pair crossing a join sees no jump.
TEST(EwaldTable, IsContinuousWhereItsIntervalsJoin) {
  const EwaldRealSpaceTable table(0.31, 10.0);
  int joins = 0;
  for (double s = table.s_min() * (1.0 + 1.0 / 32.0); s < table.s_max(); s *= 1.0 + 1.0 / 64.0) {
    // the join at or below s: s with the bits below the top 5 of the mantissa cleared
    const std::uint64_t mask = ~((std::uint64_t{1} << (52 - EwaldRealSpaceTable::kMantissaBits)) - 1);
    const double join = std::bit_cast<double>(std::bit_cast<std::uint64_t>(s) & mask);
    double e_below = 0.0, f_below = 0.0, e_at = 0.0, f_at = 0.0;
    table.eval(std::nextafter(join, 0.0), e_below, f_below);
    table.eval(join, e_at, f_at);
    EXPECT_NEAR(e_below, e_at, 1e-13 * e_at) << "s = " << join;
    EXPECT_NEAR(f_below, f_at, 1e-13 * f_at) << "s = " << join;
    ++joins;
  }
  EXPECT_GT(joins, 300);
}

// Below the table (r < r_c/90), beyond it and for special pairs (w ≠ 1, which need 1/r) the kernels
// take the exact form: the same bits as without a table.
TEST(EwaldTable, KernelsTakeTheExactFormOutsideTheTableAndForSpecialPairs) {
  const CoulombLong::Params with = kernel_params<CoulombLong>({8.0}, true), without = kernel_params<CoulombLong>({8.0});
  ASSERT_NE(with.table, nullptr);
  const double qq = -0.42 * kQqrd2eReal;
  for (const double r2 : {0.5 * with.table->s_min(), with.table->s_max() * 1.5}) {
    const KernelValue a = kernel_at<CoulombLong>(with, r2, qq, 1.0, 1.0),
                      b = kernel_at<CoulombLong>(without, r2, qq, 1.0, 1.0);
    EXPECT_EQ(a.ecoul, b.ecoul);
    EXPECT_EQ(a.fpair, b.fpair);
  }
  for (const double w : {0.0, 0.5}) {
    const KernelValue a = kernel_at<CoulombLong>(with, 2.3, qq, w, w),
                      b = kernel_at<CoulombLong>(without, 2.3, qq, w, w);
    EXPECT_EQ(a.ecoul, b.ecoul);
    EXPECT_EQ(a.fpair, b.fpair);
  }
  // Inside the table an ordinary pair is the table's, within its accuracy of the exact form.
  const KernelValue a = kernel_at<CoulombLong>(with, 7.3, qq, 1.0, 1.0),
                    b = kernel_at<CoulombLong>(without, 7.3, qq, 1.0, 1.0);
  EXPECT_NEAR(a.ecoul, b.ecoul, 1e-13 * std::abs(b.ecoul));
  EXPECT_NEAR(a.fpair, b.fpair, 1e-13 * std::abs(b.fpair));
}

TEST(EwaldTable, RefusesBadInput) {
  for (const auto& [g, rc] : {std::pair{0.0, 10.0}, std::pair{-1.0, 10.0}, std::pair{0.3, 0.0},
                              std::pair{std::nan(""), 10.0}, std::pair{0.3, std::numeric_limits<double>::infinity()}})
    EXPECT_THROW(EwaldRealSpaceTable(g, rc), std::invalid_argument) << g << " " << rc;
}

// The formulas at one distance, written out as LAMMPS's pair styles compute them.
TEST(CoulombKernels, MatchLammpsFormulas) {
  const double r = 3.7, r2 = r * r, qq = 0.4 * -0.25 * kQqrd2eReal, wlj = 0.5, wc = 0.3;
  KernelValue v = kernel_at<CoulombCut>(kernel_params<CoulombCut>({8.0}), r2, qq, wlj, wc);
  EXPECT_DOUBLE_EQ(v.ecoul, wc * qq / r);
  EXPECT_DOUBLE_EQ(v.fpair, wc * qq / r / r2);
  v = kernel_at<CoulombDebye>(kernel_params<CoulombDebye>({0.2, 8.0}), r2, qq, wlj, wc);
  EXPECT_DOUBLE_EQ(v.ecoul, wc * qq * std::exp(-0.2 * r) / r);
  const double erfc = std::erfc(kG * r);
  v = kernel_at<CoulombLong>(kernel_params<CoulombLong>({8.0}), r2, qq, wlj, wc);
  EXPECT_NEAR(v.ecoul, qq / r * (erfc - (1 - wc)), 1e-14 * std::abs(qq / r));
  const double s6 = std::pow(3.2 / r, 6);
  v = kernel_at<LjCutCoulCut>(kernel_params<LjCutCoulCut>(lj_coul(0, false)), r2, qq, wlj, wc);
  EXPECT_NEAR(v.evdwl, wlj * 4 * 0.15 * (s6 * s6 - s6), 1e-14);
  const double ro = 7.0, ri = 6.0, rs = 6.5;  // CHARMM's switch at r = 6.5
  const double sw = (ro * ro - rs * rs) * (ro * ro - rs * rs) * (ro * ro + 2 * rs * rs - 3 * ri * ri) /
                    std::pow(ro * ro - ri * ri, 3);
  const double t6 = std::pow(3.2 / rs, 6);
  v = kernel_at<LjCharmmCoulLong>(kernel_params<LjCharmmCoulLong>(charmm()), rs * rs, 0.0, 1.0, 1.0);
  EXPECT_NEAR(v.evdwl, 4 * 0.15 * (t6 * t6 - t6) * sw, 1e-15);
  // Beyond each cutoff its part is zero.
  v = kernel_at<LjCutCoulCut>(kernel_params<LjCutCoulCut>(lj_coul(0, false)), 7.5 * 7.5, qq, 1, 1);
  EXPECT_EQ(v.evdwl, 0.0);
  EXPECT_DOUBLE_EQ(v.ecoul, qq / 7.5);
  v = kernel_at<LjCharmmCoulLong>(kernel_params<LjCharmmCoulLong>(charmm()), 7.0 * 7.0 * (1 + 1e-12), qq, 1, 1);
  EXPECT_EQ(v.evdwl, 0.0);
}

// The committed system of tools/lammps_coulomb_reference.py.
struct ChargedChains {
  Eigen::Matrix3Xd x;
  Box box;
  std::vector<int> types;
  std::vector<double> charges;
  std::vector<Bond> bonds;
  ChargedChains() {
    const ImportedSystem s = read_lammps_data(std::string(STIFFMD_SOURCE_DIR) + "/tests/data/coulomb_chains.data");
    x = s.x;
    box = test::periodic_box(s.hi - s.lo, s.lo);
    for (const int t : s.type) types.push_back(t - 1);
    charges = s.charge;
    for (const auto& b : s.bonds) bonds.push_back({b.i, b.j, 0});
  }
};

constexpr SpecialWeights kLj{0.0, 0.5, 0.7};
constexpr SpecialWeights kCoul{0.0, 0.3, 0.8333333};

template <class K>
std::unique_ptr<PairTerm<K>> make_term(const ChargedChains& s, const TypePairMatrix<typename K::Coeffs>& c,
                                       SpecialWeights lj = kLj, SpecialWeights coul = kCoul) {
  auto t = std::make_unique<PairTerm<K>>("q", Level::slow, s.types, c, s.bonds, lj, s.box, 0.3,
                                         Electrostatics{s.charges, kQqrd2eReal, coul});
  if constexpr (EwaldKernel<K>) t->set_ewald_splitting(kG);
  return t;
}

template <class C>
TypePairMatrix<C> same(const C& c) {
  TypePairMatrix<C> m(2);
  m.set(0, 0, c), m.set(0, 1, c), m.set(1, 1, c);
  return m;
}
// LAMMPS's mixing of the lj/cut forms (geometric) from types (0.1, 3.0) and (0.2, 3.4).
TypePairMatrix<LjCoulCoeffs> lj_types(double kappa, bool shift) {
  TypePairMatrix<LjCoulCoeffs> m(2);
  const double eps[2] = {0.1, 0.2}, sig[2] = {3.0, 3.4};
  for (int a = 0; a < 2; ++a)
    for (int b = a; b < 2; ++b) {
      LjCoulCoeffs c;
      c.epsilon = std::sqrt(eps[a] * eps[b]), c.sigma = std::sqrt(sig[a] * sig[b]);
      c.rc = 7.0, c.coulomb_cutoff = 8.0, c.kappa = kappa, c.shift = shift;
      m.set(a, b, c);
    }
  return m;
}
// lj/charmm/coul/long mixes arithmetically: ε geometric, σ the mean (ε14, σ14 alike).
TypePairMatrix<LjCharmmCoulLong::Coeffs> charmm_types() {
  TypePairMatrix<LjCharmmCoulLong::Coeffs> m(2);
  const double eps[2] = {0.1, 0.2}, sig[2] = {3.0, 3.4}, eps14[2] = {0.05, 0.1}, sig14[2] = {2.8, 3.2};
  for (int a = 0; a < 2; ++a)
    for (int b = a; b < 2; ++b)
      m.set(a, b,
            {std::sqrt(eps[a] * eps[b]), 0.5 * (sig[a] + sig[b]), std::sqrt(eps14[a] * eps14[b]),
             0.5 * (sig14[a] + sig14[b]), 6.0, 7.0, 8.0});
  return m;
}

template <class C>
TypePairMatrix<C> one_type(const C& c) {
  TypePairMatrix<C> m(1);
  m.set(0, 0, c);
  return m;
}

struct Reference {
  double evdwl, ecoul, virial;
  std::vector<std::array<double, 3>> forces;  // atoms 1, 7, 23 (ids), the styles without k-space
};

// tools/lammps_coulomb_reference.py (lmp 29 Sep 2021), rows as printed.
const std::map<std::string, Reference>& lammps_reference() {
  static const std::map<std::string, Reference> ref = {
      // clang-format off
{"coul/cut", {0, 84.080324617988268, 84.08032461798824, {{3.1638079079095922, -0.33627571346178753, -0.110900686960634}, {0.26538402951521345, 0.041922460750572495, -0.066608666230157348}, {-4.7576942985372455, 0.11979398498883403, -0.21821795924154108}}}},
{"coul/debye", {0, -4.9174582311867763, 28.30019867857502, {{2.5727129353955371, -0.28338334742645099, -0.086230410389861706}, {0.61587285253630264, 0.038005711330524675, -0.060425274667407727}, {-4.2944577384291138, 0.10772849850534427, -0.20258676797677425}}}},
{"lj/cut/coul/cut", {199.91942429150851, 84.080324617988268, 2721.2874322334733, {{-5.86494166546498, -0.29464272014062909, -0.094626080798457662}, {-159.92079674874137, -5.5568040488855459, 9.0897220234927438}, {-4.2861586186078622, -0.24048741805361462, 0.32678573891908436}}}},
{"lj/cut/coul/cut tail", {198.93287982258335, 84.080324617988268, 2715.38775184486, {{-5.86494166546498, -0.29464272014062909, -0.094626080798457662}, {-159.92079674874137, -5.5568040488855459, 9.0897220234927438}, {-4.2861586186078622, -0.24048741805361462, 0.32678573891908436}}}},
{"lj/cut/coul/debye shift", {200.27988858576828, -4.9174582311867763, 2665.5073062940596, {{-6.4560366379790359, -0.24175035410529255, -0.069955804227685381}, {-159.57030792572027, -5.5607207983055931, 9.0959054150554906}, {-3.8229220584997301, -0.25255290453710438, 0.34241693018385116}}}},
{"coul/long", {0, 220.77262190263258, 0.9153929303453449, {}}},
{"lj/cut/coul/long", {199.91942429150851, 220.77262190263258, 2638.1225005458305, {}}},
{"lj/charmm/coul/long", {200.01117814948819, 220.77262190263258, 2637.0970037237003, {}}},
      // clang-format on
  };
  return ref;
}

// Compares a term with LAMMPS's row: evdwl and ecoul (the split of energy_and_virial: Sums::vdwl, the
// tail correction included as LAMMPS's evdwl includes it, and Sums::coulomb, which add up to the
// energy), the pair virial, the forces on atoms 1, 7, 23. Returns the largest relative difference of the energies and
// virial (see below), and of the forces (relative to the largest force component).
template <class K>
std::pair<double, double> compare(const ChargedChains& s, const PairTerm<K>& term, const std::string& name) {
  const Reference& ref = lammps_reference().at(name);
  Eigen::Matrix3Xd scratch(3, s.x.cols());
  const ForceTerm::Sums sums = term.energy_and_virial(s.x, s.box, scratch);
  const double evdwl = sums.vdwl;
  EXPECT_NEAR(sums.vdwl + sums.coulomb, sums.energy, 1e-14 * (std::abs(sums.vdwl) + std::abs(sums.coulomb))) << name;
  const auto rel = [](double a, double b) { return std::abs(a - b) / std::max(1e-300, std::abs(b)); };
  // The virial relative to the larger of |W| and |ecoul|: the coul/long virial is a sum of terms as large
  // as ecoul's that nearly cancel (0.9 against 221 kcal/mol here).
  double worst = std::max({ref.evdwl == 0 ? std::abs(evdwl) : rel(evdwl, ref.evdwl), rel(sums.coulomb, ref.ecoul),
                           std::abs(sums.virial - ref.virial) / std::max(std::abs(ref.virial), std::abs(ref.ecoul))});
  EXPECT_NEAR(term.virial(s.x, s.box), sums.virial, 1e-12 * std::abs(sums.virial)) << name;
  double worst_force = 0.0;
  if (!ref.forces.empty()) {
    const Eigen::Matrix3Xd f = test::forces_of(term, s.x, s.box);
    double scale = 0.0;
    for (const auto& row : ref.forces)
      for (double v : row) scale = std::max(scale, std::abs(v));
    const int ids[3] = {1, 7, 23};
    for (int k = 0; k < 3; ++k)
      for (int a = 0; a < 3; ++a)
        worst_force = std::max(worst_force, std::abs(f(a, ids[k] - 1) - ref.forces[k][a]) / scale);
  }
  return {worst, worst_force};
}

TEST(CoulombLammps, CutAndDebyeStylesMatchRunZero) {
  const ChargedChains s;
  const auto check = [](std::pair<double, double> d, const char* name) {
    EXPECT_LT(d.first, 1e-12) << name;
    EXPECT_LT(d.second, 1e-12) << name;
  };
  check(compare(s, *make_term<CoulombCut>(s, same<CoulombCut::Coeffs>({8.0})), "coul/cut"), "coul/cut");
  check(compare(s, *make_term<CoulombDebye>(s, same<CoulombDebye::Coeffs>({0.2, 8.0})), "coul/debye"), "coul/debye");
  check(compare(s, *make_term<LjCutCoulCut>(s, lj_types(0, false)), "lj/cut/coul/cut"), "lj/cut/coul/cut");
  auto tail = make_term<LjCutCoulCut>(s, lj_types(0, false));
  tail->set_tail(true);
  check(compare(s, *tail, "lj/cut/coul/cut tail"), "lj/cut/coul/cut tail");
  check(compare(s, *make_term<LjCutCoulDebye>(s, lj_types(0.2, true)), "lj/cut/coul/debye shift"),
        "lj/cut/coul/debye shift");
}

// The coul/long family to LAMMPS's polynomial erfc (pair_modify table 0; Abramowitz–Stegun 7.1.26,
// |error| ≤ 1.5e-7): stiffmd's real-space functions (the table, ~1e-14 of the exact form:
// forcefields/ewald_table.hpp) differ from it by that much per pair.
TEST(CoulombLammps, EwaldRealSpaceMatchesRunZeroToLammpsErfc) {
  const ChargedChains s;
  const auto d1 = compare(s, *make_term<CoulombLong>(s, same<CoulombLong::Coeffs>({8.0})), "coul/long");
  const auto d2 = compare(s, *make_term<LjCutCoulLong>(s, lj_types(0, false)), "lj/cut/coul/long");
  const auto d3 = compare(s, *make_term<LjCharmmCoulLong>(s, charmm_types()), "lj/charmm/coul/long");
  std::printf("coul/long family against LAMMPS: %.3g %.3g %.3g (largest relative difference)\n", d1.first, d2.first,
              d3.first);
  for (double d : {d1.first, d2.first, d3.first}) EXPECT_LT(d, 2e-6);
}

// A pair that special bonds exclude: never evaluated by a cut-off style; by coul/long its
// reciprocal-space interaction is subtracted, qq [erfc(g r) − 1]/r, within the cutoff only.
TEST(CoulombLong, ExcludedPairsGiveTheEwaldCorrectionWithinTheCutoff) {
  Box box = test::periodic_box({20, 20, 20}, {0, 0, 0});
  Eigen::Matrix3Xd x(3, 2);
  x << 1, 2.3, 1, 1, 1, 1;
  const std::vector<Bond> bond = {{0, 1, 0}};
  const double qq = 0.5 * -0.4 * kQqrd2eReal, r = 1.3;
  PairTerm<CoulombCut> cut("c", Level::slow, {0, 0}, one_type<CoulombCut::Coeffs>({8.0}), bond, {0, 1, 1}, box, 0.3,
                           Electrostatics{{0.5, -0.4}, kQqrd2eReal, {0, 1, 1}});
  EXPECT_EQ(test::energy_of(cut, x, box), 0.0);
  PairTerm<CoulombLong> lng("l", Level::slow, {0, 0}, one_type<CoulombLong::Coeffs>({8.0}), bond, {0, 1, 1}, box, 0.3,
                            Electrostatics{{0.5, -0.4}, kQqrd2eReal, {0, 1, 1}});
  EXPECT_THROW(test::energy_of(lng, x, box), std::invalid_argument);  // g never set
  lng.set_ewald_splitting(kG);
  EXPECT_EQ(lng.excluded_pairs(), 1u);
  EXPECT_EQ(lng.scaled_pairs().size(), 1u);
  EXPECT_NEAR(test::energy_of(lng, x, box), qq * (std::erfc(kG * r) - 1) / r, 1e-13 * std::abs(qq / r));
  EXPECT_LT(test::fd_error(lng, x, box), 1e-7);
  x(0, 1) = 1 + 8.5;  // beyond the cutoff: nothing
  EXPECT_EQ(test::energy_of(lng, x, box), 0.0);
}

// Every style on the chains: forces are −∇E (the scaled and excluded pairs included), they sum to
// zero, and the virial is −dE/dλ under dilation.
TEST(CoulombTerms, ForcesAreMinusGradientAndVirialIsDilationDerivative) {
  const ChargedChains s;
  const auto check = [&](const ForceTerm& t) {
    EXPECT_LT(test::fd_error(t, s.x, s.box, 1e-5), 1e-6) << t.style();
    const Eigen::Matrix3Xd f = test::forces_of(t, s.x, s.box);
    EXPECT_LT(f.rowwise().sum().norm(), 1e-10 * f.cwiseAbs().maxCoeff()) << t.style();
    const double w = t.virial(s.x, s.box);
    EXPECT_NEAR(test::dilation_virial(t, s.x, s.box, 1e-6), w, 1e-6 * std::max(1.0, std::abs(w))) << t.style();
  };
  check(*make_term<CoulombCut>(s, same<CoulombCut::Coeffs>({8.0})));
  check(*make_term<CoulombDebye>(s, same<CoulombDebye::Coeffs>({0.2, 8.0})));
  check(*make_term<CoulombLong>(s, same<CoulombLong::Coeffs>({8.0})));
  check(*make_term<LjCutCoulCut>(s, lj_types(0, false)));
  check(*make_term<LjCutCoulDebye>(s, lj_types(0.2, true)));
  check(*make_term<LjCutCoulLong>(s, lj_types(0, false)));
  check(*make_term<LjCharmmCoulLong>(s, charmm_types()));
  // With the weights 1 (no special pairs) and all 0.
  check(*make_term<LjCutCoulLong>(s, lj_types(0, false), {1, 1, 1}, {1, 1, 1}));
  check(*make_term<LjCutCoulLong>(s, lj_types(0, false), {0, 0, 0}, {0, 0, 0}));
}

// On a subset (a decomposed run's part) a charged term takes its particles' charges: the
// subset of every particle is the whole term, bit for bit; and it keeps g and the tail.
TEST(CoulombTerms, OnSubsetCarriesChargesSplittingAndTail) {
  const ChargedChains s;
  auto whole = make_term<LjCutCoulLong>(s, lj_types(0, false));
  whole->set_tail(true);
  std::vector<int> global(s.types.size());
  for (size_t i = 0; i < global.size(); ++i) global[i] = static_cast<int>(i);
  Topology topo;
  topo.bonds = s.bonds;
  const ParticleSubset subset{global, s.types, topo};
  const auto part = whole->on_subset(subset, s.box);
  EXPECT_EQ(test::forces_of(*part, s.x, s.box), test::forces_of(*whole, s.x, s.box));
  EXPECT_EQ(test::energy_of(*part, s.x, s.box), test::energy_of(*whole, s.x, s.box));
  EXPECT_EQ(dynamic_cast<const EwaldRealSpace&>(*part).ewald_splitting(), kG);
  EXPECT_EQ(dynamic_cast<const EwaldRealSpace&>(*part).coulomb_cutoff(), 8.0);
  EXPECT_THROW(whole->on_particles(s.types, s.bonds, s.box), std::invalid_argument);
  // move_to with the charges of another count is refused.
  auto moved = whole->on_particles({}, {}, s.box);
  auto* pairs = dynamic_cast<PairsOnParticles*>(moved.get());
  ASSERT_NE(pairs, nullptr);
  EXPECT_THROW(pairs->move_to(s.types, {}, std::span<const SpecialPair>(), {}), std::invalid_argument);
  pairs->move_to(s.types, s.charges, whole->special_pairs(), {});
  EXPECT_EQ(test::forces_of(*moved, s.x, s.box), test::forces_of(*whole, s.x, s.box));
}

TEST(CoulombTerms, RejectsBadInput) {
  const ChargedChains s;
  const auto bad = [&](auto make) { EXPECT_THROW(make(), std::invalid_argument); };
  bad([&] { return make_term<CoulombCut>(s, same<CoulombCut::Coeffs>({0.0})); });
  bad([&] {
    auto c = charmm();
    c.inner = 7.0;
    return make_term<LjCharmmCoulLong>(s, same(c));
  });
  bad([&] { return make_term<CoulombCut>(s, same<CoulombCut::Coeffs>({8.0}), kLj, {0, 1.5, 1}); });
  bad([&] {
    return std::make_unique<PairTerm<CoulombCut>>("q", Level::slow, s.types, same<CoulombCut::Coeffs>({8.0}), s.bonds,
                                                  kLj, s.box, 0.3, Electrostatics{{1.0}, kQqrd2eReal, kCoul});
  });
  bad([&] {  // the Ewald sum's one Coulomb cutoff
    auto m = lj_types(0, false);
    auto c = m(0, 1);
    c.coulomb_cutoff = 7.5;
    m.set(0, 1, c);
    return make_term<LjCutCoulLong>(s, m);
  });
  auto t = make_term<CoulombCut>(s, same<CoulombCut::Coeffs>({8.0}));
  EXPECT_THROW(t->set_tail(true), std::invalid_argument);  // no tail for a pure Coulomb style
}

}  // namespace
}  // namespace stiffmd
