// Polymer scenes end to end: every integrator runs a melt, the bundled
// decks are valid, the imported LAMMPS benchmark has the right size, the pressure of a dilute
// gas is N k T / V, and the validity monitor speaks up on a long chain.
#include <gtest/gtest.h>

#include <filesystem>
#include <fstream>
#include <map>
#include <sstream>

#include "cli_support.hpp"
#include "engine/observe/observables.hpp"
#include "engine/observe/polymer_observables.hpp"
#include "engine/run/checkpoint.hpp"
#include "engine/run/run.hpp"
#include "integrators/modes.hpp"
#include "butane_decks.hpp"
#include "test_support.hpp"

namespace stiffmd {
namespace {

namespace fs = std::filesystem;
using test::cli;

class EveryMethodOnAMelt : public ::testing::TestWithParam<std::string> {};

TEST_P(EveryMethodOnAMelt, RunsWithoutConstraintSolverFailure) {
  const std::string method = GetParam();
  const std::string h = method == "velocity-verlet" ? "2e-4" : "0.005";
  // A method that needs a temperature (fixman) runs with a weak Langevin thermostat (damp 1e3),
  // so that the energy still stays within the bound below over these 10 steps.
  std::vector<std::string> o = {"integrator.method=" + method, "integrator.h=" + h};
  if (find_method(method)->needs_temperature)
    o.insert(o.end(), {"thermostat.style=\"langevin\"", "thermostat.temperature=1.0", "thermostat.damp=1000.0",
                       "thermostat.seed=1"});
  Scene sc = test::load("tests/decks/small_melt.toml", o);
  const fs::path d = test::scratch_dir("melt_" + method);
  std::ostringstream log;
  const RunSummary s = run_simulation(sc, {d.string(), false, ""}, log);
  EXPECT_EQ(s.steps, method == "velocity-verlet" ? 250 : 10);
  EXPECT_LT(s.max_energy_error, 0.01 * std::abs(s.initial_energy)) << log.str();
  EXPECT_TRUE(fs::exists(d / "histograms.csv"));
  fs::remove_all(d);
}

INSTANTIATE_TEST_SUITE_P(SmallMelt, EveryMethodOnAMelt, ::testing::ValuesIn(test::kAllMethods), test::method_test_name);

TEST(PolymerDecks, EveryBundledDeckIsValid) {
  int n = 0;
  for (const auto& e : fs::directory_iterator(test::source_path("inputs"))) {
    if (e.path().extension() != ".toml") continue;
    const auto r = cli("check " + e.path().string());
    EXPECT_EQ(r.code, 0) << e.path() << "\n" << r.err;
    ++n;
  }
  EXPECT_GE(n, 5);
}

// inputs/trimer_fluid.toml (300 of its trimers): on its prepared state the closed-form 2 × 2 modes
// give the dense path's W and −∇W to round-off, and the effective dynamics runs its 100 steps
// conserving K + U + W.
TEST(PolymerDecks, TheTrimerFluidTakesTheEffectiveDynamicsInClosedForm) {
  Scene sc = test::load("inputs/trimer_fluid.toml", {"build.0.chains=300"});
  const StiffBonds& stiff = *sc.forces->stiff_bonds();
  ASSERT_EQ(stiff.bonds.size(), 600u);
  StiffModes fast(stiff.bonds, sc.state.inv_mass, stiff.epsilon, 2, StiffModes::Solver::fast);
  StiffModes dense(stiff.bonds, sc.state.inv_mass, stiff.epsilon, 2, StiffModes::Solver::dense);
  Eigen::VectorXd I(fast.num_modes()), I_dense(dense.num_modes());
  fast.actions(sc.state.x, sc.state.v, I);
  dense.actions(sc.state.x, sc.state.v, I_dense);
  EXPECT_LT((I - I_dense).cwiseAbs().maxCoeff(), 1e-10 * I.cwiseAbs().maxCoeff());
  Eigen::Matrix3Xd f, f_dense;
  const double W = fast.correction_force(I, sc.state.x, f), W_dense = dense.correction_force(I, sc.state.x, f_dense);
  EXPECT_NEAR(W, W_dense, 1e-13 * std::abs(W_dense));
  EXPECT_LT((f - f_dense).cwiseAbs().maxCoeff(), 1e-11 * f_dense.cwiseAbs().maxCoeff());
  const fs::path d = test::scratch_dir("trimer_fluid");
  std::ostringstream log;
  const RunSummary s = run_simulation(sc, {d.string(), false, ""}, log);
  EXPECT_EQ(s.method, "effective");
  EXPECT_EQ(s.steps, 100);
  EXPECT_LT(s.max_energy_error, 1e-3 * std::abs(s.initial_energy)) << log.str();
  fs::remove_all(d);
}

TEST(PolymerDecks, TheLammpsChainBenchmarkImportsAndRuns) {
  const Scene sc = test::load("inputs/lammps_chain.toml", {"prepare.vibrational_temperature=0"});
  EXPECT_EQ(sc.state.size(), 32000);
  EXPECT_EQ(sc.topology.bonds.size(), 31680u);
  EXPECT_NEAR(sc.box.lengths[0], 2 * 16.796, 1e-12);
  EXPECT_TRUE(sc.box.periodic.all());
  int molecules = 0;
  for (int m : sc.topology.molecule) molecules = std::max(molecules, m + 1);
  EXPECT_EQ(molecules, 320);
  // Projected onto the stiff bonds by [prepare]: every bond at ℓ = 0.97.
  ASSERT_NE(sc.forces->stiff_bonds(), nullptr);
  EXPECT_LT(max_constraint_violation(sc.state.x, sc.forces->stiff_bonds()), 1e-10);
  const auto r = cli("run " + test::source_path("inputs/lammps_chain.toml") +
                     " --no-progress --set run.t_end=0.01 -o " + test::scratch_dir("chain").string());
  EXPECT_EQ(r.code, 0) << r.err;
}

// N free-ish particles on a lattice (no overlaps) in a big periodic box with WCA: P ≈ ρ T.
TEST(Pressure, DiluteGasFollowsTheIdealGasLaw) {
  std::ostringstream deck;
  deck << "[box]\nperiodic = true\nlengths = [40, 40, 40]\n[types.atom]\nmass = 1.0\n";
  for (int i = 0; i < 5; ++i)
    for (int j = 0; j < 5; ++j)
      for (int k = 0; k < 5; ++k)
        deck << "[[particles]]\nposition = [" << 8 * i + 1 << ", " << 8 * j + 1 << ", " << 8 * k + 1 << "]\n";
  deck << "[velocities]\ntemperature = 1.5\nseed = 3\n[forces.wca]\nstyle = \"wca\"\n"
          "[integrator]\nmethod = \"velocity-verlet\"\nh = 0.005\n[run]\nt_end = 20\n[output]\nxyz = "
          "\"\"\nthermo_interval = 0.5\n";
  const fs::path d = test::scratch_dir("gas");
  std::ofstream(d / "gas.toml") << deck.str();
  const Deck dk((d / "gas.toml").string(), {});
  Scene sc = load_scene(dk);
  std::ostringstream log;
  prepare_scene(sc, log);
  run_simulation(sc, {(d / "out").string(), false, ""}, log);
  const test::CsvTable thermo = test::read_csv((d / "out" / "thermo.csv").string());
  const size_t temperature = thermo.col("temperature"), pressure = thermo.col("pressure");
  double ratio = 0.0;
  int rows = 0;
  for (const auto& v : thermo.rows) {
    ratio += v[pressure] / (125.0 / (40.0 * 40.0 * 40.0) * v[temperature]);
    ++rows;
  }
  ratio /= rows;
  RecordProperty("P_over_rhoT", std::to_string(ratio));
  // Second virial coefficient of WCA at T = 1.5 is ≈ 2σ³: P/(ρT) ≈ 1 + 2ρ ≈ 1.004, and
  // (3N − 3)/(3N) = 0.992 from the conserved momentum.
  EXPECT_NEAR(ratio, 1.0, 0.02);
  fs::remove_all(d);
}

// inputs/stiff_melt_nvt.toml as shipped: the thermal stiff limit with the OBABO splitting on a
// 3 000-bead melt at ε = 1e-3, h = 0.02 (22 × velocity Verlet's largest step). It runs its 100
// steps on the bonds (max |g| at round-off in every row) and the thermostat holds kT = 1 over
// 3N − bonds degrees of freedom (the rows after t = 1: the relaxed melt's start is colder).
TEST(PolymerDecks, TheStiffMeltNvtDeckRunsTheThermalStiffLimitWithObabo) {
  const fs::path d = test::scratch_dir("stiff_melt_nvt");
  const auto check = cli("check " + test::source_path("inputs/stiff_melt_nvt.toml"));
  ASSERT_EQ(check.code, 0) << check.err;
  EXPECT_NE(check.out.find("(obabo)"), std::string::npos) << check.out;
  const auto r = cli("run " + test::source_path("inputs/stiff_melt_nvt.toml") + " --no-progress -o " + d.string());
  ASSERT_EQ(r.code, 0) << r.err;
  std::ifstream in(d / "thermo.csv");
  std::string line;
  std::getline(in, line);
  std::map<std::string, int> col;
  {
    std::istringstream h(line);
    std::string name;
    for (int k = 0; std::getline(h, name, ','); ++k) col[name] = k;
  }
  double t_sum = 0.0;
  int rows = 0, all_rows = 0;
  while (std::getline(in, line)) {
    std::vector<double> v;
    std::istringstream row(line);
    std::string cell;
    while (std::getline(row, cell, ',')) v.push_back(std::stod(cell));
    ++all_rows;
    EXPECT_LT(v[col.at("max_violation")], 1e-10) << line;
    if (v[col.at("time")] < 1.0 - 1e-9) continue;
    t_sum += v[col.at("temperature")];
    ++rows;
  }
  EXPECT_EQ(all_rows, 21);
  ASSERT_EQ(rows, 11);
  RecordProperty("T", std::to_string(t_sum / rows));
  EXPECT_NEAR(t_sum / rows, 1.0, 0.05);
  fs::remove_all(d);
}

// The thermo's end_to_end per molecule shape (engine/observe/polymer_observables.hpp): a linear
// chain's end-to-end distance, its ends found from the bonds whatever the index order; a ring's
// root-mean-square diameter (tools/analyze.py's R), its beads taken in bond order; a star left out,
// and with no chain or ring, no end_to_end column. rg averages over every molecule.
TEST(MoleculeSizes, ChainEndToEndRingDiameterNoneForAStar) {
  Topology t;
  Eigen::Matrix3Xd x = Eigen::Matrix3Xd::Zero(3, 18);
  auto bond = [&](int i, int j) { t.bonds.push_back({i, j, 0}); };
  // Molecule 0: the chain 1 – 0 – 2 bent at a right angle; ends 1 and 2, √2 apart.
  x.col(0) << 1, 0, 0;
  x.col(2) << 1, 1, 0;
  bond(1, 0), bond(0, 2);
  // Molecule 1: a unit square ringed 3 – 5 – 4 – 6 – 3; opposite beads (3, 4) and (5, 6), √2 apart.
  x.col(3) << 0, 0, 2;
  x.col(5) << 1, 0, 2;
  x.col(4) << 1, 1, 2;
  x.col(6) << 0, 1, 2;
  bond(3, 5), bond(5, 4), bond(4, 6), bond(6, 3);
  // Molecule 2: a regular pentagon of circumradius 1; each bead's nearest-to-opposite (two on) is
  // 2 sin(2π/5) away.
  for (int k = 0; k < 5; ++k) {
    x.col(7 + k) << std::cos(2 * M_PI * k / 5), std::sin(2 * M_PI * k / 5), 4;
    bond(7 + k, 7 + (k + 1) % 5);
  }
  // Molecule 3: a three-armed star, centre 12: branched, no size. Molecule 4: a dimer 1.5 long.
  x.col(12) << 0, 0, 6;
  x.col(13) << 1, 0, 6;
  x.col(14) << 0, 1, 6;
  x.col(15) << 0, 0, 7;
  bond(12, 13), bond(12, 14), bond(12, 15);
  x.col(16) << 0, 0, 8;
  x.col(17) << 1.5, 0, 8;
  bond(16, 17);
  t.molecule = {0, 0, 0, 1, 1, 1, 1, 2, 2, 2, 2, 2, 3, 3, 3, 3, 4, 4};
  const Eigen::VectorXd unit = Eigen::VectorXd::Ones(18);

  double rg = 0, size = 0;
  Molecules(t, unit, unit).measure(x, rg, size);
  EXPECT_NEAR(size, (std::sqrt(2.0) + std::sqrt(2.0) + 2 * std::sin(2 * M_PI / 5) + 1.5) / 4, 1e-15);
  double rg_sum = 0;  // unit masses: Rg² = ⟨|x − x̄|²⟩ over the molecule's beads
  for (const std::vector<int>& m :
       std::vector<std::vector<int>>{{0, 1, 2}, {3, 4, 5, 6}, {7, 8, 9, 10, 11}, {12, 13, 14, 15}, {16, 17}}) {
    Eigen::Vector3d mean = Eigen::Vector3d::Zero();
    for (int i : m) mean += x.col(i) / m.size();
    double r2 = 0;
    for (int i : m) r2 += (x.col(i) - mean).squaredNorm() / m.size();
    rg_sum += std::sqrt(r2);
  }
  EXPECT_NEAR(rg, rg_sum / 5, 1e-15);

  // The star alone: rg, but no end-to-end distance and no column for one.
  Topology star;
  star.molecule.assign(18, 0);
  for (int i = 12; i < 16; ++i) star.molecule[i] = 1;
  for (const Bond& b : t.bonds)
    if (b.i >= 12 && b.i < 16) star.bonds.push_back(b);
  EXPECT_FALSE(Molecules(star, unit, unit).has_end_to_end());
  EXPECT_TRUE(Molecules(t, unit, unit).has_end_to_end());
  const Scene sc = test::load("inputs/double_pendulum.toml");
  const Thermo with_star(*sc.forces, unit, {}, &star), with_all(*sc.forces, unit, {}, &t);
  EXPECT_GE(with_star.column("rg"), 0);
  EXPECT_EQ(with_star.column("end_to_end"), -1);
  EXPECT_EQ(with_all.column("end_to_end"), with_all.column("rg") + 1);
}

// Rigid bonds are all of one length to SHAKE's tolerance: the bond-length histogram's bins are
// still readable ranges (not "0.97,0.97"), one of them holding every bond and 0.97.
TEST(Histograms, RigidBondLengthsGetBinsThatReadAsTheirLength) {
  const fs::path d = test::scratch_dir("histograms_rigid");
  const auto r = cli("run " + test::source_path("tests/decks/small_melt.toml") +
                     " --no-progress -q --set integrator.method=rattle -o " + d.string());
  ASSERT_EQ(r.code, 0) << r.err;
  std::ifstream in(d / "histograms.csv");
  std::string line;
  int rows = 0;
  long bonds = 0;
  while (std::getline(in, line)) {
    if (line.rfind("bond_length,", 0) != 0) continue;
    std::istringstream row(line.substr(12));
    std::string low, high, count;
    std::getline(row, low, ',');
    std::getline(row, high, ',');
    std::getline(row, count);
    ++rows;
    EXPECT_NE(low, high) << line;
    EXPECT_GT(std::stod(high) - std::stod(low), 1e-6) << line;
    if (std::stol(count) > 0) {
      bonds += std::stol(count);
      EXPECT_LE(std::stod(low), 0.97) << line;
      EXPECT_GE(std::stod(high), 0.97) << line;
    }
  }
  EXPECT_EQ(rows, 100);
  EXPECT_GT(bonds, 0);
  fs::remove_all(d);
}

TEST(ValidityMonitor, WarnsOnTheLongChainsNearlyDegenerateFrequencies) {
  const auto r = cli("run " + test::source_path("inputs/hanging_chain.toml") +
                     " --no-progress --set run.t_end=0.05 -o " + test::scratch_dir("hanging").string());
  EXPECT_EQ(r.code, 0) << r.err;
  EXPECT_NE(r.err.find("warning: frequency gap"), std::string::npos) << r.err;
  EXPECT_NE(r.err.find("at step 0 (t = 0)"), std::string::npos) << r.err;
}

// The effective dynamics' validity concerns the methods that follow it (effective, the projected
// and mollified impulse methods); velocity Verlet and the impulse method resolve the vibrations,
// whose actions may jump there (a note that says so), and rattle has none (nothing).
TEST(ValidityMonitor, WarnsOnlyForTheMethodsThatFollowTheEffectiveDynamics) {
  for (const std::string method : {"effective", "mollified-impulse", "velocity-verlet", "impulse", "rattle"}) {
    SCOPED_TRACE(method);
    const std::string h = method == "velocity-verlet" ? "2e-4" : "0.01";
    const auto r = cli("run " + test::source_path("inputs/hanging_chain.toml") +
                       " --no-progress --set run.t_end=0.02 --set integrator.h=" + h +
                       " --set integrator.method=" + method + " -o " + test::scratch_dir("hanging_" + method).string());
    EXPECT_EQ(r.code, 0) << r.err;
    const bool follows = find_method(method)->follows_effective, rigid = find_method(method)->rigid_constraints;
    EXPECT_EQ(r.err.find("effective dynamics") != std::string::npos, follows) << r.err;
    EXPECT_EQ(r.err.find("warning: frequency gap") != std::string::npos, follows) << r.err;
    EXPECT_EQ(r.err.find("note: frequency gap") != std::string::npos, !follows && !rigid) << r.err;
    EXPECT_EQ(r.err.find("adiabatic invariants") != std::string::npos, follows || !rigid) << r.err;
  }
}

}  // namespace
}  // namespace stiffmd

namespace stiffmd {
namespace {

// The final state exported as a LAMMPS data file imports back exactly (positions, velocities,
// bonds), so the same state can be run in LAMMPS.
TEST(LammpsExport, FinalStateRoundTripsThroughImport) {
  const fs::path d = test::scratch_dir("export");
  const auto r = cli("run " + test::source_path("tests/decks/small_melt.toml") +
                     " --no-progress --set output.lammps_data=final.data -o " + (d / "out").string());
  ASSERT_EQ(r.code, 0) << r.err;
  const Checkpoint end = read_checkpoint((d / "out" / "checkpoint.bin").string());
  std::ofstream(d / "import.toml") << "[types.bead]\nmass = 1.0\n[import]\nlammps_data = \"out/final.data\"\n"
                                      "atom_types = { \"1\" = \"bead\" }\nbond_types = { \"1\" = \"backbone\" }\n"
                                      "angle_types = { \"1\" = \"bend\" }\n"
                                      "[forces.bonds]\nstyle = \"fene\"\nbond_types.backbone = { K = 30, R0 = 1.5 }\n"
                                      "[forces.bend]\nstyle = \"cosine-angle\"\nangle_types.bend = { k = 1 }\n"
                                      "[integrator]\nmethod = \"velocity-verlet\"\nh = 0.001\n[run]\nt_end = 0.001\n";
  const Deck deck((d / "import.toml").string(), {});
  const Scene sc = load_scene(deck);
  ASSERT_EQ(sc.state.size(), end.state.size());
  EXPECT_TRUE((sc.state.x.array() == end.state.x.array()).all()) << "positions differ";
  EXPECT_TRUE((sc.state.v.array() == end.state.v.array()).all()) << "velocities differ";
  EXPECT_EQ(sc.topology.bonds.size(), 180u);
  EXPECT_EQ(sc.topology.angles.size(), 168u);
  fs::remove_all(d);
}

}  // namespace
}  // namespace stiffmd

namespace stiffmd {
namespace {

// A dilute gas of rigid dimers under RATTLE: without the constraint forces' virial the atomic
// pressure would be 2K/(3V) ≈ (5/3) N_d T/V; with it, P V = N_d T (an ideal gas of molecules).
TEST(Pressure, RigidDimerGasIncludesTheConstraintVirial) {
  Scene sc = test::load("tests/decks/small_melt.toml",
                        {"build.0.chains=200", "build.0.beads=2", "build.0.density=0.01",
                         "forces.bending.angle_types.bend.k=0", "integrator.method=rattle", "integrator.h=0.01",
                         "run.t_end=20", "output.thermo_interval=0.5", "prepare.vibrational_temperature=0"});
  const fs::path d = test::scratch_dir("dimers");
  std::ostringstream log;
  run_simulation(sc, {d.string(), false, ""}, log);
  const test::CsvTable thermo = test::read_csv((d / "thermo.csv").string());
  const size_t temperature = thermo.col("temperature"), pressure = thermo.col("pressure");
  const double volume = sc.box.lengths.prod();
  double ratio = 0.0;
  int rows = 0;
  for (const auto& v : thermo.rows) {
    if (rows++ == 0) continue;  // t = 0: no constraint force known yet
    ratio += v[pressure] * volume / (200.0 * v[temperature]);
  }
  ratio /= rows - 1;
  RecordProperty("PV_over_NdT", std::to_string(ratio));
  EXPECT_NEAR(ratio, 1.0, 0.05);
  fs::remove_all(d);
}

}  // namespace
}  // namespace stiffmd

namespace stiffmd {
namespace {

// tests/data/butanes.data (three butane-like chains, 2 atom types, bonds, angles, dihedrals)
// imported with the deck's force terms equal to the LAMMPS styles of
// tools/lammps_butane_reference.py: stiff-harmonic ½(α/ε)²(r−ℓ)² = bond harmonic K(r−r₀)² with
// (α/ε)² = 2K; harmonic-angle k = 2K; opls-dihedral = opls; lj cut and shifted = lj/cut with
// pair_modify shift yes; special_bonds [0, 0] (1-4 pairs interact) = special_bonds lj 0 0 1.
// `pair` is the deck text of the LJ type pairs.
std::map<std::string, double> imported_butane_energies(const std::string& pair,
                                                       const std::string& special_bonds = "[0.0, 0.0]") {
  const std::string deck =
      test::butanes_import() +
      "[forces.bond]\nstyle = \"stiff-harmonic\"\nepsilon = 0.05\n"
      "bond_types.end = { length = 1.0, alpha = \"0.05 * sqrt(2 * 200)\" }\n"
      "bond_types.mid = { length = 1.05, alpha = \"0.05 * sqrt(2 * 150)\" }\n"
      "[forces.angle]\nstyle = \"harmonic-angle\"\nangle_types.ccc = { k = 60, theta0 = 114 }\n"
      "[forces.dihedral]\nstyle = \"opls-dihedral\"\ndihedral_types.butane = { K1 = 1.41, K2 = -0.27, K3 = 3.14, K4 = "
      "0.1 }\n"
      "[forces.pair]\nstyle = \"lj\"\ncutoff = 2.5\nspecial_bonds = " +
      special_bonds + "\n" + pair + "[integrator]\nmethod = \"velocity-verlet\"\nh = 0.001\n[run]\nt_end = 0.001\n";
  const fs::path d = test::scratch_dir("butanes");
  std::ofstream(d / "butanes.toml") << deck;
  const Scene sc = load_scene(Deck((d / "butanes.toml").string(), {}));
  std::map<std::string, double> e;
  for (const auto& t : sc.forces->terms()) {
    Eigen::Matrix3Xd f = Eigen::Matrix3Xd::Zero(3, sc.state.size());
    e[t->name()] = t->add_forces(sc.state.x, sc.box, f);
  }
  return e;
}

// LAMMPS (29 Sep 2021) on the same file, `run 0`, thermo ebond eangle edihed evdwl with norm no
// and %.17g: the numbers and the input are printed by tools/lammps_butane_reference.py. The 1-2
// pair is given explicitly here (LAMMPS mixes it geometrically).
TEST(ImportedButanes, SameEnergiesAsLammps) {
  const auto e = imported_butane_energies(
      "epsilon = 1.2\nsigma = 1.05\n"
      "[[forces.pair.pair]]\ntypes = [\"CH2\", \"CH2\"]\nepsilon = 0.9\nsigma = 0.95\n"
      "[[forces.pair.pair]]\ntypes = [\"CH3\", \"CH2\"]\nepsilon = \"sqrt(1.2 * 0.9)\"\nsigma = \"sqrt(1.05 * "
      "0.95)\"\n");
  EXPECT_NEAR(e.at("bond"), 4.6419945562564111, 1e-12);
  EXPECT_NEAR(e.at("angle"), 1.7334938269372535, 1e-12);
  EXPECT_NEAR(e.at("dihedral"), 7.2235282112952071, 1e-12);
  EXPECT_NEAR(e.at("pair"), -1.1438791838745168, 1e-12);
}

// The same with per-type LJ coefficients and LAMMPS's mixing rules (pair_coeff i i only; LAMMPS
// mixes the 1-2 pair with pair_modify mix geometric, then arithmetic).
TEST(ImportedButanes, MixingRulesAsLammps) {
  const std::string per_type =
      "types.CH3 = { epsilon = 1.2, sigma = 1.05 }\ntypes.CH2 = { epsilon = 0.9, sigma = 0.95 }\n";
  EXPECT_NEAR(imported_butane_energies("mix = \"geometric\"\n" + per_type).at("pair"), -1.1438791838745168, 1e-12);
  EXPECT_NEAR(imported_butane_energies("mix = \"arithmetic\"\n" + per_type).at("pair"), -1.1476104065693902, 1e-12);
}

// 1-4 pairs at half weight: LAMMPS special_bonds lj 0.0 0.0 0.5 (else as in SameEnergiesAsLammps,
// mix geometric) gives evdwl = -0.97592348627987502.
TEST(ImportedButanes, OneFourWeightAsLammps) {
  const std::string per_type =
      "types.CH3 = { epsilon = 1.2, sigma = 1.05 }\ntypes.CH2 = { epsilon = 0.9, sigma = 0.95 }\n";
  std::string deck_pair = "mix = \"geometric\"\n" + per_type;
  const auto e = imported_butane_energies(deck_pair, "[0.0, 0.0, 0.5]");
  EXPECT_NEAR(e.at("pair"), -0.97592348627987502, 1e-12);
}

}  // namespace
}  // namespace stiffmd
