// Checkpoints and restart (docs/design.md §8): a run of 2n steps and a run
// of n steps continued from its checkpoint for n more end in the same state bit for bit, for
// every integrator, and their outputs are the same files; signals stop cleanly; a checkpoint
// is never half-written; bad output paths are clear errors.
#include <gtest/gtest.h>

#include <chrono>
#include <csignal>
#include <fstream>
#include <thread>

#include "cli_support.hpp"
#include "engine/run/checkpoint.hpp"
#include "test_support.hpp"

namespace stiffmd {
namespace {

namespace fs = std::filesystem;
using test::cli;
using test::slurp;

std::string deck() {
  return test::source_path("inputs/double_pendulum.toml");
}

class RestartEquivalence : public ::testing::TestWithParam<std::string> {};

TEST_P(RestartEquivalence, TwoHalvesEqualTheWholeBitForBit) {
  const std::string method = GetParam();
  const std::string h = method == "velocity-verlet" ? "1e-5" : "0.015625";
  const std::string common = " --no-progress --set integrator.method=" + method + " --set integrator.h=" + h +
                             " --set output.xyz_interval=0.01 --set output.thermo_interval=0.01"
                             " --set output.xyz_velocities=true";
  // Methods that need a temperature run with Langevin noise: restarts continue its counters too.
  const std::string thermostat = find_method(method)->needs_temperature
                                     ? " --set thermostat.style=langevin --set thermostat.temperature=0.1"
                                       " --set thermostat.friction=1.0 --set thermostat.seed=3"
                                     : "";
  const fs::path d = test::scratch_dir("restart_" + method);
  ASSERT_EQ(cli("run " + deck() + " -o " + (d / "whole").string() + common + thermostat + " --set run.t_end=0.25").code,
            0);
  ASSERT_EQ(
      cli("run " + deck() + " -o " + (d / "parts").string() + common + thermostat + " --set run.t_end=0.125").code, 0);
  const auto r = cli("run " + deck() + " -o " + (d / "parts").string() + common + thermostat +
                     " --set run.t_end=0.25 --restart " + (d / "parts" / "checkpoint.bin").string());
  ASSERT_EQ(r.code, 0) << r.err;
  EXPECT_NE(r.err.find("restart from"), std::string::npos);

  const Checkpoint a = read_checkpoint((d / "whole" / "checkpoint.bin").string());
  const Checkpoint b = read_checkpoint((d / "parts" / "checkpoint.bin").string());
  EXPECT_EQ(a.state.step, b.state.step);
  EXPECT_EQ(a.state.t, b.state.t);
  EXPECT_TRUE((a.state.x.array() == b.state.x.array()).all()) << "positions differ";
  EXPECT_TRUE((a.state.v.array() == b.state.v.array()).all()) << "velocities differ";
  EXPECT_EQ(a.integrator_state, b.integrator_state);
  // The continued trajectory and thermo files are the uninterrupted run's, byte for byte.
  EXPECT_EQ(slurp(d / "whole" / "trajectory.xyz"), slurp(d / "parts" / "trajectory.xyz"));
  EXPECT_EQ(slurp(d / "whole" / "thermo.csv"), slurp(d / "parts" / "thermo.csv"));
  fs::remove_all(d);
}

INSTANTIATE_TEST_SUITE_P(EveryMethod, RestartEquivalence, ::testing::ValuesIn(test::kAllMethods),
                         test::method_test_name);

TEST(Restart, DropsFramesWrittenAfterTheCheckpointAndContinuesGzipTrajectories) {
  const fs::path d = test::scratch_dir("restart_gz");
  const std::string common =
      " --no-progress --set output.xyz=traj.xyz.gz --set output.xyz_interval=0.03125 --set "
      "output.thermo_interval=0.03125";
  ASSERT_EQ(cli("run " + deck() + " -o " + (d / "whole").string() + common + " --set run.t_end=0.5").code, 0);
  // A run to t = 0.25 (step 16); keep its checkpoint; continue it to 0.375, as if it had gone on
  // after that checkpoint and then died; restart from the kept checkpoint: the frames after
  // step 16 must be cut away before the run goes on.
  ASSERT_EQ(cli("run " + deck() + " -o " + (d / "parts").string() + common + " --set run.t_end=0.25").code, 0);
  fs::copy_file(d / "parts" / "checkpoint.bin", d / "step16.bin");
  ASSERT_EQ(cli("run " + deck() + " -o " + (d / "parts").string() + common + " --set run.t_end=0.375 --restart " +
                (d / "step16.bin").string())
                .code,
            0);
  const auto r = cli("run " + deck() + " -o " + (d / "parts").string() + common + " --set run.t_end=0.5 --restart " +
                     (d / "step16.bin").string());
  ASSERT_EQ(r.code, 0) << r.err;
  EXPECT_EQ(slurp(d / "whole" / "thermo.csv"), slurp(d / "parts" / "thermo.csv"));
  // Compare the decompressed trajectories with zcat.
  const auto unz = [&](const fs::path& p) {
    std::system(("zcat " + p.string() + " > " + p.string() + ".txt").c_str());
    return slurp(p.string() + ".txt");
  };
  const std::string whole = unz(d / "whole" / "traj.xyz.gz"), parts = unz(d / "parts" / "traj.xyz.gz");
  EXPECT_FALSE(whole.empty());
  EXPECT_EQ(whole, parts);
  fs::remove_all(d);
}

TEST(Restart, RejectsACheckpointOfAnotherScene) {
  const fs::path d = test::scratch_dir("restart_bad");
  std::ofstream(d / "junk.bin") << "not a checkpoint";
  auto r = cli("run " + deck() + " -o " + d.string() + " --restart " + (d / "junk.bin").string());
  EXPECT_EQ(r.code, 2);
  EXPECT_NE(r.err.find("junk.bin: not a stiffmd checkpoint"), std::string::npos) << r.err;
  ASSERT_EQ(cli("run " + deck() + " -o " + (d / "a").string() + " --set run.t_end=0.125").code, 0);
  r = cli("run " + deck() + " -o " + (d / "a").string() +
          " --set types.bob.mass=2 --set types.pivot.mass=2 --restart " + (d / "a" / "checkpoint.bin").string());
  EXPECT_EQ(r.code, 2);
  EXPECT_NE(r.err.find("masses differ"), std::string::npos) << r.err;
  r = cli("run " + deck() + " -o " + (d / "a").string() + " --restart " + (d / "a" / "checkpoint.bin").string() +
          " --set run.t_end=0.0625");
  EXPECT_EQ(r.code, 2);
  EXPECT_NE(r.err.find("not before run.t_end"), std::string::npos) << r.err;
  fs::remove_all(d);
}

// A level's kick is part of what a checkpoint continues: the integrator's cached kick forces are
// that strategy's. A restart whose deck kicks a level otherwise (here the angles plain under the
// mollified impulse) is refused with one line; the same deck with the method's own kick spelt out
// continues the run.
TEST(Restart, RefusesACheckpointWhoseLevelsKickedOtherwise) {
  const fs::path d = test::scratch_dir("restart_kick");
  std::ifstream in(test::source_path("inputs/respa_chains.toml"));
  std::string text, line;
  int levels = 0;
  while (std::getline(in, line)) {
    text += line + "\n";
    if (line.rfind("[[integrator.levels]]", 0) == 0 && ++levels == 2) text += "kick = \"KICK\"\n";
  }
  ASSERT_EQ(levels, 3);
  const auto write = [&](const std::string& kick, const fs::path& path) {
    std::string t = text;
    t.replace(t.find("KICK"), 4, kick);
    std::ofstream(path) << t;
    return path.string();
  };
  const std::string plain = write("plain", d / "plain.toml"), own = write("mollified", d / "own.toml");
  ASSERT_EQ(cli("run " + test::source_path("inputs/respa_chains.toml") + " -o " + (d / "a").string() +
                " -q --no-progress --set run.t_end=0.05")
                .code,
            0);
  const std::string restart =
      " -q --no-progress --set run.t_end=0.1 --restart " + (d / "a" / "checkpoint.bin").string();
  auto r = cli("run " + plain + " -o " + (d / "b").string() + restart);
  EXPECT_EQ(r.code, 2) << r.err;
  EXPECT_NE(r.err.find("levels or their kicks"), std::string::npos) << r.err;
  r = cli("run " + own + " -o " + (d / "c").string() + restart);
  EXPECT_EQ(r.code, 0) << r.err;
  fs::remove_all(d);
}

TEST(Signals, SigintFinishesTheStepWritesACheckpointAndTheRunContinuesExactly) {
  const fs::path d = test::scratch_dir("sigint");
  const std::string common = " --no-progress --set variables.eps=1e-4 --set run.t_end=20";
  ASSERT_EQ(cli("run " + deck() + " -o " + (d / "whole").string() + common).code, 0);
  // The same run, interrupted: about 1 s of work, SIGINT after 0.3 s.
  const auto r =
      cli("run " + deck() + " -o " + (d / "parts").string() + common, "timeout --preserve-status -s INT 0.3 ");
  ASSERT_EQ(r.code, 128 + SIGINT) << r.err;
  EXPECT_NE(r.err.find("stopped by signal 2"), std::string::npos) << r.err;
  EXPECT_FALSE(fs::exists(d / "parts" / "summary.json")) << "an interrupted run must not look finished";
  const Checkpoint mid = read_checkpoint((d / "parts" / "checkpoint.bin").string());
  EXPECT_GT(mid.state.step, 0);
  const auto r2 = cli("run " + deck() + " -o " + (d / "parts").string() + common + " --restart " +
                      (d / "parts" / "checkpoint.bin").string());
  ASSERT_EQ(r2.code, 0) << r2.err;
  EXPECT_EQ(slurp(d / "whole" / "checkpoint.bin"), slurp(d / "parts" / "checkpoint.bin"));
  EXPECT_EQ(slurp(d / "whole" / "thermo.csv"), slurp(d / "parts" / "thermo.csv"));
  fs::remove_all(d);
}

// [output] checkpoint_interval is a time, as every output interval: the checkpoint written last
// before a kill is the one at the first step at or after the last multiple of the interval, in
// the deck's time unit (fs in real units).
TEST(Checkpoint, IsWrittenOnItsTimeGrid) {
  struct Case {
    std::string deck, settings;
    int kill_at, expect;  // the step of the kill, the step the checkpoint must hold
  };
  const std::string melt = test::source_path("inputs/polymer_melt.toml");
  for (const Case& c :
       {Case{melt, " --set output.checkpoint_interval=0.2", 41, 40},  // h = 0.005
        Case{melt, " --set output.checkpoint_interval=0.2", 81, 80},
        Case{melt, " --set output.checkpoint_interval=0.0101", 43, 41},  // off the step grid: after
        Case{test::source_path("inputs/trappe_pe.toml"), " --set output.checkpoint_interval=12", 7, 6}}) {
    SCOPED_TRACE(c.deck + c.settings + " killed at " + std::to_string(c.kill_at));
    const fs::path d = test::scratch_dir("checkpoint_grid");
    const test::CliResult r =
        cli("run " + c.deck + " -o " + d.string() + " --no-progress -q" + c.settings + " --set output.h5md=\\\"\\\"",
            "STIFFMD_SIGNAL_AT_STEP=" + std::to_string(c.kill_at) + ":9 ");
    ASSERT_EQ(r.code, 128 + SIGKILL) << r.err;
    EXPECT_EQ(read_checkpoint((d / "checkpoint.bin").string()).state.step, c.expect);
    fs::remove_all(d);
  }
}

TEST(Checkpoint, IsNeverHalfWrittenWhenKilled) {
  const fs::path d = test::scratch_dir("kill9");
  // SIGKILL at a delay after the first checkpoint appears (not after a fixed wall time from the
  // start, which a loaded machine may spend before the first step): with a checkpoint after every
  // step, the kill lands in the middle of writing one, sooner or later.
  for (const int after_ms : {0, 30, 80}) {
    fs::remove_all(d);
    const std::string cmd = "exec " + std::string(STIFFMD_EXE) + " run " + deck() + " -o " + d.string() +
                            " --no-progress --set variables.eps=1e-4 --set output.checkpoint_interval=1e-12"
                            " --set run.t_end=5 >/dev/null 2>&1";
    const pid_t pid = ::fork();
    ASSERT_GE(pid, 0);
    if (pid == 0) {
      ::execl("/bin/sh", "sh", "-c", cmd.c_str(), static_cast<char*>(nullptr));
      ::_exit(127);
    }
    const auto started = std::chrono::steady_clock::now();
    while (!fs::exists(d / "checkpoint.bin") && std::chrono::steady_clock::now() - started < std::chrono::seconds(60))
      std::this_thread::sleep_for(std::chrono::milliseconds(2));
    std::this_thread::sleep_for(std::chrono::milliseconds(after_ms));
    ::kill(pid, SIGKILL);
    int status = 0;
    ::waitpid(pid, &status, 0);
    ASSERT_TRUE(WIFSIGNALED(status) && WTERMSIG(status) == SIGKILL) << "the run ended before the kill";
    ASSERT_TRUE(fs::exists(d / "checkpoint.bin"));
    EXPECT_NO_THROW(read_checkpoint((d / "checkpoint.bin").string()));
    // Every trajectory frame on disk is whole (5 lines per frame for 3 particles).
    const std::string xyz = slurp(d / "trajectory.xyz");
    EXPECT_EQ(std::count(xyz.begin(), xyz.end(), '\n') % 5, 0);
  }
  fs::remove_all(d);
}

TEST(Outputs, BadPathsAreClearErrors) {
  const fs::path d = test::scratch_dir("badpaths");
  std::ofstream(d / "a_file") << "x";
  auto r = cli("run " + deck() + " --set run.t_end=0.125 -o " + (d / "a_file").string());
  EXPECT_EQ(r.code, 2);
  EXPECT_NE(r.err.find("a_file: output path exists and is not a directory"), std::string::npos) << r.err;
  r = cli("run " + deck() + " --set run.t_end=0.125 -o " + (d / "a_file" / "sub").string());
  EXPECT_EQ(r.code, 2);
  EXPECT_NE(r.err.find("cannot create output directory"), std::string::npos) << r.err;
  // A full disk: the thermo file is /dev/full, where every write fails with ENOSPC.
  fs::create_directories(d / "full");
  fs::create_symlink("/dev/full", d / "full" / "thermo.csv");
  r = cli("run " + deck() + " --set run.t_end=0.125 -o " + (d / "full").string());
  EXPECT_EQ(r.code, 2);
  EXPECT_NE(r.err.find("thermo.csv: write failed: No space left on device"), std::string::npos) << r.err;
  fs::remove_all(d);
}

}  // namespace
}  // namespace stiffmd
