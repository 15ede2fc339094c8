// A decomposed Run whose whole scene is made useless once its parts are built (RunOptions::started,
// engine/run/run.hpp; docs/parallel.md, "What a rank holds"): the whole system's numbers the Run,
// its thermo row and its checkpoint need — the particle count, the scene's fingerprint, the
// degrees of freedom, the row's sums, the checkpoint's blocks — come from the parts or from the
// scene as the deck made it, so that with the whole scene's per-particle arrays emptied or
// poisoned (NaN masses, positions, velocities, charges and frictions, a scrambled topology) after
// the start, thermo.csv and checkpoint.bin on 2–4 fake ranks (tests/fake_processes.hpp) are the
// bytes of the same run with the whole scene left alone, whose checkpoint holds one process's
// state and fingerprint; summary.json counts the whole system's particles. It fails if the Run
// reads a whole array after the start.
#include <gtest/gtest.h>

#include <algorithm>
#include <filesystem>
#include <fstream>
#include <functional>
#include <iterator>
#include <limits>
#include <sstream>
#include <string>
#include <vector>

#include "domain_run_support.hpp"
#include "engine/domain/part_load.hpp"
#include "engine/run/checkpoint.hpp"
#include "engine/run/run.hpp"
#include "fake_processes.hpp"
#include "test_support.hpp"

namespace stiffmd {
namespace {

namespace fs = std::filesystem;
using fake::FakeCommunicator;
using fake::run_ranks;

// A file of this source tree (not test::source_path: an inline function whose definition the
// linker may take from another test's object, built with another tree's path).
std::string tree_path(const std::string& rel) {
  return std::string(STIFFMD_SOURCE_DIR) + "/" + rel;
}

// Butane with a Langevin thermostat and a drift (molecules migrate within the run, as in
// tests/test_part_molecules.cpp), thermo rows and two periodic checkpoints; no histograms (made
// from the whole final state) and no XYZ file (its species and topology.data are the whole
// scene's).
const std::vector<std::string> kButane = {"variables.eps=0.1",
                                          "integrator.method=velocity-verlet",
                                          "integrator.h=0.002",
                                          "thermostat.style=langevin",
                                          "thermostat.temperature=1.0",
                                          "thermostat.damp=20.0",
                                          "thermostat.seed=3",
                                          "prepare.relax_steps=20",
                                          "run.steps=60",
                                          "output.thermo_interval=0.02",
                                          "output.checkpoint_interval=0.04",
                                          "observables.histograms=false",
                                          "output.xyz=\"\""};

// The stiff melt (3 000 beads) under RATTLE and csvr: rigid constraints in the degrees of freedom,
// csvr's sums over the ranks.
const std::vector<std::string> kStiffMelt = {"integrator.method=rattle",
                                             "integrator.h=0.005",
                                             "thermostat={ style = \"csvr\", temperature = 1.0, tau = 0.5, seed = 14 }",
                                             "run.steps=40",
                                             "output.xyz=\"\"",
                                             "output.thermo_interval=0.02",
                                             "output.checkpoint_interval=0.1",
                                             "observables.histograms=false"};

struct Case {
  std::string deck;
  std::vector<std::string> overrides;
  double drift = 0.0;  // added to every velocity before the run
};

Scene scene_of(const Case& c) {
  const Deck deck(tree_path(c.deck), c.overrides);
  Scene sc = load_scene(deck);
  std::ostringstream log;
  prepare_scene(sc, log);
  sc.state.v.array() += c.drift;
  return sc;
}

// Chains built by molecule, velocities by particle (engine/domain/part_load.hpp): a decomposed run
// may start from each rank's molecules made by the source.
const Case kChains{"tests/decks/chains_by_parts.toml", {}, 0.0};

std::string bytes(const fs::path& p) {
  std::ifstream in(p, std::ios::binary);
  return {std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>()};
}

// Whatever reads the whole scene's particles after the start gets NaN or another system's:
// positions, velocities, masses, charges and frictions NaN, types and molecule ids reversed,
// items joining other particles in another order; then the per-particle arrays emptied.
void poison(Scene& sc, bool empty) {
  const double nan = std::numeric_limits<double>::quiet_NaN();
  const int n = sc.state.size();
  sc.state.x.setConstant(nan);
  sc.state.v.setConstant(nan);
  sc.state.inv_mass.setConstant(nan);
  std::fill(sc.charge.begin(), sc.charge.end(), nan);
  std::reverse(sc.particle_type.begin(), sc.particle_type.end());
  sc.integrator.thermostat.friction.setConstant(nan);
  Topology& t = sc.topology;
  std::reverse(t.bonds.begin(), t.bonds.end());
  std::reverse(t.angles.begin(), t.angles.end());
  std::reverse(t.dihedrals.begin(), t.dihedrals.end());
  for (Bond& b : t.bonds) b.i = (b.i + 1) % n, b.j = (b.j + 3) % n;
  for (Angle& a : t.angles) a.i = (a.i + 5) % n;
  for (Dihedral& d : t.dihedrals) d.l = (d.l + 7) % n;
  std::reverse(t.molecule.begin(), t.molecule.end());
  if (!empty) return;
  sc.state.inv_mass.resize(0);
  sc.charge.clear();
  sc.particle_type.clear();
  sc.integrator.thermostat.friction.resize(0);
  t.bonds.clear();
  t.angles.clear();
  t.dihedrals.clear();
  t.impropers.clear();
  t.molecule.clear();
}

// A decomposed run of the case into `dir`, each rank's whole scene given to `started` once its
// parts are built (null: left as it is).
// `by_parts`: the run starts from each rank's molecules made by their source (RunOptions::part).
// `before`: what each rank's scene becomes before the Run (null: left as loaded).
void run_on_ranks(const Case& c, int ranks, const fs::path& dir, const std::function<void(Scene&)>& started,
                  bool by_parts = false, const std::function<void(Scene&)>& before = nullptr) {
  fs::remove_all(dir);
  std::vector<char> called(static_cast<size_t>(ranks), 0);
  run_ranks(
      ranks,
      [&](const FakeCommunicator& comm) {
        const test::OneThread rank_thread;
        Scene sc = scene_of(c);
        const Deck deck(tree_path(c.deck), c.overrides);
        if (before) before(sc);
        RunOptions opt;
        if (by_parts) opt.part = [&] { return chains_part(deck, sc, comm); };
        opt.out_dir = dir.string();
        opt.handle_signals = false;
        opt.processes = &comm;
        opt.started = [&] {
          if (started) started(sc);
          called[comm.rank()] = 1;
        };
        std::ostringstream log;
        run_simulation(sc, opt, log);
      },
      std::chrono::seconds(300));
  for (int r = 0; r < ranks; ++r) {
    EXPECT_TRUE(called[r]) << "rank " << r << ": the run never called `started`";
  }
}

class PartRun : public ::testing::TestWithParam<std::tuple<int, int>> {};

// The files of a run on N ranks are the same bytes with the whole scene poisoned or emptied after
// the start as without; its checkpoint holds one process's final state bit for bit and the same
// scene fingerprint (the thermo row's sums add the ranks' shares in another order than one
// process: docs/parallel.md, "The same trajectory on any number of ranks").
TEST_P(PartRun, WithTheWholeScenePoisonedAfterTheStartTheFilesAreTheSameBytes) {
  const auto [which, ranks] = GetParam();
  const Case c = which == 0 ? Case{"inputs/butane_torsions.toml", kButane, 12.0}
                            : Case{"inputs/stiff_melt_nvt.toml", kStiffMelt, 0.0};
  const test::OneThread one_thread;
  const fs::path root = fs::temp_directory_path() / ("stiffmd_part_run_" + std::to_string(::getpid()) + "_" +
                                                     std::to_string(which) + "_" + std::to_string(ranks));
  fs::remove_all(root);
  const fs::path serial_dir = root / "one", whole_dir = root / "whole", poisoned_dir = root / "poisoned";
  int particles = 0;
  {
    Scene sc = scene_of(c);
    particles = sc.state.size();
    RunOptions opt;
    opt.out_dir = serial_dir.string();
    opt.handle_signals = false;
    std::ostringstream log;
    run_simulation(sc, opt, log);
  }
  run_on_ranks(c, ranks, whole_dir, nullptr);
  const Checkpoint one = read_checkpoint((serial_dir / "checkpoint.bin").string());
  const Checkpoint decomposed = read_checkpoint((whole_dir / "checkpoint.bin").string());
  EXPECT_EQ(decomposed.scene_fingerprint, one.scene_fingerprint);
  EXPECT_TRUE(decomposed.state.x == one.state.x);
  EXPECT_TRUE(decomposed.state.v == one.state.v);
  for (const bool empty : {false, true}) {
    run_on_ranks(c, ranks, poisoned_dir, [empty](Scene& sc) { poison(sc, empty); });
    for (const char* file : {"thermo.csv", "checkpoint.bin"}) {
      const std::string want = bytes(whole_dir / file);
      ASSERT_FALSE(want.empty()) << file;
      EXPECT_TRUE(want == bytes(poisoned_dir / file))
          << file << " differs on " << ranks << " ranks (emptied: " << empty << ")";
    }
    const std::string summary = bytes(poisoned_dir / "summary.json");
    EXPECT_NE(summary.find("\"particles\": " + std::to_string(particles)), std::string::npos) << summary;
  }
  fs::remove_all(root);
}

// A run started from the source's parts (RunOptions::part) writes the bytes of the run started
// from the whole scene's cut, with the whole scene poisoned or emptied after the start too, and
// says so in summary.json (domains.setup).
class PartStartRun : public ::testing::TestWithParam<int> {};

TEST_P(PartStartRun, FromTheSourcesPartsTheFilesAreTheWholeCutsBytes) {
  const int ranks = GetParam();
  const test::OneThread one_thread;
  const fs::path root = fs::temp_directory_path() /
                        ("stiffmd_part_start_run_" + std::to_string(::getpid()) + "_" + std::to_string(ranks));
  fs::remove_all(root);
  const fs::path whole_dir = root / "whole", parts_dir = root / "parts";
  run_on_ranks(kChains, ranks, whole_dir, nullptr);
  EXPECT_NE(bytes(whole_dir / "summary.json").find("\"setup\": \"whole\""), std::string::npos);
  for (const bool empty : {false, true}) {
    run_on_ranks(
        kChains, ranks, parts_dir, [empty](Scene& sc) { poison(sc, empty); }, true);
    for (const char* file : {"thermo.csv", "checkpoint.bin"}) {
      const std::string want = bytes(whole_dir / file);
      ASSERT_FALSE(want.empty()) << file;
      EXPECT_TRUE(want == bytes(parts_dir / file))
          << file << " differs on " << ranks << " ranks (emptied: " << empty << ")";
    }
    EXPECT_NE(bytes(parts_dir / "summary.json").find("\"setup\": \"parts\""), std::string::npos);
  }
  fs::remove_all(root);
}

// A run from a scene of descriptions (no particle on any rank: every number of the whole system
// from the parts) writes the bytes of the run from the whole scene's cut: thermo.csv,
// histograms.csv (summed by parts) and checkpoint.bin; summary.json counts the whole system.
TEST_P(PartStartRun, FromTheScenesDescriptionTheFilesAreTheWholeCutsBytes) {
  const int ranks = GetParam();
  const test::OneThread one_thread;
  const fs::path root =
      fs::temp_directory_path() / ("stiffmd_described_run_" + std::to_string(::getpid()) + "_" + std::to_string(ranks));
  fs::remove_all(root);
  const Case c{kChains.deck, {"observables.histograms=true", "run.steps=60"}, 0.0};
  const fs::path whole_dir = root / "whole", described_dir = root / "described";
  run_on_ranks(c, ranks, whole_dir, nullptr);
  // Each rank's scene the deck's description (engine/scene/scene.hpp), as engine/main.cpp loads it.
  const auto describe = [&](Scene& sc) {
    sc = load_scene(Deck(tree_path(c.deck), c.overrides), {}, SceneContent::description);
    ASSERT_TRUE(sc.described());
    ASSERT_EQ(sc.state.size(), 0);
  };
  run_on_ranks(c, ranks, described_dir, nullptr, true, describe);
  for (const char* file : {"thermo.csv", "histograms.csv", "checkpoint.bin"}) {
    const std::string want = bytes(whole_dir / file);
    ASSERT_FALSE(want.empty()) << file;
    EXPECT_TRUE(want == bytes(described_dir / file)) << file << " differs on " << ranks << " ranks";
  }
  const std::string summary = bytes(described_dir / "summary.json");
  EXPECT_NE(summary.find("\"setup\": \"parts\""), std::string::npos) << summary;
  EXPECT_NE(summary.find("\"particles\": 720"), std::string::npos) << summary;
  EXPECT_NE(summary.find("\"scene\": \"description\""), std::string::npos) << summary;
  fs::remove_all(root);
}

INSTANTIATE_TEST_SUITE_P(Ranks, PartStartRun, ::testing::Values(2, 3, 4));

// One rank runs the whole scene (no parts): 2–4 ranks; the stiff melt's [prepare] on each fake
// rank is its time, so two rank counts.
INSTANTIATE_TEST_SUITE_P(Ranks, PartRun,
                         ::testing::Values(std::tuple{0, 2}, std::tuple{0, 3}, std::tuple{0, 4}, std::tuple{1, 2},
                                           std::tuple{1, 3}),
                         [](const ::testing::TestParamInfo<std::tuple<int, int>>& info) {
                           return std::string(std::get<0>(info.param) == 0 ? "butane" : "stiff_melt") + "_" +
                                  std::to_string(std::get<1>(info.param)) + "_ranks";
                         });

}  // namespace
}  // namespace stiffmd
