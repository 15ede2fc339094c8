#include "engine/run/screen.hpp"

#include <utility>

namespace stiffmd {

ThermoScreen::ThermoScreen(const ThermoOutput& table, double interval, std::FILE* out, bool levels)
    : on_(out != nullptr && interval > 0), out_(out), due_(interval > 0 ? interval : 1.0) {
  // Thermo's column, the screen's label (LAMMPS's where there is one); "/N" when normalised.
  std::vector<std::pair<const char*, const char*>> shown = {
      {"time", "Time"}, {"temperature", "Temp"}, {"kinetic", "KinEng"}};
  if (levels)
    shown.insert(shown.end(), {{"potential_slow", "PotSlow"}, {"potential_stiff", "PotStiff"}});
  else
    shown.emplace_back("potential_slow", "PotEng");
  shown.emplace_back("potential_fixman", "PotFixman");
  shown.emplace_back("total", "TotEng");
  shown.emplace_back("econserve", "EConserve");  // with a thermostat: E + ecouple
  shown.emplace_back("pressure", "Press");
  char cell[64];
  std::snprintf(cell, sizeof cell, "%10s", "Step");
  header_ = cell;
  for (const auto& [name, label] : shown) {
    const int c = table.column(name);
    if (c < 0) continue;  // pressure: only in a periodic box; potential_fixman, econserve: fixman, a thermostat
    columns_.push_back(c);
    std::snprintf(cell, sizeof cell, " %14s", (std::string(label) + (table.normalised(c) ? "/N" : "")).c_str());
    header_ += cell;
  }
  std::snprintf(cell, sizeof cell, " %10s", "S/CPU");
  header_ += cell;
}

bool ThermoScreen::due(double t, bool final) {
  if (!on_) return false;
  if (final) return t != last_printed_t_;  // the last state, unless its line is printed already
  return due_.due(t);
}

void ThermoScreen::print(const std::vector<double>& row, std::int64_t step) {
  const auto now = clock::now();
  if (!header_printed_) {
    std::fprintf(out_, "%s\n", header_.c_str());
    header_printed_ = true;
  }
  std::fprintf(out_, "%10lld", static_cast<long long>(step));
  for (int c : columns_) std::fprintf(out_, " %14.8g", row[c]);
  // Steps per wall-clock second since the previous line (LAMMPS's S/CPU, also wall time); 0 on the first.
  const double dt = have_last_ ? std::chrono::duration<double>(now - last_time_).count() : 0.0;
  std::fprintf(out_, " %10.4g\n", dt > 0 ? static_cast<double>(step - last_step_) / dt : 0.0);
  std::fflush(out_);
  last_printed_t_ = row[0];
  have_last_ = true;
  last_step_ = step;
  last_time_ = now;
}

}  // namespace stiffmd
