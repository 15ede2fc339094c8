// The command line end to end (design.md §7): exit codes, one-line errors that name the
// file, line and key, outputs that parse.
#include <gtest/gtest.h>
#include <sys/wait.h>

#include <filesystem>
#include <fstream>
#include <regex>
#include <sstream>

#include "cli_support.hpp"
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

// Every malformed deck in tests/bad_decks/ gives exit 2 and one line naming the file, the
// line, and the key(s) listed in its "# expect:" header.
TEST(Cli, MalformedDecksGiveExitTwoAndOneLineNamingTheKey) {
  int n = 0;
  for (const auto& entry : fs::directory_iterator(test::source_path("tests/bad_decks"))) {
    const std::string path = entry.path().string();
    const std::string text = slurp(path);
    std::vector<std::string> expect;
    std::istringstream lines(text);
    for (std::string line; std::getline(lines, line);)
      if (line.rfind("# expect: ", 0) == 0) expect.push_back(line.substr(10));
    ASSERT_FALSE(expect.empty()) << path << " has no '# expect:' line";
    const CliResult r = cli("check " + path);
    SCOPED_TRACE(path + "\n" + r.err);
    EXPECT_EQ(r.code, 2);
    EXPECT_EQ(count_lines(r.err), 1);
    EXPECT_NE(r.err.find(path), std::string::npos) << "message must name the file";
    EXPECT_NE(r.err.find(path + ":"), std::string::npos) << "message must name the line";
    EXPECT_TRUE(std::isdigit(static_cast<unsigned char>(r.err[r.err.find(path) + path.size() + 1])))
        << "message must name the line";
    for (const auto& e : expect) EXPECT_NE(r.err.find(e), std::string::npos) << "missing '" << e << "'";
    ++n;
  }
  EXPECT_GE(n, 30);
}

TEST(Cli, BadOverridesAndArgumentsGiveExitTwo) {
  const std::string deck = test::source_path("inputs/double_pendulum.toml");
  CliResult r = cli("check " + deck + " --set integrator.h=-1");
  EXPECT_EQ(r.code, 2);
  EXPECT_NE(r.err.find("--set integrator.h"), std::string::npos) << r.err;
  r = cli("check " + deck + " --set integrator.hh=1");
  EXPECT_EQ(r.code, 2);
  EXPECT_NE(r.err.find("integrator.hh: unknown key"), std::string::npos) << r.err;
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
      cli("run " + test::source_path("inputs/double_pendulum.toml") + " --set run.t_end=0.01 -o " + dir.string());
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
  EXPECT_EQ(count_lines(r.err), 1) << r.err;
  // Every frame in the trajectory is complete: 5 lines per frame.
  const std::string xyz = slurp(dir / "trajectory.xyz");
  EXPECT_GT(count_lines(xyz), 0);
  EXPECT_EQ(count_lines(xyz) % 5, 0);
  fs::remove_all(dir);
}

}  // namespace
}  // namespace stiffmd
