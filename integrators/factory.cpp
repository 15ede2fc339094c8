// The one table of integrator methods (integrators/methods.hpp; docs/design.md §3–§5, §8).
#include <algorithm>
#include <array>
#include <stdexcept>

#include "integrators/integrator.hpp"
#include "integrators/kick_forces.hpp"
#include "integrators/methods.hpp"
#include "integrators/multiple_time_stepping.hpp"
#include "integrators/rattle.hpp"

namespace stiffmd {
namespace {

using Ptr = std::unique_ptr<Integrator>;

const StiffBonds& stiff_bonds_of(const ForceField& forces) {
  return *forces.stiff_bonds();
}

// The O step of Langevin dynamics, when the deck asks for it (each method places it: BAOAB,
// BAOAB-RESPA, constrained BAOAB).
bool langevin_force(const IntegratorSettings& s) {
  return s.thermostat.style == ThermostatSettings::Style::langevin &&
         s.thermostat.splitting == ThermostatSettings::Splitting::lammps;
}
std::unique_ptr<LangevinNoise> langevin_of(const IntegratorSettings& s, const Eigen::VectorXd& inv_mass) {
  if (s.thermostat.style != ThermostatSettings::Style::langevin) return nullptr;
  if (langevin_force(s))
    throw std::invalid_argument("method '" + s.method +
                                "' has no Langevin splitting \"lammps\" (velocity-verlet and the impulse family do)");
  return std::make_unique<LangevinNoise>(s.thermostat, inv_mass);
}
// Langevin as a force on the outermost kick (splitting = "lammps"): velocity Verlet and the
// impulse family. Either this or langevin_of, never both.
std::unique_ptr<LangevinNoise> o_step_of(const IntegratorSettings& s, const Eigen::VectorXd& inv_mass) {
  return langevin_force(s) ? nullptr : langevin_of(s, inv_mass);
}
std::unique_ptr<LangevinForce> langevin_force_of(const IntegratorSettings& s, const Eigen::VectorXd& inv_mass) {
  return langevin_force(s) ? std::make_unique<LangevinForce>(s.thermostat, inv_mass) : nullptr;
}

// The kick strategies the impulse family's levels use (integrators/kick_forces.hpp).
std::shared_ptr<KickForce> make_kick(Kick kick, ForceField& forces, const Eigen::VectorXd& inv_mass) {
  if (kick == Kick::plain) return std::make_shared<PlainKick>();
  if (!forces.stiff_bonds())
    throw std::invalid_argument("the " + std::string(kick_name(kick)) +
                                " kick needs constraint-defining stiff bonds (a stiff-harmonic term)");
  ConstraintToolbox toolbox(stiff_bonds_of(forces).bonds, inv_mass);
  if (kick == Kick::projected) return std::make_shared<ProjectedKick>(std::move(toolbox));
  return std::make_shared<MollifiedKick>(std::move(toolbox), forces.num_particles());
}

// The impulse family: slow kick ½h, n micro steps of the fast part, slow kick ½h; with the deck's
// levels (innermost first, LAMMPS's loop factors) one stage per level, outermost first, each
// taking the loop factor of the level enclosing it as its substeps (docs/design.md §3). Every
// stage but the innermost kicks with its level's kick, by default the method's; the stages of one
// kind share one strategy, so that one constraint toolbox serves them all (S(x) factored once
// per configuration when two levels kick at the same x).
Ptr make_impulse_family(const IntegratorSettings& s, ForceField& forces, const Eigen::VectorXd& inv_mass) {
  const Kick method_kick = *find_method(s.method)->kick;
  std::array<std::shared_ptr<KickForce>, kKickNames.size()> made;
  const auto kick_of = [&](Kick k) {
    std::shared_ptr<KickForce>& p = made[static_cast<size_t>(k)];
    if (!p) p = make_kick(k, forces, inv_mass);
    return p;
  };
  std::vector<Stage> stages;
  if (s.levels.empty()) {
    stages = {{{Level::slow}, 1, kick_of(method_kick)}, {{Level::fast}, s.micro_steps, nullptr}};
  } else {
    const int n = static_cast<int>(s.levels.size());
    for (int k = n - 1; k >= 0; --k)
      stages.push_back({{Level{k}},
                        k + 1 < n ? s.levels[k + 1].substeps : 1,
                        k > 0 ? kick_of(s.levels[k].kick.value_or(method_kick)) : nullptr});
  }
  return std::make_unique<MultipleTimeStepping>(s.method, forces, std::move(stages), o_step_of(s, inv_mass),
                                                langevin_force_of(s, inv_mass), s.thermostat.splitting);
}

// Velocity Verlet: every level in one stage (the levels' substeps do not apply).
Ptr make_velocity_verlet(const IntegratorSettings& s, ForceField& forces, const Eigen::VectorXd& inv_mass) {
  return std::make_unique<MultipleTimeStepping>(s.method, forces, std::vector<Stage>{{forces.all_levels(), 1}},
                                                o_step_of(s, inv_mass), langevin_force_of(s, inv_mass),
                                                s.thermostat.splitting);
}

Ptr make_rattle(const IntegratorSettings& s, ForceField& forces, const Eigen::VectorXd& inv_mass) {
  return std::make_unique<Rattle>(s.method, forces, ConstraintToolbox(stiff_bonds_of(forces).bonds, inv_mass), nullptr,
                                  langevin_of(s, inv_mass), s.thermostat.splitting);
}
Ptr make_effective(const IntegratorSettings& s, ForceField& forces, const Eigen::VectorXd& inv_mass) {
  const StiffBonds& stiff = stiff_bonds_of(forces);
  // Every cluster the dense mode computation can take: the limit is StiffModes', not an observables
  // setting (the thermo output's max_cluster_bonds only bounds what is observed).
  StiffModes modes(stiff.bonds, inv_mass, stiff.epsilon, StiffModes::kMaxDenseBonds);
  if (modes.num_skipped_clusters() > 0)
    throw std::invalid_argument("the effective dynamics needs the modes of every constraint cluster, but " +
                                std::to_string(modes.num_skipped_clusters()) + " cluster(s) have more than " +
                                std::to_string(StiffModes::kMaxDenseBonds) +
                                " bonds (the limit of the dense mode computation); use another method");
  return std::make_unique<Rattle>(s.method, forces, ConstraintToolbox(stiff.bonds, inv_mass),
                                  std::make_unique<EffectiveCorrection>(std::move(modes)), langevin_of(s, inv_mass),
                                  s.thermostat.splitting);
}

// The thermal stiff limit (docs/design.md §5): RATTLE on U + U_F at the thermostat's kT.
Ptr make_fixman(const IntegratorSettings& s, ForceField& forces, const Eigen::VectorXd& inv_mass) {
  if (!s.thermostat.on())
    throw std::invalid_argument(
        "fixman needs a thermostat: U_F = (kT/2) log det(K^1/2 G M^-1 G^T K^1/2) is a free "
        "energy at the thermostat's kT");
  const StiffBonds& stiff = stiff_bonds_of(forces);
  return std::make_unique<Rattle>(
      s.method, forces, ConstraintToolbox(stiff.bonds, inv_mass),
      std::make_unique<FixmanCorrection>(FixmanPotential(stiff.bonds, inv_mass), s.thermostat.temperature),
      langevin_of(s, inv_mass), s.thermostat.splitting);
}

//                     name               summary                                                        stiff  micro
//                     rigid  eff.  follows eff.  kT  kick
constexpr std::array<MethodInfo, 7> kMethods = {{
    {"velocity-verlet", "Stormer-Verlet on the full H; step limited by eps", false, false, false, false, false, false,
     std::nullopt, make_velocity_verlet},
    {"impulse", "r-RESPA / impulse: slow kick, n micro steps of the fast part, slow kick", false, true, false, false,
     false, false, Kick::plain, make_impulse_family},
    {"mollified-impulse", "impulse with the mollified kick a'(x)^T f(a(x))", true, true, false, false, true, false,
     Kick::mollified, make_impulse_family},
    {"projected-impulse", "impulse with the projected kick P(x) f", true, true, false, false, true, false,
     Kick::projected, make_impulse_family},
    {"rattle", "RATTLE with the stiff bonds as rigid constraints (the rigid limit)", true, false, true, false, false,
     false, std::nullopt, make_rattle},
    {"effective", "RATTLE on U + sum I_k omega_k(x): the eps -> 0 limit at fixed actions", true, false, true, true,
     true, false, std::nullopt, make_effective},
    {"fixman", "RATTLE on U + U_F (Fixman) with a thermostat: the thermal eps -> 0 limit", true, false, true, false,
     false, true, std::nullopt, make_fixman},
}};

}  // namespace

std::span<const MethodInfo> methods() {
  return kMethods;
}

const MethodInfo* find_method(std::string_view name) {
  for (const MethodInfo& m : kMethods)
    if (m.name == name) return &m;
  return nullptr;
}

std::string method_names() {
  std::string out;
  for (const MethodInfo& m : kMethods) (out += out.empty() ? "" : ", ") += m.name;
  return out;
}

std::unique_ptr<Integrator> make_integrator(const IntegratorSettings& s, ForceField& forces,
                                            const Eigen::VectorXd& inv_mass) {
  const MethodInfo* m = find_method(s.method);
  if (!m) throw std::invalid_argument("unknown integrator method '" + s.method + "' (known: " + method_names() + ")");
  if (s.levels.empty() ? forces.num_levels() != 2 : forces.num_levels() != static_cast<int>(s.levels.size()))
    throw std::invalid_argument("the force field has " + std::to_string(forces.num_levels()) +
                                " levels, the integrator settings " +
                                std::to_string(s.levels.empty() ? 2 : s.levels.size()));
  for (size_t k = 0; k < s.levels.size(); ++k) {
    if (s.levels[k].substeps < 1 || (k == 0 && s.levels[k].substeps != 1))
      throw std::invalid_argument("level '" + s.levels[k].name + "': substeps must be >= 1 (1 on the innermost)");
    if (s.levels[k].kick && (k == 0 || !m->kick))
      throw std::invalid_argument("level '" + s.levels[k].name + "': a kick is chosen only on a level slower than " +
                                  "the innermost, for a method of the impulse family");
  }
  if (m->needs_stiff_bonds && !forces.stiff_bonds())
    throw std::invalid_argument("method '" + s.method +
                                "' needs constraint-defining stiff bonds (a stiff-harmonic term)");
  std::unique_ptr<Integrator> integrator = m->make(s, forces, inv_mass);
  if (s.thermostat.style == ThermostatSettings::Style::csvr) {
    const int rigid = m->rigid_constraints ? static_cast<int>(forces.stiff_bonds()->bonds.size()) : 0;
    const int dof = s.thermostat.degrees_of_freedom > 0
                        ? s.thermostat.degrees_of_freedom
                        : degrees_of_freedom(inv_mass, momentum_conserved(forces, inv_mass, s.thermostat), rigid);
    integrator = with_velocity_rescaling(std::move(integrator), s.thermostat, dof);
  }
  // The cell moves around the thermostatted step, at the macro step (integrators/barostat.hpp).
  if (s.barostat.on) integrator = with_cell_rescaling(std::move(integrator), s.barostat, forces, inv_mass);
  return integrator;
}

}  // namespace stiffmd
