#include "engine/observables.hpp"

#include <cmath>

namespace stiffmd {

Energies energies(const State& s, const ForceField& forces) {
  Energies e;
  e.kinetic = s.kinetic_energy();
  e.slow = forces.energy(s.x, Level::slow);
  e.stiff = forces.energy(s.x, Level::fast);
  return e;
}

double max_constraint_violation(const Eigen::Matrix3Xd& x, const Box& box, const StiffBonds* stiff) {
  if (!stiff) return 0.0;
  double worst = 0.0;
  for (const StiffBond& b : stiff->bonds)
    worst = std::max(worst, std::abs(box.min_image(x.col(b.i) - x.col(b.j)).norm() - b.length));
  return worst;
}

Thermo::Thermo(const ForceField& forces)
    : forces_(forces),
      columns_{"time", "step", "kinetic", "potential_slow", "potential_stiff", "total", "energy_drift", "max_violation"} {
  values_.resize(columns_.size());
}

const std::vector<double>& Thermo::sample(const State& s) {
  const Energies e = energies(s, forces_);
  if (!have_e0_) {
    e0_ = e.total();
    have_e0_ = true;
  }
  values_ = {s.t,
             static_cast<double>(s.step),
             e.kinetic,
             e.slow,
             e.stiff,
             e.total(),
             e.total() - e0_,
             max_constraint_violation(s.x, forces_.box(), forces_.stiff_bonds())};
  return values_;
}

}  // namespace stiffmd
