#include "engine/observe/histograms.hpp"

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <limits>
#include <optional>
#include <vector>

#include <Eigen/Geometry>

#include "core/errors.hpp"
#include "core/state.hpp"

namespace stiffmd {

namespace {

// The bins of a quantity: [lo, hi) of its values' min and max (values.empty(): none). They span
// [min, max] of the values, unless the values are equal to within 1e-6 of their size: rigid
// bonds are equal to SHAKE's tolerance (1e-12), and bins that narrow print as "0.97,0.97" (10
// significant digits) and say nothing. Then the bins span 1 % of the value (1 about 0), the value
// in the middle of one bin, so that the one filled bin reads as the value it holds.
struct Bins {
  double lo = 0.0, hi = 0.0;
  int count = 0;
  Bins(double min, double max, int bins) : lo(min), hi(max), count(bins) {
    const double size = std::max(std::abs(lo), std::abs(hi));
    if (hi - lo <= 1e-6 * size) {
      const double mid = 0.5 * (lo + hi), width = (size > 0.0 ? 1e-2 * size : 1.0) / bins;
      lo = mid - (bins / 2 + 0.5) * width;
      hi = lo + bins * width;
    }
  }
  int of(double v) const { return std::min(count - 1, static_cast<int>((v - lo) / (hi - lo) * count)); }
};

void print_histogram(std::FILE* f, const char* name, const Bins& b, const std::vector<std::int64_t>& count) {
  for (int k = 0; k < b.count; ++k)
    std::fprintf(f, "%s,%.10g,%.10g,%lld\n", name, b.lo + (b.hi - b.lo) * k / b.count,
                 b.lo + (b.hi - b.lo) * (k + 1) / b.count, static_cast<long long>(count[static_cast<size_t>(k)]));
}

void histogram(std::FILE* f, const char* name, const std::vector<double>& values, int bins) {
  if (values.empty()) return;
  const auto [lo_it, hi_it] = std::minmax_element(values.begin(), values.end());
  const Bins b(*lo_it, *hi_it, bins);
  std::vector<std::int64_t> count(static_cast<size_t>(bins), 0);
  for (double v : values) ++count[static_cast<size_t>(b.of(v))];
  print_histogram(f, name, b, count);
}

// The bond lengths (every bond) and the bond angles in degrees: the topology's angles when
// `topology_angles`, else every pair of bonds sharing a particle.
void histogram_values(const Eigen::Matrix3Xd& x, const Topology& topology, bool topology_angles,
                      std::vector<double>& lengths, std::vector<double>& angles) {
  // Molecules are whole: the raw differences are the bond vectors (core/state.hpp).
  for (const Bond& b : topology.bonds) lengths.push_back(bond_vector(x, b.i, b.j).norm());
  auto angle = [&](int i, int j, int k) {
    const Eigen::Vector3d a = bond_vector(x, i, j), c = bond_vector(x, k, j);
    return std::atan2(a.cross(c).norm(), a.dot(c)) * 180.0 / M_PI;
  };
  if (topology_angles) {
    for (const Angle& a : topology.angles) angles.push_back(angle(a.i, a.j, a.k));
  } else {
    std::vector<std::vector<int>> partners(static_cast<size_t>(x.cols()));
    for (const Bond& b : topology.bonds) partners[b.i].push_back(b.j), partners[b.j].push_back(b.i);
    for (int j = 0; j < x.cols(); ++j)
      for (size_t p = 0; p < partners[j].size(); ++p)
        for (size_t q = p + 1; q < partners[j].size(); ++q) angles.push_back(angle(partners[j][p], j, partners[j][q]));
  }
}

std::FILE* open_histograms(const std::string& path) {
  std::FILE* f = std::fopen(path.c_str(), "w");
  if (!f) throw InputError(path + ": cannot open output file for writing");
  std::fprintf(f, "quantity,bin_low,bin_high,count\n");
  return f;
}

void close_histograms(std::FILE* f, const std::string& path) {
  if (std::fclose(f) != 0) throw InputError(path + ": write failed");
}

}  // namespace

void write_histograms(const std::string& path, const Eigen::Matrix3Xd& x, const Box& box, const Topology& topology,
                      int bins) {
  (void)box;  // molecules are whole (histogram_values)
  std::vector<double> lengths, angles;
  histogram_values(x, topology, !topology.angles.empty(), lengths, angles);
  std::FILE* f = open_histograms(path);
  histogram(f, "bond_length", lengths, bins);
  histogram(f, "bond_angle_deg", angles, bins);
  close_histograms(f, path);
}

bool write_histograms_parts(const std::string& path, const Eigen::Matrix3Xd& x, const Topology& topology,
                            const Communicator& ranks, int bins) {
  std::int64_t have[2] = {static_cast<std::int64_t>(topology.bonds.size()),
                          static_cast<std::int64_t>(topology.angles.size())};
  ranks.sum(have, 2);
  if (have[0] == 0) return false;  // as write_histograms's caller: histograms of a system with bonds
  std::vector<double> values[2];
  histogram_values(x, topology, have[1] > 0, values[0], values[1]);
  // Per quantity: how many values, the min (as −max) and the max, over the ranks; then the counts.
  constexpr double kInf = std::numeric_limits<double>::infinity();
  std::int64_t total[2] = {static_cast<std::int64_t>(values[0].size()), static_cast<std::int64_t>(values[1].size())};
  ranks.sum(total, 2);
  double range[4] = {-kInf, -kInf, -kInf, -kInf};  // −min and max of each quantity
  for (int q = 0; q < 2; ++q)
    for (double v : values[q])
      range[2 * q] = std::max(range[2 * q], -v), range[2 * q + 1] = std::max(range[2 * q + 1], v);
  ranks.max(range, 4);
  std::vector<std::int64_t> count(static_cast<size_t>(2 * bins), 0);
  std::optional<Bins> b[2];
  for (int q = 0; q < 2; ++q) {
    if (total[q] == 0) continue;
    b[q].emplace(-range[2 * q], range[2 * q + 1], bins);
    for (double v : values[q]) ++count[static_cast<size_t>(q * bins + b[q]->of(v))];
  }
  ranks.sum(count.data(), 2 * bins);
  if (!ranks.root()) return true;
  std::FILE* f = open_histograms(path);
  const char* names[2] = {"bond_length", "bond_angle_deg"};
  for (int q = 0; q < 2; ++q)
    if (b[q])
      print_histogram(f, names[q], *b[q],
                      std::vector<std::int64_t>(count.begin() + q * bins, count.begin() + (q + 1) * bins));
  close_histograms(f, path);
  return true;
}

}  // namespace stiffmd
