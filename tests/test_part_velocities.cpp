// Maxwell–Boltzmann velocities by particle (integrators/part_velocities.hpp) on 1–4 fake ranks
// (tests/fake_processes.hpp) that hold the particles in scattered parts: each particle's velocity
// is the same bits whichever rank holds it, the momentum is zero and the kinetic energy is the
// temperature's exactly, fixed particles are at rest, and the velocities are Maxwell–Boltzmann.
#include <gtest/gtest.h>

#include <cmath>
#include <cstring>
#include <vector>

#include "fake_processes.hpp"
#include "integrators/part_velocities.hpp"

namespace stiffmd {
namespace {

constexpr int kParticles = 3000;
constexpr double kT = 1.7;

// Heavier and lighter particles, every 97th fixed.
double inverse_mass(int g) {
  return g % 97 == 5 ? 0.0 : 1.0 / (1.0 + (g % 7));
}

TEST(PartVelocities, EachParticlesVelocityIsTheSameOnAnyNumberOfRanks) {
  std::vector<int> all(kParticles);
  Eigen::VectorXd im(kParticles);
  for (int g = 0; g < kParticles; ++g) all[g] = g, im[g] = inverse_mass(g);
  const Eigen::Matrix3Xd one = maxwell_boltzmann_by_particle(im, all, kT, 42, nullptr);
  for (int ranks = 1; ranks <= 4; ++ranks) {
    std::vector<Eigen::Matrix3Xd> v(ranks);
    std::vector<std::vector<int>> mine(ranks);
    for (int g = 0; g < kParticles; ++g) mine[(g * 7 + g / 11) % ranks].push_back(g);  // scattered parts
    fake::run_ranks(ranks, [&](const Communicator& comm) {
      const std::vector<int>& ids = mine[comm.rank()];
      Eigen::VectorXd part(static_cast<Eigen::Index>(ids.size()));
      for (size_t k = 0; k < ids.size(); ++k) part[static_cast<Eigen::Index>(k)] = im[ids[k]];
      v[comm.rank()] = maxwell_boltzmann_by_particle(part, ids, kT, 42, &comm);
    });
    for (int r = 0; r < ranks; ++r)
      for (size_t k = 0; k < mine[r].size(); ++k)
        ASSERT_EQ(
            std::memcmp(v[r].col(static_cast<Eigen::Index>(k)).data(), one.col(mine[r][k]).data(), 3 * sizeof(double)),
            0)
            << ranks << " ranks, particle " << mine[r][k];
  }
}

TEST(PartVelocities, MomentumZeroTemperatureExactFixedAtRestAndMaxwellBoltzmann) {
  std::vector<int> all(kParticles);
  Eigen::VectorXd im(kParticles);
  for (int g = 0; g < kParticles; ++g) all[g] = g, im[g] = inverse_mass(g);
  const Eigen::Matrix3Xd v = maxwell_boltzmann_by_particle(im, all, kT, 7, nullptr);
  Eigen::Vector3d p = Eigen::Vector3d::Zero();
  double twice_kinetic = 0.0, scale = 0.0, z2 = 0.0;
  int mobile = 0;
  for (int g = 0; g < kParticles; ++g) {
    if (im[g] == 0.0) {
      EXPECT_EQ(v.col(g).squaredNorm(), 0.0) << "fixed particle " << g;
      continue;
    }
    ++mobile;
    p += v.col(g) / im[g];
    scale += v.col(g).norm() / im[g];
    twice_kinetic += v.col(g).squaredNorm() / im[g];
    z2 += v.col(g).squaredNorm() / (kT * im[g]);  // χ² with 3 degrees of freedom per particle
  }
  EXPECT_LT(p.norm(), 1e-13 * scale);
  EXPECT_NEAR(twice_kinetic, (3.0 * mobile - 3.0) * kT, 1e-12 * twice_kinetic);
  // ⟨z²⟩ = 3 per particle; its standard error over 2 969 particles is √(6/2969) ≈ 0.045.
  EXPECT_NEAR(z2 / mobile, 3.0, 0.2);
  const Eigen::Matrix3Xd other = maxwell_boltzmann_by_particle(im, all, kT, 8, nullptr);
  EXPECT_NE(std::memcmp(v.data(), other.data(), sizeof(double) * v.size()), 0) << "another seed, the same velocities";
}

}  // namespace
}  // namespace stiffmd
