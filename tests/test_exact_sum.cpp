// ExactSum (core/exact_sum.hpp): the value of a sum of non-negative terms, rounded once,
// whatever the order of the terms and however they are split into partial sums (threads,
// processes): what csvr's kinetic energy needs to be the same bits on any number of processes.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <random>
#include <vector>

#include "core/exact_sum.hpp"

namespace stiffmd {
namespace {

// Terms of every size a kinetic energy has (1e-12 … 1e4), fractions above ½ among them.
std::vector<double> terms(int n, unsigned seed) {
  std::mt19937_64 rng(seed);
  std::uniform_real_distribution<double> exponent(-12.0, 4.0), mantissa(0.5, 1.0);
  std::vector<double> t(n);
  for (double& v : t) v = mantissa(rng) * std::pow(10.0, exponent(rng));
  return t;
}

double exact_sum(const std::vector<double>& t) {
  ExactSum s;
  for (double v : t) s.add(v);
  return s.value();
}

TEST(ExactSum, IsTheSumToTheTruncationOfEachTerm) {
  for (unsigned seed : {1u, 2u, 3u}) {
    const std::vector<double> t = terms(20000, seed);
    long double reference = 0.0L;  // 64-bit mantissa: enough to judge a sum of 20 000 terms
    std::vector<double> sorted = t;
    std::sort(sorted.begin(), sorted.end());
    for (double v : sorted) reference += v;
    const double s = exact_sum(t);
    // Each term truncated to a multiple of 2⁻⁶⁴: at most 20 000 · 2⁻⁶⁴ below, and one rounding.
    EXPECT_NEAR(s, static_cast<double>(reference), 4e-16 * static_cast<double>(reference) + 20000 * 0x1p-64);
  }
  EXPECT_EQ(exact_sum({0.75, 0.75}), 1.5);  // fractions ≥ ½: carries into the whole part
  EXPECT_EQ(exact_sum({0.0}), 0.0);
  EXPECT_EQ(exact_sum({3.0, 0.5, 0.25}), 3.75);
}

TEST(ExactSum, DoesNotDependOnTheOrderOrTheSplitOfTheTerms) {
  std::vector<double> t = terms(5000, 7);
  const double first = exact_sum(t);
  std::mt19937 rng(8);
  bool naive_differs = false;
  double naive_first = 0.0;
  for (double v : t) naive_first += v;
  for (int k = 0; k < 20; ++k) {
    std::shuffle(t.begin(), t.end(), rng);
    EXPECT_EQ(exact_sum(t), first);
    // Split into parts at random places, each summed apart, then combined (threads, processes).
    const int cut1 = static_cast<int>(rng() % t.size()), cut2 = static_cast<int>(rng() % t.size());
    ExactSum a, b, c;
    for (int i = 0; i < static_cast<int>(t.size()); ++i)
      (i < std::min(cut1, cut2) ? a : i < std::max(cut1, cut2) ? b : c).add(t[i]);
    c.add(a), c.add(b);
    EXPECT_EQ(c.value(), first);
    double naive = 0.0;
    for (double v : t) naive += v;
    naive_differs |= naive != naive_first;
  }
  EXPECT_TRUE(naive_differs) << "these terms would not show an order-dependent sum";
}

// The barostat's sums (SignedExactSum, ExactDiagonal): terms of either sign, a term added twice in
// one call as two calls, the same value in any order and split (processes: through the words), and
// a term that is not finite making the value NaN.
TEST(SignedExactSum, TakesBothSignsInAnyOrder) {
  std::vector<double> t = terms(3000, 9);
  for (size_t i = 0; i < t.size(); i += 2) t[i] = -t[i];
  SignedExactSum once, twice;
  double positive = 0.0, negative = 0.0;
  for (double v : t) {
    once.add(v);
    once.add(v);
    twice.add(v, 2);
    (v >= 0 ? positive : negative) += v >= 0 ? v : -v;
  }
  EXPECT_EQ(once.value(), twice.value());
  EXPECT_NEAR(once.value(), 2.0 * (positive - negative), 1e-12 * (positive + negative));
  std::mt19937 rng(10);
  std::shuffle(t.begin(), t.end(), rng);
  SignedExactSum a, b;
  for (size_t i = 0; i < t.size(); ++i) (i < t.size() / 3 ? a : b).add(t[i], 2);
  std::int64_t words[SignedExactSum::kWords], more[SignedExactSum::kWords];
  a.to_words(words);
  b.to_words(more);
  for (int k = 0; k < SignedExactSum::kWords; ++k) words[k] += more[k];  // a sum over processes
  SignedExactSum together;
  together.from_words(words);
  EXPECT_EQ(together.value(), twice.value());
  together.add(std::nan(""));
  EXPECT_TRUE(std::isnan(together.value()));
}

}  // namespace
}  // namespace stiffmd
