// The force-style readers (engine/scene/force_registry.cpp): every style parameter's range is checked
// by the kind of quantity it is (forcefields/coefficients.hpp), and a bad value is reported at
// its deck key — its file:line, or the --set that supplied it.
#include <gtest/gtest.h>

#include <cmath>
#include <filesystem>
#include <fstream>
#include <numbers>
#include <string>
#include <vector>

#include <unistd.h>

#include "core/errors.hpp"
#include "engine/deck/deck.hpp"
#include "engine/scene/scene.hpp"
#include "tests/butane_decks.hpp"
#include "tests/test_support.hpp"

namespace stiffmd {
namespace {

namespace fs = std::filesystem;

// Two bonded beads 1.0 apart in a periodic box of 10, then the deck's [forces] text.
std::string deck_with(const std::string& forces) {
  return "[box]\nperiodic = true\nlengths = [10, 10, 10]\n[types.bead]\nmass = 1.0\n"
         "[[particles]]\ntype = \"bead\"\nposition = [1, 1, 1]\n"
         "[[particles]]\ntype = \"bead\"\nposition = [2, 1, 1]\n"
         "[[particles]]\ntype = \"bead\"\nposition = [2, 2, 1]\n"
         "[[bonds]]\nparticles = [0, 1]\ntype = \"b\"\n[[bonds]]\nparticles = [1, 2]\ntype = \"b\"\n" +
         forces + "[integrator]\nmethod = \"velocity-verlet\"\nh = 0.001\n[run]\nt_end = 0.001\n";
}

// Loads `text` (written to a scratch file) with `overrides`; returns the InputError's message,
// or "" when the deck loads.
std::string load_error(const std::string& text, const std::vector<std::string>& overrides = {}) {
  const fs::path p = fs::temp_directory_path() / ("stiffmd_registry_" + std::to_string(::getpid()) + ".toml");
  std::ofstream(p) << text;
  try {
    const Deck deck(p.string(), overrides);
    load_scene(deck);
  } catch (const InputError& e) {
    fs::remove(p);
    return e.what();
  }
  fs::remove(p);
  return "";
}

const std::string kFene = "[forces.chain]\nstyle = \"fene\"\nbond_types.b = { K = 30, R0 = 1.5 }\n";
const std::string kWca = "[forces.pair]\nstyle = \"wca\"\n";

TEST(ForceRegistry, GoodDeckLoads) {
  EXPECT_EQ(load_error(deck_with(kFene + kWca)), "");
}

// One bad value per kind of quantity, through the readers of several styles: the message names
// the deck key and the range of its kind.
TEST(ForceRegistry, RangeChecksNameTheKeyAndTheKind) {
  struct Case {
    std::string forces, key, expected;
  };
  const std::vector<Case> cases = {
      {"[forces.chain]\nstyle = \"fene\"\nbond_types.b = { K = 30, R0 = -1.5 }\n", "forces.chain.bond_types.b.R0",
       "expected a length > 0, got -1.5"},
      {"[forces.chain]\nstyle = \"fene\"\nbond_types.b = { K = -3, R0 = 1.5 }\n", "forces.chain.bond_types.b.K",
       "expected a stiffness >= 0, got -3"},
      {"[forces.chain]\nstyle = \"fene\"\nbond_types.b = { K = 3, R0 = 1.5, epsilon = -1 }\n",
       "forces.chain.bond_types.b.epsilon", "expected an energy >= 0, got -1"},
      {"[forces.s]\nstyle = \"stiff-harmonic\"\nepsilon = 0.01\nbond_types.b = { length = 1, alpha = 0 }\n",
       "forces.s.bond_types.b.alpha", "expected a number > 0, got 0"},
      {"[forces.s]\nstyle = \"stiff-harmonic\"\nepsilon = 0\nbond_types.b = { length = 1, alpha = 1 }\n",
       "forces.s.epsilon", "expected a number > 0, got 0"},
      {kFene + "[forces.p]\nstyle = \"lj\"\nsigma = 0\n", "forces.p.sigma", "expected a length > 0, got 0"},
      {kFene + "[forces.p]\nstyle = \"lj\"\n[[forces.p.pair]]\ntypes = [\"bead\", \"bead\"]\ncutoff = -2\n",
       "forces.p.pair[0].cutoff", "expected a length > 0, got -2"},
      {kFene + "[forces.p]\nstyle = \"soft\"\nA = -1\n", "forces.p.A", "expected an energy >= 0, got -1"},
      {kFene + "[forces.p]\nstyle = \"wca\"\nskin = -0.1\n", "forces.p.skin", "expected a length >= 0, got -0.1"},
      {kFene + "[forces.t]\nstyle = \"harmonic-tether\"\nk = -1\ncenter = [0, 0, 0]\n", "forces.t.k",
       "expected a stiffness >= 0, got -1"},
  };
  for (const Case& c : cases) {
    const std::string err = load_error(deck_with(c.forces));
    EXPECT_NE(err.find(".toml:"), std::string::npos) << err;  // file:line
    EXPECT_NE(err.find(": " + c.key + ": " + c.expected), std::string::npos) << err;
  }
}

TEST(ForceRegistry, AngleStiffnessIsCheckedAtItsKey) {
  const std::string text =
      "[types.bead]\nmass = 1.0\n[[build]]\nstyle = \"linear-chains\"\nchains = 1\nbeads = 4\n"
      "bond_length = 1.0\nbond_type = \"b\"\nangle_type = \"a\"\nseed = 1\n" +
      kFene + "[forces.bend]\nstyle = \"harmonic-angle\"\nangle_types.a = { k = -2 }\n" +
      "[integrator]\nmethod = \"velocity-verlet\"\nh = 0.001\n[run]\nt_end = 0.001\n";
  const std::string err = load_error(text);
  EXPECT_NE(err.find("forces.bend.angle_types.a.k: expected a stiffness >= 0, got -2"), std::string::npos) << err;
}

// Dihedral styles: a builder's dihedral type is claimed by dihedral_types.TYPE, read by kind at its
// key; an unclaimed dihedral type and LAMMPS's forbidden d are refused where they are.
TEST(ForceRegistry, DihedralCoefficientsAreCheckedAtTheirKeys) {
  const std::string head =
      "[types.bead]\nmass = 1.0\n[[build]]\nstyle = \"linear-chains\"\nchains = 1\nbeads = 5\n"
      "bond_length = 1.0\nbond_type = \"b\"\ndihedral_type = \"t\"\nseed = 1\n" +
      kFene;
  const std::string tail = "[integrator]\nmethod = \"velocity-verlet\"\nh = 0.001\n[run]\nt_end = 0.001\n";
  struct Case {
    std::string forces, expected;
  };
  const std::vector<Case> cases = {
      {"[forces.tor]\nstyle = \"harmonic-dihedral\"\ndihedral_types.t = { K = 1, d = 2, n = 3 }\n",
       "forces.tor.dihedral_types.t.d: expected +1 or -1"},
      {"[forces.tor]\nstyle = \"harmonic-dihedral\"\ndihedral_types.t = { K = 1, d = 1, n = -3 }\n",
       "forces.tor.dihedral_types.t.n: expected a multiplicity 0 .. 12"},
      {"[forces.tor]\nstyle = \"opls-dihedral\"\ndihedral_types.t = { K1 = 1, K5 = 3 }\n", "K5"},
      {"[forces.tor]\nstyle = \"multi-harmonic-dihedral\"\ndihedral_types.t = { A1 = inf }\n",
       "forces.tor.dihedral_types.t.A1: expected a finite"},
      {"", "dihedral type 't' is not defined by any force term (add [forces.NAME.dihedral_types.t])"},
  };
  for (const Case& c : cases) {
    const std::string err = load_error(head + c.forces + tail);
    EXPECT_NE(err.find(c.expected), std::string::npos) << err;
  }
  // Negative torsion amplitudes are LAMMPS's too, and the five-bead chain has two dihedrals.
  const fs::path p = fs::temp_directory_path() / ("stiffmd_dihedrals_" + std::to_string(::getpid()) + ".toml");
  std::ofstream(p) << head + "[forces.tor]\nstyle = \"opls-dihedral\"\ndihedral_types.t = { K1 = -1.5, K3 = 2 }\n" +
                          tail;
  const Scene sc = load_scene(Deck(p.string(), {}));
  fs::remove(p);
  EXPECT_EQ(sc.topology.dihedrals.size(), 2u);
  EXPECT_EQ(sc.topology.dihedrals[1].i, 1);
  EXPECT_EQ(sc.topology.dihedrals[1].l, 4);
}

// Mixing rules: per-type LJ coefficients mixed as LAMMPS's pair_modify mix does it, checked on one
// A–B pair at r = 1.2 against the formula with hand-mixed coefficients.
std::string two_types(const std::string& lj) {
  return "[box]\nperiodic = true\nlengths = [10, 10, 10]\n[types.A]\nmass = 1.0\n[types.B]\nmass = 2.0\n"
         "[[particles]]\ntype = \"A\"\nposition = [1, 1, 1]\n[[particles]]\ntype = \"B\"\nposition = [2.2, 1, 1]\n"
         "[forces.lj]\nstyle = \"lj\"\n" +
         lj + "[integrator]\nmethod = \"velocity-verlet\"\nh = 0.001\n[run]\nt_end = 0.001\n";
}
double lj_energy(const std::string& text) {
  const fs::path p = fs::temp_directory_path() / ("stiffmd_mix_" + std::to_string(::getpid()) + ".toml");
  std::ofstream(p) << text;
  const Scene sc = load_scene(Deck(p.string(), {}));
  fs::remove(p);
  Eigen::Matrix3Xd f = Eigen::Matrix3Xd::Zero(3, 2);
  return sc.forces->terms().at(0)->add_forces(sc.state.x, sc.box, f);
}
double lj_cut_shifted(double eps, double sigma, double rc, double r) {
  auto e = [&](double x) { return 4 * eps * (std::pow(sigma / x, 12) - std::pow(sigma / x, 6)); };
  return r < rc ? e(r) - e(rc) : 0.0;
}

TEST(ForceRegistry, MixingRulesFillTheTypePairsAsLammps) {
  const std::string per_type =
      "types.A = { epsilon = 1.2, sigma = 1.05, cutoff = 2.5 }\ntypes.B = { epsilon = 0.9, sigma = 0.95, cutoff = 3.0 "
      "}\n";
  const double eps = std::sqrt(1.2 * 0.9);
  // geometric (LAMMPS's default): σ and the cutoff are geometric means too.
  EXPECT_NEAR(lj_energy(two_types(per_type)), lj_cut_shifted(eps, std::sqrt(1.05 * 0.95), std::sqrt(2.5 * 3.0), 1.2),
              1e-14);
  EXPECT_NEAR(lj_energy(two_types("mix = \"geometric\"\n" + per_type)),
              lj_cut_shifted(eps, std::sqrt(1.05 * 0.95), std::sqrt(7.5), 1.2), 1e-14);
  // arithmetic (Lorentz–Berthelot): arithmetic means of σ and of the cutoffs, ε still geometric.
  EXPECT_NEAR(lj_energy(two_types("mix = \"arithmetic\"\n" + per_type)), lj_cut_shifted(eps, 1.0, 2.75, 1.2), 1e-14);
  // An explicit pair overrides the mixed value, key by key: σ given, ε and the cutoff stay mixed.
  EXPECT_NEAR(lj_energy(two_types("mix = \"arithmetic\"\n" + per_type +
                                  "[[forces.lj.pair]]\ntypes = [\"A\", \"B\"]\nsigma = 1.1\n")),
              lj_cut_shifted(eps, 1.1, 2.75, 1.2), 1e-14);
  // A per-type table without a cutoff takes the term's.
  EXPECT_NEAR(lj_energy(two_types("cutoff = 2.0\ntypes.A = { epsilon = 1.2, sigma = 1.05 }\n"
                                  "types.B = { epsilon = 0.9, sigma = 0.95 }\n")),
              lj_cut_shifted(eps, std::sqrt(1.05 * 0.95), 2.0, 1.2), 1e-14);
  // Refusals, at their keys.
  struct Case {
    std::string lj, expected;
  };
  for (const Case& c : std::vector<Case>{
           {"mix = \"sixthpower\"\n" + per_type, "forces.lj.mix: expected \"geometric\" or \"arithmetic\""},
           {"mix = \"geometric\"\n", "forces.lj.mix: a mixing rule needs per-type coefficients forces.lj.types.NAME"},
           {"types.A = { epsilon = 1.2, sigma = 1.05 }\n", "forces.lj.types: no coefficients for particle type 'B'"},
           {per_type + "types.C = { epsilon = 1 }\n", "forces.lj.types.C: unknown particle type 'C'"},
           {"types.A = { epsilon = 1.2, sigma = -1 }\ntypes.B = { epsilon = 1 }\n",
            "forces.lj.types.A.sigma: expected a length > 0, got -1"},
       }) {
    const std::string err = load_error(two_types(c.lj));
    EXPECT_NE(err.find(c.expected), std::string::npos) << err;
  }
}

// A value from the command line is reported as the --set that gave it, not as the file's line.
TEST(ForceRegistry, ValuesFromSetAreReportedAsTheSet) {
  const std::string err = load_error(deck_with(kFene), {"forces.chain.bond_types.b.R0=-2"});
  EXPECT_EQ(err.rfind("--set forces.chain.bond_types.b.R0: forces.chain.bond_types.b.R0: expected a length > 0", 0), 0u)
      << err;
  const std::string skin = load_error(deck_with(kFene + kWca), {"forces.pair.skin=-1"});
  EXPECT_EQ(skin.rfind("--set forces.pair.skin: forces.pair.skin: expected a length >= 0, got -1", 0), 0u) << skin;
}

// A bond outside its kernel's domain at the start (FENE beyond R0) is the deck's fault: an
// InputError at bond_types naming the bond, not a numerical failure at step 1.
TEST(ForceRegistry, BondOutsideTheKernelsDomainAtTheStart) {
  const std::string err = load_error(deck_with(kFene), {"forces.chain.bond_types.b.R0=0.9"});
  EXPECT_NE(err.find("forces.chain.bond_types: fene 'chain': bond between particles 0 and 1: stretched to r = 1"),
            std::string::npos)
      << err;
  EXPECT_NE(err.find("in the initial state"), std::string::npos) << err;
}

// stiff-harmonic's angle_types: each angle of the type gets a third stiff bond between its ends,
// of the law-of-cosines length, as LAMMPS's fix shake `a` (rigid water: a triangle); an arm that
// is not a stiff bond of the term is refused at the angle type.
std::string waters(const std::string& stiff) {
  return "[types.O]\nmass = 15.9994\n[types.H]\nmass = 1.008\n"
         "[import]\nlammps_data = \"" +
         test::source_path("tests/data/two_waters.data") +
         "\"\natom_types = { \"1\" = \"O\", \"2\" = \"H\" }\nbond_types = { \"1\" = \"OH\" }\n"
         "angle_types = { \"1\" = \"HOH\" }\n"
         "[forces.bend]\nstyle = \"harmonic-angle\"\nangle_types.HOH = { k = 100, theta0 = 109.47 }\n"
         "[forces.rigid]\nstyle = \"stiff-harmonic\"\nepsilon = 0.01\n" +
         stiff + "[integrator]\nmethod = \"rattle\"\nh = 0.001\n[run]\nt_end = 0.001\n";
}

TEST(ForceRegistry, RigidAnglesCloseTheTriangle) {
  const fs::path p = fs::temp_directory_path() / ("stiffmd_waters_" + std::to_string(::getpid()) + ".toml");
  std::ofstream(p) << waters(
      "bond_types.OH = { length = 1.0, alpha = 1 }\nangle_types.HOH = { theta0 = 109.47, alpha = 1 }\n");
  const Scene sc = load_scene(Deck(p.string(), {}));
  fs::remove(p);
  const StiffBonds* sb = sc.forces->stiff_bonds();
  ASSERT_NE(sb, nullptr);
  ASSERT_EQ(sb->bonds.size(), 6u);  // four O–H bonds, then one H–H per water
  const double hh = 2.0 * std::sin(109.47 / 2 * std::numbers::pi / 180.0);
  for (int w = 0; w < 2; ++w) {
    const StiffBond& b = sb->bonds[4 + w];
    EXPECT_EQ(std::min(b.i, b.j), 3 * w + 1);
    EXPECT_EQ(std::max(b.i, b.j), 3 * w + 2);
    EXPECT_NEAR(b.length, hh, 1e-14);
  }
  const std::string err =
      load_error(waters("bond_types.OH = { length = 1.0, alpha = 1 }\n"
                        "angle_types.HOH = { theta0 = 180, alpha = 1 }\n"));
  EXPECT_NE(err.find("forces.rigid.angle_types.HOH.theta0: expected the rigid angle in degrees"), std::string::npos)
      << err;
}

// stiff-harmonic's masses (LAMMPS's fix shake … m): on tests/data/butanes.data (CH3 15, CH2 14;
// Bond Coeffs 1: K 200, r0 1.0 — the CH3–CH2 bonds; 2: K 150, r0 1.05 — CH2–CH2), masses = [15]
// makes the six end bonds rigid with the file's r0 and α = ε√(2K), and a harmonic-bond term with
// coefficients = "data" takes the middle bonds: the two terms' energy is the bonds' LAMMPS energy,
// 4.6419945562564111 (tools/lammps_butane_reference.py, as ImportedButanes.SameEnergiesAsLammps).
// masses = [14] selects every bond (each has a CH2 end); a bond_types entry takes precedence over
// the data file for its type.
Scene butanes_by_mass(const std::string& stiff, const std::string& more) {
  const std::string deck =
      test::butanes_import() + "[forces.rigid]\nstyle = \"stiff-harmonic\"\nepsilon = 0.05\n" + stiff + more +
      "[forces.angle]\nstyle = \"harmonic-angle\"\ncoefficients = \"data\"\n"
      "[forces.dihedral]\nstyle = \"opls-dihedral\"\ndihedral_types.butane = { K1 = 1.41, K2 = -0.27, K3 = 3.14, K4 = "
      "0.1 }\n[integrator]\nmethod = \"rattle\"\nh = 0.001\n[run]\nt_end = 0.001\n";
  const fs::path p = fs::temp_directory_path() / ("stiffmd_butanes_" + std::to_string(::getpid()) + ".toml");
  std::ofstream(p) << deck;
  Scene sc = load_scene(Deck(p.string(), {}));
  fs::remove(p);
  return sc;
}

double bond_energy(const Scene& sc) {
  double e = 0.0;
  for (const auto& t : sc.forces->terms())
    if (t->name() == "rigid" || t->name() == "flex") {
      Eigen::Matrix3Xd f = Eigen::Matrix3Xd::Zero(3, sc.state.size());
      e += t->add_forces(sc.state.x, sc.box, f);
    }
  return e;
}

TEST(ForceRegistry, StiffBondsSelectedByMassAsLammpsShake) {
  const std::string flex = "[forces.flex]\nstyle = \"harmonic-bond\"\ncoefficients = \"data\"\n";
  const Scene ends = butanes_by_mass("masses = [15.0]\n", flex);
  const StiffBonds& sb = *ends.forces->stiff_bonds();
  std::vector<std::pair<int, int>> end_bonds, rigid;
  for (const Bond& b : ends.topology.bonds)
    if (ends.topology.bond_types[b.type] == "end") end_bonds.emplace_back(b.i, b.j);
  for (const StiffBond& b : sb.bonds) {
    rigid.emplace_back(b.i, b.j);
    EXPECT_EQ(b.length, 1.0);
    EXPECT_NEAR(b.alpha, 0.05 * std::sqrt(400.0), 1e-15);
  }
  EXPECT_EQ(rigid, end_bonds);
  ASSERT_EQ(rigid.size(), 6u);
  EXPECT_NEAR(bond_energy(ends), 4.6419945562564111, 1e-12);
  // Within LAMMPS's 0.1 of a listed mass: 15.05 selects the CH3 ends, not the CH2 (14).
  EXPECT_EQ(butanes_by_mass("masses = [15.05]\n", flex).forces->stiff_bonds()->bonds.size(), 6u);
  const Scene all = butanes_by_mass("masses = [14.0]\n", "");
  EXPECT_EQ(all.forces->stiff_bonds()->bonds.size(), 9u);
  EXPECT_NEAR(bond_energy(all), 4.6419945562564111, 1e-12);
  const Scene named = butanes_by_mass("masses = [14.0]\nbond_types.mid = { length = 1.5, alpha = 2.0 }\n", "");
  const std::vector<StiffBond>& mixed = named.forces->stiff_bonds()->bonds;
  ASSERT_EQ(mixed.size(), 9u);
  for (size_t k = 0; k < mixed.size(); ++k)
    EXPECT_EQ(mixed[k].length, named.topology.bond_types[named.topology.bonds[k].type] == "mid" ? 1.5 : 1.0) << k;
}

}  // namespace
}  // namespace stiffmd
