// SIGINT/SIGTERM as a request to stop cleanly: the run loop finishes the macro step in
// progress, writes a checkpoint, flushes its outputs and exits (exit code 128 + signal).
#pragma once

#include <csignal>

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

}  // namespace stiffmd
