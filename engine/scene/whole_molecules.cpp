#include "engine/scene/whole_molecules.hpp"

#include <cmath>
#include <sstream>

#include "core/format.hpp"

namespace stiffmd {

std::optional<WholeMoleculesProblem> make_molecules_whole(Eigen::Matrix3Xd& x,
                                                          const std::vector<std::pair<int, int>>& bonds, const Box& box,
                                                          bool keep_images) {
  if (!box.any_periodic() || bonds.empty()) return std::nullopt;
  const int n = static_cast<int>(x.cols());
  // Adjacency (CSR) of the bond graph.
  std::vector<int> start(static_cast<size_t>(n) + 1, 0), edge(2 * bonds.size());
  for (const auto& [i, j] : bonds) ++start[i + 1], ++start[j + 1];
  for (int p = 0; p < n; ++p) start[p + 1] += start[p];
  std::vector<int> fill(start.begin(), start.end() - 1);
  for (int b = 0; b < static_cast<int>(bonds.size()); ++b)
    edge[fill[bonds[b].first]++] = b, edge[fill[bonds[b].second]++] = b;

  Eigen::Matrix3Xd y = x;  // x stays untouched until every bond has been checked
  std::vector<char> seen(static_cast<size_t>(n), 0), tree(bonds.size(), 0);
  std::vector<int> queue;
  for (int root = 0; root < n; ++root) {
    if (seen[root]) continue;
    seen[root] = 1;
    queue.assign(1, root);
    for (size_t head = 0; head < queue.size(); ++head) {
      const int p = queue[head];
      for (int k = start[p]; k < start[p + 1]; ++k) {
        const int b = edge[k];
        const int q = bonds[b].first == p ? bonds[b].second : bonds[b].first;
        if (seen[q]) continue;
        seen[q] = 1;
        tree[b] = 1;
        queue.push_back(q);
        if (keep_images) continue;
        // Minimum image of the bond from p (placed) to q: shift q by n·L, n = round((x_q − x_p)/L).
        // n = 0 leaves q untouched, bit for bit.
        for (int a = 0; a < 3; ++a) {
          if (!box.periodic[a]) continue;
          const double images = round_nearest((y(a, q) - y(a, p)) / box.lengths[a]);
          if (images != 0.0) y(a, q) -= images * box.lengths[a];
        }
      }
    }
  }
  // Every bond, tree or ring-closing, must now be its own minimum image, unambiguously.
  for (int b = 0; b < static_cast<int>(bonds.size()); ++b) {
    const auto [i, j] = bonds[b];
    for (int a = 0; a < 3; ++a) {
      if (!box.periodic[a]) continue;
      const double d = y(a, i) - y(a, j), half = 0.5 * box.lengths[a];
      if (std::abs(d) < half) continue;
      const std::string axis(1, static_cast<char>('x' + a));
      const std::string span = "spans " + format_number(std::abs(d), 10) + " along " + axis + ", ";
      const std::string box_length = "the periodic box length " + format_number(box.lengths[a], 10);
      if (keep_images)
        return WholeMoleculesProblem{b,
                                     span + "at least half " + box_length +
                                         " (a bond must be its own minimum image; if the image flags are not "
                                         "meaningful, remove them and the molecules are unwrapped along their bonds)"};
      if (tree[b])
        return WholeMoleculesProblem{b, span + "exactly half " + box_length + ": which image it joins is ambiguous"};
      return WholeMoleculesProblem{
          b, "closes a ring only across a jump of a box length along " + axis + " (" + box_length +
                 "; the bond spans " + format_number(std::abs(d), 10) +
                 " once the rest of its molecule is whole): the molecule cannot be made whole"};
    }
  }
  for (int b = 0; b < static_cast<int>(bonds.size()); ++b)
    if ((y.col(bonds[b].first) - y.col(bonds[b].second)).isZero(0.0))
      return WholeMoleculesProblem{b,
                                   "has zero length once its molecule is whole: its two particles are the same "
                                   "point of the periodic box (zero-length bond)"};
  x = y;
  return std::nullopt;
}

}  // namespace stiffmd
