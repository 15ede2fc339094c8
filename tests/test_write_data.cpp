// `stiffmd check DECK --write-data FILE`: the prepared initial state (after [prepare]) as a LAMMPS
// data file — what tools/bench_lammps.py hands to LAMMPS so that both codes start from one state.
#include <gtest/gtest.h>

#include <cmath>
#include <filesystem>
#include <fstream>
#include <map>
#include <sstream>

#include "engine/deck/deck.hpp"
#include "engine/io/lammps_data.hpp"
#include "engine/scene/scene.hpp"
#include "forcefields/force_term.hpp"
#include "tests/cli_support.hpp"
#include "tests/test_support.hpp"

namespace stiffmd {
namespace {

namespace fs = std::filesystem;
using namespace test;

TEST(WriteData, CheckWritesThePreparedInitialState) {
  // A built, projected and thermalised melt: [prepare] changes the state, so a file written
  // before it (or after a step) would differ from load_scene's.
  const std::string deck = std::string(STIFFMD_SOURCE_DIR) + "/inputs/hard/stiff_chain_melt.toml";
  const fs::path out = scratch_dir("write_data") / "state.data";
  const CliResult r = cli("check " + deck + " --write-data " + out.string());
  ASSERT_EQ(r.code, 0) << r.err;
  EXPECT_NE(r.out.find("initial state written to"), std::string::npos) << r.out;

  Scene scene = load_scene(Deck(deck, {}));
  std::ostringstream log;
  prepare_scene(scene, log);
  const ImportedSystem data = read_lammps_data(out.string());
  ASSERT_EQ(data.x.cols(), scene.state.x.cols());
  EXPECT_EQ(data.bonds.size(), scene.topology.bonds.size());
  // Written at full precision: the same state back, to round-off.
  EXPECT_LE((data.x - scene.state.x).cwiseAbs().maxCoeff(), 1e-12);
  EXPECT_LE((data.v - scene.state.v).cwiseAbs().maxCoeff(), 1e-12);
  EXPECT_GT(scene.state.v.norm(), 0.0);
}

TEST(WriteData, AnUnwritablePathIsAnInputError) {
  const CliResult r = cli("check " + std::string(STIFFMD_SOURCE_DIR) +
                          "/inputs/double_pendulum.toml --write-data /nonexistent_dir/state.data");
  EXPECT_EQ(r.code, 2) << r.err;
  EXPECT_NE(r.err.find("/nonexistent_dir/state.data"), std::string::npos) << r.err;
}

// inputs/trappe_pe.toml with its [types] in the other order (CH2 first), so that the deck's order
// is not the data file's numbering (CH3 = 1, CH2 = 2), importing `data`.
fs::path trappe_deck(const fs::path& dir, const std::string& data, const std::string& name) {
  std::string text = slurp(source_path("inputs/trappe_pe.toml"));
  const std::string ch3 = "[types.CH3]\nmass = 15.035\nelement = \"C\"\n\n";
  const auto at = text.find(ch3);
  EXPECT_NE(at, std::string::npos);
  text.erase(at, ch3.size());
  const auto ch2_end = text.find("\n\n", text.find("[types.CH2]")) + 2;
  text.insert(ch2_end, ch3);
  const std::string import = "lammps_data = \"trappe_pe.data\"";
  text.replace(text.find(import), import.size(), "lammps_data = \"" + data + "\"");
  const fs::path deck = dir / name;
  std::ofstream(deck) << text;
  return deck;
}

double term_energy(const Scene& sc, const std::string& name) {
  for (const auto& t : sc.forces->terms())
    if (t->name() == name) {
      Eigen::Matrix3Xd f = Eigen::Matrix3Xd::Zero(3, sc.state.size());
      return t->add_forces(sc.state.x, sc.box, f);
    }
  ADD_FAILURE() << "no term " << name;
  return 0.0;
}

// The numbers of a Coeffs row after its type.
std::vector<double> coeffs_of(const ImportedSystem& d, const std::string& section, int type) {
  for (const auto& c : d.coeffs)
    if (c.name == section)
      for (const auto& row : c.rows) {
        std::istringstream in(row);
        int t = 0;
        in >> t;
        if (t != type) continue;
        std::vector<double> out;
        for (double v; in >> v;) out.push_back(v);
        return out;
      }
  ADD_FAILURE() << "no row " << type << " in " << section;
  return {};
}

TEST(WriteData, KeepsImportedTypeNumbersAndWritesTheForceField) {
  const fs::path dir = scratch_dir("write_data_types");
  const std::string data = source_path("inputs/trappe_pe.data");
  const fs::path deck = trappe_deck(dir, data, "deck.toml"), out = dir / "state.data";
  const CliResult r = cli("check " + deck.string() + " --write-data " + out.string());
  ASSERT_EQ(r.code, 0) << r.err;
  const ImportedSystem original = read_lammps_data(data), written = read_lammps_data(out.string());
  // The file's numbers, not the deck's order (which would make CH2 type 1).
  EXPECT_EQ(written.type, original.type);
  EXPECT_EQ(written.type_mass, original.type_mass);
  std::map<std::string, std::string> styles;
  for (const auto& c : written.coeffs) styles[c.name] = c.style;
  EXPECT_EQ(styles, (std::map<std::string, std::string>{{"PairIJ Coeffs", "lj/cut"},
                                                        {"Bond Coeffs", "harmonic"},
                                                        {"Angle Coeffs", "harmonic"},
                                                        {"Dihedral Coeffs", "opls"}}));
  // LAMMPS's conventions: bond and angle harmonic K = k/2, θ0 in degrees, opls K_n as the deck's.
  const double kB = 0.0019872067;
  const auto bond = coeffs_of(written, "Bond Coeffs", 1);
  ASSERT_EQ(bond.size(), 2u);
  EXPECT_NEAR(bond[0], 0.5 * 536.0, 1e-9);
  EXPECT_EQ(bond[1], 1.54);
  const auto angle = coeffs_of(written, "Angle Coeffs", 1);
  ASSERT_EQ(angle.size(), 2u);
  EXPECT_NEAR(angle[0], 0.5 * 62500 * kB, 1e-12);
  EXPECT_NEAR(angle[1], 114.0, 1e-12);
  const auto torsion = coeffs_of(written, "Dihedral Coeffs", 1);
  ASSERT_EQ(torsion.size(), 4u);
  EXPECT_NEAR(torsion[0], 2 * 355.03 * kB, 1e-12);
  EXPECT_NEAR(torsion[2], 2 * 791.32 * kB, 1e-12);
  // PairIJ rows "I J epsilon sigma cutoff": the CH3-CH2 pair mixed by Lorentz-Berthelot.
  bool mixed = false;
  for (const auto& c : written.coeffs)
    for (const auto& row : c.rows)
      if (c.name == "PairIJ Coeffs" && row.rfind("1 2 ", 0) == 0) {
        std::istringstream in(row.substr(4));
        double eps = 0, sigma = 0, cut = 0;
        in >> eps >> sigma >> cut;
        EXPECT_NEAR(eps, std::sqrt(98 * 46) * kB, 1e-12);
        EXPECT_NEAR(sigma, 0.5 * (3.75 + 3.95), 1e-12);
        EXPECT_EQ(cut, 10.0);
        mixed = true;
      }
  EXPECT_TRUE(mixed);
}

TEST(WriteData, ReimportedDataGivesTheSameEnergies) {
  const fs::path dir = scratch_dir("write_data_energies");
  const fs::path deck = trappe_deck(dir, source_path("inputs/trappe_pe.data"), "deck.toml"), out = dir / "state.data";
  ASSERT_EQ(cli("check " + deck.string() + " --write-data " + out.string()).code, 0);
  const Scene first = load_scene(Deck(deck.string(), {}));
  const Scene again = load_scene(Deck(trappe_deck(dir, out.string(), "again.toml").string(), {}));
  ASSERT_EQ(again.state.x.cols(), first.state.x.cols());
  EXPECT_EQ(again.particle_type, first.particle_type);
  for (const char* term : {"bonds", "bend", "torsion", "lj"}) {
    const double e = term_energy(first, term);
    EXPECT_NEAR(term_energy(again, term), e, 1e-12 * std::abs(e)) << term;
  }
  // The written coefficients in LAMMPS's own formulas give the deck's bonded energies: bond and
  // angle harmonic K(r − r0)², K(θ − θ0)² (θ0 in degrees).
  const ImportedSystem d = read_lammps_data(out.string());
  const auto b = coeffs_of(d, "Bond Coeffs", 1), a = coeffs_of(d, "Angle Coeffs", 1);
  ASSERT_EQ(b.size(), 2u);
  ASSERT_EQ(a.size(), 2u);
  double bonds = 0, bends = 0;
  for (const auto& bond : d.bonds) {
    const double r = (d.x.col(bond.i) - d.x.col(bond.j)).norm();
    bonds += b[0] * (r - b[1]) * (r - b[1]);
  }
  for (const auto& ang : d.angles) {
    const Eigen::Vector3d u = d.x.col(ang.i) - d.x.col(ang.j), v = d.x.col(ang.k) - d.x.col(ang.j);
    const double theta = std::acos(std::clamp(u.dot(v) / (u.norm() * v.norm()), -1.0, 1.0));
    bends += a[0] * (theta - a[1] * M_PI / 180) * (theta - a[1] * M_PI / 180);
  }
  EXPECT_NEAR(bonds, term_energy(first, "bonds"), 1e-9 * bonds);
  EXPECT_NEAR(bends, term_energy(first, "bend"), 1e-9 * bends);
}

// One atom type: "Pair Coeffs" (rows "I coeffs"), which MDAnalysis reads too. A kind whose terms
// need several LAMMPS styles (tests/decks/every_force_style.toml: stiff, FENE and Morse bonds; four
// pair terms) is left out rather than written half.
TEST(WriteData, WritesTheSectionsLammpsCanRead) {
  const fs::path dir = scratch_dir("write_data_sections");
  const fs::path kg = dir / "kg.data", every = dir / "every.data";
  ASSERT_EQ(cli("check " + source_path("inputs/kremer_grest.toml") + " --write-data " + kg.string()).code, 0);
  const ImportedSystem d = read_lammps_data(kg.string());
  std::map<std::string, std::vector<std::string>> rows;
  for (const auto& c : d.coeffs) rows[c.name + " # " + c.style] = c.rows;
  EXPECT_EQ(rows, (std::map<std::string, std::vector<std::string>>{{"Pair Coeffs # lj/cut", {"1 1 1 1.12"}},
                                                                   {"Bond Coeffs # fene", {"1 30 1.5 1 1"}}}));
  ASSERT_EQ(cli("check " + source_path("tests/decks/every_force_style.toml") + " --write-data " + every.string()).code,
            0);
  EXPECT_TRUE(read_lammps_data(every.string()).coeffs.empty());
}

}  // namespace
}  // namespace stiffmd
