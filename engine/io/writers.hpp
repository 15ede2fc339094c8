// Run outputs: extended XYZ trajectory (plain or gzip) and CSV tables. Each frame/row is
// written whole and flushed, so a run stopped by a numerical failure (exit 3), a signal or
// a kill leaves files that hold every frame written before it. On restart the files are
// continued: anything written after the checkpoint's time is dropped first, then appended.
#pragma once

#include <cmath>
#include <cstdint>
#include <limits>
#include <memory>
#include <string>
#include <vector>

#include "core/box.hpp"
#include "core/state.hpp"

namespace stiffmd {

// A text file that is plain or gzip-compressed by its name (".gz").
class TextFile {
 public:
  // mode "w" (truncate) or "a" (append).
  TextFile(const std::string& path, const char* mode);
  ~TextFile();
  TextFile(const TextFile&) = delete;
  TextFile& operator=(const TextFile&) = delete;
  void write(const std::string& text);  // whole, then flushed; throws InputError on failure

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

// Continuing files on restart: keeps the leading part of `path` that was written up to
// time `t` (a frame or row whose time is ≤ t + tolerance), drops the rest. Returns false if
// the file does not exist (the caller then starts it afresh).
bool truncate_xyz_after(const std::string& path, double t, double tolerance);
bool truncate_csv_after(const std::string& path, double t, double tolerance, const std::vector<std::string>& columns);

// Extended XYZ (read by ASE, OVITO): per frame "N", a comment line with
//   Properties=species:S:1:pos:R:3[:masses:R:1][:velo:R:3] time=<t> step=<n> pbc="F F F" [Lattice="..."]
// then one line per particle. Species are element symbols, named per particle type: each row is
// given its particle's type (a decomposed run's rank 0 gets it with the particle's row), so no
// per-particle table of N names is kept.
class XyzWriter {
 public:
  // species: the element symbol of each particle type. masses (one per type, or empty): a
  // masses:R:1 column, so that ASE takes the beads' masses from the file instead of the element's
  // (N: 14.007). Named "masses", ASE's own name for the array, because ASE 3.22 maps a column
  // called "mass" to nothing (it stays arrays["mass"]).
  XyzWriter(const std::string& path, std::vector<std::string> species, const Box& box, bool velocities,
            bool append = false, std::vector<double> masses = {});
  // Times and velocities written in other units than the engine's: t·time_scale, v·velocity_scale
  // (core/units.hpp; positions need none).
  void set_units(double time_scale, double velocity_scale) {
    time_scale_ = time_scale, velocity_scale_ = velocity_scale;
  }
  // The frame of state s, whose particle i has type type[i].
  void write(const State& s, const int* type);
  // A frame written in pieces, in order of global index (a decomposed run's rank 0 streams it in
  // blocks: engine/run/outputs.cpp): the frame's first two lines, then the lines of the next
  // `count` particles (x, and v when the frame has velocities: 3 × count, column-major; their
  // types: count), each piece written as it comes. write(s, type) is begin_frame, one write_rows,
  // the same bytes.
  void begin_frame(int n, double t, std::int64_t step);
  void write_rows(int count, const double* x, const double* v, const int* type);
  // The box of the frames written from now on (a barostat moves it): their Lattice and Origin.
  void set_box(const Box& box);

 private:
  TextFile file_;
  double time_scale_ = 1.0, velocity_scale_ = 1.0;
  std::vector<std::string> species_;  // per type
  std::vector<double> masses_;        // per type
  std::string header_;                // the invariant part of the comment line
  bool velocities_;
  std::string buffer_;
};

class CsvWriter {
 public:
  CsvWriter(const std::string& path, const std::vector<std::string>& columns, bool append = false);
  void write(const std::vector<double>& row);

 private:
  TextFile file_;
  std::string buffer_;
};

// Output at a fixed time interval, independent of the step: due(t) is true once per
// interval boundary crossed (every step when the interval is shorter than the step); an interval
// that is not > 0 is never due.
class IntervalSchedule {
 public:
  // The step of a grid that is never due again.
  static constexpr std::int64_t kNever = std::numeric_limits<std::int64_t>::max();

  explicit IntervalSchedule(double interval) : interval_(interval) {}
  bool due(double t) {
    if (!(interval_ > 0.0)) return false;
    const long long k = index(t);
    if (k <= last_) return false;
    last_ = k;
    return true;
  }
  // On restart: the boundary at or before t has been served by the interrupted run.
  void served_until(double t) {
    if (interval_ > 0.0) last_ = index(t);
  }

  // The first step j > k at which due(time(j)) will be true, given the steps' times time(j) (a
  // run's t_j = t0 + (j − k0) h, nondecreasing in j) and h > 0: found once per due step, so that a
  // run calls due() only there, and between outputs compares integers instead of dividing and
  // rounding a time every step. due() is false at every step before it and changes nothing there,
  // so skipping those calls is the same schedule. The boundary's step is guessed from its time
  // (index(t) > last_ from t = (last_ + 1 − 1e-9) interval / (1 + 1e-12) on) two steps early, then
  // index(time(j)) itself, nondecreasing in j, is tested forwards to the first step past it: the
  // exact step. (After 64 steps the search stops early, which costs one due() that is false.)
  // kNever when the grid is never due or its next boundary lies beyond 10¹⁸ steps.
  template <class Time>
  std::int64_t next_due_step(std::int64_t k, double h, Time time) const {
    if (!(interval_ > 0.0) || !(h > 0.0)) return kNever;
    const double boundary = (static_cast<double>(last_) + 1.0 - 1e-9) * interval_ / (1.0 + 1e-12);
    const double ahead = std::floor((boundary - time(k)) / h) - 2.0;
    if (!(ahead < 1e18)) return kNever;
    std::int64_t j = k + 1 + (ahead > 0.0 ? static_cast<std::int64_t>(ahead) : 0);
    for (int n = 0; n < 64 && index(time(j)) <= last_; ++n) ++j;
    return j;
  }

 private:
  long long index(double t) const { return static_cast<long long>(std::floor(t / interval_ * (1.0 + 1e-12) + 1e-9)); }
  double interval_;
  long long last_ = -1;
};

}  // namespace stiffmd
