// Numbers as text, in one place: for messages, a short human form (format_number) or the exact
// value in the fewest digits (format_exact); for files, the shortest round-trip text of
// std::to_chars (append_shortest).
#pragma once

#include <charconv>
#include <cstdlib>
#include <sstream>
#include <string>

namespace stiffmd {

// `significant` digits as `std::ostream << v` prints them (%g): "0.001", "1e+20", "3.14159".
inline std::string format_number(double v, int significant = 6) {
  std::ostringstream s;
  s.precision(significant);
  s << v;
  return s.str();
}

// The fewest significant digits, at least 6, that read back as v (%g style: "100000", "1e+20",
// "0.1234567"): a deck's value quoted exactly, without the noise digits of a fixed 17.
inline std::string format_exact(double v) {
  for (int p = 6; p < 17; ++p) {
    std::string t = format_number(v, p);
    if (std::strtod(t.c_str(), nullptr) == v) return t;
  }
  return format_number(v, 17);
}

// Appends the shortest text that reads back as v (std::to_chars' guarantee): for data files.
inline void append_shortest(std::string& out, double v) {
  char buf[32];
  const auto r = std::to_chars(buf, buf + sizeof buf, v);
  out.append(buf, r.ptr);
}

}  // namespace stiffmd
