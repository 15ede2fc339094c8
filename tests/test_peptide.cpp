// Charged decks against LAMMPS's `run 0` of the same styles on the same data file, with an Ewald sum
// at 1e-8: every energy term, the forces and the pressure.
//   - LAMMPS's peptide example (a CHARMM22 5-mer in water, 2004 atoms, atom_style full): harmonic
//     bonds, charmm angles (Urey–Bradley) and dihedrals (weighted 1-4 pairs), harmonic impropers,
//     lj/charmm/coul/long (tests/data/peptide_lammps/, made by tools/peptide_deck.py --reference);
//   - a salt-free polyelectrolyte of our own (8 chains, every second bead charged, counterions; lj
//     units): harmonic bonds, WCA + Coulomb as lj/cut/coul/long with Coulomb between bonded
//     neighbours (tests/data/polyelectrolyte_lammps/, made by tools/polyelectrolyte.py --reference);
// and on the peptide the thermo's evdwl, and the example's SHAKE set chosen by mass as by bond type.
#include <gtest/gtest.h>

#include <cmath>
#include <fstream>
#include <map>
#include <set>
#include <sstream>
#include <string>
#include <vector>

#include "core/units.hpp"
#include "engine/deck/deck.hpp"
#include "engine/observe/observables.hpp"
#include "engine/scene/scene.hpp"
#include "forcefields/charmm_terms.hpp"
#include "forcefields/ewald_real_space.hpp"
#include "tests/test_support.hpp"

namespace stiffmd {
namespace {

std::map<std::string, double> lammps_energies(const std::string& dir) {
  std::ifstream in(test::source_path(dir + "/energies.txt"));
  std::map<std::string, double> out;
  for (std::string line; std::getline(in, line);) {
    if (line.empty() || line[0] == '#') continue;
    std::istringstream s(line);
    std::string name;
    double v = 0.0;
    s >> name >> v;
    out[name] = v;
  }
  return out;
}

Eigen::Matrix3Xd lammps_forces(const std::string& dir, int n) {
  std::ifstream in(test::source_path(dir + "/forces.txt"));
  Eigen::Matrix3Xd f = Eigen::Matrix3Xd::Constant(3, n, std::nan(""));
  for (std::string line; std::getline(in, line);) {
    if (line.empty() || line[0] == '#') continue;
    std::istringstream s(line);
    int id = 0;
    s >> id;
    s >> f(0, id - 1) >> f(1, id - 1) >> f(2, id - 1);
  }
  return f;
}

// The deck's run-0 state against LAMMPS's reference in `dir`: the energy terms `names` (LAMMPS's
// thermo names) each to 1e-6 relative, every force component within 1e-6 of the RMS force, the
// pressure ((2 KE + W)/3V in the deck's units, × `pressure_unit`) to 1e-6 relative.
// Returns stiffmd's energy terms by LAMMPS's names.
std::map<std::string, double> expect_lammps_run_zero(const std::string& deck, const std::string& dir,
                                                     std::vector<std::string> names, double pressure_unit) {
  const Scene sc = test::load(deck);
  const int n = sc.state.size();
  const Eigen::Matrix3Xd& x = sc.state.x;
  std::map<std::string, double> e;
  Eigen::Matrix3Xd total = Eigen::Matrix3Xd::Zero(3, n);
  double virial = 0.0;  // the atomic virial Σ r_ij·f_ij, LAMMPS's pressure's
  for (const auto& term : sc.forces->terms()) {
    Eigen::Matrix3Xd f = Eigen::Matrix3Xd::Zero(3, n), scratch = Eigen::Matrix3Xd::Zero(3, n);
    term->add_forces(x, sc.box, f);
    const ForceTerm::Sums s = term->energy_and_virial(x, sc.box, scratch);
    total += f;
    const std::string style(term->style());
    if (term->uses_neighbor_list() && term->uses_charges()) {
      e["E_vdwl"] += s.energy - s.coulomb, e["E_coul"] += s.coulomb, virial += s.virial;
    } else if (style == "ewald") {
      e["E_long"] += s.energy, virial += s.virial;
    } else {
      // Bonded: within whole molecules, so Σ x_i·f_i is the sum of r_ij·f_ij over its interactions.
      virial += (x.array() * f.array()).sum();
      if (style == "harmonic-bond") e["E_bond"] += s.energy;
      if (style == "charmm-angle") e["E_angle"] += s.energy;
      if (style == "harmonic-improper") e["E_impro"] += s.energy;
      if (style == "charmm-dihedral") {
        const auto parts = dynamic_cast<const CharmmDihedral&>(*term).energy_parts(x, sc.box);
        e["E_dihed"] += parts.torsion, e["E_vdwl"] += parts.lj14, e["E_coul"] += parts.coul14;
        EXPECT_NEAR(parts.torsion + parts.lj14 + parts.coul14, s.energy, 1e-10 * std::abs(s.energy));
        EXPECT_NEAR(s.coulomb, parts.coul14, 1e-12 * std::abs(parts.coul14));  // the thermo's ecoul share
      }
    }
  }
  const auto ref = lammps_energies(dir);
  // Each term to 1e-6 relative: the real-space Coulomb differs by LAMMPS's polynomial erfc (~1e-7,
  // docs/electrostatics.md), the rest by round-off.
  for (const std::string& name : names) {
    EXPECT_TRUE(ref.count(name)) << name;
    if (!ref.count(name)) continue;
    EXPECT_NEAR(e[name], ref.at(name), 1e-6 * std::abs(ref.at(name))) << name;
    std::printf("%-8s stiffmd %.12g  LAMMPS %.12g  relative %.2e\n", name.c_str(), e[name], ref.at(name),
                std::abs(e[name] - ref.at(name)) / std::abs(ref.at(name)));
  }
  // Forces: each component within 1e-6 of the RMS force.
  const Eigen::Matrix3Xd f_ref = lammps_forces(dir, n);
  EXPECT_FALSE(f_ref.hasNaN()) << "a particle without a LAMMPS force in " << dir;
  const double rms = std::sqrt(f_ref.squaredNorm() / n);
  const double worst = (total - f_ref).cwiseAbs().maxCoeff();
  std::printf("forces: max |Δf| = %.3g, RMS |f| = %.6g (ratio %.2e)\n", worst, rms, worst / rms);
  EXPECT_LT(worst, 1e-6 * rms);
  // Pressure: (2 KE + W) / 3V, with the data file's velocities.
  double ke = 0.0;
  for (int i = 0; i < n; ++i) ke += 0.5 * sc.state.v.col(i).squaredNorm() / sc.state.inv_mass[i];
  EXPECT_NEAR(ke, ref.at("KinEng"), 1e-9 * ref.at("KinEng"));
  const double volume = sc.box.lengths.prod();
  const double pressure = (2.0 * ke + virial) / (3.0 * volume) * pressure_unit;
  std::printf("pressure: stiffmd %.10g, LAMMPS %.10g\n", pressure, ref.at("Press"));
  EXPECT_NEAR(pressure, ref.at("Press"), 1e-6 * std::abs(ref.at("Press")));
  return e;
}

TEST(PeptideLammps, EveryEnergyTermTheForcesAndThePressureAsLammps) {
  expect_lammps_run_zero("tests/decks/peptide_run0.toml", "tests/data/peptide_lammps",
                         {"E_bond", "E_angle", "E_dihed", "E_impro", "E_vdwl", "E_coul", "E_long"},
                         Units::kRealPressure);
}

// The polyelectrolyte's real-space Coulomb energy is a sum of terms of both signs (2.3 from pairs
// of size ~1 each): LAMMPS's polynomial erfc (pair_modify table 0: Abramowitz–Stegun 7.1.26,
// |error| ≤ 1.5e-7) moves it by up to 1.5e-7 Σ|qq|/r, which is more than 1e-6 of the sum. It is
// checked by what it is: the same pairs summed here with LAMMPS's erfc equal LAMMPS's E_coul to
// 1e-10, and stiffmd's (its table, ~1e-14 of the exact form) is within that bound of it.
TEST(PolyelectrolyteLammps, EveryEnergyTermTheForcesAndThePressureAsLammps) {
  const std::string deck = "tests/decks/polyelectrolyte_run0.toml", dir = "tests/data/polyelectrolyte_lammps";
  const auto e = expect_lammps_run_zero(deck, dir, {"E_bond", "E_vdwl", "E_long"}, 1.0);
  const double lammps = lammps_energies(dir).at("E_coul");
  const Scene sc = test::load(deck);
  const EwaldRealSpace* pair = nullptr;
  for (const auto& term : sc.forces->terms())
    if (auto* p = dynamic_cast<const EwaldRealSpace*>(term.get())) pair = p;
  ASSERT_NE(pair, nullptr);
  const double g = pair->ewald_splitting(), rc = pair->coulomb_cutoff();
  const auto lammps_erfc = [](double x) {  // LAMMPS pair_lj_cut_coul_long.cpp, its EWALD_P and A1..A5
    const double t = 1.0 / (1.0 + 0.3275911 * x);
    return t * (0.254829592 + t * (-0.284496736 + t * (1.421413741 + t * (-1.453152027 + t * 1.061405429)))) *
           std::exp(-x * x);
  };
  double with_lammps_erfc = 0.0, bound = 0.0;  // special_coul is 1 for every pair: no exclusions
  const Eigen::Matrix3Xd& x = sc.state.x;
  for (int i = 0; i < sc.state.size(); ++i)
    for (int j = i + 1; j < sc.state.size(); ++j) {
      Eigen::Vector3d d = x.col(i) - x.col(j);
      for (int a = 0; a < 3; ++a) d[a] -= sc.box.lengths[a] * std::round(d[a] / sc.box.lengths[a]);
      const double r = d.norm(), qq = sc.charge[i] * sc.charge[j];
      if (r >= rc || qq == 0.0) continue;
      with_lammps_erfc += qq * lammps_erfc(g * r) / r;
      bound += 1.5e-7 * std::abs(qq) / r;
    }
  std::printf("E_coul: stiffmd %.12g, with LAMMPS's erfc %.12g, LAMMPS %.12g; bound %.3g\n", e.at("E_coul"),
              with_lammps_erfc, lammps, bound);
  EXPECT_NEAR(with_lammps_erfc, lammps, 1e-10 * std::abs(lammps));
  EXPECT_NEAR(e.at("E_coul"), lammps, bound);
}

// The thermo row's evdwl, ecoul and elong on the same run 0: evdwl (the lj/charmm pairs and the
// charmm dihedrals' 1-4 Lennard-Jones) is LAMMPS's E_vdwl, and with ecoul, elong and the bonded
// terms' own energies (bonds, charmm angles, the torsions without their 1-4 pairs, impropers) it
// is the potential energy to round-off.
TEST(PeptideLammps, ThermoEvdwlIsLammpsAndTheColumnsAddUpToThePotential) {
  const Scene sc = test::load("tests/decks/peptide_run0.toml");
  Thermo thermo(*sc.forces, sc.state.inv_mass, ObservableSettings{}, &sc.topology);
  const std::vector<double> row = thermo.sample(sc.state);
  const auto column = [&](const char* name) {
    const int k = thermo.column(name);
    EXPECT_GE(k, 0) << name;
    return k < 0 ? std::nan("") : row[static_cast<size_t>(k)];
  };
  const double evdwl = column("evdwl"), ecoul = column("ecoul"), elong = column("elong");
  EXPECT_EQ(thermo.column("evdwl") + 1, thermo.column("ecoul"));  // LAMMPS's order: evdwl ecoul elong
  const auto ref = lammps_energies("tests/data/peptide_lammps");
  std::printf("evdwl: stiffmd %.15g  LAMMPS %.15g  relative %.2e\n", evdwl, ref.at("E_vdwl"),
              std::abs(evdwl - ref.at("E_vdwl")) / ref.at("E_vdwl"));
  EXPECT_NEAR(evdwl, ref.at("E_vdwl"), 1e-9 * ref.at("E_vdwl"));
  double bonded = 0.0;
  for (const auto& term : sc.forces->terms()) {
    const std::string style(term->style());
    Eigen::Matrix3Xd f = Eigen::Matrix3Xd::Zero(3, sc.state.size());
    if (style == "charmm-dihedral")
      bonded += dynamic_cast<const CharmmDihedral&>(*term).energy_parts(sc.state.x, sc.box).torsion;
    else if (style == "harmonic-bond" || style == "charmm-angle" || style == "harmonic-improper")
      bonded += term->add_forces(sc.state.x, sc.box, f);
  }
  const double potential = column("potential_slow") + column("potential_stiff");
  EXPECT_NEAR(evdwl + ecoul + elong + bonded, potential, 1e-12 * (std::abs(ecoul) + std::abs(elong)));
}

// LAMMPS's fix shake … m 1.008 on the peptide: every bond with a hydrogen, the CHARMM ones (1.008)
// and the water's (1.01, within LAMMPS's 0.1), is in.peptide's `b 4 6 8 10 12 14 18` and no other.
// The deck with the bond_types entries replaced by masses = [1.008] makes the same bonds rigid, in
// the same order, with the same lengths (the data file's r0, as the entries were written from it)
// and stiffnesses (α = ε√(2K) from the Bond Coeffs row; the entries are that to 12 digits), and
// the water angle's third bond from the mass-selected arms.
TEST(PeptideShake, BondsToHydrogenByMassAreTheExamplesBondTypes) {
  std::ifstream in(test::source_path("inputs/peptide.toml"));
  std::string by_mass, line;
  int named = 0;
  while (std::getline(in, line)) {
    if (line.rfind("bond_types.\"", 0) == 0) {
      if (named++ == 0) by_mass += "masses = [1.008]\n";
      continue;
    }
    if (line.rfind("lammps_data = ", 0) == 0)
      line = "lammps_data = \"" + test::source_path("inputs/peptide_solvated.data") + "\"";
    by_mass += line + "\n";
  }
  ASSERT_EQ(named, 7);
  const Scene a = load_scene(Deck(test::source_path("inputs/peptide.toml"), {}));
  const Scene b = load_scene(Deck(Deck::Text{"peptide_by_mass.toml", by_mass}, {}));
  const StiffBonds& by_type = *a.forces->stiff_bonds();
  const StiffBonds& chosen = *b.forces->stiff_bonds();
  // 1320 bonds to hydrogen (1280 of them the waters' O–H) and one H–H per water (640).
  ASSERT_EQ(by_type.bonds.size(), 1320u + 640u);
  ASSERT_EQ(chosen.bonds.size(), by_type.bonds.size());
  EXPECT_EQ(chosen.epsilon, by_type.epsilon);
  for (size_t k = 0; k < by_type.bonds.size(); ++k) {
    const StiffBond &x = by_type.bonds[k], &y = chosen.bonds[k];
    ASSERT_EQ(x.i, y.i) << k;
    ASSERT_EQ(x.j, y.j) << k;
    EXPECT_EQ(x.length, y.length) << k;
    EXPECT_NEAR(x.alpha, y.alpha, 1e-11 * x.alpha) << k;
  }
  // Every bond with a particle of mass near 1.008 is rigid, and every rigid bond of the file has one.
  std::set<std::pair<int, int>> rigid;
  for (const StiffBond& s : chosen.bonds) rigid.insert({std::min(s.i, s.j), std::max(s.i, s.j)});
  const auto hydrogen = [&](int i) { return std::abs(1.0 / b.state.inv_mass[i] - 1.008) <= 0.1; };
  int with_h = 0;
  for (const Bond& bond : b.topology.bonds) {
    const bool h = hydrogen(bond.i) || hydrogen(bond.j);
    with_h += h;
    EXPECT_EQ(rigid.count({std::min(bond.i, bond.j), std::max(bond.i, bond.j)}), h ? 1u : 0u);
  }
  EXPECT_EQ(with_h, 1320);
}

}  // namespace
}  // namespace stiffmd
