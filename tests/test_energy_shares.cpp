// A decomposed run's thermo row is summed by parts (ForceTerm::energy_and_virial,
// Thermo::sums): each rank's pair term counts a pair of an owned particle and a ghost half, so
// the ranks' energies and virials add up to the whole system's. Without ghosts the sums are the
// plain energy and virial (the one-process thermo row is unchanged).
#include <gtest/gtest.h>

#include <random>
#include <vector>

#include "core/parallel.hpp"
#include "forcefields/force_field.hpp"
#include "forcefields/pair_term.hpp"
#include "test_support.hpp"

namespace stiffmd {
namespace {

constexpr double kCutoff = 2.5;
constexpr double kSkin = 0.3;
constexpr SpecialWeights kWeights{0.0, 0.5, 1.0};  // 1-2 pairs excluded, 1-3 pairs scaled

// m³ beads on a jittered cubic lattice (spacing 1.2) in a periodic box, in trimers
// (3k, 3k + 1, 3k + 2): the molecules a rank owns whole.
struct Melt {
  Eigen::Matrix3Xd x;
  Box box;
  int size() const { return static_cast<int>(x.cols()); }
};

Melt melt(int m, unsigned seed) {
  std::mt19937 rng(seed);
  std::uniform_real_distribution<double> jitter(-0.25, 0.25);
  Melt s;
  s.x.resize(3, m * m * m);
  int k = 0;
  for (int ix = 0; ix < m; ++ix)
    for (int iy = 0; iy < m; ++iy)
      for (int iz = 0; iz < m; ++iz)
        s.x.col(k++) = 1.2 * Eigen::Vector3d(ix + 0.5, iy + 0.5, iz + 0.5) +
                       Eigen::Vector3d(jitter(rng), jitter(rng), jitter(rng));
  s.box.lengths = Eigen::Vector3d::Constant(1.2 * m);
  s.box.periodic = Eigen::Vector3i::Ones();
  return s;
}

// The bonds of the trimers whose first bead `owns` says is owned (all when null).
std::vector<Bond> trimer_bonds(int n, const std::vector<char>* owned) {
  std::vector<Bond> bonds;
  for (int k = 0; 3 * k + 2 < n; ++k)
    if (!owned || (*owned)[3 * k]) {
      bonds.push_back({3 * k, 3 * k + 1, 0});
      bonds.push_back({3 * k + 1, 3 * k + 2, 0});
    }
  return bonds;
}

ForceField lj_field(const Melt& s, const std::vector<Bond>& bonds) {
  TypePairMatrix<LennardJones::Coeffs> c(1);
  c.set(0, 0, {1.0, 1.0, kCutoff});
  ForceField ff(s.box, s.size());
  ff.add(std::make_unique<LennardJonesPair>("lj", Level::slow, std::vector<int>(s.size(), 0), c, bonds, kWeights, s.box,
                                            kSkin));
  return ff;
}

using test::ThreadCount;

TEST(EnergyShares, WithoutGhostsTheyAreTheEnergyAndTheVirial) {
  for (const int threads : {1, 2}) {
    const ThreadCount scope(threads);
    const Melt s = melt(17, 3);  // 4913 beads: the pair loop runs on the threads
    const ForceField ff = lj_field(s, trimer_bonds(s.size(), nullptr));
    std::vector<double> levels;
    double virial = 0.0;
    ff.energies_and_virial(s.x, levels, virial);
    ASSERT_EQ(levels.size(), 2u);
    EXPECT_EQ(levels[Level::slow.index], ff.energy(s.x, Level::slow));
    EXPECT_EQ(levels[Level::fast.index], 0.0);
    EXPECT_EQ(virial, ff.terms()[0]->virial(s.x, s.box));
  }
}

// Three ranks owning the trimers round robin, each seeing every other bead as a ghost (a ghost
// shell as wide as the box): their shares add up to the whole system's energy and virial, though
// each rank's own sums are far from a third of them.
TEST(EnergyShares, TheRanksSharesAddUpToTheWholeSystems) {
  for (const int threads : {1, 2}) {
    SCOPED_TRACE(testing::Message() << threads << " thread(s)");
    const ThreadCount scope(threads);
    const Melt s = melt(17, 4);
    const ForceField whole = lj_field(s, trimer_bonds(s.size(), nullptr));
    std::vector<double> levels;
    double virial = 0.0;
    whole.energies_and_virial(s.x, levels, virial);
    const double energy = levels[Level::slow.index];
    ASSERT_GT(std::abs(energy), 1000.0);  // a dense liquid: many pairs inside the cutoff
    ASSERT_GT(std::abs(virial), 1000.0);

    constexpr int kRanks = 3;
    double energy_sum = 0.0, virial_sum = 0.0, plain_sum = 0.0;
    for (int r = 0; r < kRanks; ++r) {
      std::vector<char> owned(s.size()), ghost(s.size());
      for (int i = 0; i < s.size(); ++i) owned[i] = (i / 3) % kRanks == r, ghost[i] = !owned[i];
      ForceField part = lj_field(s, trimer_bonds(s.size(), &owned));
      part.set_ghosts(ghost);
      std::vector<double> e;
      double w = 0.0;
      part.energies_and_virial(s.x, e, w);
      energy_sum += e[Level::slow.index];
      virial_sum += w;
      plain_sum += part.energy(s.x, Level::slow);  // every pair with a ghost counted whole
    }
    EXPECT_NEAR(energy_sum, energy, 1e-11 * std::abs(energy));
    EXPECT_NEAR(virial_sum, virial, 1e-11 * std::abs(virial));
    // Counted whole, the pairs across ranks would be counted twice.
    EXPECT_GT(std::abs(plain_sum - energy), 0.1 * std::abs(energy));
  }
}

}  // namespace
}  // namespace stiffmd
