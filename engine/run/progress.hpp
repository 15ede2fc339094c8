// A progress bar with ETA on stderr, drawn only when stderr is a terminal.
#pragma once

#include <unistd.h>

#include <chrono>
#include <cstdint>
#include <cstdio>

namespace stiffmd {

class Progress {
 public:
  Progress(bool wanted, std::int64_t total)
      : enabled_(wanted && isatty(STDERR_FILENO)), total_(total), start_(clock::now()), last_(start_) {}

  void update(std::int64_t done) {
    if (!enabled_ || (done & 1023) != 0) return;  // look at the clock rarely
    const auto now = clock::now();
    if (now - last_ < std::chrono::milliseconds(200)) return;
    last_ = now;
    draw(done, now);
  }

  // The bar as it ends: `done` of the total steps (fewer when a signal stopped the run).
  void finish(std::int64_t done) {
    if (!enabled_) return;
    draw(done, clock::now());
    std::fputc('\n', stderr);
  }

 private:
  using clock = std::chrono::steady_clock;

  void draw(std::int64_t done, clock::time_point now) {
    const double frac = total_ > 0 ? static_cast<double>(done) / total_ : 1.0;
    const double elapsed = std::chrono::duration<double>(now - start_).count();
    const double eta = frac > 0 ? elapsed * (1.0 - frac) / frac : 0.0;
    const int width = 40, filled = static_cast<int>(frac * width);
    std::fprintf(stderr, "\r[%.*s%*s] %5.1f%%  %lld/%lld steps  ETA %.0f s ", filled,
                 "########################################", width - filled, "", 100 * frac,
                 static_cast<long long>(done), static_cast<long long>(total_), eta);
    std::fflush(stderr);
  }

  bool enabled_;
  std::int64_t total_;
  clock::time_point start_, last_;
};

}  // namespace stiffmd
