// Self-monitoring ([monitor], engine/observe/monitor.hpp) end to end through the CLI, on the paper's
// double pendulum: the impulse method at h = 1/4 loses the actions' adiabatic invariance and
// drifts in energy (Lubich & Weiss §5), the projected impulse method does not.
#include <gtest/gtest.h>

#include <filesystem>
#include <fstream>

#include "engine/observe/monitor.hpp"
#include "engine/observe/observables.hpp"
#include "engine/run/checkpoint.hpp"
#include "engine/scene/scene.hpp"
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

// A temperature meant in kelvin in reduced units: the trimers' stiff springs (ε = 0.1, α = 1)
// vibrate at kT = 300 with rms amplitude ε√kT/α = 1.73 of their length 1; the run finishes with
// finite numbers, its energy 480 times E(0). The deck warns at load with the likely cause, and the
// monitor's default bond check alerts (named cause included) and counts it in the thermo. At
// kT = 1 neither says a word.
TEST(Monitor, AKelvinTemperatureInReducedUnitsIsNamedAndCaught) {
  const std::string trimers = source_path("inputs/nvt_trimers.toml");
  const fs::path out = scratch_dir("monitor_kelvin");
  const CliResult r = cli("run " + trimers + " -o " + (out / "hot").string() +
                          " --no-progress -q --set run.t_end=5 --set thermostat.temperature=300");
  ASSERT_EQ(r.code, 0) << r.err;
  const std::string cause = "kT = 300 in LJ units (k_B = 1): the stiff bonds vibrate with rms amplitude";
  // At the key: here the --set that gave the temperature.
  EXPECT_NE(r.err.find("warning: --set thermostat.temperature: thermostat.temperature: " + cause), std::string::npos)
      << r.err;
  EXPECT_NE(r.err.find("173 % of their length; a temperature in kelvin needs units = \"real\""), std::string::npos)
      << r.err;
  EXPECT_NE(r.err.find("warning: monitor: a stiff bond deviates from its rest length by"), std::string::npos) << r.err;
  EXPECT_NE(r.err.find("[monitor] bond_deviation = 1) (" + cause), std::string::npos) << r.err;
  const CsvTable hot = read_csv((out / "hot" / "thermo.csv").string());
  EXPECT_GE(hot.rows.back()[hot.col("alerts")], 1.0);

  const CliResult quiet =
      cli("run " + trimers + " -o " + (out / "kT1").string() + " --no-progress -q --set run.t_end=20");
  ASSERT_EQ(quiet.code, 0) << quiet.err;
  EXPECT_EQ(quiet.err.find("warning"), std::string::npos) << quiet.err;
  // Off when asked: bond_deviation = false.
  const CliResult off = cli("run " + trimers + " -o " + (out / "off").string() +
                            " --no-progress -q --set run.t_end=5 --set thermostat.temperature=300"
                            " --set monitor.bond_deviation=false");
  ASSERT_EQ(off.code, 0) << off.err;
  EXPECT_EQ(off.err.find("warning: monitor"), std::string::npos) << off.err;
  fs::remove_all(out);
}

// The thermostatted run's default checks on rows made by hand: the kinetic temperature is left
// alone for ten relaxation times (1/γ = 1 here), then compared with the thermostat's (50 %, or six
// standard deviations of its fluctuation, √(2/dof) = 0.033 for 1 800 dof); the energy against
// ten times max(|E(0)|, K(0), dof kT/2).
TEST(Monitor, TemperatureAndEnergyRunawayOfAThermostattedRun) {
  const Scene sc = load("inputs/nvt_trimers.toml");
  EXPECT_EQ(sc.monitor.temperature_deviation, MonitorSettings::kDefaultTemperatureDeviation);
  EXPECT_EQ(sc.monitor.energy_runaway, MonitorSettings::kDefaultEnergyRunaway);
  EXPECT_EQ(sc.monitor.bond_deviation, MonitorSettings::kDefaultBondDeviation);
  EXPECT_EQ(sc.monitor.energy_error, MonitorSettings::kOff);  // a bath exchanges energy
  EXPECT_EQ(sc.monitor.scene.relaxation, 1.0);
  const Thermo thermo(*sc.forces, sc.state.inv_mass, sc.observables, &sc.topology);
  const int dof = thermo.degrees_of_freedom();
  ASSERT_EQ(dof, 1800);
  const auto col = [&](const char* name) { return static_cast<size_t>(thermo.column(name)); };
  const double e0 = 1000.0, bath = 0.5 * dof * 1.0;
  const auto row = [&](double t, double temperature, double total) {
    std::vector<double> r(thermo.columns().size(), 0.0);
    r[col("time")] = t;
    r[col("temperature")] = temperature;
    r[col("kinetic")] = 0.5 * dof * temperature;
    r[col("total")] = total;
    return r;
  };
  Monitor m(sc.monitor, thermo, 0.1, false);
  std::ostringstream log;
  EXPECT_EQ(m.check(row(0.0, 0.0, e0), e0, log), 0);   // the reference: a cold start
  EXPECT_EQ(m.check(row(9.9, 0.4, e0), e0, log), 0);   // still relaxing
  EXPECT_EQ(m.check(row(10.0, 1.2, e0), e0, log), 0);  // within 50 %
  EXPECT_EQ(m.check(row(10.0, 0.55, e0), e0, log), 0);
  EXPECT_EQ(log.str(), "");
  EXPECT_EQ(m.check(row(12.0, 1.6, e0), e0, log), 1);
  EXPECT_NE(log.str().find("warning: monitor: kinetic temperature 1.6 is 60 % off the thermostat's 1"),
            std::string::npos)
      << log.str();
  EXPECT_EQ(m.check(row(12.0, 0.45, e0), e0, log), 1);
  // |E − E(0)| against 10 max(|E(0)|, K(0), dof kT/2) = 10 × 1 000: 9 000 is within, 11 000 not.
  EXPECT_EQ(m.check(row(12.0, 1.0, e0 + 9.0 * e0), e0, log), 0);
  EXPECT_EQ(m.check(row(12.0, 1.0, e0 - 11.0 * std::max(e0, bath)), e0, log), 1);
  EXPECT_NE(log.str().find("warning: monitor: energy runaway"), std::string::npos) << log.str();
}

}  // namespace
}  // namespace stiffmd
