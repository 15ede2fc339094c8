// The integrator interface: one macro step of size h, state and h passed as arguments
// (style.md §5). Integrators see forces only through ForceField's levels.
#pragma once

#include <memory>
#include <string>
#include <string_view>
#include <vector>

#include "engine/state.hpp"
#include "forcefields/force_field.hpp"

namespace stiffmd {

struct IntegratorSettings {
  std::string method = "velocity-verlet";
  double h = 0.0;       // macro step
  int micro_steps = 1;  // n micro steps δ = h/n per macro step (impulse family)
};

class Integrator {
 public:
  virtual ~Integrator() = default;
  virtual void step(State& s, double h) = 0;
  // Forget cached forces: call when the state was changed other than by step().
  virtual void reset() {}
  virtual std::string_view method() const = 0;
};

// The method names the deck and CLI accept (design.md §7).
const std::vector<std::string>& integrator_methods();

// Builds the integrator named by settings.method; throws std::invalid_argument for an
// unknown name or a method the scene cannot run.
std::unique_ptr<Integrator> make_integrator(const IntegratorSettings& settings, ForceField& forces);

}  // namespace stiffmd
