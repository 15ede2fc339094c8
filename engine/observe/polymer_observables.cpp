#include "engine/observe/polymer_observables.hpp"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <map>

#include <Eigen/Geometry>

#include "engine/core/errors.hpp"
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
  std::map<int, std::vector<int>> by_id;
  for (size_t i = 0; i < topology.molecule.size(); ++i) by_id[topology.molecule[i]].push_back(static_cast<int>(i));
  for (auto& [id, members] : by_id)
    if (members.size() >= 2) members_.push_back(std::move(members));
  (void)inv_mass;
}

void Molecules::measure(const Eigen::Matrix3Xd& x, double& rg, double& end_to_end) const {
  rg = end_to_end = 0.0;
  for (const auto& m : members_) {
    Eigen::Vector3d com = Eigen::Vector3d::Zero();
    double total = 0.0;
    for (int i : m) com += mass_[i] * x.col(i), total += mass_[i];
    com /= total;
    double r2 = 0.0;
    for (int i : m) r2 += mass_[i] * (x.col(i) - com).squaredNorm();
    rg += std::sqrt(r2 / total);
    end_to_end += (x.col(m.back()) - x.col(m.front())).norm();
  }
  if (!members_.empty()) rg /= members_.size(), end_to_end /= members_.size();
}

namespace {

void histogram(std::FILE* f, const char* name, std::vector<double> values, int bins) {
  if (values.empty()) return;
  const auto [lo_it, hi_it] = std::minmax_element(values.begin(), values.end());
  double lo = *lo_it, hi = *hi_it;
  if (hi - lo < 1e-12 * std::max(1.0, std::abs(hi))) lo -= 0.5e-6, hi += 0.5e-6;  // all equal: one narrow bin range
  std::vector<long> count(bins, 0);
  for (double v : values) ++count[std::min(bins - 1, static_cast<int>((v - lo) / (hi - lo) * bins))];
  for (int k = 0; k < bins; ++k)
    std::fprintf(f, "%s,%.10g,%.10g,%ld\n", name, lo + (hi - lo) * k / bins, lo + (hi - lo) * (k + 1) / bins, count[k]);
}

}  // namespace

void write_histograms(const std::string& path, const Eigen::Matrix3Xd& x, const Box& box, const Topology& topology,
                      int bins) {
  std::vector<double> lengths, angles;
  (void)box;  // molecules are whole: the raw differences are the bond vectors (engine/core/state.hpp)
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
