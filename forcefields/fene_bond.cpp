#include "forcefields/fene_bond.hpp"

#include <sstream>
#include <stdexcept>

#include "engine/errors.hpp"

namespace stiffmd {

FeneBond::FeneBond(std::string name, Level level, std::vector<Bond> bonds, std::vector<FeneCoeffs> types)
    : ForceTerm(std::move(name), level), types_(std::move(types)) {
  auto fail = [&](const std::string& what) { throw std::invalid_argument("fene '" + this->name() + "': " + what); };
  std::vector<Params> params;
  params.reserve(types_.size());
  for (size_t t = 0; t < types_.size(); ++t) {
    const FeneCoeffs& c = types_[t];
    std::ostringstream m;
    m << "bond type " << t << ": ";
    if (!(c.K >= 0.0) || !std::isfinite(c.K))
      m << "K must be finite and >= 0, got " << c.K;
    else if (!(c.R0 > 0.0) || !std::isfinite(c.R0))
      m << "R0 must be finite and > 0, got " << c.R0;
    else if (!(c.epsilon >= 0.0) || !std::isfinite(c.epsilon))
      m << "epsilon must be finite and >= 0, got " << c.epsilon;
    else if (c.epsilon > 0.0 && !(c.sigma > 0.0 && std::isfinite(c.sigma)))
      m << "sigma must be finite and > 0 when epsilon > 0, got " << c.sigma;
    else {
      // WCA cutoff r_c = 2^{1/6} σ, where 4ε[(σ/r)¹² − (σ/r)⁶] has its minimum −ε: the +ε shift
      // makes the core purely repulsive and continuous (with its derivative) at r_c.
      const double wca_cut_sq = c.epsilon > 0.0 ? std::cbrt(2.0) * c.sigma * c.sigma : 0.0;
      params.push_back(
          {c.K, c.R0, 1.0 / (c.R0 * c.R0), 0.5 * c.K * c.R0 * c.R0, c.epsilon, c.sigma * c.sigma, wca_cut_sq});
      continue;
    }
    fail(m.str());
  }
  instances_.reserve(bonds.size());
  for (const Bond& b : bonds) {
    const std::string which = "bond (" + std::to_string(b.i) + ", " + std::to_string(b.j) + ")";
    if (b.i < 0 || b.j < 0) fail(which + ": particle indices must be >= 0");
    if (b.i == b.j) fail(which + ": a bond joins a particle to itself");
    if (b.type < 0 || static_cast<size_t>(b.type) >= params.size())
      fail(which + ": bond type " + std::to_string(b.type) + " is not defined (" + std::to_string(params.size()) +
           " types)");
    instances_.push_back({b.i, b.j, params[b.type]});
  }
}

void FeneBond::Kernel::out_of_range(double r, double R0) {
  std::ostringstream m;
  m.precision(10);
  m << "FENE bond length r = " << r << " outside (0, R0 = " << R0 << ")";
  throw NumericalError(m.str());
}

// Only reached on failure, so the second pass over the bonds costs nothing in a normal step. The
// test is the kernel's own, term for term, so the bond it refused is found.
void FeneBond::throw_out_of_range(const Eigen::Matrix3Xd& x, const Box& box) const {
  (void)box;  // the bond vector needs no box: molecules are whole (engine/state.hpp)
  for (const auto& b : instances_) {
    const double r = bond_vector(x, b.i, b.j).norm();
    if (r > 0.0 && r * r * b.params.inv_R0_sq < 1.0) continue;
    std::ostringstream m;
    m.precision(10);
    m << "fene '" << name() << "': bond between particles " << b.i << " and " << b.j;
    if (r > 0.0)
      m << " stretched to r = " << r << " >= R0 = " << b.params.R0 << " (FENE is defined only for r < R0)";
    else if (r == 0.0)
      m << ": the particles coincide (r = 0, the force direction is undefined)";
    else
      m << " has a non-finite length r = " << r;
    throw NumericalError(m.str());
  }
  throw NumericalError("fene '" + name() + "': a bond length left (0, R0)");  // not reached
}

double FeneBond::add_forces(const Eigen::Matrix3Xd& x, const Box& box, Eigen::Matrix3Xd& f) const {
  try {
    return accumulate_bond_forces<Kernel>(instances_, x, box, f, partition_);
  } catch (const NumericalError&) {
    throw_out_of_range(x, box);  // f holds the bonds before the failing one: the run is over anyway
  }
}

double FeneBond::virial(const Eigen::Matrix3Xd& x, const Box& box) const {
  try {
    return accumulate_bond_virial<Kernel>(instances_, x, box);
  } catch (const NumericalError&) {
    throw_out_of_range(x, box);
  }
}

std::string FeneBond::describe() const {
  std::ostringstream s;
  s << instances_.size() << " FENE bonds";
  for (size_t t = 0; t < types_.size(); ++t)
    s << (t == 0 ? "; " : ", ") << "type " << t << ": K = " << types_[t].K << ", R0 = " << types_[t].R0
      << ", epsilon = " << types_[t].epsilon << ", sigma = " << types_[t].sigma;
  return s.str();
}

}  // namespace stiffmd
