// Staged protocols (docs/decks.md "[[stage]]", engine/run/stages.hpp): a stage's deck is the base
// deck with the stage merged over it key by key, values named where the file has them; the
// checkpoint names its stage (format version 6, version 5 read as a run without stages); the CLI
// runs the stages into OUT/<k>_<name>, checks every stage, and refuses a checkpoint of another
// stage. Restarts bit for bit on 1 and 2 ranks: tests/test_stages.py (ctest stages_restart_N).
#include <gtest/gtest.h>
#include <zlib.h>

#include <algorithm>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <functional>
#include <regex>
#include <string>
#include <vector>

#include "cli_support.hpp"
#include "core/errors.hpp"
#include "engine/deck/deck.hpp"
#include "engine/run/checkpoint.hpp"
#include "engine/run/stages.hpp"
#include "engine/scene/stage_deck.hpp"
#include "test_support.hpp"

namespace stiffmd {
namespace {

namespace fs = std::filesystem;
using test::cli;
using test::CliResult;
using test::scratch_dir;
using test::slurp;

// A small stiff scene: 4 trimers, no pair term, every stage a few steps.
const char* kBase = R"(# line 1
[box]
lengths = [20, 20, 20]
[types.bead]
mass = 1.0
[[build]]
style = "linear-chains"
type = "bead"
chains = 4
beads = 3
bond_length = 1.0
bond_type = "b"
seed = 3
[velocities]
temperature = 1.0
seed = 4
[forces.bonds]
style = "stiff-harmonic"
epsilon = 0.1
bond_types.b = { length = 1.0, alpha = 1.0 }
[integrator]
method = "projected-impulse"
h = 0.05
micro_dt = 0.005
[output]
xyz = ""
thermo_interval = 0.1
)";

const char* kStages = R"(
[[stage]]
name = "heat"
steps = 20
[stage.integrator]
h = 0.025
[stage.thermostat]
style = "langevin"
temperature = 1.0
damp = 1.0
seed = 5

[[stage]]
name = "cool"
t_end = 1.0
)";

std::string write_deck(const fs::path& dir, const std::string& name, const std::string& text) {
  const fs::path p = dir / name;
  std::ofstream(p) << text;
  return p.string();
}

std::string first_error(const std::function<void()>& f) {
  try {
    f();
  } catch (const InputError& e) {
    return e.what();
  }
  return "";
}

TEST(StageDeck, AStageIsMergedOverTheBaseDeckKeyByKey) {
  const fs::path dir = scratch_dir("stage_merge");
  const Deck base(write_deck(dir, "d.toml", std::string(kBase) + kStages), {});
  DeckTable root = base.root();
  const std::vector<StageSpec> stages = read_stages(root);
  ASSERT_EQ(stages.size(), 2u);
  EXPECT_EQ(stages[1].identity.name, "cool");
  EXPECT_EQ(stages[1].identity.number, 2);
  EXPECT_EQ(stages[1].identity.count, 2);
  EXPECT_EQ(stage_directory(stages[1].identity), "2_cool");

  const Scene heat = load_stage_scene(*stage_deck(base, stages[0]), stages[0]);
  EXPECT_EQ(heat.integrator.method, "projected-impulse");  // the base deck's
  EXPECT_EQ(heat.integrator.h, 0.025);                     // the stage's
  EXPECT_EQ(heat.integrator.micro_steps, 5);               // the base deck's micro_dt, the stage's h
  EXPECT_TRUE(heat.thermostatted());
  EXPECT_EQ(heat.integrator.thermostat.seed, 5u);  // stage 1: the deck's seed
  EXPECT_EQ(heat.run.steps, 20);
  EXPECT_EQ(heat.stage.name, "heat");
  // Every stage starts from the base deck: stage 2 has no thermostat, the base deck's h.
  const Scene cool = load_stage_scene(*stage_deck(base, stages[1]), stages[1]);
  EXPECT_FALSE(cool.thermostatted());
  EXPECT_EQ(cool.integrator.h, 0.05);
  EXPECT_EQ(cool.num_steps(), 20);
  fs::remove_all(dir);
}

TEST(StageDeck, AStageOfNoStepsHasNoRunButItsState) {
  const fs::path dir = scratch_dir("stage_zero");
  const std::string text =
      std::string(kBase) + "[[stage]]\nname = \"relax\"\nsteps = 0\n[stage.minimize]\nftol = 0.1\n";
  const Deck base(write_deck(dir, "d.toml", text), {});
  DeckTable root = base.root();
  const std::vector<StageSpec> stages = read_stages(root);
  const Scene sc = load_stage_scene(*stage_deck(base, stages[0]), stages[0]);
  EXPECT_EQ(sc.num_steps(), 0);
  EXPECT_TRUE(sc.minimize.requested);
  // A plain deck's run takes a step at least.
  const std::string plain = std::string(kBase) + "[run]\nsteps = 0\n";
  EXPECT_NE(first_error([&] { load_scene(Deck(write_deck(dir, "p.toml", plain), {})); }).find("1 .. 1e12"),
            std::string::npos);
  fs::remove_all(dir);
}

TEST(StageDeck, ErrorsNameTheStageAndTheLineWhereTheValueIsWritten) {
  const fs::path dir = scratch_dir("stage_errors");
  std::string text = std::string(kBase) + kStages;
  text.replace(text.find("h = 0.025"), 9, "h = -0.025");
  const std::string path = write_deck(dir, "d.toml", text);
  const Deck base(path, {});
  DeckTable root = base.root();
  const std::vector<StageSpec> stages = read_stages(root);
  const std::string e = first_error([&] { load_protocol(base, stages, 1); });
  int line = 1;
  for (size_t at = 0; (at = text.find('\n', at)) < text.find("h = -0.025"); ++at) ++line;
  EXPECT_EQ(e, "stage 1 (heat): " + path + ":" + std::to_string(line) +
                   ": stage[0].integrator.h: expected a macro step h > 0")
      << e;
  // A --set of a stage's key is named as given.
  const Deck set(write_deck(dir, "s.toml", std::string(kBase) + kStages), {"stage.1.t_end=0.33"});
  DeckTable set_root = set.root();
  const std::vector<StageSpec> set_stages = read_stages(set_root);
  const std::string s = first_error([&] { load_protocol(set, set_stages, 1); });
  EXPECT_EQ(s.find("stage 2 (cool): --set stage.1.t_end: stage[1].t_end: t_end = 0.33 is 6.6 macro steps"), 0u) << s;
  // A --set of the base deck's h that a stage replaces is not named where the stage's h fails.
  const Deck both(path, {"integrator.h=0.05"});
  DeckTable both_root = both.root();
  const std::vector<StageSpec> both_stages = read_stages(both_root);
  const std::string b = first_error([&] { load_protocol(both, both_stages, 1); });
  EXPECT_EQ(b.find("--set"), std::string::npos) << b;
  fs::remove_all(dir);
}

TEST(StageDeck, NoiseSeedsAreTheStages) {
  EXPECT_EQ(stage_seed(7, 1), 7u);
  EXPECT_NE(stage_seed(7, 2), 7u);
  EXPECT_NE(stage_seed(7, 2), stage_seed(7, 3));
  EXPECT_NE(stage_seed(7, 2), stage_seed(8, 2));
}

// A checkpoint as version 5 wrote it: without the stage's number and name after the method, and
// without the box block before the force terms' count (a checkpoint without force terms: the last
// 8 bytes are that count).
std::string as_version_5(std::string b, const std::string& method) {
  b.erase(b.size() - 8 - (8 + 6 * 8), 8 + 6 * 8);  // the box: u64 count 6 and six doubles
  const std::size_t after_method = 40 + 8 + 8 + 8 + 8 + 8 + method.size();
  b.erase(after_method, 16);  // stage 0 (i64), name "" (u64 length 0)
  const std::uint32_t five = 5;
  std::memcpy(b.data() + 12, &five, 4);
  const std::uint64_t length = b.size();
  std::memcpy(b.data() + 24, &length, 8);
  const auto crc = static_cast<std::uint32_t>(
      ::crc32(0, reinterpret_cast<const Bytef*>(b.data() + 12), static_cast<uInt>(b.size() - 12)));
  std::memcpy(b.data() + 8, &crc, 4);
  return b;
}

TEST(StageCheckpoint, NamesItsStageAndReadsVersionFiveAsNone) {
  const fs::path dir = scratch_dir("stage_checkpoint");
  Checkpoint c;
  c.state.x = Eigen::Matrix3Xd::Random(3, 4);
  c.state.v = Eigen::Matrix3Xd::Random(3, 4);
  c.state.inv_mass = Eigen::VectorXd::Ones(4);
  c.state.step = 12;
  c.state.t = 0.6;
  c.method = "rattle";
  c.h = 0.05;
  c.run_state.assign(4, 0.0);
  c.stage = 2;
  c.stage_name = "equilibrate";
  const std::string staged = (dir / "staged.bin").string(), plain = (dir / "plain.bin").string();
  write_checkpoint(staged, c);
  Checkpoint back = read_checkpoint(staged);
  EXPECT_EQ(back.stage, 2);
  EXPECT_EQ(back.stage_name, "equilibrate");
  EXPECT_EQ(back.state.x, c.state.x);

  c.stage = 0;
  c.stage_name.clear();
  write_checkpoint(plain, c);
  const std::string v5 = (dir / "v5.bin").string();
  std::ofstream(v5, std::ios::binary) << as_version_5(slurp(plain), c.method);
  back = read_checkpoint(v5);
  EXPECT_EQ(back.stage, 0);
  EXPECT_EQ(back.stage_name, "");
  EXPECT_EQ(back.state.x, c.state.x);
  EXPECT_EQ(back.state.v, c.state.v);
  EXPECT_EQ(back.state.step, 12);
  EXPECT_EQ(back.method, "rattle");
  EXPECT_FALSE(back.has_box);  // the deck's box stays
  EXPECT_TRUE(read_checkpoint(plain).has_box);
  fs::remove_all(dir);
}

bool has(const std::string& text, const std::string& part) {
  return text.find(part) != std::string::npos;
}

int lines(const std::string& s) {
  return static_cast<int>(std::count(s.begin(), s.end(), '\n'));
}

TEST(StageCli, RunsTheStagesIntoTheirDirectoriesAndListsThem) {
  const fs::path dir = scratch_dir("stage_run");
  const fs::path out = dir / "out";
  const CliResult r = cli("run " + test::source_path("inputs/staged_chains.toml") + " -o " + out.string() +
                          " --no-progress --set stage.1.steps=20 --set stage.2.t_end=0.2");
  ASSERT_EQ(r.code, 0) << r.err;
  for (const char* line : {"stage 1/3 relax -> ", "stage 2/3 equilibrate -> ", "stage 3/3 produce -> "})
    EXPECT_TRUE(has(r.out, line)) << r.out;
  EXPECT_TRUE(has(r.err, "minimize: FIRE stopped by")) << r.err;  // stage 1's, on stderr
  for (const char* stage : {"1_relax", "2_equilibrate", "3_produce"})
    for (const char* file : {"thermo.csv", "checkpoint.bin", "summary.json"})
      EXPECT_TRUE(fs::exists(out / stage / file)) << stage << "/" << file;
  EXPECT_TRUE(fs::exists(out / "3_produce" / "trajectory.h5md"));  // the stage's [output]
  const std::string relax = slurp(out / "1_relax" / "summary.json");
  EXPECT_TRUE(has(relax, "\"stage\": {\"number\": 1, \"of\": 3, \"name\": \"relax\"}")) << relax;
  EXPECT_TRUE(has(relax, "\"minimize\": {\"style\": \"fire\"")) << relax;
  EXPECT_TRUE(has(relax, "\"steps\": 0,")) << relax;
  const std::string equilibrate = slurp(out / "2_equilibrate" / "summary.json");
  EXPECT_TRUE(has(equilibrate, "\"steps\": 20,")) << equilibrate;
  EXPECT_FALSE(has(equilibrate, "\"minimize\"")) << equilibrate;
  // Each stage's time from 0: the produce stage's thermo rows end at its own t_end.
  const std::string thermo = slurp(out / "3_produce" / "thermo.csv");
  EXPECT_TRUE(std::regex_search(thermo, std::regex("\n0\\.2,10,"))) << thermo.substr(thermo.size() - 300);
  const std::string protocol = slurp(out / "protocol.json");
  for (const char* part : {"\"restarted_from\": null", "\"number\": 2, \"name\": \"equilibrate\"", "\"steps\": 20",
                           "\"method\": \"fixman\"", "\"final_energy\": ", "\"wall_seconds\": "})
    EXPECT_TRUE(has(protocol, part)) << part << "\n" << protocol;
  EXPECT_TRUE(has(protocol, (out / "3_produce" / "summary.json").string())) << protocol;
  fs::remove_all(dir);
}

TEST(StageCli, CheckChecksEveryStageAndPrintsItsSettings) {
  const CliResult r = cli("check " + test::source_path("inputs/staged_chains.toml"));
  ASSERT_EQ(r.code, 0) << r.err;
  EXPECT_TRUE(has(r.out, "stages:      3\n")) << r.out;
  EXPECT_TRUE(has(r.out, "stage 2/3 equilibrate:\n  integrator:  rattle, h = 0.02\n  thermostat:  langevin")) << r.out;
  EXPECT_TRUE(has(r.out, "stage 3/3 produce:\n  integrator:  fixman, h = 0.02\n")) << r.out;
  EXPECT_TRUE(has(r.out, "deck is valid")) << r.out;
  EXPECT_FALSE(has(r.err, "minimize: FIRE stopped")) << "check of a later stage does not minimise";
}

// A one-stage protocol is the plain run of its deck: the same thermo file, bit for bit.
TEST(StageCli, OneStageIsThePlainRunOfItsDeck) {
  const fs::path dir = scratch_dir("stage_one");
  const std::string staged = write_deck(dir, "staged.toml", std::string(kBase) + R"(
[[stage]]
name = "only"
t_end = 1.0
[stage.thermostat]
style = "langevin"
temperature = 1.0
damp = 1.0
seed = 5
)");
  const std::string plain = write_deck(dir, "plain.toml", std::string(kBase) + R"(
[run]
t_end = 1.0
[thermostat]
style = "langevin"
temperature = 1.0
damp = 1.0
seed = 5
)");
  ASSERT_EQ(cli("run " + staged + " -q --no-progress -o " + (dir / "a").string()).code, 0);
  ASSERT_EQ(cli("run " + plain + " -q --no-progress -o " + (dir / "b").string()).code, 0);
  EXPECT_EQ(slurp(dir / "a" / "1_only" / "thermo.csv"), slurp(dir / "b" / "thermo.csv"));
  fs::remove_all(dir);
}

// The deck's overlapping beads are stage 1's to relax ([stage.minimize]); a later stage, which
// starts from the relaxed state, is not refused for them.
TEST(StageCli, AStageThatMinimisesRelaxesTheDecksOverlap) {
  const fs::path dir = scratch_dir("stage_overlap");
  std::string text = slurp(test::source_path("inputs/minimize_overlap.toml"));
  const auto minimize = text.find("\n[minimize]") + 1, integrator = text.find("\n[integrator]") + 1;
  const std::string table = text.substr(minimize, integrator - minimize);
  text.erase(minimize, integrator - minimize);
  text.erase(text.find("\n[run]") + 1);
  const std::string deck = write_deck(dir, "overlap.toml",
                                      text + "[[stage]]\nname = \"relax\"\nsteps = 0\n[stage.minimize]" +
                                          table.substr(table.find('\n')) + "[[stage]]\nname = \"run\"\nsteps = 20\n");
  const CliResult r = cli("run " + deck + " -q --no-progress -o " + (dir / "out").string());
  EXPECT_EQ(r.code, 0) << r.err;
  EXPECT_TRUE(has(r.err, "minimize: FIRE stopped by ftol")) << r.err;
  EXPECT_TRUE(fs::exists(dir / "out" / "2_run" / "summary.json"));
  // Without the minimisation, stage 1 is refused for the overlap.
  std::string bare = slurp(deck);
  bare.erase(bare.find("[stage.minimize]"), bare.find("[[stage]]\nname = \"run\"") - bare.find("[stage.minimize]"));
  const CliResult refused = cli("check " + write_deck(dir, "bare.toml", bare));
  EXPECT_EQ(refused.code, 2);
  EXPECT_TRUE(has(refused.err, "stage 1 (relax): ")) << refused.err;
  fs::remove_all(dir);
}

TEST(StageCli, ACheckpointOfAnotherStageOrOfNoneIsRefused) {
  const fs::path dir = scratch_dir("stage_refuse");
  const std::string staged = write_deck(dir, "staged.toml", std::string(kBase) + kStages);
  const std::string plain = write_deck(dir, "plain.toml", std::string(kBase) + "[run]\nt_end = 1.0\n");
  const fs::path out = dir / "out", other = dir / "other";
  ASSERT_EQ(cli("run " + staged + " -q --no-progress -o " + out.string()).code, 0);
  ASSERT_EQ(cli("run " + plain + " -q --no-progress -o " + other.string()).code, 0);
  const std::string heat = (out / "1_heat" / "checkpoint.bin").string();
  const std::string cool = (out / "2_cool" / "checkpoint.bin").string();
  struct Case {
    std::string args, expected;
  };
  const std::vector<Case> cases = {
      {plain + " --restart " + heat,
       "checkpoint of stage 1 (heat) of a staged protocol, and the deck has no [[stage]]"},
      {staged + " --restart " + (other / "checkpoint.bin").string(),
       "checkpoint of a run without stages, and the deck is a protocol of 2 stages"},
      {staged + " --set stage.0.name=warm --restart " + heat,
       "checkpoint of stage 1 (heat), and the deck's stage 1 is named \"warm\""},
      {staged + " --restart " + cool, "checkpoint at the end of stage 2 (cool), the protocol's last stage"},
  };
  for (const Case& c : cases) {
    const CliResult r = cli("run " + c.args + " -q --no-progress -o " + (dir / "again").string());
    EXPECT_EQ(r.code, 2) << c.args << "\n" << r.err;
    EXPECT_EQ(lines(r.err), 1) << r.err;
    EXPECT_TRUE(has(r.err, c.expected)) << r.err;
    EXPECT_FALSE(fs::exists(dir / "again"));
  }
  // The final checkpoint of stage 1 starts stage 2 from its state: the uninterrupted files.
  fs::copy(out, dir / "copy", fs::copy_options::recursive);
  fs::remove_all(dir / "copy" / "2_cool");
  const CliResult r = cli("run " + staged + " -q --no-progress -o " + (dir / "copy").string() + " --restart " +
                          (dir / "copy" / "1_heat" / "checkpoint.bin").string());
  ASSERT_EQ(r.code, 0) << r.err;
  EXPECT_TRUE(has(r.err, "stage 1 (heat) ended at step 20; stage 2 (cool) starts from its state")) << r.err;
  EXPECT_EQ(slurp(dir / "copy" / "2_cool" / "thermo.csv"), slurp(out / "2_cool" / "thermo.csv"));
  EXPECT_EQ(slurp(dir / "copy" / "2_cool" / "checkpoint.bin"), slurp(out / "2_cool" / "checkpoint.bin"));
  fs::remove_all(dir);
}

}  // namespace
}  // namespace stiffmd
