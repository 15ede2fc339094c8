// Self-monitoring ([monitor], engine/observe/monitor.hpp) end to end through the CLI, on the paper's
// double pendulum: the impulse method at h = 1/4 loses the actions' adiabatic invariance and
// drifts in energy (Lubich & Weiss §5), the projected impulse method does not.
#include <gtest/gtest.h>

#include <filesystem>
#include <fstream>

#include "engine/run/checkpoint.hpp"
#include "tests/cli_support.hpp"
#include "tests/test_support.hpp"

namespace stiffmd {
namespace {

namespace fs = std::filesystem;
using namespace test;

// The bundled pendulum deck with a [monitor] table appended.
fs::path deck_with_monitor(const std::string& name, const std::string& monitor) {
  const fs::path dir = scratch_dir(name);
  const fs::path deck = dir / "deck.toml";
  std::ofstream(deck) << slurp(fs::path(STIFFMD_SOURCE_DIR) / "inputs/double_pendulum.toml") << "\n[monitor]\n"
                      << monitor;
  return deck;
}

std::string run_args(const fs::path& deck, const std::string& method, const fs::path& out) {
  return "run " + deck.string() + " -o " + out.string() + " --no-progress --set integrator.method=" + method +
         " --set integrator.h=0.25 --set output.h5md=\\\"\\\" --set output.xyz=\\\"\\\"";
}

TEST(Monitor, WarnsWithStepAndTimeAndCountsAlertsInTheThermoOutput) {
  const fs::path deck = deck_with_monitor("monitor_warn", "energy_error = 0.01\naction_drift = 0.05\n");
  const fs::path out = deck.parent_path() / "impulse";
  const CliResult r = cli(run_args(deck, "impulse", out));
  ASSERT_EQ(r.code, 0) << r.err;
  EXPECT_NE(r.err.find("warning: monitor: relative energy error"), std::string::npos) << r.err;
  EXPECT_NE(r.err.find("> [monitor] energy_error = 0.01 at step"), std::string::npos) << r.err;
  EXPECT_NE(r.err.find("warning: monitor: action I_"), std::string::npos) << r.err;
  const CsvTable t = read_csv((out / "thermo.csv").string());
  const size_t alerts = t.col("alerts"), drift = t.col("energy_drift"), total = t.col("total");
  EXPECT_EQ(t.rows.front()[alerts], 0.0);
  int rows_with_alerts = 0;
  for (const auto& row : t.rows) {
    const bool energy_over = std::abs(row[drift]) > 0.01 * std::abs(t.rows.front()[total]);
    if (energy_over) {
      EXPECT_GE(row[alerts], 1.0) << "t = " << row[0];
    }
    rows_with_alerts += row[alerts] > 0;
  }
  EXPECT_GT(rows_with_alerts, 0);

  // The projected impulse method keeps energy and actions within the same thresholds.
  const fs::path out2 = deck.parent_path() / "projected";
  const CliResult p = cli(run_args(deck, "projected-impulse", out2));
  ASSERT_EQ(p.code, 0) << p.err;
  EXPECT_EQ(p.err.find("monitor"), std::string::npos) << p.err;
  for (const auto& row : read_csv((out2 / "thermo.csv").string()).rows) EXPECT_EQ(row[alerts], 0.0);
}

TEST(Monitor, StopExitsThreeKeepingTheLastGoodStateAndReadableOutputs) {
  const fs::path deck = deck_with_monitor("monitor_stop", "energy_error = 0.01\non_alert = \"stop\"\n");
  const fs::path out = deck.parent_path() / "run";
  const CliResult r = cli(run_args(deck, "impulse", out));
  EXPECT_EQ(r.code, 3) << r.err;
  EXPECT_NE(r.err.find("error: monitor: relative energy error"), std::string::npos) << r.err;
  EXPECT_NE(r.err.find("stopped ([monitor] on_alert = \"stop\")"), std::string::npos) << r.err;
  EXPECT_FALSE(fs::exists(out / "summary.json")) << "a stopped run has no summary";
  const CsvTable t = read_csv((out / "thermo.csv").string());
  ASSERT_GE(t.rows.size(), 2u);
  const auto& last = t.rows.back();
  EXPECT_GE(last[t.col("alerts")], 1.0) << "the alerting sample is the last row";
  for (size_t k = 0; k + 1 < t.rows.size(); ++k) EXPECT_EQ(t.rows[k][t.col("alerts")], 0.0);
  // The checkpoint holds the last sampled state within the threshold: the row before the alert.
  const Checkpoint c = read_checkpoint((out / "checkpoint.bin").string());
  EXPECT_EQ(static_cast<double>(c.state.step), t.rows[t.rows.size() - 2][t.col("step")]);
  EXPECT_TRUE(c.state.x.allFinite());
}

// Without a [monitor] table an energy-conserving run still checks its energy
// (MonitorSettings::kDefaultEnergyError): the drifting impulse run warns, the projected one does
// not, and energy_error = false (or 0) switches the check off.
TEST(Monitor, EnergyCheckIsOnByDefault) {
  const fs::path dir = scratch_dir("monitor_default");
  const fs::path deck = dir / "deck.toml";
  std::ofstream(deck) << slurp(fs::path(STIFFMD_SOURCE_DIR) / "inputs/double_pendulum.toml");
  const CliResult drifting = cli(run_args(deck, "impulse", dir / "impulse"));
  ASSERT_EQ(drifting.code, 0) << drifting.err;
  EXPECT_NE(drifting.err.find("warning: monitor: relative energy error"), std::string::npos) << drifting.err;
  EXPECT_NE(drifting.err.find("> [monitor] energy_error = 0.01 at step"), std::string::npos) << drifting.err;
  const CliResult clean = cli(run_args(deck, "projected-impulse", dir / "projected"));
  ASSERT_EQ(clean.code, 0) << clean.err;
  EXPECT_EQ(clean.err.find("monitor"), std::string::npos) << clean.err;
  for (const std::string off : {"false", "0"}) {
    const fs::path quiet = deck_with_monitor("monitor_off", "energy_error = " + off + "\n");
    const CliResult r = cli(run_args(quiet, "impulse", quiet.parent_path() / "impulse"));
    ASSERT_EQ(r.code, 0) << r.err;
    EXPECT_EQ(r.err.find("energy error"), std::string::npos) << off << ": " << r.err;
  }
}

TEST(Monitor, BadSettingsAreInputErrors) {
  for (const std::string& bad : {std::string("on_alert = \"maybe\"\n"), std::string("energy_error = -1\n"),
                                 std::string("energy_eror = 0.1\n")}) {
    const fs::path deck = deck_with_monitor("monitor_bad", bad);
    const CliResult r = cli("check " + deck.string());
    EXPECT_EQ(r.code, 2) << bad << r.err;
    EXPECT_NE(r.err.find("deck.toml"), std::string::npos) << r.err;
    EXPECT_NE(r.err.find("monitor"), std::string::npos) << r.err;
  }
}

}  // namespace
}  // namespace stiffmd
