// The process's peak resident set (getrusage's ru_maxrss: the high-water mark of physical memory
// since the process started, set-up included), in MiB. Linux reports ru_maxrss in KiB.
#pragma once

#include <sys/resource.h>

namespace stiffmd {

inline double peak_resident_mib() {
  rusage usage{};
  if (getrusage(RUSAGE_SELF, &usage) != 0) return 0.0;
  return static_cast<double>(usage.ru_maxrss) / 1024.0;
}

}  // namespace stiffmd
