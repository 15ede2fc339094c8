// A rank's part of a deck's LAMMPS data file import (engine/domain/import_part.hpp) on 1–4 fake
// partitions, against the whole path: every deck that imports a data file (chains with and
// without image flags, scattered atom ids, charges, angles, dihedrals and impropers, bonded maps
// given and left out, coefficients = "data", Langevin frictions by type) loaded whole by
// load_scene.
//
// What must hold: for the molecules of each part — a block of the file's molecules (whole_block's),
// or the molecules whose anchor lies in a rank's domain — the part is cut_part(whole scene, its
// particles) bit for bit (inverse masses, types, charges, molecule ids, frictions, every bonded
// item with the whole scene's type and its place in the whole scene's list), its x and v are the
// whole scene's columns, the parts tile the system, and what the part describes of the scene (box,
// type names, LAMMPS type numbers, the Coeffs sections and their numbers per type) is the whole
// scene's; and a decomposition started from these parts holds, on every rank, what a start from
// the whole scene's blocks gives it.
#include <gtest/gtest.h>

#include <unistd.h>

#include <algorithm>
#include <cmath>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <sstream>
#include <string>
#include <vector>

#include "core/errors.hpp"
#include "decomposition_fixtures.hpp"
#include "engine/deck/deck.hpp"
#include "engine/domain/decomposition.hpp"
#include "engine/domain/import_part.hpp"
#include "engine/domain/part_molecules.hpp"
#include "engine/scene/scene.hpp"
#include "fake_processes.hpp"
#include "test_support.hpp"

namespace stiffmd {
namespace {

struct ImportCase {
  std::string name, deck;
  std::vector<std::string> overrides;
  bool file_velocities = true;  // false: the deck's [velocities] replaces the file's
  bool anchors = true;          // the file has image flags (or no bonded terms): parts by anchor too
};

void PrintTo(const ImportCase& c, std::ostream* os) {
  *os << c.name;
}

// A deck of its own (tests write it in the temporary directory): three chains of six beads across
// the periodic faces, written wrapped without image flags (the import makes them whole along their
// bonds), atom ids neither 1 … N nor in order, molecule ids with gaps and out of order, two atom
// types and two bond types of one name whose first bond is of type 2, velocities.
std::string wrapped_deck() {
  const std::filesystem::path dir =
      std::filesystem::temp_directory_path() / ("stiffmd_test_import_part_" + std::to_string(::getpid()));
  std::filesystem::create_directories(dir);
  const int chains = 3, beads = 6, n = chains * beads;
  const int mol[chains] = {40, 7, 19};
  std::ostringstream data;
  data.precision(17);
  data << "wrapped chains for tests/test_import_part.cpp\n\n"
       << n << " atoms\n"
       << chains * (beads - 1) << " bonds\n2 atom types\n2 bond types\n"
       << "0 6 xlo xhi\n0 6 ylo yhi\n0 6 zlo zhi\n\nMasses\n\n1 1.0\n2 2.0\n\nAtoms # bond\n\n";
  const auto id = [&](int i) { return 3 * (n - 1 - i) + 2; };  // decreasing with the bead
  for (int i = n - 1; i >= 0; --i) {                           // written by increasing id
    const int c = i / beads, b = i % beads;
    double x[3] = {5.3 + 0.9 * b, 1.0 + 1.5 * c + 0.3 * b, 5.6 + 0.35 * b};
    for (double& q : x) q = std::fmod(q, 6.0);
    data << id(i) << " " << mol[c] << " " << 1 + (b % 2) << " " << x[0] << " " << x[1] << " " << x[2] << "\n";
  }
  data << "\nVelocities\n\n";
  for (int i = 0; i < n; ++i) data << id(i) << " " << 0.1 * i << " " << -0.05 * i << " 0.25\n";
  data << "\nBonds\n\n";
  int k = 0;
  for (int c = 0; c < chains; ++c)
    for (int b = 0; b + 1 < beads; ++b) {
      ++k;
      data << k << " " << 2 - (k % 2 == 0) << " " << id(c * beads + b) << " " << id(c * beads + b + 1) << "\n";
    }
  std::ofstream(dir / "wrapped.data") << data.str();
  std::ofstream(dir / "wrapped.toml")
      << "[types.A]\nmass = 1.0\n\n[types.B]\nmass = 2.0\n\n[import]\n"
         "lammps_data = \"wrapped.data\"\natom_types = { \"1\" = \"A\", \"2\" = \"B\" }\n"
         "bond_types = { \"1\" = \"b\", \"2\" = \"b\" }\n\n[forces.bonds]\n"
         "style = \"harmonic-bond\"\nbond_types.b = { k = 10.0, r0 = 1.0 }\n\n"
         "[integrator]\nmethod = \"velocity-verlet\"\nh = 0.01\n\n[run]\nt_end = 0.1\n";
  return (dir / "wrapped.toml").string();
}

std::string deck_path(const std::string& deck) {
  if (deck == "wrapped") {
    // Written once per process, removed at its end.
    static const struct Written {
      std::string path = wrapped_deck();
      ~Written() {
        std::error_code ec;
        std::filesystem::remove_all(std::filesystem::path(path).parent_path(), ec);
      }
    } written;
    return written.path;
  }
  return test::source_path(deck);
}

// The whole path: the deck loaded as a run loads it (no [prepare]: load_scene does not apply it).
struct Whole {
  Scene scene;
  LammpsImportDeck deck;
  std::vector<double> type_friction;  // per particle type, from the particles' (empty: none)
  WholeParticles particles() const {
    const Eigen::VectorXd& friction = scene.integrator.thermostat.friction;
    return {std::span<const double>(scene.state.inv_mass.data(), static_cast<size_t>(scene.state.size())),
            scene.particle_type,
            scene.charge,
            scene.topology.molecule,
            std::span<const double>(friction.data(), static_cast<size_t>(friction.size())),
            scene.topology};
  }
  ImportTypes types() const { return {scene.types, scene.units.velocity_in(1.0), type_friction}; }
  int size() const { return scene.state.size(); }
};

Whole load_whole(const ImportCase& c) {
  const Deck deck(deck_path(c.deck), c.overrides);
  Whole w{load_scene(deck), {}, {}};
  DeckTable root = deck.root();
  auto t = root.table("import");
  EXPECT_TRUE(t.has_value());
  w.deck = read_lammps_import(*t, std::filesystem::path(deck.path()).parent_path().string());
  const Eigen::VectorXd& friction = w.scene.integrator.thermostat.friction;
  if (friction.size() > 0) {
    w.type_friction.assign(w.scene.types.size(), -1.0);
    for (int i = 0; i < w.size(); ++i) {
      double& f = w.type_friction[static_cast<size_t>(w.scene.particle_type[i])];
      EXPECT_TRUE(f < 0.0 || f == friction[i]) << "the friction is not one per type";
      f = friction[i];
    }
  }
  return w;
}

template <class T>
bool same_bits(const std::vector<T>& a, const std::vector<T>& b) {
  return a.size() == b.size() && (a.empty() || std::memcmp(a.data(), b.data(), sizeof(T) * a.size()) == 0);
}
bool same_bits(const Eigen::Matrix3Xd& a, const Eigen::Matrix3Xd& b) {
  return a.cols() == b.cols() && (a.size() == 0 || std::memcmp(a.data(), b.data(), sizeof(double) * a.size()) == 0);
}

template <class Item>
bool same_items(const std::vector<PartMolecules::Placed<Item>>& a, const std::vector<PartMolecules::Placed<Item>>& b) {
  if (a.size() != b.size()) return false;
  for (size_t e = 0; e < a.size(); ++e)
    if (a[e].place != b[e].place || std::memcmp(&a[e].item, &b[e].item, sizeof(Item)) != 0) return false;
  return true;
}

void expect_same_molecules(const PartMolecules& got, const PartMolecules& want) {
  EXPECT_EQ(got.global, want.global);
  EXPECT_TRUE(same_bits(got.inv_mass, want.inv_mass));
  EXPECT_EQ(got.type, want.type);
  EXPECT_TRUE(same_bits(got.charge, want.charge));
  EXPECT_EQ(got.molecule_id, want.molecule_id);
  EXPECT_TRUE(same_bits(got.friction, want.friction));
  EXPECT_TRUE(same_items(got.bonds, want.bonds)) << got.bonds.size() << " bonds, " << want.bonds.size() << " wanted";
  EXPECT_TRUE(same_items(got.angles, want.angles));
  EXPECT_TRUE(same_items(got.dihedrals, want.dihedrals));
  EXPECT_TRUE(same_items(got.impropers, want.impropers));
}

// The part against the whole scene's cut of its particles, and what it describes of the scene.
void expect_whole_cut(const Whole& w, const ImportedMolecules& part, bool file_velocities) {
  const Scene& sc = w.scene;
  expect_same_molecules(part.molecules, cut_part(w.particles(), part.molecules.global));
  const auto n = static_cast<Eigen::Index>(part.molecules.size());
  Eigen::Matrix3Xd x(3, n), v(3, n);
  for (Eigen::Index k = 0; k < n; ++k)
    x.col(k) = sc.state.x.col(part.molecules.global[k]), v.col(k) = sc.state.v.col(part.molecules.global[k]);
  EXPECT_TRUE(same_bits(part.x, x));
  if (file_velocities) {
    EXPECT_TRUE(same_bits(part.v, v));
  }
  EXPECT_EQ(part.box.origin, sc.box.origin);
  EXPECT_EQ(part.box.lengths, sc.box.lengths);
  EXPECT_EQ(part.box.periodic, sc.box.periodic);
  EXPECT_EQ(part.names.bond_types, sc.topology.bond_types);
  EXPECT_EQ(part.names.angle_types, sc.topology.angle_types);
  EXPECT_EQ(part.names.dihedral_types, sc.topology.dihedral_types);
  EXPECT_EQ(part.names.improper_types, sc.topology.improper_types);
  const LammpsTypeNumbers& a = part.lammps_types;
  const LammpsTypeNumbers& b = sc.lammps_types;
  EXPECT_EQ(a.atom, b.atom);
  EXPECT_EQ(a.bond, b.bond);
  EXPECT_EQ(a.angle, b.angle);
  EXPECT_EQ(a.dihedral, b.dihedral);
  EXPECT_EQ(a.improper, b.improper);
  EXPECT_EQ(a.masses, b.masses);
  const LammpsDataCoeffs& c = part.lammps_data_coeffs;
  const LammpsDataCoeffs& d = sc.lammps_data_coeffs;
  EXPECT_EQ(c.file, d.file);
  ASSERT_EQ(c.sections.size(), d.sections.size());
  for (size_t k = 0; k < c.sections.size(); ++k) {
    EXPECT_EQ(c.sections[k].name, d.sections[k].name);
    EXPECT_EQ(c.sections[k].style, d.sections[k].style);
    EXPECT_EQ(c.sections[k].rows, d.sections[k].rows);
  }
  EXPECT_EQ(c.bond, d.bond);
  EXPECT_EQ(c.angle, d.angle);
  EXPECT_EQ(c.dihedral, d.dihedral);
  EXPECT_EQ(c.improper, d.improper);
  EXPECT_EQ(part.num_particles, w.size());
  const std::vector<int> molecule = bonded_molecules(sc.topology, w.size());
  EXPECT_EQ(part.num_molecules, molecule.empty() ? 0 : *std::max_element(molecule.begin(), molecule.end()) + 1);
}

// Every particle in exactly one part, every item of the whole scene in one.
void expect_tiling(const Whole& w, const std::vector<ImportedMolecules>& parts) {
  std::vector<int> owner(static_cast<size_t>(w.size()), -1);
  size_t bonds = 0, angles = 0, dihedrals = 0, impropers = 0;
  for (size_t r = 0; r < parts.size(); ++r) {
    for (const int g : parts[r].molecules.global) {
      EXPECT_EQ(owner[static_cast<size_t>(g)], -1) << "particle " << g << " in two parts";
      owner[static_cast<size_t>(g)] = static_cast<int>(r);
    }
    bonds += parts[r].molecules.bonds.size();
    angles += parts[r].molecules.angles.size();
    dihedrals += parts[r].molecules.dihedrals.size();
    impropers += parts[r].molecules.impropers.size();
  }
  EXPECT_EQ(std::count(owner.begin(), owner.end(), -1), 0) << "particles in no part";
  EXPECT_EQ(bonds, w.scene.topology.bonds.size());
  EXPECT_EQ(angles, w.scene.topology.angles.size());
  EXPECT_EQ(dihedrals, w.scene.topology.dihedrals.size());
  EXPECT_EQ(impropers, w.scene.topology.impropers.size());
}

class ImportPart : public ::testing::TestWithParam<ImportCase> {};

TEST_P(ImportPart, EachBlockOfMoleculesIsTheWholeScenesCutBitForBit) {
  const ImportCase& c = GetParam();
  const Whole w = load_whole(c);
  ASSERT_GT(w.size(), 0);
  int items = 0;
  for (int ranks = 1; ranks <= 4; ++ranks) {
    std::vector<ImportedMolecules> parts;
    for (int r = 0; r < ranks; ++r) {
      SCOPED_TRACE(std::to_string(ranks) + " blocks, block " + std::to_string(r));
      parts.push_back(import_part(w.deck, w.types(), {nullptr, {r, ranks}}));
      EXPECT_EQ(parts.back().molecules.global, whole_block(w.scene.topology, w.size(), ranks, r));
      expect_whole_cut(w, parts.back(), c.file_velocities);
      items += static_cast<int>(parts.back().molecules.bonds.size());
    }
    expect_tiling(w, parts);
  }
  if (!w.scene.topology.bonds.empty()) {
    EXPECT_GT(items, 0);
  }
}

TEST_P(ImportPart, EachDomainsMoleculesByAnchorAreTheWholeScenesCutBitForBit) {
  const ImportCase& c = GetParam();
  const Whole w = load_whole(c);
  if (!c.anchors && !w.scene.topology.bonds.empty()) {
    // No image flags: no anchor before the molecules are made whole, which needs them whole.
    try {
      import_part(w.deck, w.types(), {[](const Eigen::Vector3d&) { return true; }, {}});
      ADD_FAILURE() << "a file without image flags was read by anchors";
    } catch (const InputError& e) {
      EXPECT_NE(std::string(e.what()).find("Atoms: no image flags"), std::string::npos) << e.what();
    }
    return;
  }
  for (int ranks = 1; ranks <= 4; ++ranks) {
    const DomainGrid grid = make_domain_grid(w.scene.box, ranks, nullptr, Eigen::Matrix3Xd());
    std::vector<ImportedMolecules> parts;
    for (int r = 0; r < ranks; ++r) {
      SCOPED_TRACE(std::to_string(ranks) + " domains, domain " + std::to_string(r));
      parts.push_back(import_part(w.deck, w.types(),
                                  {[&](const Eigen::Vector3d& anchor) { return grid.domain_of(anchor) == r; }, {}}));
      expect_whole_cut(w, parts.back(), c.file_velocities);
    }
    expect_tiling(w, parts);
  }
}

INSTANTIATE_TEST_SUITE_P(
    Decks, ImportPart,
    ::testing::Values(
        // 32 000 beads of data.chain (LAMMPS's example), Langevin.
        ImportCase{"kremer_grest", "inputs/kremer_grest.toml", {}},
        ImportCase{"half_melt", "inputs/half_melt.toml", {}},
        ImportCase{"lammps_chain", "inputs/lammps_chain.toml", {}, false},
        // Charges, angles, dihedrals, impropers, a water solvent; Langevin; no bonded maps (each
        // type named by its file number, the first bond of type 3).
        ImportCase{"peptide", "inputs/peptide.toml", {}},
        // coefficients = "data": the Coeffs sections and every file number per scene type.
        ImportCase{"peptide_bonded", "inputs/peptide_bonded.toml", {}},
        ImportCase{"polyelectrolyte", "inputs/polyelectrolyte.toml", {}},
        // No image flags: molecules made whole along their bonds; angles.
        ImportCase{"spce_water", "inputs/spce_water.toml", {}, true, false},
        // Scattered atom ids in no order; dihedrals; a friction per type.
        ImportCase{"trappe_pe_scaled_friction", "inputs/trappe_pe.toml", {"thermostat.scale={ CH3 = 2.0 }"}},
        // Every bonded style, bonded maps that name two file types alike; no image flags.
        ImportCase{"every_all_atom_style", "tests/decks/every_all_atom_style.toml", {}, true, false},
        ImportCase{"every_charged_style", "tests/decks/every_charged_style.toml", {}, true, false},
        // Wrapped chains without image flags, scattered ids, molecule ids with gaps.
        ImportCase{"wrapped_chains", "wrapped", {}, true, false},
        // Two file types under one name (the smallest file number kept, both listed for "data").
        ImportCase{"two_bond_types_one_name",
                   "tests/decks/every_all_atom_style.toml",
                   {"import.bond_types={ \"1\" = \"single\", \"2\" = \"single\" }",
                    "forces.stretch.bond_types={ single = { k = 500.0, r0 = 1.5 } }"},
                   true,
                   false}),
    [](const ::testing::TestParamInfo<ImportCase>& info) { return info.param.name; });

// What a rank holds after the decomposition's start, from a rank's given molecules.
struct Started {
  std::vector<int> ids;
  PartMolecules molecules;
  Eigen::Matrix3Xd x, v;
};

std::vector<Started> start_from(const Whole& w, int ranks, int source) {
  std::vector<Started> out(static_cast<size_t>(ranks));
  fake::run_ranks(ranks, [&](const Communicator& comm) {
    Started& o = out[static_cast<size_t>(comm.rank())];
    if (source == 0) {  // the whole scene's block, as DomainIntegrator::start cuts it
      const std::vector<int> mine = whole_block(w.scene.topology, w.size(), comm.size(), comm.rank());
      o.molecules = cut_part(w.particles(), mine);
      o.x.resize(3, static_cast<Eigen::Index>(mine.size()));
      o.v.resize(3, static_cast<Eigen::Index>(mine.size()));
      for (size_t k = 0; k < mine.size(); ++k)
        o.x.col(k) = w.scene.state.x.col(mine[k]), o.v.col(k) = w.scene.state.v.col(mine[k]);
    } else {
      const DomainGrid grid = make_domain_grid(w.scene.box, comm.size(), nullptr, Eigen::Matrix3Xd());
      ImportSelection select{nullptr, {comm.rank(), comm.size()}};
      if (source == 2) select.keep = [&](const Eigen::Vector3d& a) { return grid.domain_of(a) == comm.rank(); };
      ImportedMolecules part = import_part(w.deck, w.types(), select);
      o.molecules = std::move(part.molecules);
      o.x = std::move(part.x);
      o.v = std::move(part.v);
    }
    Decomposition d(w.scene.box, comm, 2.5, 0.3, nullptr);
    d.start(o.molecules, o.x, o.v);
    o.ids = d.owned_ids();
  });
  return out;
}

class ImportPartStart : public ::testing::TestWithParam<ImportCase> {};

TEST_P(ImportPartStart, StartsAsTheWholeScenesBlocksDo) {
  const ImportCase& c = GetParam();
  const Whole w = load_whole(c);
  for (int ranks = 1; ranks <= 4; ++ranks) {
    const std::vector<Started> want = start_from(w, ranks, 0);
    int moved = 0;
    for (const int source : {1, 2}) {
      if (source == 2 && !c.anchors) continue;
      const std::vector<Started> got = start_from(w, ranks, source);
      for (int r = 0; r < ranks; ++r) {
        SCOPED_TRACE(std::to_string(ranks) + " ranks, rank " + std::to_string(r) +
                     (source == 1 ? ", from blocks" : ", from anchors"));
        const Started& a = got[static_cast<size_t>(r)];
        const Started& b = want[static_cast<size_t>(r)];
        EXPECT_EQ(a.ids, b.ids);
        expect_same_molecules(a.molecules, b.molecules);
        EXPECT_TRUE(same_bits(a.x, b.x));
        EXPECT_TRUE(same_bits(a.v, b.v));
        moved += a.ids != whole_block(w.scene.topology, w.size(), ranks, r);
      }
    }
    if (ranks > 1) {
      EXPECT_GT(moved, 0) << "no molecule left its block: the start's exchange is not tested";
    }
  }
}

INSTANTIATE_TEST_SUITE_P(Decks, ImportPartStart,
                         ::testing::Values(ImportCase{"half_melt", "inputs/half_melt.toml", {}},
                                           ImportCase{"peptide", "inputs/peptide.toml", {}},
                                           ImportCase{"spce_water", "inputs/spce_water.toml", {}, true, false},
                                           ImportCase{"wrapped_chains", "wrapped", {}, true, false},
                                           ImportCase{"trappe_pe_scaled_friction",
                                                      "inputs/trappe_pe.toml",
                                                      {"thermostat.scale={ CH3 = 2.0 }"}}),
                         [](const ::testing::TestParamInfo<ImportCase>& info) { return info.param.name; });

// The whole import's refusals, worded alike and at the same deck key, on every rank.
TEST(ImportPartErrors, AnUnnamedTypeOrAMassThatDisagreesIsRefusedAsTheWholeImportRefusesIt) {
  for (const std::string& set : {std::string("import.atom_types={ \"1\" = \"O\" }"), std::string("types.H.mass=1.5"),
                                 std::string("import.angle_types={ \"2\" = \"x\" }")}) {
    SCOPED_TRACE(set);
    std::string whole;
    try {
      load_scene(Deck(test::source_path("inputs/spce_water.toml"), {set}));
      ADD_FAILURE() << "the whole import took it";
    } catch (const InputError& e) {
      whole = e.what();
    }
    const Deck deck(test::source_path("inputs/spce_water.toml"), {set});
    DeckTable root = deck.root();
    auto t = root.table("import");
    const LammpsImportDeck d = read_lammps_import(*t, std::filesystem::path(deck.path()).parent_path().string());
    std::vector<ParticleType> types = {{"O", 15.9994, "O", -0.8476}, {"H", 1.008, "H", 0.4238}};
    if (set.starts_with("types.H")) types[1].mass = 1.5;
    try {
      import_part(d, {types, 1.0, {}}, {nullptr, {0, 2}});
      ADD_FAILURE() << "the part's import took it";
    } catch (const InputError& e) {
      EXPECT_EQ(std::string(e.what()), whole);
    }
  }
}

}  // namespace
}  // namespace stiffmd
