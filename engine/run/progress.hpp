// A progress bar with ETA on stderr, drawn only when stderr is a terminal (never into a pipe or
// a CI log), redrawn at most every half second of wall time and at the end.
#pragma once

#include <unistd.h>

#include <algorithm>
#include <chrono>
#include <cstdint>
#include <cstdio>

namespace stiffmd {

class Progress {
 public:
  // out: the stream of the bar (a terminal, or nothing is drawn).
  Progress(bool wanted, std::int64_t total, std::FILE* out = stderr)
      : enabled_(wanted && isatty(fileno(out))),
        out_(out),
        total_(total),
        start_(clock::now()),
        last_check_(start_),
        last_draw_(start_) {}

  bool enabled() const { return enabled_; }

  // After `done` steps. The clock is read every check_every_ steps, adapted to the step rate so
  // that it is read about every 50 ms: cheap at a microsecond per step and prompt at a second.
  void update(std::int64_t done) {
    if (enabled_ && --countdown_ <= 0) check(done);
  }

  // Erases the bar (before a line is printed on the same terminal); the next update redraws it.
  void clear() {
    if (!enabled_ || !drawn_) return;
    std::fputs("\r\033[K", out_);
    std::fflush(out_);
    drawn_ = false;
  }

  // The bar as it ends: `done` of the total steps (fewer when a signal stopped the run).
  void finish(std::int64_t done) {
    if (!enabled_) return;
    draw(done, clock::now());
    std::fputc('\n', out_);
    drawn_ = false;
  }

 private:
  using clock = std::chrono::steady_clock;

  // The clock read of update, out of line: the run loop calls update every step.
  [[gnu::noinline]] void check(std::int64_t done) {
    const auto now = clock::now();
    const double since = std::chrono::duration<double>(now - last_check_).count();
    const double rate = static_cast<double>(done - done_at_check_) / std::max(since, 1e-9);
    check_every_ = static_cast<std::int64_t>(std::clamp(0.05 * rate, 1.0, 1048576.0));
    countdown_ = check_every_;
    last_check_ = now;
    done_at_check_ = done;
    if (now - last_draw_ < std::chrono::milliseconds(500) && drawn_) return;
    draw(done, now);
  }

  void draw(std::int64_t done, clock::time_point now) {
    last_draw_ = now;
    drawn_ = true;
    const double frac = total_ > 0 ? static_cast<double>(done) / total_ : 1.0;
    const double elapsed = std::chrono::duration<double>(now - start_).count();
    const double eta = frac > 0 ? elapsed * (1.0 - frac) / frac : 0.0;
    const int width = 40, filled = static_cast<int>(frac * width);
    std::fprintf(out_, "\r[%.*s%*s] %5.1f%%  %lld/%lld steps  ETA %.0f s ", filled,
                 "########################################", width - filled, "", 100 * frac,
                 static_cast<long long>(done), static_cast<long long>(total_), eta);
    std::fflush(out_);
  }

  bool enabled_;
  std::FILE* out_;
  std::int64_t total_;
  clock::time_point start_, last_check_, last_draw_;
  std::int64_t check_every_ = 1, countdown_ = 1, done_at_check_ = 0;
  bool drawn_ = false;
};

}  // namespace stiffmd
