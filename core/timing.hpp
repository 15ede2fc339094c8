// Where a run's wall time goes (docs/design.md §9): the step loop's time split into phases, as
// LAMMPS's "MPI task timing breakdown" splits its loop. Code marks a phase with a ScopedPhase;
// nested scopes are exclusive (the time of a neighbour-list build inside a pair evaluation is the
// build's, not the pair forces'), and the time outside every scope while the clock runs is
// "other". So the phases add up to the clock's span by construction, and a test that compares
// their sum with a separately measured loop time checks that no time is counted twice or lost.
//
// A Run owns its clock and runs it while it steps (PhaseClock::current); the thread that runs the
// step loop reads and writes it, and a scope opened inside a parallel region (by a worker thread)
// records nothing. With no clock running a ScopedPhase costs one branch, with one two
// steady_clock reads.
#pragma once

#include <array>
#include <chrono>
#include <string_view>

#ifdef _OPENMP
#include <omp.h>
#endif

namespace stiffmd {

enum class Phase : int {
  pair,         // pair forces through the neighbour list
  kspace,       // the reciprocal-space sums of long-range electrostatics (Ewald, PPPM)
  bonded,       // bonds, angles, dihedrals, external fields; the stiff bonds (and the fused micro step)
  neighbor,     // neighbour-list builds and their keep-or-rebuild checks
  constraints,  // SHAKE/RATTLE, the projections, the mollifier, Fixman's potential, the stiff modes
  integrate,    // kicks and drifts
  thermostat,   // the O steps, the Langevin force, velocity rescaling
  output,       // thermo samples' bookkeeping, trajectories, checkpoints, the terminal
  domain,       // a decomposed run's halo, its step's reduction, redistributing the molecules
  other,        // the rest of the loop
  count
};

inline constexpr std::array<std::string_view, static_cast<int>(Phase::count)> kPhaseNames = {
    "pair", "kspace", "bonded", "neighbor", "constraints", "integrate", "thermostat", "output", "domain", "other"};

class PhaseClock {
 public:
  using clock = std::chrono::steady_clock;
  // The clock that is running (a Run's, while it steps), or none.
  static PhaseClock*& current() {
    static PhaseClock* running = nullptr;
    return running;
  }
  // Runs this clock (charging "other" until a scope opens) until pause(); the phases accumulate
  // over every span it runs.
  void resume() {
    depth_ = 0;
    stack_[0] = Phase::other;
    last_ = clock::now();
    current() = this;
  }
  void pause() {
    if (current() != this) return;
    charge(clock::now());
    current() = nullptr;
  }
  double seconds(Phase p) const { return seconds_[static_cast<int>(p)]; }
  double total() const {
    double t = 0.0;
    for (double s : seconds_) t += s;
    return t;
  }

  // Whether this thread may record (the loop's thread, outside parallel regions).
  static bool recording_thread() {
#ifdef _OPENMP
    return !omp_in_parallel();
#else
    return true;
#endif
  }
  void enter(Phase p) {
    charge(clock::now());
    if (depth_ + 1 < static_cast<int>(stack_.size())) stack_[++depth_] = p;
  }
  void leave() {
    charge(clock::now());
    if (depth_ > 0) --depth_;
  }

 private:
  void charge(clock::time_point now) {
    seconds_[static_cast<int>(stack_[depth_])] += std::chrono::duration<double>(now - last_).count();
    last_ = now;
  }
  std::array<double, static_cast<int>(Phase::count)> seconds_{};
  std::array<Phase, 16> stack_{};
  int depth_ = 0;
  clock::time_point last_{};
};

// Marks the enclosing block as phase p while a run's clock is running.
class ScopedPhase {
 public:
  explicit ScopedPhase(Phase p) : clock_(PhaseClock::current()) {
    if (clock_ && PhaseClock::recording_thread())
      clock_->enter(p);
    else
      clock_ = nullptr;
  }
  ~ScopedPhase() {
    if (clock_ && PhaseClock::current() == clock_) clock_->leave();
  }
  ScopedPhase(const ScopedPhase&) = delete;
  ScopedPhase& operator=(const ScopedPhase&) = delete;

 private:
  PhaseClock* clock_;
};

}  // namespace stiffmd
