// The rules of a set of stiff bonds, checked in one place (forcefields/stiff_bond.hpp).
#include "forcefields/stiff_bond.hpp"

#include <functional>
#include <limits>
#include <queue>
#include <set>
#include <sstream>
#include <utility>

#include "core/format.hpp"

namespace stiffmd {
namespace {

std::string name(int b, const StiffBond& bond) {
  return "stiff " + describe_bond(b, bond);
}

// The polygon inequality on every cycle (see the header): for each bond e = (u, v), a Dijkstra
// search from u over the other bonds, stopped once the distance exceeds ℓ_e. It explores only
// the neighbourhood of radius ℓ_e, a few bonds in a polymer, so the whole check is O(bonds).
std::optional<StiffBondProblem> unrealisable_cycle(const std::vector<StiffBond>& bonds) {
  int n = 0;
  for (const StiffBond& b : bonds) n = std::max({n, b.i + 1, b.j + 1});
  std::vector<int> start(static_cast<size_t>(n) + 1, 0), edge(2 * bonds.size());
  for (const StiffBond& b : bonds) ++start[b.i + 1], ++start[b.j + 1];
  for (int p = 0; p < n; ++p) start[p + 1] += start[p];
  std::vector<int> fill(start.begin(), start.end() - 1);
  for (int k = 0; k < static_cast<int>(bonds.size()); ++k) edge[fill[bonds[k].i]++] = k, edge[fill[bonds[k].j]++] = k;
  constexpr double kInf = std::numeric_limits<double>::infinity();
  std::vector<double> dist(static_cast<size_t>(n), kInf);
  std::vector<int> touched;
  using Item = std::pair<double, int>;
  std::priority_queue<Item, std::vector<Item>, std::greater<Item>> queue;
  for (int e = 0; e < static_cast<int>(bonds.size()); ++e) {
    const StiffBond& be = bonds[e];
    // Equality up to rounding counts as degenerate: 0.1 + 0.2 against 0.3 is still collinear.
    const double limit = be.length * (1.0 + 1e-12);
    double found = kInf;
    dist[be.i] = 0.0;
    touched.push_back(be.i);
    queue.push({0.0, be.i});
    while (!queue.empty()) {
      const auto [d, p] = queue.top();
      queue.pop();
      if (d > limit) break;
      if (d > dist[p]) continue;
      if (p == be.j) {
        found = d;
        break;
      }
      for (int k = start[p]; k < start[p + 1]; ++k) {
        if (edge[k] == e) continue;
        const StiffBond& b = bonds[edge[k]];
        const int q = b.i == p ? b.j : b.i;
        const double dq = d + b.length;
        if (dq < dist[q]) {
          if (dist[q] == kInf) touched.push_back(q);
          dist[q] = dq;
          queue.push({dq, q});
        }
      }
    }
    for (int p : touched) dist[p] = kInf;
    touched.clear();
    queue = {};
    if (found <= limit)
      return StiffBondProblem{e, name(e, be) + " has length " + format_number(be.length, 10) +
                                     ", but the other stiff bonds join its particles by a path of total length " +
                                     format_number(found, 10) +
                                     ": no configuration satisfies these rigid lengths (a bond of a cycle must be "
                                     "shorter than the sum of the others)"};
  }
  return std::nullopt;
}

}  // namespace

std::optional<StiffBondProblem> find_stiff_bond_problem(const std::vector<StiffBond>& bonds,
                                                        const Eigen::VectorXd* inv_mass) {
  if (inv_mass)
    for (Eigen::Index p = 0; p < inv_mass->size(); ++p)
      if (!std::isfinite((*inv_mass)[p]) || (*inv_mass)[p] < 0.0)
        return StiffBondProblem{-1, "particle " + std::to_string(p) + ": inverse mass must be finite and >= 0, got " +
                                        format_number((*inv_mass)[p], 10)};
  const long n = inv_mass ? static_cast<long>(inv_mass->size()) : std::numeric_limits<int>::max();
  std::set<std::pair<int, int>> pairs;
  for (int b = 0; b < static_cast<int>(bonds.size()); ++b) {
    const StiffBond& bond = bonds[b];
    if (bond.i < 0 || bond.i >= n || bond.j < 0 || bond.j >= n)
      return StiffBondProblem{b, name(b, bond) + ": particle index out of range" +
                                     (inv_mass ? " [0, " + std::to_string(n) + ")" : std::string(" (negative)"))};
    if (bond.i == bond.j) return StiffBondProblem{b, name(b, bond) + " joins a particle to itself"};
    if (!(bond.length > 0.0) || !std::isfinite(bond.length))
      return StiffBondProblem{b,
                              name(b, bond) + ": length must be finite and > 0, got " + format_number(bond.length, 10)};
    if (!(bond.alpha > 0.0) || !std::isfinite(bond.alpha))
      return StiffBondProblem{b,
                              name(b, bond) + ": alpha must be finite and > 0, got " + format_number(bond.alpha, 10)};
    if (inv_mass && (*inv_mass)[bond.i] == 0.0 && (*inv_mass)[bond.j] == 0.0)
      return StiffBondProblem{b, name(b, bond) + " joins two fixed particles: it constrains nothing"};
    if (!pairs.insert({std::min(bond.i, bond.j), std::max(bond.i, bond.j)}).second)
      return StiffBondProblem{b, name(b, bond) + ": particles " + std::to_string(bond.i) + "–" +
                                     std::to_string(bond.j) + " are joined by more than one stiff bond"};
  }
  return unrealisable_cycle(bonds);
}

}  // namespace stiffmd
