// The one table of integrator methods (docs/design.md §3–§5, §8): every fact about a method — its deck
// name, what it needs from the scene and what it does with the stiff bonds — lives in its row.
// The deck reader, the factory, the run loop, the outputs and the tests all read this table;
// nothing else tests method names.
#pragma once

#include <memory>
#include <optional>
#include <span>
#include <string>
#include <string_view>

#include "integrators/integrator.hpp"

namespace stiffmd {

struct MethodInfo {
  std::string_view name;     // as in the deck: integrator.method
  std::string_view summary;  // one line, for --help, `check` and README
  bool needs_stiff_bonds;    // refuses a scene without a constraint-defining term
  bool micro_steps;          // takes micro_dt / micro_steps (the impulse family)
  bool rigid_constraints;    // integrates on g(x) = 0: removes one degree of freedom per bond
  bool effective;            // carries actions I and the correction potential W(I, x)
  // Its solution approaches the effective dynamics' as ε → 0: the effective method itself, and
  // the projected and mollified impulse methods, whose error against it falls like h² down to
  // O(ε) (docs/design.md §7). Both rest on the actions being adiabatic invariants, which needs
  // separated, nonresonant stiff frequencies: the thermo's validity warnings concern these
  // methods only (a method that resolves the vibrations, or has none, needs no such assumption).
  bool follows_effective;
  bool needs_temperature;  // its model potential is a free energy at kT: refuses a run without a thermostat
  // The impulse family's kick on every level slower than the innermost, unless the level names
  // its own ([[integrator.levels]] kick); none: a method without such kicks (velocity Verlet
  // steps every level at once, the constrained methods have no levels to split).
  std::optional<Kick> kick;
  // Builds the integrator for a scene whose force field and inverse masses are given; throws
  // std::invalid_argument when the scene cannot run it.
  std::unique_ptr<Integrator> (*make)(const IntegratorSettings&, ForceField&, const Eigen::VectorXd& inv_mass);
};

// Every method, in the order README and --help list them.
std::span<const MethodInfo> methods();
// The row of `name`, or nullptr for an unknown name.
const MethodInfo* find_method(std::string_view name);
// "velocity-verlet, impulse, …": for error messages.
std::string method_names();

}  // namespace stiffmd
