// Where a run's time goes (core/timing.hpp, core/parallel.hpp): the phase clock's
// exclusive accounting, the time inside the parallel loops, and every run's report — the phases
// add up to the step loop's separately measured wall time within 2 %, the serial share is a
// fraction, and a system too small to time by parts says so.
#include <gtest/gtest.h>

#include <chrono>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <sstream>
#include <thread>

#include "core/parallel.hpp"
#include "core/timing.hpp"
#include "tests/cli_support.hpp"
#include "tests/test_support.hpp"

namespace stiffmd {
namespace {

namespace fs = std::filesystem;
using namespace std::chrono_literals;

// Busy for at least d (a sleep would do, but a loaded machine may oversleep by milliseconds).
void busy(std::chrono::microseconds d) {
  const auto until = std::chrono::steady_clock::now() + d;
  while (std::chrono::steady_clock::now() < until) {
  }
}

// Nested scopes are exclusive: the inner one's time is its own, not also its parent's; the time
// outside every scope is "other"; the phases add up to the clock's span; nothing is recorded
// while the clock is paused or by a scope opened in a parallel region.
TEST(PhaseClock, NestedScopesAreExclusiveAndAddUpToTheSpan) {
  PhaseClock clock;
  const auto t0 = std::chrono::steady_clock::now();
  clock.resume();
  busy(2ms);  // other
  {
    const ScopedPhase pair(Phase::pair);
    busy(3ms);
    {
      const ScopedPhase list(Phase::neighbor);
      busy(4ms);
    }
    busy(1ms);
  }
  clock.pause();
  const double span = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  {
    const ScopedPhase ignored(Phase::constraints);  // paused: nothing recorded
    busy(2ms);
  }
  EXPECT_GE(clock.seconds(Phase::neighbor), 4e-3);
  EXPECT_GE(clock.seconds(Phase::pair), 4e-3);
  EXPECT_GE(clock.seconds(Phase::other), 2e-3);
  EXPECT_EQ(clock.seconds(Phase::constraints), 0.0);
  EXPECT_LE(clock.total(), span);  // the neighbour list's 4 ms counted twice would exceed it
  EXPECT_NEAR(clock.total(), span, 0.02 * span);
}

// A run counts the parallel loops only while it steps: after stop_parallel_seconds nothing is
// added (tests/test_parallel.cpp, ParallelSeconds.*, has the counting rules).
TEST(ParallelSeconds, StopKeepsTheCountAndCountsNoMore) {
  reset_parallel_seconds();
  run_parts(1, [](int) { busy(1ms); });
  const double counted = parallel_seconds();
  EXPECT_GE(counted, 1e-3);
  stop_parallel_seconds();
  run_parts(1, [](int) { busy(1ms); });
  EXPECT_EQ(parallel_seconds(), counted);
}

double json_number(const std::string& json, const std::string& key) {
  const size_t at = json.find("\"" + key + "\": ");
  if (at == std::string::npos) return std::nan("");
  return std::stod(json.substr(at + key.size() + 4));
}

// Every run reports its step loop; from kParallelMin particles on by phase, with the serial
// share, on the terminal and in summary.json, the phases adding up to the loop's wall time.
TEST(RunTiming, PhasesAddUpToTheStepLoopAndTheSerialShareIsAFraction) {
  const fs::path dir = test::scratch_dir("timing");
  for (const char* threads : {"1", "2"}) {
    SCOPED_TRACE(std::string("threads ") + threads);
    const test::CliResult r = test::cli("run " + test::source_path("inputs/polymer_melt.toml") + " -o " + dir.string() +
                                            " --no-progress -q --set run.t_end=0.05",
                                        std::string("OMP_NUM_THREADS=") + threads + " ");
    ASSERT_EQ(r.code, 0) << r.err;
    EXPECT_NE(r.out.find("timing:        step loop "), std::string::npos) << r.out;
    EXPECT_NE(r.out.find(std::string(" on ") + threads + (threads[0] == '1' ? " thread, " : " threads, ")),
              std::string::npos)
        << r.out;
    EXPECT_NE(r.out.find("serial share"), std::string::npos) << r.out;
    const std::string json = test::slurp(dir / "summary.json");
    const double loop = json_number(json, "loop_seconds");
    ASSERT_GT(loop, 0.0) << json;
    double sum = 0.0;
    for (std::string_view p : kPhaseNames) {
      const double s = json_number(json, std::string(p));
      ASSERT_GE(s, 0.0) << p << "\n" << json;
      EXPECT_NE(r.out.find("  " + std::string(p) + " "), std::string::npos) << p;
      sum += s;
    }
    EXPECT_NEAR(sum, loop, 0.02 * loop) << json;
    EXPECT_GT(json_number(json, "pair"), 0.0);  // WCA through the neighbour list
    EXPECT_GT(json_number(json, "constraints") + json_number(json, "bonded"), 0.0);
    const double serial = json_number(json, "serial_share");
    EXPECT_GE(serial, 0.0);
    EXPECT_LT(serial, 1.0);
    // The process's peak resident set (getrusage): at least the melt's 10 000 positions, velocities
    // and forces, far below a gigabyte.
    const double rss = json_number(json, "peak_rss_mib");
    EXPECT_GT(rss, 3 * 3 * 8 * 10000 / 1048576.0) << json;
    EXPECT_LT(rss, 1024.0) << json;
    EXPECT_NE(r.out.find("memory:        peak resident set "), std::string::npos) << r.out;
  }
  // The pendulum: too small to time by parts, and it says so.
  const test::CliResult small = test::cli("run " + test::source_path("inputs/double_pendulum.toml") + " -o " +
                                          dir.string() + " --no-progress -q --set run.t_end=1");
  ASSERT_EQ(small.code, 0) << small.err;
  EXPECT_NE(small.out.find("by phase from 4096 particles on"), std::string::npos) << small.out;
  const std::string json = test::slurp(dir / "summary.json");
  EXPECT_NE(json.find("\"serial_share\": null"), std::string::npos) << json;
  EXPECT_NE(json.find("\"timing\": {}"), std::string::npos) << json;
  fs::remove_all(dir);
}

// A small system with a k-space term (384 charged beads, PPPM): its step is milliseconds long, so it
// is timed by phase, and the mesh's time is its own phase, above zero, the phases adding up.
TEST(RunTiming, AKSpaceTermIsTimedByPhaseAtAnySize) {
  const fs::path dir = test::scratch_dir("timing_kspace");
  const test::CliResult r = test::cli("run " + test::source_path("inputs/polyelectrolyte.toml") + " -o " +
                                          dir.string() + " --no-progress -q --set run.t_end=0.5",
                                      "OMP_NUM_THREADS=1 ");
  ASSERT_EQ(r.code, 0) << r.err;
  EXPECT_NE(r.out.find("  kspace "), std::string::npos) << r.out;
  const std::string json = test::slurp(dir / "summary.json");
  EXPECT_GT(json_number(json, "kspace"), 0.0) << json;
  EXPECT_GT(json_number(json, "pair"), 0.0) << json;
  double sum = 0.0;
  for (std::string_view p : kPhaseNames) sum += json_number(json, std::string(p));
  const double loop = json_number(json, "loop_seconds");
  EXPECT_NEAR(sum, loop, 0.02 * loop) << json;
  fs::remove_all(dir);
}

// The thread count a summary gives is that of the step loop's loops, not OMP_NUM_THREADS: the
// pendulum's loops (two bonds, two particles) all run on one thread at any thread count.
TEST(RunTiming, ThreadCountIsTheThreadsTheLoopsRanOn) {
  const fs::path dir = test::scratch_dir("timing_threads");
  const test::CliResult r = test::cli("run " + test::source_path("inputs/double_pendulum.toml") + " -o " +
                                          dir.string() + " --no-progress -q --set run.t_end=1",
                                      "OMP_NUM_THREADS=2 ");
  ASSERT_EQ(r.code, 0) << r.err;
  EXPECT_NE(r.out.find(" s wall on 1 thread; "), std::string::npos) << r.out;
  EXPECT_EQ(json_number(test::slurp(dir / "summary.json"), "threads"), 1.0);
  fs::remove_all(dir);
}

}  // namespace
}  // namespace stiffmd
