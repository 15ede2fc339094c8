#include "engine/observe/polymer_observables.hpp"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <map>

#include <Eigen/Geometry>

#include "core/errors.hpp"
#include "integrators/thermostat.hpp"

namespace stiffmd {

int degrees_of_freedom(const State& s, bool momentum_conserved, int constraints) {
  return degrees_of_freedom(s.inv_mass, momentum_conserved, constraints);  // integrators/thermostat.hpp
}

double pressure(const State& s, const ForceField& forces, double volume, double kinetic) {
  double w = 0.0;
  for (const auto& term : forces.terms()) w += term->virial(s.x, forces.box());
  return (2.0 * (kinetic >= 0.0 ? kinetic : s.kinetic_energy()) + w) / (3.0 * volume);
}

Molecules::Molecules(const Topology& topology, const Eigen::VectorXd& inv_mass, const Eigen::VectorXd& mass)
    : mass_(mass) {
  (void)inv_mass;
  if (topology.molecule.empty()) return;
  std::map<int, std::vector<int>> by_id;
  for (size_t i = 0; i < topology.molecule.size(); ++i) by_id[topology.molecule[i]].push_back(static_cast<int>(i));
  // Each particle's bonded neighbours within its own molecule.
  std::vector<std::vector<int>> neighbours(topology.molecule.size());
  for (const Bond& b : topology.bonds)
    if (topology.molecule[b.i] == topology.molecule[b.j])
      neighbours[b.i].push_back(b.j), neighbours[b.j].push_back(b.i);
  for (auto& [id, members] : by_id) {
    if (members.size() < 2) continue;
    Molecule m;
    m.members = std::move(members);
    const int n = static_cast<int>(m.members.size());
    std::vector<int> ends;
    bool degree_at_most_two = true;
    for (int i : m.members) {
      if (neighbours[i].size() == 1) ends.push_back(i);
      degree_at_most_two = degree_at_most_two && neighbours[i].size() <= 2;
    }
    // Walk the bonds from a start bead (a chain's lower-index end, a ring's lowest index) and keep
    // the shape only if the walk visits the whole molecule: a path, or a single cycle.
    const bool linear = degree_at_most_two && ends.size() == 2;
    const bool ring = degree_at_most_two && ends.empty();
    if (linear || ring) {
      std::vector<int> walk = {linear ? ends.front() : m.members.front()};
      int previous = -1;
      while (static_cast<int>(walk.size()) < n) {
        const std::vector<int>& next = neighbours[walk.back()];
        int step = -1;  // the first step of a ring: its lower-index neighbour (as tools/analyze.py)
        for (int k : next)
          if (k != previous && (step < 0 || (previous < 0 && k < step))) step = k;
        if (step < 0 || step == walk.front()) break;  // a chain's far end, or a cycle shorter than the molecule
        previous = walk.back();
        walk.push_back(step);
      }
      if (static_cast<int>(walk.size()) == n) {
        m.shape = linear ? Shape::linear : Shape::ring;
        m.path = linear ? ends : std::move(walk);
        ++num_sized_;
      }
    }
    molecules_.push_back(std::move(m));
  }
}

void Molecules::measure(const Eigen::Matrix3Xd& x, double& rg, double& end_to_end) const {
  sum(x, rg, end_to_end);
  if (!molecules_.empty()) rg /= molecules_.size();
  if (num_sized_ > 0) end_to_end /= num_sized_;
}

void Molecules::sum(const Eigen::Matrix3Xd& x, double& rg, double& end_to_end) const {
  rg = end_to_end = 0.0;
  for (const Molecule& m : molecules_) {
    Eigen::Vector3d com = Eigen::Vector3d::Zero();
    double total = 0.0;
    for (int i : m.members) com += mass_[i] * x.col(i), total += mass_[i];
    com /= total;
    double r2 = 0.0;
    for (int i : m.members) r2 += mass_[i] * (x.col(i) - com).squaredNorm();
    rg += std::sqrt(r2 / total);
    if (m.shape == Shape::linear) {
      end_to_end += (x.col(m.path[1]) - x.col(m.path[0])).norm();
    } else if (m.shape == Shape::ring) {
      const size_t n = m.path.size(), half = n / 2;
      double d2 = 0.0;
      for (size_t k = 0; k < n; ++k) d2 += (x.col(m.path[(k + half) % n]) - x.col(m.path[k])).squaredNorm();
      end_to_end += std::sqrt(d2 / static_cast<double>(n));
    }
  }
}

}  // namespace stiffmd
