// The one table of integrator methods (design.md §3, §7).
#include <algorithm>
#include <stdexcept>

#include "integrators/integrator.hpp"
#include "integrators/kick_forces.hpp"
#include "integrators/multiple_time_stepping.hpp"
#include "integrators/rattle.hpp"

namespace stiffmd {

const std::vector<std::string>& integrator_methods() {
  static const std::vector<std::string> names = {"velocity-verlet",   "impulse", "mollified-impulse",
                                                 "projected-impulse", "rattle",  "effective"};
  return names;
}

bool method_needs_stiff_bonds(const std::string& method) {
  return method == "mollified-impulse" || method == "projected-impulse" || method == "rattle" || method == "effective";
}

std::unique_ptr<Integrator> make_integrator(const IntegratorSettings& s, ForceField& forces,
                                            const Eigen::VectorXd& inv_mass) {
  const auto& names = integrator_methods();
  if (std::find(names.begin(), names.end(), s.method) == names.end())
    throw std::invalid_argument("unknown integrator method '" + s.method + "'");
  const StiffBonds* stiff = forces.stiff_bonds();
  if (method_needs_stiff_bonds(s.method) && !stiff)
    throw std::invalid_argument("method '" + s.method +
                                "' needs constraint-defining stiff bonds (a stiff-harmonic term)");

  // The impulse family: slow kick ½h, n micro steps of the fast part, slow kick ½h.
  const std::vector<Stage> impulse_stages = {{{Level::slow}, 1}, {{Level::fast}, s.micro_steps}};
  if (s.method == "velocity-verlet")
    return std::make_unique<MultipleTimeStepping>(s.method, forces,
                                                  std::vector<Stage>{{{Level::fast, Level::slow}, 1}});
  if (s.method == "impulse") return std::make_unique<MultipleTimeStepping>(s.method, forces, impulse_stages);
  if (s.method == "projected-impulse")
    return std::make_unique<MultipleTimeStepping>(
        s.method, forces, impulse_stages, std::make_unique<ProjectedKick>(ConstraintToolbox(stiff->bonds, inv_mass)));
  if (s.method == "mollified-impulse")
    return std::make_unique<MultipleTimeStepping>(
        s.method, forces, impulse_stages,
        std::make_unique<MollifiedKick>(ConstraintToolbox(stiff->bonds, inv_mass), forces.num_particles()));
  if (s.method == "rattle")
    return std::make_unique<Rattle>(s.method, forces, ConstraintToolbox(stiff->bonds, inv_mass), nullptr);
  // effective
  auto modes = std::make_unique<StiffModes>(stiff->bonds, inv_mass, stiff->epsilon, s.max_cluster_bonds);
  if (modes->num_skipped_clusters() > 0)
    throw std::invalid_argument(
        "the effective dynamics needs the modes of every constraint cluster, but " +
        std::to_string(modes->num_skipped_clusters()) +
        " cluster(s) have more than max_cluster_bonds = " + std::to_string(s.max_cluster_bonds) + " bonds");
  return std::make_unique<Rattle>(s.method, forces, ConstraintToolbox(stiff->bonds, inv_mass), std::move(modes));
}

}  // namespace stiffmd
