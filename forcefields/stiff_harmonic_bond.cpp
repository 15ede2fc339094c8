#include "forcefields/stiff_harmonic_bond.hpp"

#include <sstream>
#include <stdexcept>

#include "forcefields/coefficients.hpp"

namespace stiffmd {

StiffHarmonicBond::StiffHarmonicBond(std::string name, Level level, StiffBonds bonds)
    : ForceTerm(std::move(name), level), bonds_(std::move(bonds)) {
  require(bonds_.epsilon, kPositive, "epsilon");
  const double inv_eps2 = 1.0 / (bonds_.epsilon * bonds_.epsilon);
  instances_.reserve(bonds_.bonds.size());
  for (const StiffBond& b : bonds_.bonds) {
    if (b.i == b.j) throw std::invalid_argument("a bond joins a particle to itself");
    require(b.length, kLength, "bond length");
    require(b.alpha, kPositive, "bond alpha");
    instances_.push_back({b.i, b.j, {b.length, b.alpha * b.alpha * inv_eps2}});
  }
}

double StiffHarmonicBond::add_forces(const Eigen::Matrix3Xd& x, const Box& box, Eigen::Matrix3Xd& f) const {
  return accumulate_bond_forces<Kernel>(instances_, x, box, f, partition_);
}

std::string StiffHarmonicBond::describe() const {
  std::ostringstream s;
  s << bonds_.bonds.size() << " stiff bonds, epsilon = " << bonds_.epsilon;
  return s.str();
}

}  // namespace stiffmd
