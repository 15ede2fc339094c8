// The one table of integrator methods (design.md §3, §7).
#include <stdexcept>

#include "integrators/integrator.hpp"
#include "integrators/multiple_time_stepping.hpp"

namespace stiffmd {

const std::vector<std::string>& integrator_methods() {
  static const std::vector<std::string> names = {"velocity-verlet", "impulse"};
  return names;
}

std::unique_ptr<Integrator> make_integrator(const IntegratorSettings& s, ForceField& forces) {
  if (s.method == "velocity-verlet")
    return std::make_unique<MultipleTimeStepping>(s.method, forces,
                                                  std::vector<Stage>{{{Level::fast, Level::slow}, 1}});
  if (s.method == "impulse")
    return std::make_unique<MultipleTimeStepping>(
        s.method, forces, std::vector<Stage>{{{Level::slow}, 1}, {{Level::fast}, s.micro_steps}});
  throw std::invalid_argument("unknown integrator method '" + s.method + "'");
}

}  // namespace stiffmd
