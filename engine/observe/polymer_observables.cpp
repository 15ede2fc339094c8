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

namespace {

// The bins span [min, max] of the values, unless the values are equal to within 1e-6 of their
// size: rigid bonds are equal to SHAKE's tolerance (1e-12), and bins that narrow print as
// "0.97,0.97" (10 significant digits) and say nothing. Then the bins span 1 % of the value (1
// about 0), the value in the middle of one bin, so that the one filled bin reads as the value it
// holds.
void histogram(std::FILE* f, const char* name, std::vector<double> values, int bins) {
  if (values.empty()) return;
  const auto [lo_it, hi_it] = std::minmax_element(values.begin(), values.end());
  double lo = *lo_it, hi = *hi_it;
  const double size = std::max(std::abs(lo), std::abs(hi));
  if (hi - lo <= 1e-6 * size) {
    const double mid = 0.5 * (lo + hi), width = (size > 0.0 ? 1e-2 * size : 1.0) / bins;
    lo = mid - (bins / 2 + 0.5) * width;
    hi = lo + bins * width;
  }
  std::vector<long> count(bins, 0);
  for (double v : values) ++count[std::min(bins - 1, static_cast<int>((v - lo) / (hi - lo) * bins))];
  for (int k = 0; k < bins; ++k)
    std::fprintf(f, "%s,%.10g,%.10g,%ld\n", name, lo + (hi - lo) * k / bins, lo + (hi - lo) * (k + 1) / bins, count[k]);
}

}  // namespace

void write_histograms(const std::string& path, const Eigen::Matrix3Xd& x, const Box& box, const Topology& topology,
                      int bins) {
  std::vector<double> lengths, angles;
  (void)box;  // molecules are whole: the raw differences are the bond vectors (core/state.hpp)
  for (const Bond& b : topology.bonds) lengths.push_back(bond_vector(x, b.i, b.j).norm());
  auto angle = [&](int i, int j, int k) {
    const Eigen::Vector3d a = bond_vector(x, i, j), c = bond_vector(x, k, j);
    return std::atan2(a.cross(c).norm(), a.dot(c)) * 180.0 / M_PI;
  };
  if (!topology.angles.empty()) {
    for (const Angle& a : topology.angles) angles.push_back(angle(a.i, a.j, a.k));
  } else {
    std::vector<std::vector<int>> partners(static_cast<size_t>(x.cols()));
    for (const Bond& b : topology.bonds) partners[b.i].push_back(b.j), partners[b.j].push_back(b.i);
    for (int j = 0; j < x.cols(); ++j)
      for (size_t p = 0; p < partners[j].size(); ++p)
        for (size_t q = p + 1; q < partners[j].size(); ++q) angles.push_back(angle(partners[j][p], j, partners[j][q]));
  }
  std::FILE* f = std::fopen(path.c_str(), "w");
  if (!f) throw InputError(path + ": cannot open output file for writing");
  std::fprintf(f, "quantity,bin_low,bin_high,count\n");
  histogram(f, "bond_length", std::move(lengths), bins);
  histogram(f, "bond_angle_deg", std::move(angles), bins);
  if (std::fclose(f) != 0) throw InputError(path + ": write failed");
}

}  // namespace stiffmd
