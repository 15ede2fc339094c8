// The one number formatter (core/format.hpp).
#include "core/format.hpp"

#include <gtest/gtest.h>

#include <cstdlib>
#include <limits>
#include <string>

namespace stiffmd {
namespace {

TEST(Format, NumberIsTheStreamsShortForm) {
  EXPECT_EQ(format_number(0.1234567), "0.123457");
  EXPECT_EQ(format_number(1e20), "1e+20");
  EXPECT_EQ(format_number(100000.0), "100000");
  EXPECT_EQ(format_number(0.97000000001, 10), "0.97");
  EXPECT_EQ(format_number(1.23456789012, 10), "1.23456789");
}

TEST(Format, ExactReadsBackInTheFewestDigits) {
  EXPECT_EQ(format_exact(0.1234567), "0.1234567");  // was 0.12345670000000001 (17 digits)
  EXPECT_EQ(format_exact(1e20), "1e+20");
  EXPECT_EQ(format_exact(100000.0), "100000");
  EXPECT_EQ(format_exact(0.1 + 0.2), "0.30000000000000004");
  for (double v : {1.0 / 3.0, 2.0 / 3.0 * 1e-300, std::numeric_limits<double>::max(), 123456.789, -7.25})
    EXPECT_EQ(std::strtod(format_exact(v).c_str(), nullptr), v) << format_exact(v);
}

TEST(Format, ShortestIsToChars) {
  std::string s;
  append_shortest(s, 0.1);
  s += ' ';
  append_shortest(s, 1e20);
  s += ' ';
  append_shortest(s, 100000.0);
  EXPECT_EQ(s, "0.1 1e+20 1e+05");
}

}  // namespace
}  // namespace stiffmd
