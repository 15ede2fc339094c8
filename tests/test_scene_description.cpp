// The scene's description (load_scene with SceneContent::description, engine/scene/scene.hpp):
// the [[build]]s of linear chains grown by molecule counted, not built. Against the whole load of
// the same deck it holds no particle or item, counts the particles it left out, and agrees on
// everything else — types, units, box, settings, notes, sources, topology type names, LAMMPS
// coefficients, the monitor, `describe` but for the terms' own lines, and each force term's
// description (on_subset on no particle, then define) — so that part_source and chains_part give
// the same answers from it (chains_part's parts bit for bit on 1–3 fake ranks). A deck it cannot
// stand for loads whole; bad input gives the whole load's message.
#include <gtest/gtest.h>
#include <sys/resource.h>

#include <bit>
#include <chrono>
#include <filesystem>
#include <fstream>
#include <sstream>
#include <string>
#include <tuple>
#include <vector>

#include "core/errors.hpp"
#include "engine/domain/part_load.hpp"
#include "engine/run/checkpoint.hpp"
#include "engine/scene/kspace_deck.hpp"
#include "fake_processes.hpp"
#include "forcefields/kspace/ewald_sum.hpp"
#include "forcefields/kspace/pppm.hpp"
#include "forcefields/pair_potentials.hpp"
#include "forcefields/pair_term.hpp"
#include "forcefields/parameter_record.hpp"
#include "forcefields/particle_subset.hpp"

namespace stiffmd {
namespace {

using fake::run_ranks;

std::string tree_path(const std::string& rel) {
  return std::string(STIFFMD_SOURCE_DIR) + "/" + rel;
}

struct DescribedDeck {
  const char* deck;
  std::vector<std::string> overrides;
};

const DescribedDeck kDecks[] = {
    {"tests/decks/chains_by_parts.toml", {}},
    {"inputs/melt_minimize_by_parts.toml", {}},
    {"tests/decks/melt_million_parts.toml", {"build.0.chains=200"}},
    {"tests/decks/charged_chains_by_parts.toml", {}},
    {"inputs/stiff_melt_by_parts.toml", {}},
    {"inputs/stiff_melt_by_parts.toml", {"integrator.method=\"fixman\"", "integrator.h=0.02"}},
};

// A term's description's definition: the term made again on a subset of no particle.
std::uint64_t description_of(const ForceTerm& term, const Box& box) {
  const std::vector<int> none;
  const Topology empty;
  const ParticleSubset nobody{none, none, empty};
  ParameterRecord r;
  term.on_subset(nobody, box)->define(r);
  return r.value();
}

// describe_scene up to the force terms' lines (a term describes its own items, which a
// description does not hold).
std::string scene_header(const Scene& sc) {
  const std::string s = describe_scene(sc);
  return s.substr(0, s.find("force terms:"));
}

// The notes that do not come from the particles: the pair terms' overlap finding is the whole
// load's alone.
std::vector<std::string> notes_without_overlap(const Scene& sc) {
  std::vector<std::string> out;
  for (const std::string& n : sc.notes)
    if (n.find("[minimize] relaxes them before the run") == std::string::npos) out.push_back(n);
  return out;
}

void expect_same_section(const LammpsCoeffs::Section& a, const LammpsCoeffs::Section& b) {
  EXPECT_EQ(a.style, b.style);
  EXPECT_EQ(a.representable, b.representable);
  EXPECT_EQ(a.pairwise, b.pairwise);
  EXPECT_EQ(a.rows, b.rows);
}

// Everything but the particles and items: the whole load's.
void expect_same_description(const Scene& whole, const Scene& desc) {
  ASSERT_EQ(desc.types.size(), whole.types.size());
  for (size_t k = 0; k < whole.types.size(); ++k) {
    EXPECT_EQ(desc.types[k].name, whole.types[k].name);
    EXPECT_EQ(desc.types[k].mass, whole.types[k].mass);
    EXPECT_EQ(desc.types[k].element, whole.types[k].element);
    EXPECT_EQ(desc.types[k].charge, whole.types[k].charge);
  }
  EXPECT_EQ(desc.units.name, whole.units.name);
  EXPECT_EQ(desc.units.time, whole.units.time);
  EXPECT_EQ(desc.units.coulomb, whole.units.coulomb);
  EXPECT_TRUE(desc.box.origin == whole.box.origin);
  EXPECT_TRUE(desc.box.lengths == whole.box.lengths);  // bit for bit
  EXPECT_TRUE(desc.box.periodic == whole.box.periodic);
  EXPECT_EQ(desc.box_from_source, whole.box_from_source);
  const IntegratorSettings &a = desc.integrator, &b = whole.integrator;
  EXPECT_EQ(a.method, b.method);
  EXPECT_EQ(a.h, b.h);
  EXPECT_EQ(a.micro_steps, b.micro_steps);
  EXPECT_EQ(a.levels.size(), b.levels.size());
  EXPECT_EQ(a.thermostat.style, b.thermostat.style);
  EXPECT_EQ(a.thermostat.splitting, b.thermostat.splitting);
  EXPECT_EQ(a.thermostat.temperature, b.thermostat.temperature);
  EXPECT_EQ(a.thermostat.tau, b.thermostat.tau);
  EXPECT_EQ(a.thermostat.seed, b.thermostat.seed);
  EXPECT_EQ(a.barostat.on, b.barostat.on);
  EXPECT_EQ(desc.num_steps(), whole.num_steps());
  EXPECT_EQ(desc.run.t_end, whole.run.t_end);
  EXPECT_EQ(desc.minimize.requested, whole.minimize.requested);
  EXPECT_EQ(desc.minimize.max_force, whole.minimize.max_force);
  EXPECT_EQ(describe_settings(desc), describe_settings(whole));
  // The stiff bonds a description counts by type: their number and what the monitor reads of them.
  EXPECT_EQ(whole_stiff_bonds(desc), whole_stiff_bonds(whole));
  EXPECT_EQ(desc.monitor.scene.min_bond_length, whole.monitor.scene.min_bond_length);
  EXPECT_EQ(desc.monitor.scene.likely_cause, whole.monitor.scene.likely_cause);
  EXPECT_EQ(desc.monitor.bond_deviation, whole.monitor.bond_deviation);
  EXPECT_EQ(scene_header(desc), scene_header(whole));
  EXPECT_EQ(desc.notes, notes_without_overlap(whole));
  EXPECT_EQ(output_files(desc), output_files(whole));
  EXPECT_EQ(desc.charged(), whole.charged());
  // The monitor's defaults, from the thermostat's frictions and the stiff bonds.
  EXPECT_EQ(desc.monitor.energy_error, whole.monitor.energy_error);
  EXPECT_EQ(desc.monitor.temperature_deviation, whole.monitor.temperature_deviation);
  EXPECT_EQ(desc.monitor.energy_runaway, whole.monitor.energy_runaway);
  EXPECT_EQ(desc.monitor.scene.relaxation, whole.monitor.scene.relaxation);
  EXPECT_EQ(desc.monitor.scene.kT, whole.monitor.scene.kT);
  EXPECT_EQ(desc.monitor.scene.min_bond_length, whole.monitor.scene.min_bond_length);
  ASSERT_EQ(desc.sources.size(), whole.sources.size());
  for (size_t k = 0; k < whole.sources.size(); ++k) {
    EXPECT_EQ(desc.sources[k].first, whole.sources[k].first);
    EXPECT_EQ(desc.sources[k].count, whole.sources[k].count);
    EXPECT_EQ(desc.sources[k].what, whole.sources[k].what);
  }
  EXPECT_EQ(desc.topology.bond_types, whole.topology.bond_types);
  EXPECT_EQ(desc.topology.angle_types, whole.topology.angle_types);
  EXPECT_EQ(desc.topology.dihedral_types, whole.topology.dihedral_types);
  EXPECT_EQ(desc.topology.improper_types, whole.topology.improper_types);
  expect_same_section(desc.lammps_coeffs.pair, whole.lammps_coeffs.pair);
  expect_same_section(desc.lammps_coeffs.bond, whole.lammps_coeffs.bond);
  expect_same_section(desc.lammps_coeffs.angle, whole.lammps_coeffs.angle);
  expect_same_section(desc.lammps_coeffs.dihedral, whole.lammps_coeffs.dihedral);
  const auto &dt = desc.forces->terms(), &wt = whole.forces->terms();
  ASSERT_EQ(dt.size(), wt.size());
  EXPECT_EQ(desc.forces->num_levels(), whole.forces->num_levels());
  for (size_t k = 0; k < wt.size(); ++k) {
    SCOPED_TRACE("term " + wt[k]->name());
    EXPECT_EQ(dt[k]->name(), wt[k]->name());
    EXPECT_EQ(std::string(dt[k]->style()), std::string(wt[k]->style()));
    EXPECT_EQ(dt[k]->level(), wt[k]->level());
    EXPECT_EQ(description_of(*dt[k], desc.box), description_of(*wt[k], whole.box));
  }
}

// Every field of a bonded item: its particles and its type.
std::tuple<int, int, int> fields(const Bond& b) {
  return {b.i, b.j, b.type};
}
std::tuple<int, int, int, int> fields(const Angle& a) {
  return {a.i, a.j, a.k, a.type};
}
std::tuple<int, int, int, int, int> fields(const Dihedral& d) {
  return {d.i, d.j, d.k, d.l, d.type};
}
std::tuple<int, int, int, int, int> fields(const Improper& d) {
  return {d.i, d.j, d.k, d.l, d.type};
}

template <class Item>
void expect_same_items(const std::vector<PartMolecules::Placed<Item>>& got,
                       const std::vector<PartMolecules::Placed<Item>>& want) {
  ASSERT_EQ(got.size(), want.size());
  for (size_t k = 0; k < got.size(); ++k) {
    EXPECT_EQ(got[k].place, want[k].place);
    EXPECT_EQ(fields(got[k].item), fields(want[k].item));
  }
}

// One rank's part made from the description and from the whole scene: every column, item,
// position and velocity bit for bit.
void expect_same_part(const ScenePart& got, const ScenePart& want) {
  EXPECT_EQ(got.molecules.global, want.molecules.global);
  EXPECT_EQ(got.molecules.inv_mass, want.molecules.inv_mass);
  EXPECT_EQ(got.molecules.charge, want.molecules.charge);
  EXPECT_EQ(got.molecules.type, want.molecules.type);
  EXPECT_EQ(got.molecules.molecule_id, want.molecules.molecule_id);
  EXPECT_EQ(got.molecules.friction, want.molecules.friction);
  expect_same_items(got.molecules.bonds, want.molecules.bonds);
  expect_same_items(got.molecules.angles, want.molecules.angles);
  expect_same_items(got.molecules.dihedrals, want.molecules.dihedrals);
  expect_same_items(got.molecules.impropers, want.molecules.impropers);
  ASSERT_EQ(got.x.cols(), want.x.cols());
  ASSERT_EQ(got.v.cols(), want.v.cols());
  EXPECT_TRUE((got.x.array() == want.x.array()).all());
  EXPECT_TRUE((got.v.array() == want.v.array()).all());
}

// chains_part from either scene on `ranks` fake ranks: the same parts bit for bit.
void expect_same_chains_parts(const Deck& deck, const Scene& whole, const Scene& desc, int ranks) {
  std::vector<ScenePart> from_whole(static_cast<size_t>(ranks)), from_desc(static_cast<size_t>(ranks));
  run_ranks(ranks, [&](const Communicator& comm) {
    from_whole[static_cast<size_t>(comm.rank())] = chains_part(deck, whole, comm);
    from_desc[static_cast<size_t>(comm.rank())] = chains_part(deck, desc, comm);
  });
  int covered = 0;
  for (int r = 0; r < ranks; ++r) {
    SCOPED_TRACE("rank " + std::to_string(r) + " of " + std::to_string(ranks));
    const ScenePart &g = from_desc[static_cast<size_t>(r)], &w = from_whole[static_cast<size_t>(r)];
    covered += g.molecules.size();
    expect_same_part(g, w);
  }
  EXPECT_EQ(covered, whole.state.size());
}

class SceneDescription : public ::testing::TestWithParam<int> {};

TEST_P(SceneDescription, IsTheWholeSceneWithoutItsParticles) {
  const DescribedDeck& d = kDecks[GetParam()];
  SCOPED_TRACE(d.deck);
  const Deck deck(tree_path(d.deck), d.overrides);
  const Scene whole = load_scene(deck);
  const Scene desc = load_scene(deck, {}, SceneContent::description);
  ASSERT_FALSE(whole.described());
  ASSERT_TRUE(desc.described());
  EXPECT_EQ(whole.undescribed_particles, 0);
  EXPECT_EQ(desc.undescribed_particles, whole.state.size());
  EXPECT_EQ(desc.whole_particles(), whole.whole_particles());
  // Nothing of the particles' size.
  EXPECT_EQ(desc.state.size(), 0);
  EXPECT_EQ(desc.state.x.cols(), 0);
  EXPECT_EQ(desc.state.v.cols(), 0);
  EXPECT_TRUE(desc.particle_type.empty());
  EXPECT_TRUE(desc.charge.empty());
  EXPECT_TRUE(desc.topology.bonds.empty());
  EXPECT_TRUE(desc.topology.angles.empty());
  EXPECT_TRUE(desc.topology.dihedrals.empty());
  EXPECT_TRUE(desc.topology.impropers.empty());
  EXPECT_TRUE(desc.topology.molecule.empty());
  EXPECT_EQ(desc.integrator.thermostat.friction.size(), 0);
  expect_same_description(whole, desc);

  const PartSource from_whole = part_source(deck, whole), from_desc = part_source(deck, desc);
  EXPECT_EQ(from_desc.make, from_whole.make);
  EXPECT_EQ(from_desc.refusal, from_whole.refusal);
  ASSERT_EQ(from_whole.make, &chains_part);
  for (int ranks = 1; ranks <= 3; ++ranks) expect_same_chains_parts(deck, whole, desc, ranks);
}

INSTANTIATE_TEST_SUITE_P(Decks, SceneDescription, ::testing::Range(0, static_cast<int>(std::size(kDecks))));

// The charged deck's description is charged, from its type's charge, and its net charge is the
// whole sum's to the bit (the warning's number).
TEST(SceneDescription, ChargedFromTheTypes) {
  const Deck deck(tree_path("tests/decks/charged_chains_by_parts.toml"), {});
  const Scene desc = load_scene(deck, {}, SceneContent::description);
  ASSERT_TRUE(desc.described());
  EXPECT_TRUE(desc.charge.empty());
  EXPECT_TRUE(desc.charged());
  ASSERT_EQ(desc.notes.size(), 1u);
  EXPECT_NE(desc.notes[0].find("net charge is 75 e"), std::string::npos) << desc.notes[0];
}

// A deck of [[particles]] has nothing to describe: the description is the whole scene.
TEST(SceneDescription, ParticlesLoadWhole) {
  const Deck deck(tree_path("tests/decks/periodic_free.toml"), {});
  const Scene whole = load_scene(deck);
  const Scene desc = load_scene(deck, {}, SceneContent::description);
  EXPECT_FALSE(desc.described());
  EXPECT_TRUE(desc.described_sources.empty());
  EXPECT_EQ(desc.state.size(), whole.state.size());
  EXPECT_TRUE(desc.state.x == whole.state.x);
  EXPECT_TRUE(desc.state.v == whole.state.v);
  EXPECT_EQ(desc.particle_type, whole.particle_type);
  EXPECT_EQ(describe(desc), describe(whole));
}

// Decks the description cannot stand for load whole: a term that reads every particle (here
// gravity, holding every mass), a barostat, and a builder grown together after the chains.
TEST(SceneDescription, DecksItCannotStandForLoadWhole) {
  const std::vector<std::vector<std::string>> overrides = {
      {"forces.fall={ style = \"gravity\", g = [0.0, 0.0, -0.1] }"},
      {"barostat={ style = \"c-rescale\", pressure = 1.0, tau = 1.0, compressibility = 1.0 }"},
  };
  for (const auto& o : overrides) {
    SCOPED_TRACE(o.front());
    const Deck deck(tree_path("tests/decks/chains_by_parts.toml"), o);
    std::string whole_error, desc_error;
    Scene whole, desc;
    try {
      whole = load_scene(deck);
    } catch (const InputError& e) {
      whole_error = e.what();
    }
    try {
      desc = load_scene(deck, {}, SceneContent::description);
    } catch (const InputError& e) {
      desc_error = e.what();
    }
    EXPECT_EQ(desc_error, whole_error);
    if (!whole_error.empty()) continue;
    EXPECT_FALSE(desc.described());
    EXPECT_EQ(desc.state.size(), whole.state.size());
    EXPECT_EQ(describe(desc), describe(whole));
  }
}

// The text of tests/decks/chains_by_parts.toml with `from` replaced by `to`.
std::string chains_deck_with(const std::string& from, const std::string& to) {
  std::ifstream in(tree_path("tests/decks/chains_by_parts.toml"));
  std::stringstream s;
  s << in.rdbuf();
  std::string text = s.str();
  const auto at = text.find(from);
  if (at == std::string::npos) throw std::logic_error("no '" + from + "' in the deck");
  return text.replace(at, from.size(), to);
}

std::string load_error(const Deck& deck, SceneContent content) {
  try {
    load_scene(deck, {}, content);
  } catch (const InputError& e) {
    return e.what();
  }
  return "";
}

// Bad input: the whole load's message in both modes.
TEST(SceneDescription, BadInputGivesTheWholeLoadsMessage) {
  const std::vector<std::pair<std::string, std::string>> edits = {
      {"beads = 12", "beads = 1"},                              // too few beads
      {"bond_length = 0.97", "bond_length = 0.97\nbeadz = 3"},  // an unknown key
      {"min_distance = 0.8", "min_distance = -0.5"},            // the builder's own check
      {"density = 0.3", "density = 0.3\noffset = [0.0, 1.0]"},  // an offset of two numbers
      {"bond_types.backbone", "bond_types.other"},              // the chains' bond type undefined
      {"mass = 1.0\n", "mass = 1.0\ncharge = 0.5\n"},           // a charge no term acts on
      {"chains = 60", "chains = 1\n"},                          // still valid: one chain
  };
  for (const auto& [from, to] : edits) {
    SCOPED_TRACE(to);
    const Deck deck(Deck::Text{"chains.toml", chains_deck_with(from, to)}, {});
    const std::string whole = load_error(deck, SceneContent::whole);
    EXPECT_EQ(load_error(deck, SceneContent::description), whole);
    EXPECT_EQ(whole.empty(), to == "chains = 1\n");
  }
}

// [[particles]] before the chains: the chains are described, the particles loaded at their whole
// indices (the loaded particles come first).
TEST(SceneDescription, ParticlesBeforeTheChainsArePartlyDescribed) {
  const std::string text =
      chains_deck_with("\n[[build]]\n",
                       "\n[[particles]]\ntype = \"bead\"\nposition = [0.5, 0.5, 0.5]\n\n"
                       "[[particles]]\ntype = \"bead\"\nposition = [2.0, 0.5, 0.5]\n\n[[build]]\n");
  const Deck deck(Deck::Text{"mixed.toml", text}, {});
  const Scene whole = load_scene(deck);
  const Scene desc = load_scene(deck, {}, SceneContent::description);
  ASSERT_TRUE(desc.described());
  EXPECT_EQ(desc.state.size(), 2);
  EXPECT_EQ(desc.undescribed_particles, whole.state.size() - 2);
  EXPECT_TRUE(desc.state.x == whole.state.x.leftCols(2));
  EXPECT_EQ(scene_header(desc), scene_header(whole));
  EXPECT_EQ(describe_settings(desc), describe_settings(whole));
  ASSERT_EQ(desc.sources.size(), 3u);
  EXPECT_EQ(desc.sources[2].first, 2);
  EXPECT_EQ(desc.sources[2].count, whole.sources[2].count);
  EXPECT_NE(part_source(deck, desc).refusal, "");  // the part path refuses [[particles]]
}

// ---------------------------------------------------------------- a LAMMPS data file

// The text of `rel` with each `from` replaced by its `to`, in order (each must be there).
std::string deck_text_with(const std::string& rel, const std::vector<std::pair<std::string, std::string>>& edits) {
  std::ifstream in(tree_path(rel));
  std::stringstream s;
  s << in.rdbuf();
  std::string text = s.str();
  for (const auto& [from, to] : edits) {
    const auto at = text.find(from);
    if (at == std::string::npos) throw std::logic_error("no '" + from + "' in " + rel);
    text.replace(at, from.size(), to);
  }
  return text;
}

// The decks whose [import] of a data file the description counts: Kremer–Grest's and the half
// melt's (FENE, Langevin), the half melt with a charge on its type (a net charge no q column
// gives), SPC/E water's file (atom_style full: two types, charges from the q column, angles) with
// flexible bonds and angles, cut-off Coulomb and a friction scaled by type, and the peptide's
// (14 atom types, angles, dihedrals, impropers; the bond and angle maps left out, so named by
// their numbers) with harmonic dihedrals in place of charmm's.
Deck import_deck(int k) {
  const std::string dir = tree_path("inputs") + "/";
  switch (k) {
    case 0:
      return Deck(tree_path("inputs/kremer_grest.toml"), {});
    case 1:
      return Deck(tree_path("inputs/half_melt.toml"), {});
    case 2:
      return Deck(
          Deck::Text{dir + "charged_half_melt.toml",
                     deck_text_with("inputs/half_melt.toml", {{"mass = 1.0\n", "mass = 1.0\ncharge = 0.5\n"},
                                                              {"[forces.lj]",
                                                               "[forces.coulomb]\nstyle = \"coul/debye\"\nkappa = 1.0\n"
                                                               "coulomb_cutoff = 2.5\nspecial_bonds = [0.0, 1.0]\n\n"
                                                               "[forces.lj]"}})},
          {});
    case 3:
      return Deck(Deck::Text{dir + "flexible_water.toml",
                             "units = \"real\"\n[types.O]\nmass = 15.9994\ncharge = -0.8476\n"
                             "[types.H]\nmass = 1.008\ncharge = 0.4238\n"
                             "[import]\nlammps_data = \"spce_water.data\"\n"
                             "atom_types = { \"1\" = \"O\", \"2\" = \"H\" }\nbond_types = { \"1\" = \"OH\" }\n"
                             "angle_types = { \"1\" = \"HOH\" }\n"
                             "[forces.bonds]\nstyle = \"harmonic-bond\"\nbond_types.OH = { k = 450.0, r0 = 1.0 }\n"
                             "[forces.angles]\nstyle = \"harmonic-angle\"\n"
                             "angle_types.HOH = { k = 55.0, theta0 = 109.47 }\n"
                             "[forces.coulomb]\nstyle = \"coul/cut\"\ncoulomb_cutoff = 9.0\n"
                             "special_bonds = [0.0, 0.0, 0.0]\n"
                             "[integrator]\nmethod = \"velocity-verlet\"\nh = 0.5\n"
                             "[thermostat]\nstyle = \"langevin\"\ntemperature = 300.0\ndamp = 100.0\nseed = 3\n"
                             "scale = { H = 2.0 }\n[run]\nt_end = 5.0\n"},
                  {});
    default: {
      std::string torsion = "[forces.dihedrals]\nstyle = \"harmonic-dihedral\"\n";
      for (int t = 1; t <= 21; ++t)
        torsion += "dihedral_types.\"" + std::to_string(t) + "\" = { K = " + std::to_string(0.1 * t) +
                   ", d = " + (t % 2 ? "1" : "-1") + ", n = " + std::to_string(1 + t % 3) + " }\n";
      std::string text = deck_text_with("inputs/peptide_bonded.toml", {{"[forces.dihedrals]", "[forces.charmm]"}});
      // The charmm table (from its header to the next table) replaced by the harmonic one.
      const auto from = text.find("[forces.charmm]"), to = text.find("[forces.impropers]");
      text.replace(from, to - from, torsion + "\n");
      return Deck(Deck::Text{dir + "harmonic_peptide.toml", text}, {});
    }
  }
}
constexpr int kImportDecks = 5;

class ImportDescription : public ::testing::TestWithParam<int> {};

// The description of a deck whose particles all come from a data file: no particle or item, the
// whole load's counts, notes, names, coefficients and terms; data_file_part makes the same parts
// from it as from the whole scene on 1–3 fake ranks; and the checkpoint's fingerprint taken by
// parts on the description is the whole scene's.
TEST_P(ImportDescription, IsTheWholeSceneWithoutItsParticles) {
  if (GetParam() == 0 && !std::filesystem::exists("/usr/share/lammps/examples/COUPLE/multiple/data.chain"))
    GTEST_SKIP() << "LAMMPS's data.chain is not installed";
  const Deck deck = import_deck(GetParam());
  SCOPED_TRACE(deck.path());
  const Scene whole = load_scene(deck);
  const Scene desc = load_scene(deck, {}, SceneContent::description);
  ASSERT_FALSE(whole.described());
  ASSERT_TRUE(desc.described());
  EXPECT_EQ(desc.undescribed_particles, whole.state.size());
  EXPECT_EQ(desc.whole_particles(), whole.whole_particles());
  EXPECT_EQ(desc.state.size(), 0);
  EXPECT_TRUE(desc.particle_type.empty());
  EXPECT_TRUE(desc.charge.empty());
  EXPECT_TRUE(desc.topology.bonds.empty());
  EXPECT_TRUE(desc.topology.angles.empty());
  EXPECT_TRUE(desc.topology.dihedrals.empty());
  EXPECT_TRUE(desc.topology.impropers.empty());
  EXPECT_TRUE(desc.topology.molecule.empty());
  EXPECT_EQ(desc.integrator.thermostat.friction.size(), 0);
  expect_same_description(whole, desc);
  EXPECT_EQ(desc.lammps_types.atom, whole.lammps_types.atom);
  EXPECT_EQ(desc.lammps_types.bond, whole.lammps_types.bond);
  EXPECT_EQ(desc.lammps_types.angle, whole.lammps_types.angle);
  EXPECT_EQ(desc.lammps_types.dihedral, whole.lammps_types.dihedral);
  EXPECT_EQ(desc.lammps_types.improper, whole.lammps_types.improper);
  EXPECT_EQ(desc.lammps_types.masses, whole.lammps_types.masses);
  EXPECT_EQ(desc.lammps_data_coeffs.file, whole.lammps_data_coeffs.file);
  ASSERT_EQ(desc.lammps_data_coeffs.sections.size(), whole.lammps_data_coeffs.sections.size());
  for (size_t k = 0; k < whole.lammps_data_coeffs.sections.size(); ++k) {
    EXPECT_EQ(desc.lammps_data_coeffs.sections[k].name, whole.lammps_data_coeffs.sections[k].name);
    EXPECT_EQ(desc.lammps_data_coeffs.sections[k].style, whole.lammps_data_coeffs.sections[k].style);
    EXPECT_EQ(desc.lammps_data_coeffs.sections[k].rows, whole.lammps_data_coeffs.sections[k].rows);
  }
  EXPECT_EQ(desc.lammps_data_coeffs.bond, whole.lammps_data_coeffs.bond);
  EXPECT_EQ(desc.lammps_data_coeffs.angle, whole.lammps_data_coeffs.angle);
  EXPECT_EQ(desc.lammps_data_coeffs.dihedral, whole.lammps_data_coeffs.dihedral);
  EXPECT_EQ(desc.lammps_data_coeffs.improper, whole.lammps_data_coeffs.improper);

  const PartSource from_whole = part_source(deck, whole), from_desc = part_source(deck, desc);
  EXPECT_EQ(from_desc.make, from_whole.make);
  EXPECT_EQ(from_desc.refusal, from_whole.refusal);
  ASSERT_EQ(from_whole.make, &data_file_part);
  for (int ranks = 1; ranks <= 3; ++ranks) {
    std::vector<ScenePart> w(static_cast<size_t>(ranks)), g(static_cast<size_t>(ranks));
    std::vector<std::uint64_t> fingerprint(static_cast<size_t>(ranks));
    run_ranks(ranks, [&](const Communicator& comm) {
      const auto r = static_cast<size_t>(comm.rank());
      w[r] = data_file_part(deck, whole, comm);
      g[r] = data_file_part(deck, desc, comm);
      fingerprint[r] = scene_fingerprint_parts(desc, g[r].molecules, comm);
    });
    int covered = 0;
    for (int r = 0; r < ranks; ++r) {
      SCOPED_TRACE("rank " + std::to_string(r) + " of " + std::to_string(ranks));
      const ScenePart &a = g[static_cast<size_t>(r)], &b = w[static_cast<size_t>(r)];
      covered += a.molecules.size();
      expect_same_part(a, b);
      EXPECT_EQ(fingerprint[static_cast<size_t>(r)], scene_fingerprint(whole));
    }
    EXPECT_EQ(covered, whole.state.size());
  }
}

INSTANTIATE_TEST_SUITE_P(Decks, ImportDescription, ::testing::Range(0, kImportDecks));

// The charged half melt: charged from its type (no q column), its net charge the whole sum's to
// the bit; the water's file: charged by its q column, and neutral as the whole scene is.
TEST(ImportDescription, ChargesFromTheTypesOrTheFile) {
  const Scene melt = load_scene(import_deck(2), {}, SceneContent::description);
  EXPECT_TRUE(melt.charged());
  ASSERT_EQ(melt.notes.size(), 1u);
  EXPECT_NE(melt.notes[0].find("net charge is 1000 e"), std::string::npos) << melt.notes[0];
  const Scene water = load_scene(import_deck(3), {}, SceneContent::description);
  EXPECT_TRUE(water.charged());
  EXPECT_TRUE(water.notes.empty());
  // No term acts on the file's charges: refused naming its first charged particle, as the whole load.
  const Deck uncharged(
      Deck::Text{tree_path("inputs") + "/no_coulomb.toml",
                 deck_text_with("inputs/half_melt.toml", {{"mass = 1.0\n", "mass = 1.0\ncharge = 0.5\n"}})},
      {});
  const std::string whole = load_error(uncharged, SceneContent::whole);
  EXPECT_NE(whole.find("particle 0 ("), std::string::npos) << whole;
  EXPECT_EQ(load_error(uncharged, SceneContent::description), whole);
}

// Bad input the description reads (the type maps, masses, an undefined bond type, the file's
// structure): the whole load's message.
TEST(ImportDescription, BadInputGivesTheWholeLoadsMessage) {
  const std::vector<std::pair<std::string, std::string>> edits = {
      {"atom_types = { \"1\" = \"bead\" }", "atom_types = { \"2\" = \"bead\" }"},   // type 1 unnamed
      {"atom_types = { \"1\" = \"bead\" }", "atom_types = { \"1\" = \"bed\" }"},    // an unknown type
      {"mass = 1.0\n", "mass = 2.0\n"},                                             // the Masses disagree
      {"bond_types = { \"1\" = \"fene\" }", "bond_types = { \"1\" = \"other\" }"},  // undefined bond type
      {"bond_types = { \"1\" = \"fene\" }", "bond_types = { \"2\" = \"fene\" }"},   // bond type 1 unnamed
      {"velocities", "velocitiez"},                                                 // an unknown key
      {"lammps_data = \"half_melt.data\"", "lammps_data = \"no_such.data\""},       // no file
      {"lammps_data = \"half_melt.data\"", "lammps_data = \".\""},                  // a directory
  };
  for (const auto& [from, to] : edits) {
    SCOPED_TRACE(to);
    std::string text = deck_text_with("inputs/half_melt.toml", {});
    if (to == "velocitiez")
      text = deck_text_with("inputs/half_melt.toml", {{"[import]\n", "[import]\nvelocitiez = true\n"}});
    else
      text = deck_text_with("inputs/half_melt.toml", {{from, to}});
    const Deck deck(Deck::Text{tree_path("inputs") + "/bad.toml", text}, {});
    const std::string whole = load_error(deck, SceneContent::whole);
    EXPECT_FALSE(whole.empty());
    EXPECT_EQ(load_error(deck, SceneContent::description), whole);
  }
}

// An XYZ import, [[particles]] beside the file, or a term that reads every particle: loaded whole.
TEST(ImportDescription, DecksItCannotStandForLoadWhole) {
  for (const char* deck : {"inputs/trappe_pe.toml", "inputs/peptide_bonded.toml", "inputs/spce_water.toml",
                           "tests/decks/every_charged_style.toml"}) {
    SCOPED_TRACE(deck);
    EXPECT_FALSE(load_scene(Deck(tree_path(deck), {}), {}, SceneContent::description).described());
  }
}

long peak_rss_kib() {
  rusage u{};
  getrusage(RUSAGE_SELF, &u);
  return u.ru_maxrss;
}

// The 10⁶-bead deck: the description's time and peak memory, then the whole load's (run by hand:
// --gtest_also_run_disabled_tests --gtest_filter='*MillionBeads*').
TEST(SceneDescription, DISABLED_MillionBeads) {
  const Deck deck(tree_path("tests/decks/melt_million_parts.toml"), {});
  const long before = peak_rss_kib();
  auto t0 = std::chrono::steady_clock::now();
  {
    const Scene desc = load_scene(deck, {}, SceneContent::description);
    EXPECT_EQ(desc.undescribed_particles, 1'000'000);
  }
  auto t1 = std::chrono::steady_clock::now();
  const long after_desc = peak_rss_kib();
  {
    const Scene whole = load_scene(deck);
    EXPECT_EQ(whole.state.size(), 1'000'000);
  }
  auto t2 = std::chrono::steady_clock::now();
  const long after_whole = peak_rss_kib();
  std::cout << "description: " << std::chrono::duration<double>(t1 - t0).count() << " s, peak RSS +"
            << (after_desc - before) / 1024.0 << " MiB\n"
            << "whole:       " << std::chrono::duration<double>(t2 - t1).count() << " s, peak RSS +"
            << (after_whole - after_desc) / 1024.0 << " MiB (over the description's)\n";
}

// ---------------------------------------------------------------- the k-space terms' parameters

// The text of the deck at `rel` with `from` replaced by `to` (nothing replaced when `from` is empty).
std::string deck_text_with(const std::string& rel, const std::string& from, const std::string& to) {
  std::ifstream in(tree_path(rel));
  std::stringstream s;
  s << in.rdbuf();
  std::string text = s.str();
  if (from.empty()) return text;
  const auto at = text.find(from);
  if (at == std::string::npos) throw std::logic_error("no '" + from + "' in " + rel);
  return text.replace(at, from.size(), to);
}

const ForceTerm& kspace_term(const Scene& sc) {
  for (const auto& t : sc.forces->terms())
    if (t->phase() == Phase::kspace) return *t;
  throw std::logic_error("no k-space term");
}

// Equal to the last bit (EXPECT_EQ on doubles would also take −0 for +0).
#define EXPECT_SAME_BITS(a, b) EXPECT_EQ(std::bit_cast<std::uint64_t>(a), std::bit_cast<std::uint64_t>(b))

// The description's k-space term has the whole load's parameters bit for bit — g_ewald, the
// resolution (kmax or mesh and order), the requested accuracy and the estimated error — and holds
// the loaded particles' charges only (none for the builder's chains: each part takes its own).
void expect_same_kspace(const Scene& whole, const Scene& desc) {
  const ForceTerm &w = kspace_term(whole), &d = kspace_term(desc);
  ASSERT_EQ(std::string(d.style()), std::string(w.style()));
  if (const auto* we = dynamic_cast<const EwaldSum*>(&w)) {
    const auto& de = dynamic_cast<const EwaldSum&>(d);
    const EwaldParameters &a = de.parameters(), &b = we->parameters();
    EXPECT_SAME_BITS(a.g_ewald, b.g_ewald);
    for (int k = 0; k < 3; ++k) EXPECT_EQ(a.kmax[k], b.kmax[k]);
    EXPECT_SAME_BITS(a.accuracy_absolute, b.accuracy_absolute);
    EXPECT_SAME_BITS(a.estimated_error, b.estimated_error);
    EXPECT_EQ(de.charges().size(), static_cast<std::size_t>(desc.state.size()));
    EXPECT_EQ(we->charges().size(), static_cast<std::size_t>(whole.state.size()));
  } else {
    const auto& wp = dynamic_cast<const ParticleParticleParticleMesh&>(w);
    const auto& dp = dynamic_cast<const ParticleParticleParticleMesh&>(d);
    const MeshParameters &a = dp.parameters(), &b = wp.parameters();
    EXPECT_SAME_BITS(a.g_ewald, b.g_ewald);
    for (int k = 0; k < 3; ++k) EXPECT_EQ(a.mesh[k], b.mesh[k]);
    EXPECT_EQ(a.order, b.order);
    EXPECT_SAME_BITS(a.accuracy_absolute, b.accuracy_absolute);
    EXPECT_SAME_BITS(a.estimated_error, b.estimated_error);
    EXPECT_EQ(dp.charges().size(), static_cast<std::size_t>(desc.state.size()));
    EXPECT_EQ(wp.charges().size(), static_cast<std::size_t>(whole.state.size()));
  }
  // The sums themselves, and the real-space terms' g (set by the k-space reader).
  const ChargeSums cw = charge_sums(whole), cd = charge_sums(desc);
  EXPECT_EQ(cd.particles, cw.particles);
  EXPECT_EQ(cd.charged, cw.charged);
  EXPECT_SAME_BITS(cd.sum_q, cw.sum_q);
  EXPECT_SAME_BITS(cd.sum_q2, cw.sum_q2);
  EXPECT_SAME_BITS(cd.max_abs, cw.max_abs);
}

// Charged chains by molecule with coul/long and PPPM or Ewald (tests/decks/charged_chains_pppm.toml):
// the description chooses the whole load's parameters from the counted beads' charge sums, at
// several sizes (one chain to 2 500 beads), orders, and with the deck's own g_ewald or resolution
// (whose error estimate counts the charged beads); and the description is the whole scene's
// everywhere else, its parts the whole scene's cut (IsTheWholeSceneWithoutItsParticles' checks).
TEST(SceneDescription, KspaceParametersAreTheWholeLoads) {
  const std::vector<std::vector<std::string>> variants = {
      {},
      {"forces.mesh.style=\"ewald\""},
      {"forces.mesh.order=3"},
      {"forces.mesh.order=7", "forces.mesh.accuracy=1e-5"},
      {"forces.mesh.g_ewald=0.9"},
      {"forces.mesh.mesh=[8, 8, 10]"},
      {"forces.mesh.style=\"ewald\"", "forces.mesh.kmax=[4, 4, 5]"},
      {"forces.mesh.style=\"ewald\"", "forces.mesh.accuracy=1e-6"},
  };
  for (const char* chains : {"1", "3", "40", "250"})
    for (const auto& v : variants) {
      std::vector<std::string> o = v;
      o.push_back(std::string("build.0.chains=") + chains);
      SCOPED_TRACE(std::string("chains = ") + chains + (v.empty() ? "" : ", " + v.front()) +
                   (v.size() > 1 ? ", " + v.back() : ""));
      const Deck deck(tree_path("tests/decks/charged_chains_pppm.toml"), o);
      const Scene whole = load_scene(deck);
      const Scene desc = load_scene(deck, {}, SceneContent::description);
      ASSERT_TRUE(desc.described());
      EXPECT_TRUE(desc.charge.empty());
      expect_same_kspace(whole, desc);
      expect_same_description(whole, desc);
      if (std::string(chains) == "40" && v.empty())
        for (int ranks = 2; ranks <= 3; ++ranks) expect_same_chains_parts(deck, whole, desc, ranks);
    }
}

// Sources in a row: [[particles]] loaded first (a partly described scene), then two builds of
// chains of opposite charges (cations +0.3 e, anions −0.1 e), each counted: the sums run over
// the loaded charges, then each build's beads in turn, the whole load's order.
TEST(SceneDescription, KspaceParametersOverLoadedAndCountedSources) {
  const std::string anions =
      "\n[[build]]\nstyle = \"linear-chains\"\ngrowth = \"by-molecule\"\ntype = \"anion\"\nchains = 37\n"
      "beads = 9\nbond_length = 0.97\nbond_type = \"backbone\"\nangle_type = \"bend\"\nmin_distance = 0.8\n"
      "seed = 45\n\n[velocities]";
  const std::string particles =
      "\n[[particles]]\ntype = \"anion\"\nposition = [0.5, 0.5, 0.5]\n\n[[particles]]\ntype = \"cation\"\n"
      "position = [3.0, 0.5, 0.5]\n\n[[build]]";
  std::string text = deck_text_with("tests/decks/charged_chains_pppm.toml", "\n[velocities]", anions);
  for (const bool loaded : {false, true})
    for (const char* style : {"pppm", "ewald"}) {
      SCOPED_TRACE(std::string(style) + (loaded ? ", two particles loaded first" : ""));
      std::string t = text;
      if (loaded) t.replace(t.find("\n[[build]]"), 10, particles);
      const Deck deck(Deck::Text{"sources.toml", t}, {std::string("forces.mesh.style=\"") + style + "\""});
      const Scene whole = load_scene(deck);
      const Scene desc = load_scene(deck, {}, SceneContent::description);
      ASSERT_TRUE(desc.described());
      ASSERT_EQ(desc.described_sources.size(), 2u);
      EXPECT_EQ(desc.state.size(), loaded ? 2 : 0);
      expect_same_kspace(whole, desc);
      EXPECT_EQ(scene_header(desc), scene_header(whole));
      EXPECT_EQ(desc.notes, notes_without_overlap(whole));
    }
}

// Why the beads are summed in turn: n equal charges summed one by one are not n q² (each partial
// sum rounds), and a last bit of Σq² moves the chosen g_ewald. So a description that multiplied
// would choose other parameters than the whole load, which the tests above would see: here, on
// the charged deck's 400 beads of +0.3 e, the product's Σq² differs from the sum in turn and
// both choices' g_ewald differ, while ChargeSums::add(q, n) is n calls of add(q) to the bit.
TEST(SceneDescription, CountedChargesAreSummedInTurn) {
  const Deck deck(tree_path("tests/decks/charged_chains_pppm.toml"), {});
  const Scene whole = load_scene(deck);
  const ChargeSums listed = charge_sums(whole);
  const double q = whole.charge.front();  // every bead the cation's +0.3 e
  const std::int64_t n = whole.state.size();
  ChargeSums counted;
  counted.add(q, n);
  EXPECT_SAME_BITS(counted.sum_q, listed.sum_q);
  EXPECT_SAME_BITS(counted.sum_q2, listed.sum_q2);
  EXPECT_EQ(counted.particles, listed.particles);
  EXPECT_EQ(counted.charged, listed.charged);
  ChargeSums product = listed;
  product.sum_q2 = static_cast<double>(n) * (q * q);
  ASSERT_NE(std::bit_cast<std::uint64_t>(product.sum_q2), std::bit_cast<std::uint64_t>(listed.sum_q2));
  const double rc = 3.0;
  EXPECT_NE(std::bit_cast<std::uint64_t>(choose_pppm(1e-4, rc, product, whole.box, 1.0).g_ewald),
            std::bit_cast<std::uint64_t>(choose_pppm(1e-4, rc, listed, whole.box, 1.0).g_ewald));
  EXPECT_NE(std::bit_cast<std::uint64_t>(choose_ewald(1e-4, rc, product, whole.box, 1.0).g_ewald),
            std::bit_cast<std::uint64_t>(choose_ewald(1e-4, rc, listed, whole.box, 1.0).g_ewald));
  // And the span overloads sum the particles in their order: the whole load's parameters.
  EXPECT_SAME_BITS(choose_pppm(1e-4, rc, whole.charge, whole.box, 1.0).g_ewald,
                   choose_pppm(1e-4, rc, listed, whole.box, 1.0).g_ewald);
}

// ---------------------------------------------------------------- the pair terms' tail correction

const PairTerm<LennardJones>& lj_term(const Scene& sc, const std::string& name) {
  for (const auto& t : sc.forces->terms())
    if (t->name() == name) return dynamic_cast<const PairTerm<LennardJones>&>(*t);
  throw std::logic_error("no term " + name);
}

// The LJ tail correction Σ_ab N_a N_b etail_ab (and ptail) from the description's counted beads
// by type, added to its loaded particles' types: the whole load's bits — a melt of one type at
// several sizes, and loaded particles before two builds of two types (the unlike pair counted
// twice, as LAMMPS's Pair::init).
TEST(SceneDescription, TailCorrectionFromTheCountedTypes) {
  const std::string lj =
      "{ style = \"lj\", epsilon = 1.0, sigma = 1.0, cutoff = 2.5, tail = true, "
      "special_bonds = [0.0, 1.0, 1.0] }";
  for (const char* chains : {"12", "24", "300"}) {
    SCOPED_TRACE(std::string("melt, chains = ") + chains);
    const Deck deck(tree_path("inputs/melt_minimize_by_parts.toml"),
                    {"forces.excluded_volume=" + lj, std::string("build.0.chains=") + chains});
    const Scene whole = load_scene(deck);
    const Scene desc = load_scene(deck, {}, SceneContent::description);
    ASSERT_TRUE(desc.described());
    const auto &w = lj_term(whole, "excluded_volume"), &d = lj_term(desc, "excluded_volume");
    ASSERT_TRUE(w.tail());
    EXPECT_TRUE(d.tail());
    EXPECT_NE(w.tail_energy_volume(), 0.0);
    EXPECT_SAME_BITS(d.tail_energy_volume(), w.tail_energy_volume());
    EXPECT_SAME_BITS(d.tail_pressure_volume(), w.tail_pressure_volume());
    expect_same_description(whole, desc);
  }
  const std::string anions =
      "\n[[build]]\nstyle = \"linear-chains\"\ngrowth = \"by-molecule\"\ntype = \"anion\"\nchains = 37\n"
      "beads = 9\nbond_length = 0.97\nbond_type = \"backbone\"\nangle_type = \"bend\"\nmin_distance = 0.8\n"
      "seed = 45\n\n[velocities]";
  const std::string particles =
      "\n[[particles]]\ntype = \"anion\"\nposition = [0.5, 0.5, 0.5]\n\n[[particles]]\ntype = \"anion\"\n"
      "position = [3.0, 0.5, 0.5]\n\n[[build]]";
  std::string text = deck_text_with("tests/decks/charged_chains_pppm.toml", "\n[velocities]", anions);
  text.replace(text.find("\n[[build]]"), 10, particles);
  const Deck deck(Deck::Text{"tail.toml", text},
                  {"forces.lj={ style = \"lj\", epsilon = 1.0, sigma = 1.0, cutoff = 2.5, tail = true, "
                   "types.anion = { epsilon = 0.7, sigma = 1.2 }, types.cation = { epsilon = 1.1, sigma = 0.9 }, "
                   "special_bonds = [0.0, 1.0, 1.0] }",
                   "minimize={ style = \"fire\", max_force = 10.0 }"});
  const Scene whole = load_scene(deck);
  const Scene desc = load_scene(deck, {}, SceneContent::description);
  ASSERT_EQ(desc.described_sources.size(), 2u);
  EXPECT_EQ(desc.state.size(), 2);
  const auto &w = lj_term(whole, "lj"), &d = lj_term(desc, "lj");
  EXPECT_SAME_BITS(d.tail_energy_volume(), w.tail_energy_volume());
  EXPECT_SAME_BITS(d.tail_pressure_volume(), w.tail_pressure_volume());
  EXPECT_EQ(scene_header(desc), scene_header(whole));
}

}  // namespace
}  // namespace stiffmd
