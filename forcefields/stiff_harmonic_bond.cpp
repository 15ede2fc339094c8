#include "forcefields/stiff_harmonic_bond.hpp"

#include <sstream>
#include <stdexcept>

#include "forcefields/coefficients.hpp"

namespace stiffmd {

StiffHarmonicBond::StiffHarmonicBond(std::string name, Level level, StiffBonds bonds)
    : ForceTerm(std::move(name), level), bonds_(std::move(bonds)) {
  require(bonds_.epsilon, kPositive, "epsilon");
  if (bonds_.shake_tolerance != 0.0) require(bonds_.shake_tolerance, kPositive, "shake_tolerance");
  const double inv_eps2 = 1.0 / (bonds_.epsilon * bonds_.epsilon);
  instances_.reserve(bonds_.bonds.size());
  // The masses are not known here: the rules that need them are checked by the deck reader
  // (engine/scene/force_registry.cpp) and the constraint toolbox, with the same function.
  if (const auto problem = find_stiff_bond_problem(bonds_.bonds, nullptr)) throw std::invalid_argument(problem->what);
  for (const StiffBond& b : bonds_.bonds) instances_.push_back({b.i, b.j, {b.length, b.alpha * b.alpha * inv_eps2}});
}

double StiffHarmonicBond::add_forces(const Eigen::Matrix3Xd& x, const Box& box, Eigen::Matrix3Xd& f) const {
  return accumulate_bond_forces<Kernel>(instances_, x, box, f, partition_);
}

namespace {

// Whether the rule can read the subset's topology: every bond's type known to the rule, every
// angle's type ≥ 0, and every stiff bond (a claimed type's) and rigid angle within the subset —
// the system's topology restricted to whole molecules.
bool topology_within(const ParticleSubset& subset, const StiffBondRule& rule) {
  const int types = static_cast<int>(rule.bond_claim.size());
  for (const Bond& b : subset.topology.bonds)
    if (b.type < 0 || b.type >= types ||
        (rule.bond_claim[static_cast<size_t>(b.type)] >= 0 && reaches_outside(b, subset, &Bond::i, &Bond::j)))
      return false;
  for (const Angle& a : subset.topology.angles)
    if (a.type < 0 || (rule.rigid(a.type) && reaches_outside(a, subset, &Angle::i, &Angle::j, &Angle::k))) return false;
  return true;
}

}  // namespace

std::unique_ptr<ForceTerm> StiffHarmonicBond::on_subset(const ParticleSubset& subset, const Box&) const {
  StiffBonds mine;
  mine.epsilon = bonds_.epsilon;
  mine.shake_tolerance = bonds_.shake_tolerance;
  const std::string who = "stiff-harmonic '" + name() + "'";
  if (!rule_.empty() && topology_within(subset, rule_)) {
    mine.bonds = rule_.bonds_of(subset.topology);
  } else {
    mine.bonds = items_on_subset(bonds_.bonds, subset, who, "stiff bond", &StiffBond::i, &StiffBond::j);
    // A stiff bond or rigid angle of the subset's topology across the subset's edge is refused
    // even when this term's list no longer holds it.
    const int types = static_cast<int>(rule_.bond_claim.size());
    for (const Bond& b : subset.topology.bonds)
      if (b.type >= 0 && b.type < types && rule_.bond_claim[static_cast<size_t>(b.type)] >= 0 &&
          reaches_outside(b, subset, &Bond::i, &Bond::j))
        refuse_cut_item(b, subset, who, "stiff bond", &Bond::i, &Bond::j);
    for (const Angle& a : subset.topology.angles)
      if (rule_.rigid(a.type) && reaches_outside(a, subset, &Angle::i, &Angle::j, &Angle::k))
        refuse_cut_item(a, subset, who, "rigid angle", &Angle::i, &Angle::j, &Angle::k);
  }
  auto out = std::make_unique<StiffHarmonicBond>(name(), level(), std::move(mine));
  out->rule_ = rule_;
  return out;
}

std::string StiffHarmonicBond::describe() const {
  std::ostringstream s;
  s << bonds_.bonds.size() << " stiff bonds, epsilon = " << bonds_.epsilon;
  if (bonds_.shake_tolerance > 0.0) s << ", SHAKE tolerance " << bonds_.shake_tolerance << " (LAMMPS's)";
  return s.str();
}

void StiffHarmonicBond::define(ParameterRecord& record) const {
  record.add("epsilon", bonds_.epsilon);
  record.add("bonds", bonds_.bonds.size());
  for (const StiffBond& b : bonds_.bonds) {
    record.add("bond", {b.i, b.j});
    record.add("length", b.length);
    record.add("alpha", b.alpha);
  }
}

}  // namespace stiffmd
