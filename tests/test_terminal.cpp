// What a run shows on the terminal (engine/run/screen.*, progress.hpp): the thermo lines are the
// thermo file's rows at the screen interval, continue after a restart and change no output; the
// [output] thermo_norm option divides the energies by N in the CSV and the H5MD file alike;
// --quiet leaves stdout to the summary; the progress bar is drawn on a terminal only, at most
// every half second; [prepare] says what it does while it does it.
#include <fcntl.h>
#include <gtest/gtest.h>
#include <hdf5.h>
#include <unistd.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <map>
#include <sstream>
#include <string>
#include <vector>

#include "cli_support.hpp"
#include "engine/run/progress.hpp"
#include "test_support.hpp"

namespace stiffmd {
namespace {

namespace fs = std::filesystem;
using test::cli;
using test::CliResult;
using test::scratch_dir;
using test::slurp;

// 8 chains × 8 beads, periodic (pressure), stiff bonds (two levels), thermo every 0.015, H5MD.
std::string melt() {
  return test::source_path("tests/decks/restart_melt.toml");
}
constexpr int kMeltParticles = 64;

// The thermo lines of a run's stdout: the header's labels and each line's cells as printed.
struct ScreenLines {
  std::vector<std::string> labels;
  std::vector<std::vector<std::string>> rows;
};

ScreenLines screen_lines(const std::string& out) {
  ScreenLines s;
  std::istringstream in(out);
  bool in_table = false;
  for (std::string line; std::getline(in, line);) {
    std::istringstream cells(line);
    std::vector<std::string> c;
    for (std::string w; cells >> w;) c.push_back(w);
    if (!c.empty() && c[0] == "Step") {
      if (s.labels.empty()) s.labels = c;
      EXPECT_EQ(c, s.labels) << "the header changed";
      in_table = true;
    } else if (in_table && c.size() == s.labels.size() && c[0].find_first_not_of("0123456789") == std::string::npos) {
      s.rows.push_back(c);
    } else {
      in_table = false;
    }
  }
  return s;
}

// The thermo column each screen label shows.
const std::map<std::string, std::string> kColumnOf = {{"Time", "time"},
                                                      {"Temp", "temperature"},
                                                      {"KinEng", "kinetic"},
                                                      {"PotSlow", "potential_slow"},
                                                      {"PotStiff", "potential_stiff"},
                                                      {"PotFixman", "potential_fixman"},
                                                      {"PotEng", "potential_slow"},
                                                      {"TotEng", "total"},
                                                      {"EConserve", "econserve"},
                                                      {"Press", "pressure"}};

// Every screen line is the thermo file's row of its step.
void expect_lines_are_csv_rows(const ScreenLines& s, const test::CsvTable& csv, const std::string& suffix = "") {
  const size_t step = csv.col("step");
  for (const auto& line : s.rows) {
    const std::vector<double>* row = nullptr;
    for (const auto& r : csv.rows)
      if (static_cast<long long>(r[step]) == std::stoll(line[0])) row = &r;
    ASSERT_NE(row, nullptr) << "no thermo row at step " << line[0];
    for (size_t k = 1; k + 1 < s.labels.size(); ++k) {
      std::string label = s.labels[k];
      const bool per_atom = label.size() > 2 && label.substr(label.size() - 2) == "/N";
      if (per_atom) label.resize(label.size() - 2);
      std::string column = kColumnOf.at(label);
      if (per_atom) column += suffix;
      // Equal to the screen's 8 significant digits (%.8g: within 5e-8 relative; the CSV has 12).
      const double want = (*row)[csv.col(column)];
      EXPECT_NEAR(std::stod(line[k]), want, 6e-8 * std::abs(want)) << s.labels[k] << " at step " << line[0];
    }
  }
}

std::vector<double> times_of(const ScreenLines& s) {
  std::vector<double> t;
  for (const auto& r : s.rows) t.push_back(std::stod(r[1]));
  return t;
}

// /observables/NAME/value of an H5MD file.
std::vector<double> h5_observable(const fs::path& file, const std::string& name) {
  std::vector<double> v;
  const hid_t f = H5Fopen(file.c_str(), H5F_ACC_RDONLY, H5P_DEFAULT);
  if (f < 0) return v;
  const std::string group = "/observables/" + name;
  const hid_t d =
      H5Lexists(f, group.c_str(), H5P_DEFAULT) > 0 ? H5Dopen2(f, (group + "/value").c_str(), H5P_DEFAULT) : -1;
  if (d >= 0) {
    const hid_t space = H5Dget_space(d);
    v.resize(static_cast<size_t>(H5Sget_simple_extent_npoints(space)));
    H5Dread(d, H5T_NATIVE_DOUBLE, H5S_ALL, H5S_ALL, H5P_DEFAULT, v.data());
    H5Sclose(space);
    H5Dclose(d);
  }
  H5Fclose(f);
  return v;
}

// Under fixman the model potential is Fixman's U_F, a free energy (up to a constant), not the
// springs' energy: it has its own column potential_fixman (screen: PotFixman), in the total, and
// potential_stiff stays the stiff bonds' energy (0 on rigid bonds, to SHAKE's tolerance).
TEST(Terminal, FixmansPotentialHasAColumnOfItsOwn) {
  const fs::path dir = scratch_dir("screen_fixman");
  const CliResult r = cli("run " + melt() +
                          " --no-progress --set run.t_end=0.075 --set output.screen_interval=0.015"
                          " --set integrator.method=fixman --set thermostat.style=langevin"
                          " --set thermostat.temperature=1.0 --set thermostat.damp=1.0 --set thermostat.seed=3"
                          " --set monitor.energy_error=0 -o " +
                          dir.string());
  ASSERT_EQ(r.code, 0) << r.err;
  const ScreenLines s = screen_lines(r.out);
  ASSERT_EQ(std::count(s.labels.begin(), s.labels.end(), "PotFixman"), 1) << r.out;
  const test::CsvTable csv = test::read_csv((dir / "thermo.csv").string());
  expect_lines_are_csv_rows(s, csv);
  ASSERT_FALSE(csv.rows.empty());
  for (const auto& row : csv.rows) {
    EXPECT_NE(row[csv.col("potential_fixman")], 0.0);
    EXPECT_LT(std::abs(row[csv.col("potential_stiff")]), 1e-12);
    const double sum = row[csv.col("kinetic")] + row[csv.col("potential_slow")] + row[csv.col("potential_stiff")] +
                       row[csv.col("potential_fixman")];
    EXPECT_NEAR(row[csv.col("total")], sum, 1e-10 * std::abs(sum));
  }
  fs::remove_all(dir);
}

double json_number(const std::string& json, const std::string& key) {
  const size_t at = json.find("\"" + key + "\": ");
  if (at == std::string::npos) return std::nan("");
  return std::stod(json.substr(at + key.size() + 4));
}

// Under a thermostat E is not conserved: the thermo has ecouple (−the heat the thermostat put in)
// and econserve = total + ecouple (per atom with thermo_norm), the screen an EConserve column, and
// the summary the conserved energy's drift per particle and time unit where an NVE run has its
// energy error.
TEST(Terminal, AThermostattedRunShowsTheEnergyItConservesWithTheHeat) {
  const fs::path d = scratch_dir("screen_nvt");
  const std::string args =
      " --no-progress --set run.t_end=0.15 --set output.screen_interval=0.03 --set thermostat.style=langevin"
      " --set thermostat.temperature=1.0 --set thermostat.damp=0.5 --set thermostat.seed=3"
      " --set monitor.energy_error=0";
  const CliResult nvt = cli("run " + melt() + args + " -o " + (d / "total").string());
  const CliResult norm = cli("run " + melt() + args + " --set output.thermo_norm=true -o " + (d / "norm").string());
  ASSERT_EQ(nvt.code, 0) << nvt.err;
  ASSERT_EQ(norm.code, 0) << norm.err;
  const test::CsvTable csv = test::read_csv((d / "total" / "thermo.csv").string());
  const ScreenLines s = screen_lines(nvt.out);
  ASSERT_EQ(std::count(s.labels.begin(), s.labels.end(), "EConserve"), 1) << nvt.out;
  expect_lines_are_csv_rows(s, csv);
  const ScreenLines sn = screen_lines(norm.out);
  ASSERT_EQ(std::count(sn.labels.begin(), sn.labels.end(), "EConserve/N"), 1) << norm.out;
  expect_lines_are_csv_rows(sn, test::read_csv((d / "norm" / "thermo.csv").string()), "_per_atom");
  const size_t ec = csv.col("econserve"), total = csv.col("total"), heat = csv.col("ecouple");
  EXPECT_EQ(csv.rows.front()[heat], 0.0);
  EXPECT_NE(csv.rows.back()[heat], 0.0);
  for (const auto& row : csv.rows) EXPECT_NEAR(row[ec], row[total] + row[heat], 1e-10 * std::abs(row[total]));
  // The summary: the conserved energy's drift, not |E − E(0)|, which the heat makes large.
  EXPECT_NE(nvt.out.find("conserved:     E + ecouple"), std::string::npos) << nvt.out;
  EXPECT_EQ(nvt.out.find("max |E - E(0)|"), std::string::npos) << nvt.out;
  const std::string json = slurp(d / "total" / "summary.json");
  const double ec0 = csv.rows.front()[ec], ec1 = csv.rows.back()[ec];
  EXPECT_NEAR(json_number(json, "initial_conserved_energy"), ec0, 1e-10 * std::abs(ec0));
  EXPECT_NEAR(json_number(json, "final_conserved_energy"), ec1, 1e-10 * std::abs(ec1));
  const double drift = (ec1 - ec0) / (kMeltParticles * 0.15);
  EXPECT_NEAR(json_number(json, "conserved_energy_drift"), drift, 1e-9 * std::abs(ec0) / (kMeltParticles * 0.15));
  EXPECT_NE(drift, 0.0);
  // Without a thermostat: the energy error as before, no ecouple or econserve.
  const CliResult nve = cli("run " + melt() + " --no-progress -q --set run.t_end=0.03 -o " + (d / "nve").string());
  ASSERT_EQ(nve.code, 0) << nve.err;
  EXPECT_NE(nve.out.find("max |E - E(0)|"), std::string::npos) << nve.out;
  EXPECT_EQ(nve.out.find("conserved:"), std::string::npos) << nve.out;
  const test::CsvTable plain = test::read_csv((d / "nve" / "thermo.csv").string());
  EXPECT_EQ(std::count(plain.header.begin(), plain.header.end(), "econserve"), 0);
  fs::remove_all(d);
}

TEST(Terminal, ThermoLinesAreTheThermoRowsAtTheScreenInterval) {
  const fs::path dir = scratch_dir("screen");
  const CliResult r =
      cli("run " + melt() + " --no-progress --set run.t_end=0.3 --set output.screen_interval=0.075 -o " + dir.string());
  ASSERT_EQ(r.code, 0) << r.err;
  const ScreenLines s = screen_lines(r.out);
  ASSERT_EQ(s.labels, (std::vector<std::string>{"Step", "Time", "Temp", "KinEng", "PotSlow", "PotStiff", "TotEng",
                                                "Press", "S/CPU"}))
      << r.out;
  const std::vector<double> t = times_of(s);
  ASSERT_EQ(t.size(), 5u) << r.out;  // 0, 0.075, …, 0.3: every fifth row of the thermo file
  for (size_t k = 0; k < t.size(); ++k) EXPECT_NEAR(t[k], 0.075 * k, 1e-12);
  expect_lines_are_csv_rows(s, test::read_csv((dir / "thermo.csv").string()));
  // The header comes once, before the first line; the lines come before the summary.
  EXPECT_LT(r.out.find("Step"), r.out.find("method:"));
  fs::remove_all(dir);
}

TEST(Terminal, TheDefaultIsAboutTenLinesAndTheLastStateIsAlwaysShown) {
  const fs::path dir = scratch_dir("screen_default");
  // t_end = 0.3 on the thermo grid of 0.015: 20 rows, a line every 2 (round(0.03/0.015)), 11 lines.
  CliResult r = cli("run " + melt() + " --no-progress --set run.t_end=0.3 -o " + dir.string());
  ASSERT_EQ(r.code, 0) << r.err;
  EXPECT_EQ(screen_lines(r.out).rows.size(), 11u) << r.out;
  // An interval that does not divide t_end: the last state gets a line anyway.
  r = cli("run " + melt() + " --no-progress --set run.t_end=0.2 --set output.screen_interval=0.08 -o " + dir.string());
  ASSERT_EQ(r.code, 0) << r.err;
  const std::vector<double> t = times_of(screen_lines(r.out));
  ASSERT_EQ(t.size(), 4u) << r.out;  // 0; the first thermo rows at or after 0.08 and 0.16; the end
  EXPECT_NEAR(t[1], 0.09, 1e-12);
  EXPECT_NEAR(t[2], 0.165, 1e-12);
  EXPECT_NEAR(t[3], 0.2, 1e-12);
  // 0: no lines.
  r = cli("run " + melt() + " --no-progress --set run.t_end=0.05 --set output.screen_interval=0 -o " + dir.string());
  ASSERT_EQ(r.code, 0) << r.err;
  EXPECT_EQ(r.out.find("Step"), std::string::npos) << r.out;
  fs::remove_all(dir);
}

TEST(Terminal, ScreenLinesChangeNoOutputBitForBit) {
  const fs::path d = scratch_dir("screen_same");
  const std::string args = " --no-progress --set run.t_end=0.15";
  const CliResult on = cli("run " + melt() + args + " --set output.screen_interval=0.015 -o " + (d / "on").string());
  const CliResult off = cli("run " + melt() + args + " --quiet -o " + (d / "off").string());
  ASSERT_EQ(on.code, 0) << on.err;
  ASSERT_EQ(off.code, 0) << off.err;
  EXPECT_EQ(screen_lines(on.out).rows.size(), 11u) << on.out;  // a line at every thermo row
  EXPECT_EQ(screen_lines(off.out).rows.size(), 0u) << off.out;
  for (const char* f : {"thermo.csv", "trajectory.xyz", "checkpoint.bin", "topology.data", "histograms.csv"})
    EXPECT_TRUE(slurp(d / "on" / f) == slurp(d / "off" / f)) << f << " differs";
  for (const char* obs : {"total", "pressure", "action_1"})
    EXPECT_EQ(h5_observable(d / "on" / "trajectory.h5", obs), h5_observable(d / "off" / "trajectory.h5", obs)) << obs;
  fs::remove_all(d);
}

TEST(Terminal, QuietLeavesStdoutToTheSummaryAndStderrToNotes) {
  const fs::path dir = scratch_dir("quiet");
  const CliResult r = cli("run " + melt() + " --quiet --set run.t_end=0.03 -o " + dir.string());
  ASSERT_EQ(r.code, 0) << r.err;
  EXPECT_EQ(r.out.find("Step"), std::string::npos) << r.out;
  EXPECT_EQ(r.out.rfind("stiffmd ", 0), 0u) << r.out;  // the first line, then the summary
  EXPECT_NE(r.out.find("method:"), std::string::npos) << r.out;
  EXPECT_EQ(r.err.find("prepare: projecting"), std::string::npos) << r.err;
  EXPECT_NE(r.err.find("prepare: projected"), std::string::npos) << r.err;  // what it did, as before
  fs::remove_all(dir);
}

TEST(Terminal, PrepareSaysWhatItDoesWhileItDoesIt) {
  const fs::path dir = scratch_dir("prepare_progress");
  const CliResult r = cli("run " + melt() + " --no-progress --set run.t_end=0.01 -o " + dir.string());
  ASSERT_EQ(r.code, 0) << r.err;
  // In order: projection, relaxation (100 steps: a line every 10), vibrations, then the summary line.
  const size_t project = r.err.find("prepare: projecting 64 particles onto 56 stiff bonds"),
               relax = r.err.find("prepare: relaxing 100 steps"), step10 = r.err.find("prepare: relax step 10/100:"),
               step100 = r.err.find("prepare: relax step 100/100:"),
               vibrate = r.err.find("prepare: thermalising the vibrations of 56 stiff bonds at T = 1"),
               done = r.err.find("prepare: projected onto the constraint manifold");
  ASSERT_NE(project, std::string::npos) << r.err;
  EXPECT_LT(project, relax);
  EXPECT_LT(relax, step10);
  EXPECT_LT(step10, step100);
  EXPECT_LT(step100, vibrate);
  EXPECT_LT(vibrate, done);
  size_t relax_lines = 0;
  for (size_t p = r.err.find("prepare: relax step"); p != std::string::npos;
       p = r.err.find("prepare: relax step", p + 1))
    ++relax_lines;
  EXPECT_EQ(relax_lines, 10u) << r.err;
  fs::remove_all(dir);
}

TEST(Terminal, ThermoNormDividesTheEnergiesByNInTheCsvTheH5mdAndTheLine) {
  const fs::path d = scratch_dir("norm");
  const std::string args = " --no-progress --set run.t_end=0.15 --set output.screen_interval=0.03";
  const CliResult total = cli("run " + melt() + args + " -o " + (d / "total").string());
  const CliResult norm = cli("run " + melt() + args + " --set output.thermo_norm=true -o " + (d / "norm").string());
  ASSERT_EQ(total.code, 0) << total.err;
  ASSERT_EQ(norm.code, 0) << norm.err;
  const auto a = test::read_csv((d / "total" / "thermo.csv").string());
  const auto b = test::read_csv((d / "norm" / "thermo.csv").string());
  ASSERT_EQ(a.rows.size(), b.rows.size());
  ASSERT_EQ(a.header.size(), b.header.size());
  const std::vector<std::string> extensive = {"kinetic", "potential_slow", "potential_stiff", "total", "energy_drift"};
  size_t num_divided = 0;
  for (size_t c = 0; c < a.header.size(); ++c) {
    const bool divided = std::find(extensive.begin(), extensive.end(), a.header[c]) != extensive.end();
    num_divided += divided;
    EXPECT_EQ(b.header[c], divided ? a.header[c] + "_per_atom" : a.header[c]);
    // The CSV's 12 significant digits (%.12g) of the same numbers: equal within its rounding.
    for (size_t k = 0; k < a.rows.size(); ++k) {
      const double want = divided ? a.rows[k][c] / kMeltParticles : a.rows[k][c];
      EXPECT_NEAR(b.rows[k][c], want, 1e-11 * std::abs(want)) << a.header[c] << " row " << k;
    }
  }
  EXPECT_EQ(num_divided, extensive.size());
  // H5MD holds the doubles themselves: exactly total / N, the same names.
  for (const std::string& name : {std::string("total"), std::string("kinetic"), std::string("pressure")}) {
    const bool divided = name != "pressure";
    const auto x = h5_observable(d / "total" / "trajectory.h5", name);
    const auto y = h5_observable(d / "norm" / "trajectory.h5", divided ? name + "_per_atom" : name);
    ASSERT_EQ(x.size(), y.size()) << name;
    ASSERT_GT(x.size(), 3u) << name;
    EXPECT_TRUE(h5_observable(d / "norm" / "trajectory.h5", divided ? name : name + "_per_atom").empty()) << name;
    for (size_t k = 0; k < x.size(); ++k) EXPECT_EQ(y[k], divided ? x[k] / kMeltParticles : x[k]) << name;
  }
  // The terminal: "/N" on the energies, whose values are the per-atom rows; T and P unchanged.
  const ScreenLines s = screen_lines(norm.out);
  ASSERT_EQ(s.labels, (std::vector<std::string>{"Step", "Time", "Temp", "KinEng/N", "PotSlow/N", "PotStiff/N",
                                                "TotEng/N", "Press", "S/CPU"}))
      << norm.out;
  EXPECT_EQ(s.rows.size(), 6u);
  expect_lines_are_csv_rows(s, b, "_per_atom");
  fs::remove_all(d);
}

TEST(Terminal, ARestartedRunContinuesItsLines) {
  const fs::path d = scratch_dir("screen_restart");
  const std::string args = " --no-progress --set output.screen_interval=0.075";
  const CliResult whole = cli("run " + melt() + args + " -o " + (d / "whole").string());
  const CliResult first = cli("run " + melt() + args + " --set run.t_end=0.3 -o " + (d / "parts").string());
  ASSERT_EQ(whole.code, 0) << whole.err;
  ASSERT_EQ(first.code, 0) << first.err;
  const CliResult second = cli("run " + melt() + args + " -o " + (d / "parts").string() + " --restart " +
                               (d / "parts" / "checkpoint.bin").string());
  ASSERT_EQ(second.code, 0) << second.err;
  // The restart goes on from the checkpoint at t = 0.3 with the uninterrupted run's lines (the
  // one at the checkpoint again, as its files write that frame again), S/CPU aside.
  const ScreenLines w = screen_lines(whole.out), p = screen_lines(second.out);
  ASSERT_EQ(w.rows.size(), 9u) << whole.out;
  ASSERT_EQ(p.rows.size(), 5u) << second.out;
  for (size_t k = 0; k < p.rows.size(); ++k) {
    const auto& a = w.rows[4 + k];
    const auto& b = p.rows[k];
    EXPECT_EQ(std::vector<std::string>(a.begin(), a.end() - 1), std::vector<std::string>(b.begin(), b.end() - 1));
  }
  fs::remove_all(d);
}

TEST(Terminal, TheProgressBarNeverWritesIntoAPipe) {
  // The binary, its stderr into a pipe: not a character of the bar.
  const fs::path dir = scratch_dir("bar_pipe");
  const CliResult r = cli("run " + melt() + " --set run.t_end=0.1 -o " + dir.string() + " 2>&1 | cat");
  ASSERT_EQ(r.code, 0) << r.err;
  EXPECT_EQ(r.out.find('\r'), std::string::npos) << r.out;
  EXPECT_EQ(r.out.find("ETA"), std::string::npos) << r.out;
  fs::remove_all(dir);
  // The class on a pipe: off, and silent.
  int fd[2];
  ASSERT_EQ(::pipe(fd), 0);
  std::FILE* w = ::fdopen(fd[1], "w");
  {
    Progress bar(true, 100, w);
    EXPECT_FALSE(bar.enabled());
    for (int k = 1; k <= 100; ++k) bar.update(k);
    bar.finish(100);
  }
  std::fclose(w);
  char c;
  EXPECT_EQ(::read(fd[0], &c, 1), 0);  // end of file: nothing was written
  ::close(fd[0]);
}

TEST(Terminal, TheProgressBarOnATerminalIsRedrawnAtMostTwiceASecond) {
  const int master = ::posix_openpt(O_RDWR | O_NOCTTY);
  ASSERT_GE(master, 0);
  ASSERT_EQ(::grantpt(master), 0);
  ASSERT_EQ(::unlockpt(master), 0);
  const int slave = ::open(::ptsname(master), O_WRONLY | O_NOCTTY);
  ASSERT_GE(slave, 0);
  std::FILE* tty = ::fdopen(slave, "w");
  ASSERT_NE(tty, nullptr);
  const auto start = std::chrono::steady_clock::now();
  double seconds = 0;
  std::int64_t done = 0;
  volatile double sink = 0;  // work the compiler cannot drop
  {
    Progress bar(true, 1'000'000'000, tty);
    ASSERT_TRUE(bar.enabled());
    while (seconds < 1.2) {  // steps of about a microsecond for 1.2 s
      bar.update(++done);
      for (int spin = 0; spin < 200; ++spin) sink = sink + 1.0;
      if ((done & 255) == 0) seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
    }
    bar.finish(done);
  }
  std::fclose(tty);
  std::string shown;
  ::fcntl(master, F_SETFL, O_NONBLOCK);
  char buf[4096];
  for (ssize_t n; (n = ::read(master, buf, sizeof buf)) > 0;) shown.append(buf, static_cast<size_t>(n));
  ::close(master);
  size_t draws = 0;
  for (size_t p = shown.find("\r["); p != std::string::npos; p = shown.find("\r[", p + 1)) ++draws;
  // The first update, then one per half second at most (≤ 3 in 1.2 s), then the end.
  EXPECT_GE(draws, 2u) << shown;
  EXPECT_LE(draws, 4u + 1u) << shown;
  EXPECT_NE(shown.find(std::to_string(done) + "/1000000000 steps"), std::string::npos) << shown;
}

}  // namespace
}  // namespace stiffmd
