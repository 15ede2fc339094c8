// Run outputs: extended XYZ trajectory and thermo CSV. Each frame/row is written whole and
// flushed, so a run stopped by a numerical failure (exit 3) or a kill leaves files that
// hold every frame written before it.
#pragma once

#include <cmath>
#include <cstdio>
#include <string>
#include <vector>

#include "engine/box.hpp"
#include "engine/state.hpp"

namespace stiffmd {

// Extended XYZ (read by ASE, OVITO): per frame "N", a comment line with
//   Properties=species:S:1:pos:R:3[:velo:R:3] time=<t> step=<n> pbc="F F F" [Lattice="..."]
// then one line per particle. Species are element symbols.
class XyzWriter {
 public:
  XyzWriter(const std::string& path, std::vector<std::string> species, const Box& box, bool velocities);
  ~XyzWriter();
  XyzWriter(const XyzWriter&) = delete;
  XyzWriter& operator=(const XyzWriter&) = delete;
  void write(const State& s);

 private:
  std::FILE* file_;
  std::string path_;
  std::vector<std::string> species_;
  std::string header_;  // the invariant part of the comment line
  bool velocities_;
};

class CsvWriter {
 public:
  CsvWriter(const std::string& path, const std::vector<std::string>& columns);
  ~CsvWriter();
  CsvWriter(const CsvWriter&) = delete;
  CsvWriter& operator=(const CsvWriter&) = delete;
  void write(const std::vector<double>& row);

 private:
  std::FILE* file_;
  std::string path_;
};

// Output at a fixed time interval, independent of the step: due(t) is true once per
// interval boundary crossed (every step when the interval is shorter than the step).
class IntervalSchedule {
 public:
  explicit IntervalSchedule(double interval) : interval_(interval) {}
  bool due(double t) {
    const auto k = static_cast<long long>(std::floor(t / interval_ * (1.0 + 1e-12) + 1e-9));
    if (k <= last_) return false;
    last_ = k;
    return true;
  }

 private:
  double interval_;
  long long last_ = -1;
};

}  // namespace stiffmd
