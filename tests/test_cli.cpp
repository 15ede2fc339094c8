// The command line end to end (docs/design.md §8): exit codes, one-line errors that name the
// file, line and key, outputs that parse.
#include <gtest/gtest.h>
#include <sys/wait.h>

#include <algorithm>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <optional>
#include <regex>
#include <sstream>
#include <string>
#include <vector>

#include "cli_support.hpp"
#include "engine/scene/force_registry.hpp"
#include "integrators/methods.hpp"
#include "test_support.hpp"

namespace stiffmd {
namespace {

namespace fs = std::filesystem;

using test::cli;
using test::CliResult;
using test::scratch_dir;
using test::slurp;

int count_lines(const std::string& s) {
  return static_cast<int>(std::count(s.begin(), s.end(), '\n'));
}

// The malformed-input corpus: tests/bad_decks/*.toml, one deck per case, each headed by
//   # What is wrong: …        what the deck gets wrong (for the reader)
//   # expect: TEXT            one or more: text the error line must contain (key, section, file, …)
//   # args: ARGS              optional: `stiffmd run` arguments instead of -o OUT; {deck} is the deck's path
//   # mkdir: NAME             optional: a directory NAME made in the output directory beforehand
//                             (the message then names that output file instead of the deck)
//   # line: none              optional: the error is about no line of the deck (an output path)
// `stiffmd run DECK -o OUT` must exit 2 — no crash (signal), no hang (a timeout kills it
// after 60 s) — with exactly one line on stderr, "error: …", naming the deck and (unless "line:
// none") a line of it, and containing every expected text; it must write no summary.json and,
// unless the case is about the output directory, not even create OUT. `stiffmd check DECK` must
// fail the same way — or succeed, for decks with args or mkdir: those are valid until run.
struct BadDeck {
  std::string path;
  std::vector<std::string> expect;
  std::string args, mkdir;
  bool names_line = true;
};

std::vector<BadDeck> bad_decks() {
  std::vector<BadDeck> out;
  for (const auto& entry : fs::directory_iterator(test::source_path("tests/bad_decks"))) {
    if (entry.path().extension() != ".toml") continue;
    BadDeck d{entry.path().string(), {}, "", "", true};
    std::istringstream lines(slurp(d.path));
    for (std::string line; std::getline(lines, line);) {
      const auto value = [&](const char* prefix) {
        return line.rfind(prefix, 0) == 0 ? std::optional<std::string>(line.substr(std::strlen(prefix))) : std::nullopt;
      };
      if (auto v = value("# expect: ")) d.expect.push_back(*v);
      if (auto v = value("# args: ")) {
        d.args = *v;
        for (size_t at; (at = d.args.find("{deck}")) != std::string::npos;) d.args.replace(at, 6, d.path);
      }
      if (auto v = value("# mkdir: ")) d.mkdir = *v;
      if (value("# line: none")) d.names_line = false;
    }
    out.push_back(std::move(d));
  }
  std::sort(out.begin(), out.end(), [](const BadDeck& a, const BadDeck& b) { return a.path < b.path; });
  return out;
}

void PrintTo(const BadDeck& d, std::ostream* os) {
  *os << d.path;
}

class MalformedDeck : public ::testing::TestWithParam<BadDeck> {};

// `file`: what the message must name, the deck or (for an obstacle in the output directory) the
// output file.
void expect_one_line_naming(const CliResult& r, const BadDeck& d, const std::string& file) {
  EXPECT_EQ(r.code, 2) << "expected exit 2 (bad input)";
  EXPECT_EQ(count_lines(r.err), 1) << "expected exactly one line on stderr";
  EXPECT_EQ(r.err.rfind("error: ", 0), 0u);
  const size_t at = r.err.find(file);
  ASSERT_NE(at, std::string::npos) << "message must name the file " << file;
  if (d.names_line) {
    EXPECT_EQ(r.err[at + file.size()], ':') << "message must name the line";
    EXPECT_TRUE(std::isdigit(static_cast<unsigned char>(r.err[at + file.size() + 1]))) << "message must name the line";
  }
  for (const auto& e : d.expect) EXPECT_NE(r.err.find(e), std::string::npos) << "missing '" << e << "'";
}

TEST_P(MalformedDeck, RunExitsTwoWithOneLineNamingFileLineAndKey) {
  const BadDeck& d = GetParam();
  ASSERT_FALSE(d.expect.empty()) << d.path << " has no '# expect:' line";
  ASSERT_EQ(slurp(d.path).rfind("# What is wrong: ", 0), 0u) << d.path << " must start with '# What is wrong: '";
  const fs::path dir = scratch_dir("bad_deck_" + fs::path(d.path).stem().string());
  const fs::path out = dir / "out";
  if (!d.mkdir.empty()) fs::create_directories(out / d.mkdir);
  const CliResult r =
      cli("run " + d.path + " --no-progress " + (d.args.empty() ? "-o " + out.string() : d.args), "timeout 60 ");
  SCOPED_TRACE(d.path + "\n" + r.err);
  expect_one_line_naming(r, d, d.mkdir.empty() ? d.path : (out / d.mkdir).string());
  EXPECT_FALSE(fs::exists(out / "summary.json")) << "a failed run must not look finished";
  if (d.args.empty() && d.mkdir.empty()) {
    EXPECT_FALSE(fs::exists(out)) << "refused before any output";
  }
  if (!d.mkdir.empty()) {
    // Refused before the first step: nothing was written next to the obstacle.
    for (const auto& e : fs::directory_iterator(out))
      EXPECT_EQ(e.path().filename().string(), d.mkdir) << "written before the error: " << e.path();
  }
  fs::remove_all(dir);
}

TEST_P(MalformedDeck, CheckExitsTwoWithTheSameLine) {
  const BadDeck& d = GetParam();
  const CliResult r = cli("check " + d.path, "timeout 60 ");
  SCOPED_TRACE(d.path + "\n" + r.err);
  if (!d.args.empty() || !d.mkdir.empty()) {
    // The case is about the output directory: the deck itself is valid.
    EXPECT_EQ(r.code, 0) << "the deck itself must be valid; only its outputs are not";
    return;
  }
  expect_one_line_naming(r, d, d.path);
}

INSTANTIATE_TEST_SUITE_P(Corpus, MalformedDeck, ::testing::ValuesIn(bad_decks()),
                         [](const ::testing::TestParamInfo<BadDeck>& info) {
                           std::string name = fs::path(info.param.path).stem().string();
                           for (char& c : name)
                             if (!std::isalnum(static_cast<unsigned char>(c))) c = '_';
                           return name;
                         });

TEST(Cli, TheMalformedDeckCorpusCoversTheCases) {
  // One deck per case; the list in the brief of what must be refused, at least.
  EXPECT_GE(bad_decks().size(), 90u);
}

TEST(Cli, MissingDirectoryAndEndlessDecksGiveExitTwo) {
  const fs::path dir = scratch_dir("missing_deck");
  const std::pair<std::string, std::string> cases[] = {
      {(dir / "no_such_deck.toml").string(), "cannot open deck file"},
      {dir.string(), "is a directory"},
      {"/dev/zero", "larger than 64 MiB"},  // read no further than a deck can be
  };
  for (const auto& [path, expected] : cases) {
    const CliResult r = cli("run " + path + " --no-progress -o " + (dir / "out").string(), "timeout 60 ");
    EXPECT_EQ(r.code, 2) << r.err;
    EXPECT_EQ(count_lines(r.err), 1) << r.err;
    EXPECT_EQ(r.err.find("error: " + path + ": " + expected), 0u) << r.err;
    EXPECT_FALSE(fs::exists(dir / "out"));
  }
  fs::remove_all(dir);
}

TEST(Cli, BadOverridesAndArgumentsGiveExitTwo) {
  const std::string deck = test::source_path("inputs/double_pendulum.toml");
  CliResult r = cli("check " + deck + " --set integrator.h=-1");
  EXPECT_EQ(r.code, 2);
  EXPECT_NE(r.err.find("--set integrator.h"), std::string::npos) << r.err;
  r = cli("check " + deck + " --set integrator.hh=1");
  EXPECT_EQ(r.code, 2);
  EXPECT_NE(r.err.find("integrator.hh: unknown key"), std::string::npos) << r.err;
  // An override of an array element is named as given, not as the deck file without a line.
  r = cli("check " + deck + " --set 'particles.1.position=[\"sqrt(-1)\", 0, 0]'");
  EXPECT_EQ(r.code, 2);
  EXPECT_EQ(r.err.find("error: --set particles.1.position: particles[1].position[0]: expression"), 0u) << r.err;
  r = cli("check " + deck + " --set noequals");
  EXPECT_EQ(r.code, 2);
  r = cli("check /nonexistent/deck.toml");
  EXPECT_EQ(r.code, 2);
  EXPECT_NE(r.err.find("/nonexistent/deck.toml"), std::string::npos);
  r = cli("frobnicate");
  EXPECT_EQ(r.code, 2);
  r = cli("");
  EXPECT_EQ(r.code, 2);
}

// A first word that is no subcommand is named, with the nearest subcommand when it looks like a
// misspelling of one (the same rule as a deck key's "did you mean").
TEST(Cli, AnUnknownSubcommandIsNamedWithTheNearestOne) {
  CliResult r = cli("runn " + test::source_path("inputs/double_pendulum.toml"));
  EXPECT_EQ(r.code, 2);
  EXPECT_EQ(r.err, "error: unknown subcommand 'runn'; did you mean 'run'?\n");
  r = cli("chek");
  EXPECT_EQ(r.code, 2);
  EXPECT_EQ(r.err, "error: unknown subcommand 'chek'; did you mean 'check'?\n");
  r = cli("frobnicate");
  EXPECT_EQ(r.code, 2);
  EXPECT_EQ(r.err, "error: unknown subcommand 'frobnicate'; expected run, check or list\n");
}

// The H5MD and state files are written only when named: an option of one given without its name
// does nothing, and says so at the key (the deck's line, or the --set). An output named "" is
// switched off on purpose: its options are quiet.
TEST(Cli, OptionsOfAnOutputThatIsNotWrittenWarnAtTheKey) {
  const std::string trimers = test::source_path("inputs/nvt_trimers.toml");
  CliResult r = cli("check " + trimers + " --set output.h5md_interval=2 --set output.h5md_velocity=true");
  ASSERT_EQ(r.code, 0) << r.err;
  EXPECT_NE(r.err.find("warning: --set output.h5md_interval: output.h5md_interval: does nothing: output.h5md is not "
                       "given, so no such file is written (e.g. output.h5md = \"trajectory.h5md\" writes one)"),
            std::string::npos)
      << r.err;
  EXPECT_NE(r.err.find("warning: --set output.h5md_velocity: output.h5md_velocity: does nothing"), std::string::npos)
      << r.err;
  r = cli("check " + trimers + " --set output.state_interval=2");
  EXPECT_NE(r.err.find("warning: --set output.state_interval: output.state_interval: does nothing: output.state is "
                       "not given"),
            std::string::npos)
      << r.err;
  r = cli("check " + trimers + " --set output.h5md_interval=2 --set 'output.h5md=\"\"'");
  EXPECT_EQ(r.err.find("warning"), std::string::npos) << r.err;
  r = cli("check " + test::source_path("inputs/double_pendulum.toml"));  // names its H5MD file
  EXPECT_EQ(r.err.find("warning"), std::string::npos) << r.err;
}

// [prepare] vibrational_temperature under a method that holds the stiff bonds rigid: its start
// projects the vibrations away, so the key warns, at its line (and with the --set that chose the
// method). The methods that keep them (the effective dynamics as its actions) are quiet.
TEST(Cli, VibrationsThatARigidMethodProjectsAwayWarnAtTheKey) {
  const std::string melt = test::source_path("tests/decks/small_melt.toml");
  for (const char* method : {"rattle", "fixman"}) {
    const CliResult r = cli("check " + melt + " --set integrator.method=" + method +
                            " --set 'thermostat={style=\"langevin\", temperature=1.0, damp=1.0, seed=1}'");
    ASSERT_EQ(r.code, 0) << r.err;
    EXPECT_NE(r.err.find("warning: " + melt +
                         ":40 (with --set integrator.method): prepare.vibrational_temperature: "
                         "method '" +
                         method + "' holds the stiff bonds rigid"),
              std::string::npos)
        << r.err;
  }
  for (const char* method : {"projected-impulse", "velocity-verlet", "effective"}) {
    const CliResult r = cli("check " + melt + " --set integrator.method=" + method);
    ASSERT_EQ(r.code, 0) << r.err;
    EXPECT_EQ(r.err.find("vibrational_temperature"), std::string::npos) << method << ": " << r.err;
  }
}

// The effective dynamics takes every constraint cluster the dense mode computation can (up to
// StiffModes::kMaxDenseBonds = 128 bonds), whatever observables.max_cluster_bonds says: data.chain's
// 99-bond chains once needed that observables setting raised. `check` builds the integrator, so
// exit 0 here means `run` builds it too.
TEST(Cli, EffectiveDynamicsDoesNotDependOnAnObservablesSetting) {
  const CliResult r = cli("check " + test::source_path("inputs/lammps_chain.toml") +
                          " --set integrator.method=effective --set observables.max_cluster_bonds=8");
  EXPECT_EQ(r.code, 0) << r.err;
}

TEST(Cli, HelpAndVersion) {
  CliResult r = cli("--help");
  EXPECT_EQ(r.code, 0);
  EXPECT_NE(r.out.find("run"), std::string::npos);
  r = cli("--version");
  EXPECT_EQ(r.code, 0);
  EXPECT_NE(r.out.find("stiffmd"), std::string::npos);
  r = cli("run --help");
  EXPECT_EQ(r.code, 0);
  EXPECT_NE(r.out.find("--set"), std::string::npos);
}

// `stiffmd list`: every method, force style, thermostat and builder a deck may name, with its
// summary; `--help` points there.
TEST(Cli, ListNamesEveryMethodAndStyle) {
  const CliResult r = cli("list");
  ASSERT_EQ(r.code, 0) << r.err;
  for (const MethodInfo& m : methods()) {
    EXPECT_NE(r.out.find(std::string(m.name)), std::string::npos) << m.name;
    EXPECT_NE(r.out.find(std::string(m.summary)), std::string::npos) << m.summary;
  }
  for (const ForceStyle& s : force_styles()) {
    EXPECT_NE(r.out.find("  " + std::string(s.name) + " "), std::string::npos) << s.name;
    EXPECT_NE(r.out.find(s.summary), std::string::npos) << s.summary;
  }
  for (const char* heading :
       {"integrator.method:", "bond styles:", "angle styles:", "dihedral styles:", "pair styles:", "external fields:",
        "thermostat.style:", "barostat.style:", "minimize.style:", "build.style:"})
    EXPECT_NE(r.out.find(heading), std::string::npos) << heading;
  for (const char* name : {"langevin", "csvr", "c-rescale", "fire", "cg", "sd", "linear-chains", "rings", "stars"})
    EXPECT_NE(r.out.find(name), std::string::npos) << name;
  EXPECT_NE(cli("--help").out.find("stiffmd list"), std::string::npos);
}

// run.steps = N ends the run at step N (t = N h), also after a restart (--set run.steps=M: to step
// M); a --set of one of run.steps and run.t_end replaces the deck's other.
TEST(Cli, RunStepsEndsAtThatStep) {
  const fs::path dir = scratch_dir("run_steps");
  const std::string deck = test::source_path("inputs/double_pendulum.toml");
  CliResult r = cli("run " + deck + " -q --no-progress --set run.steps=64 -o " + dir.string());
  ASSERT_EQ(r.code, 0) << r.err;
  EXPECT_NE(r.out.find("steps:         64 to t = 1 "), std::string::npos) << r.out;
  r = cli("run " + deck + " -q --no-progress --set run.steps=96 -o " + dir.string() + " --restart " +
          (dir / "checkpoint.bin").string());
  ASSERT_EQ(r.code, 0) << r.err;
  EXPECT_NE(r.out.find("steps:         96 to t = 1.5 "), std::string::npos) << r.out;
  r = cli("run " + deck + " -q --no-progress --set run.steps=64 -o " + dir.string() + " --restart " +
          (dir / "checkpoint.bin").string());
  EXPECT_EQ(r.code, 2);
  EXPECT_NE(r.err.find("checkpoint is at step 96, not before run.steps = 64"), std::string::npos) << r.err;
  r = cli("check " + deck + " --set run.steps=64");
  ASSERT_EQ(r.code, 0) << r.err;
  EXPECT_NE(r.out.find("(64 steps)"), std::string::npos) << r.out;
  r = cli("check " + deck + " --set run.steps=64 --set run.t_end=1");
  EXPECT_EQ(r.code, 2);
  EXPECT_NE(r.err.find("--set run.steps: run.steps: run.t_end is given too; expected either t_end (a time) or steps"),
            std::string::npos)
      << r.err;
  fs::remove_all(dir);
}

TEST(Cli, CheckDescribesTheScene) {
  const CliResult r = cli("check " + test::source_path("inputs/double_pendulum.toml"));
  EXPECT_EQ(r.code, 0) << r.err;
  EXPECT_NE(r.out.find("particles:   3 (1 fixed)"), std::string::npos) << r.out;
  EXPECT_NE(r.out.find("stiff-harmonic, fast"), std::string::npos);
  EXPECT_NE(r.out.find("gravity, slow"), std::string::npos);
}

TEST(Cli, RunsTheBundledDeckAndWritesParsableOutputs) {
  const fs::path dir = scratch_dir("run");
  const CliResult r = cli("run " + test::source_path("inputs/double_pendulum.toml") +
                          " --set run.t_end=0.5 --set integrator.h=0.0125 --set output.xyz_interval=0.1 --set "
                          "output.thermo_interval=0.05 -o " +
                          dir.string());
  ASSERT_EQ(r.code, 0) << r.err;
  EXPECT_NE(r.out.find("projected-impulse"), std::string::npos);
  EXPECT_NE(r.out.find("actions:"), std::string::npos);
  EXPECT_NE(r.out.find("max |E - E(0)|"), std::string::npos);

  // XYZ: frames at t = 0, 0.1, …, 0.5, each "3", a comment with time=, 3 particle lines.
  std::ifstream xyz(dir / "trajectory.xyz");
  std::vector<double> times;
  for (std::string count; std::getline(xyz, count);) {
    ASSERT_EQ(count, "3");
    std::string comment;
    std::getline(xyz, comment);
    std::smatch m;
    ASSERT_TRUE(std::regex_search(comment, m, std::regex(R"(time=([-+0-9.eE]+))"))) << comment;
    EXPECT_NE(comment.find("Properties=species:S:1:pos:R:3"), std::string::npos);
    times.push_back(std::stod(m[1]));
    for (int i = 0; i < 3; ++i) {
      std::string line;
      ASSERT_TRUE(std::getline(xyz, line));
      std::istringstream ls(line);
      std::string species;
      double x, y, z;
      ASSERT_TRUE(ls >> species >> x >> y >> z) << line;
      EXPECT_EQ(species, i == 0 ? "Fe" : "C");
    }
  }
  ASSERT_EQ(times.size(), 6u);
  for (size_t k = 0; k < times.size(); ++k) EXPECT_NEAR(times[k], 0.1 * k, 1e-9);

  // Thermo CSV: header row, then one row per 0.05 in time.
  std::ifstream csv(dir / "thermo.csv");
  std::string header;
  std::getline(csv, header);
  EXPECT_EQ(header,
            "time,step,kinetic,potential_slow,potential_stiff,total,energy_drift,max_violation,temperature,"
            "omega_1,omega_2,action_1,action_2,min_gap,min_resonance,alerts");
  int rows = 0;
  for (std::string line; std::getline(csv, line);) ++rows;
  EXPECT_EQ(rows, 11);

  // A second run into the same directory says that it overwrites.
  const CliResult again =
      cli("run " + test::source_path("inputs/double_pendulum.toml") + " --set run.t_end=0.015625 -o " + dir.string());
  EXPECT_EQ(again.code, 0);
  EXPECT_NE(again.err.find("overwriting"), std::string::npos);
  fs::remove_all(dir);
}

TEST(Cli, OutputIntervalIsInTimeUnitsIndependentOfTheStep) {
  const fs::path dir = scratch_dir("interval");
  for (const char* h : {"1e-4", "2.5e-5"}) {
    const CliResult r =
        cli("run " + test::source_path("inputs/double_pendulum.toml") + " --set run.t_end=0.2 --set integrator.h=" + h +
            " --set output.thermo_interval=0.02 -o " + dir.string());
    ASSERT_EQ(r.code, 0) << r.err;
    EXPECT_EQ(count_lines(slurp(dir / "thermo.csv")), 1 + 11) << "h = " << h;
  }
  fs::remove_all(dir);
}

// An interval longer than the run gives the first and the final frame only: a warning at the key,
// in the deck's time unit, for every output that has one; none for intervals within the run.
TEST(Cli, AnIntervalLongerThanTheRunWarns) {
  const fs::path dir = scratch_dir("long_interval");
  const std::string deck = test::source_path("inputs/double_pendulum.toml");
  const CliResult r = cli("run " + deck +
                          " --no-progress -q --set run.t_end=0.5 --set output.xyz_interval=100"
                          " --set output.h5md_interval=0.25 --set output.checkpoint_interval=7 -o " +
                          dir.string());
  ASSERT_EQ(r.code, 0) << r.err;
  // At the key: the --set that gave it, or its line with the --set that shortened the run.
  EXPECT_NE(r.err.find("warning: --set output.xyz_interval: output.xyz_interval = 100 is longer than the run "
                       "(run.t_end = 0.5): only the first and the final frames are written"),
            std::string::npos)
      << r.err;
  const CliResult short_run = cli("check " + deck + " --set run.t_end=0.005 --set integrator.h=0.005");
  ASSERT_EQ(short_run.code, 0) << short_run.err;
  EXPECT_NE(short_run.err.find("warning: " + deck +
                               ":76 (with --set run.t_end): output.thermo_interval = 0.01 is longer than the run"),
            std::string::npos)
      << short_run.err;
  EXPECT_NE(r.err.find("output.checkpoint_interval = 7 is longer than the run (run.t_end = 0.5): no checkpoint "
                       "before the final one"),
            std::string::npos)
      << r.err;
  EXPECT_EQ(r.err.find("h5md_interval"), std::string::npos) << r.err;
  EXPECT_EQ(count_lines(slurp(dir / "trajectory.xyz")) / 5, 2);  // two frames of a pendulum (5 lines each)
  // In real units the interval and the run are in fs.
  const CliResult real = cli("check " + test::source_path("inputs/trappe_pe.toml") +
                             " --set run.t_end=40 --set output.thermo_interval=400");
  ASSERT_EQ(real.code, 0) << real.err;
  EXPECT_NE(real.err.find("output.thermo_interval = 400 is longer than the run (run.t_end = 40)"), std::string::npos)
      << real.err;
  const CliResult fine = cli("check " + deck);
  EXPECT_EQ(fine.err.find("warning"), std::string::npos) << fine.err;
  fs::remove_all(dir);
}

TEST(Cli, NumericalBlowUpGivesExitThreeAndKeepsOutputsReadable) {
  const fs::path dir = scratch_dir("blowup");
  // h far beyond the stability limit of velocity Verlet (h ω/ε < 2).
  const CliResult r =
      cli("run " + test::source_path("inputs/double_pendulum.toml") +
          " --set integrator.method=velocity-verlet --set integrator.h=0.01 --set output.xyz_interval=0.01 -o " +
          dir.string());
  EXPECT_EQ(r.code, 3) << r.err;
  EXPECT_NE(r.err.find("step"), std::string::npos) << r.err;
  EXPECT_NE(r.err.find("t = "), std::string::npos) << r.err;
  // One error line, the last; before it the default energy check may have warned (it does: the
  // energy grows long before positions turn non-finite).
  EXPECT_EQ(r.err.find("error:"), r.err.rfind("error:")) << r.err;
  EXPECT_EQ(r.err.rfind('\n', r.err.size() - 2) == std::string::npos ? 0 : r.err.rfind('\n', r.err.size() - 2) + 1,
            r.err.find("error:"))
      << r.err;
  // Every frame in the trajectory is complete: 5 lines per frame.
  const std::string xyz = slurp(dir / "trajectory.xyz");
  EXPECT_GT(count_lines(xyz), 0);
  EXPECT_EQ(count_lines(xyz) % 5, 0);
  fs::remove_all(dir);
}

}  // namespace
}  // namespace stiffmd
