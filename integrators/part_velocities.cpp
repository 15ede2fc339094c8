#include "integrators/part_velocities.hpp"

#include <cmath>
#include <stdexcept>
#include <string>

#include "core/exact_sum.hpp"
#include "integrators/thermostat.hpp"

namespace stiffmd {

namespace {

// The words of several signed exact sums, added over the ranks as integers (exact in any order).
void add_over_ranks(SignedExactSum* sums, int count, const Communicator* ranks) {
  if (!ranks || ranks->size() == 1) return;
  constexpr int n = SignedExactSum::kWords;
  std::vector<std::int64_t> words(static_cast<size_t>(n * count));
  for (int k = 0; k < count; ++k) sums[k].to_words(words.data() + n * k);
  ranks->sum(words.data(), n * count);
  for (int k = 0; k < count; ++k) sums[k].from_words(words.data() + n * k);
}

}  // namespace

Eigen::Matrix3Xd maxwell_boltzmann_by_particle(const Eigen::VectorXd& inv_mass, std::span<const int> global, double kT,
                                               std::uint64_t seed, const Communicator* ranks) {
  if (!(kT >= 0.0) || !std::isfinite(kT))
    throw std::invalid_argument("maxwell_boltzmann_by_particle: kT = " + std::to_string(kT) +
                                ": expected a finite kT >= 0");
  if (static_cast<size_t>(inv_mass.size()) != global.size())
    throw std::invalid_argument("maxwell_boltzmann_by_particle: one global index per particle expected");
  const Eigen::Index n = inv_mass.size();
  std::int64_t mobile = 0;
  for (Eigen::Index i = 0; i < n; ++i) {
    if (!(inv_mass[i] >= 0.0) || !std::isfinite(inv_mass[i]))
      throw std::invalid_argument("maxwell_boltzmann_by_particle: inverse mass of particle " +
                                  std::to_string(global[i]) + ": expected a finite value >= 0 (0 = fixed)");
    if (inv_mass[i] > 0.0) ++mobile;
  }
  if (ranks && ranks->size() > 1) ranks->sum(&mobile, 1);
  Eigen::Matrix3Xd v = Eigen::Matrix3Xd::Zero(3, n);
  const std::int64_t dof = 3 * mobile - 3;
  if (dof <= 0 || kT == 0.0) return v;  // nothing can move once the momentum is removed

  // The stream of step −1: the Langevin noise's keys are of steps ≥ 0, so these normals are none of them.
  const std::uint64_t key = noise_key(seed, -1, 0);
  for (Eigen::Index i = 0; i < n; ++i)
    if (inv_mass[i] > 0.0) v.col(i) = std::sqrt(kT * inv_mass[i]) * particle_noise(key, global[i]);
  // The centre-of-mass velocity removed twice: the second pass takes what rounding left.
  for (int pass = 0; pass < 2; ++pass) {
    SignedExactSum sums[4];  // Σ m, Σ m v_x, Σ m v_y, Σ m v_z
    for (Eigen::Index i = 0; i < n; ++i) {
      if (inv_mass[i] == 0.0) continue;
      const double m = 1.0 / inv_mass[i];
      sums[0].add(m);
      for (int a = 0; a < 3; ++a) sums[1 + a].add(m * v(a, i));
    }
    add_over_ranks(sums, 4, ranks);
    const double mass = sums[0].value();
    const Eigen::Vector3d vcm(sums[1].value() / mass, sums[2].value() / mass, sums[3].value() / mass);
    for (Eigen::Index i = 0; i < n; ++i)
      if (inv_mass[i] > 0.0) v.col(i) -= vcm;
  }
  // The exact kinetic temperature: Σ m v² = dof kT (a common factor keeps Σ m v = 0).
  SignedExactSum twice_kinetic;
  for (Eigen::Index i = 0; i < n; ++i)
    if (inv_mass[i] > 0.0)
      for (int a = 0; a < 3; ++a) twice_kinetic.add(v(a, i) * v(a, i) / inv_mass[i]);
  add_over_ranks(&twice_kinetic, 1, ranks);
  if (twice_kinetic.value() > 0.0) v *= std::sqrt(static_cast<double>(dof) * kT / twice_kinetic.value());
  return v;
}

}  // namespace stiffmd
