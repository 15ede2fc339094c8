// The thermo line on stdout (the deck's [output] screen_interval): a header, then one line per
// screen interval — step, time, temperature, energies (by level when the scene has a fast level;
// Fixman's potential under fixman; with a thermostat, the energy conserved with its heat),
// pressure when the box is periodic, and steps per wall-clock second (LAMMPS's S/CPU) — LAMMPS's
// thermo output in spirit. Lines are printed at thermo samples only, from the row the thermo file
// gets (ThermoOutput: normalised the same way), so the terminal costs no force evaluation and
// changes no output.
#pragma once

#include <chrono>
#include <cstdint>
#include <cstdio>
#include <string>
#include <vector>

#include "engine/io/writers.hpp"
#include "engine/observe/observables.hpp"

namespace stiffmd {

class ThermoScreen {
 public:
  // out: where the lines go (null: nowhere); interval 0: no lines. levels: the scene has a fast
  // level (show the potential energy by level; else one potential column).
  ThermoScreen(const ThermoOutput& table, double interval, std::FILE* out, bool levels);
  bool on() const { return on_; }
  // On restart: the lines up to t were printed by the interrupted run.
  void served_until(double t) { due_.served_until(t); }
  // At a thermo sample at time t (`final`: the run's last state, always shown): whether a line is due.
  bool due(double t, bool final);
  // Prints the line for the written row `row` (ThermoOutput's), the header before the first.
  void print(const std::vector<double>& row, std::int64_t step);
  const std::string& header() const { return header_; }

 private:
  using clock = std::chrono::steady_clock;
  bool on_;
  std::FILE* out_;
  IntervalSchedule due_;
  std::vector<int> columns_;  // of the written row, in screen order
  std::string header_;
  bool header_printed_ = false;
  double last_printed_t_ = -1.0;
  bool have_last_ = false;
  std::int64_t last_step_ = 0;
  clock::time_point last_time_;
};

}  // namespace stiffmd
