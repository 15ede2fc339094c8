// SIGINT/SIGTERM as a request to stop cleanly: the run loop finishes the macro step in
// progress, writes a checkpoint, flushes its outputs and exits (exit code 128 + signal).
//
// For tests of interruption at an exact step: STIFFMD_SIGNAL_AT_STEP="K:SIG" makes the run raise
// signal SIG at itself once step K has been taken and its outputs written, where a signal from
// outside could arrive — a real signal through the real handler (SIGTERM, SIGINT) or a real
// death (SIGKILL), but at a reproducible step.
#pragma once

#include <csignal>
#include <cstdint>
#include <cstdio>
#include <cstdlib>

namespace stiffmd {

inline volatile std::sig_atomic_t g_stop_signal = 0;

inline void install_stop_handlers() {
  auto handler = [](int sig) { g_stop_signal = sig; };
  std::signal(SIGINT, handler);
  std::signal(SIGTERM, handler);
}

inline int stop_requested() {
  return g_stop_signal;
}

// The step and signal of STIFFMD_SIGNAL_AT_STEP ({-1, 0} when unset or malformed).
struct SignalAtStep {
  std::int64_t step = -1;
  int signal = 0;

  static SignalAtStep from_environment() {
    SignalAtStep s;
    const char* e = std::getenv("STIFFMD_SIGNAL_AT_STEP");
    long long k = 0;
    int sig = 0;
    if (e && std::sscanf(e, "%lld:%d", &k, &sig) == 2 && k >= 0 && sig > 0) s = {k, sig};
    return s;
  }
  void at(std::int64_t k) const {
    if (k == step) std::raise(signal);
  }
};

}  // namespace stiffmd
