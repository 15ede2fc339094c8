// Particles that overlap at the start: closer than a pair term can bear. The whole load checks its
// scene (engine/scene/force_registry.cpp, check_overlaps); a scene's description holds no position
// of its counted chains, so it keeps each pair term's rule, and a decomposed run applies it to the
// parts at the start (engine/domain/part_overlaps.hpp; docs/parallel.md, "The run on the
// description"). Both give the same message for the same closest pair.
#pragma once

#include <Eigen/Core>
#include <algorithm>
#include <array>
#include <cmath>
#include <string>
#include <vector>

#include "core/box.hpp"
#include "forcefields/neighbor_list.hpp"

namespace stiffmd {

// One pair term's rule: a pair of types (a, b) overlaps below below[a · num_types + b], and
// rule[a · num_types + b] says why ("sigma/2 = 0.5 (the pair energy there is above 1.6e4
// epsilon)"). Pairs of special weight 0 (SpecialPair::weight) are not checked.
struct OverlapRule {
  std::string where;  // the term's table, "file:line: forces.NAME" (DeckTable::where())
  std::string term;   // the term's name
  int num_types = 0;
  std::vector<double> below;
  std::vector<std::string> rule;
  double distance(int a, int b) const { return below[static_cast<size_t>(a * num_types + b)]; }
  const std::string& why(int a, int b) const { return rule[static_cast<size_t>(a * num_types + b)]; }
  // The largest distance of any type pair: the range a search must cover.
  double range() const { return below.empty() ? 0.0 : *std::max_element(below.begin(), below.end()); }
};

// What the check says of the closest overlapping pair (without the term's `where`): `first` and
// `second` name the two particles (particle_and_source), r their distance, (a, b) their types,
// `overlapping` the pairs that overlap in all.
std::string overlap_message(const OverlapRule& rule, const std::string& first, const std::string& second, double r,
                            int a, int b, long overlapping);

// Every pair (i < j) of the columns of x closer than `range` (minimum image on periodic axes),
// found through cells at least `range` wide: O(N) for a scene of roughly uniform density. The
// cells are capped at a few per particle (a tiny range in a big box would ask for millions of
// empty ones). visit(i, j, r).
template <class Visit>
void close_pairs(const Eigen::Matrix3Xd& x, const Box& box, double range, Visit visit) {
  const int n = static_cast<int>(x.cols());
  if (n < 2) return;
  double lo[3], len[3];
  long cells[3];
  for (int a = 0; a < 3; ++a) {
    lo[a] = box.periodic[a] ? box.origin[a] : x.row(a).minCoeff();
    len[a] = box.periodic[a] ? box.lengths[a] : std::max(x.row(a).maxCoeff() - lo[a], range);
    cells[a] = std::clamp(static_cast<long>(len[a] / range), 1L, 1L << 20);
  }
  while (cells[0] * cells[1] * cells[2] > 4L * n + 64) {
    const int a = static_cast<int>(std::max_element(cells, cells + 3) - cells);
    cells[a] = std::max(1L, cells[a] / 2);
  }
  std::vector<std::array<long, 3>> coord(static_cast<size_t>(n));
  std::vector<long> cell_of(static_cast<size_t>(n));
  std::vector<int> start(static_cast<size_t>(cells[0] * cells[1] * cells[2] + 1), 0), order(static_cast<size_t>(n));
  for (int i = 0; i < n; ++i) {
    for (int a = 0; a < 3; ++a) {
      double f = (x(a, i) - lo[a]) / len[a];
      if (box.periodic[a]) f -= std::floor(f);
      coord[i][a] = std::clamp(static_cast<long>(f * cells[a]), 0L, cells[a] - 1);
    }
    cell_of[i] = (coord[i][0] * cells[1] + coord[i][1]) * cells[2] + coord[i][2];
    ++start[static_cast<size_t>(cell_of[i]) + 1];
  }
  for (size_t c = 1; c < start.size(); ++c) start[c] += start[c - 1];
  std::vector<int> fill(start.begin(), start.end() - 1);
  for (int i = 0; i < n; ++i) order[static_cast<size_t>(fill[static_cast<size_t>(cell_of[i])]++)] = i;
  const MinimumImage image(box);
  for (int i = 0; i < n; ++i) {
    long seen[27];
    int nseen = 0;
    for (int dx = -1; dx <= 1; ++dx)
      for (int dy = -1; dy <= 1; ++dy)
        for (int dz = -1; dz <= 1; ++dz) {
          long c[3] = {coord[i][0] + dx, coord[i][1] + dy, coord[i][2] + dz};
          bool inside = true;
          for (int a = 0; a < 3; ++a) {
            if (c[a] >= 0 && c[a] < cells[a]) continue;
            if (box.periodic[a])
              c[a] = (c[a] + cells[a]) % cells[a];
            else
              inside = false;
          }
          if (!inside) continue;
          const long cell = (c[0] * cells[1] + c[1]) * cells[2] + c[2];
          if (std::find(seen, seen + nseen, cell) != seen + nseen) continue;  // a narrow periodic axis
          seen[nseen++] = cell;
          for (int k = start[static_cast<size_t>(cell)]; k < start[static_cast<size_t>(cell) + 1]; ++k) {
            const int j = order[static_cast<size_t>(k)];
            if (j <= i) continue;
            Eigen::Vector3d d = x.col(i) - x.col(j);
            image.apply(d[0], d[1], d[2]);
            const double r = d.norm();
            if (r < range) visit(i, j, r);
          }
        }
  }
}

}  // namespace stiffmd
