#include "engine/scene/thermostat_deck.hpp"

#include <cmath>
#include <sstream>

#include "forcefields/force_field.hpp"
#include "integrators/constraints.hpp"
#include "integrators/methods.hpp"
#include "integrators/thermostat.hpp"

namespace stiffmd {

// [thermostat]
//   style       = "langevin" | "csvr"
//   temperature = kT (k_B = 1) in lj units, T in K in real units (kT = k_B T inside)
//   damp        = 1/γ in time units (fs in real), as LAMMPS's fix langevin, or friction = γ: exactly one
//                 (langevin)
//   [thermostat.scale] TYPE = r > 0: damp of that type multiplied by r, γ divided by r (LAMMPS's
//                      `scale TYPE r`: fix_langevin.cpp multiplies its friction factor by 1/ratio)
//   tau         = relaxation time of the kinetic energy (csvr, Bussi et al. 2007)
//   seed        = integer >= 0: the noise is a function of (seed, step, particle) only
//   splitting   = "baoab" (default) | "lammps" | "obabo": Langevin as an exact O step (BAOAB,
//                 BAOAB-RESPA, constrained BAOAB), as a friction and noise force in the outermost
//                 kick force (LAMMPS's fix nve + fix langevin; velocity-verlet and the impulse family
//                 only), or as exact O steps of ½h around the Hamiltonian step (OBABO, every
//                 method; for the constrained ones one SHAKE per step instead of BAOAB's two)
namespace {

// The constrained O step is exact only with one friction on each rigid cluster
// (integrators/thermostat.hpp, uneven_friction_in_cluster): a [thermostat.scale] that gives two
// particles of one cluster different frictions is refused at the key of one of their types.
void refuse_uneven_friction(DeckTable& scale, const Scene& sc) {
  const StiffBonds* stiff = sc.forces->stiff_bonds();
  if (!stiff) return;
  const auto u = uneven_friction_in_cluster(find_clusters(stiff->bonds, sc.state.inv_mass), sc.state.inv_mass,
                                            sc.integrator.thermostat.friction);
  if (!u) return;
  const std::string& ta = sc.types[sc.particle_type[u->a]].name;
  const std::string& tb = sc.types[sc.particle_type[u->b]].name;
  std::ostringstream m;
  m << "type " << tb << " (particle " << u->b << ") and type " << ta << " (particle " << u->a
    << ") get different frictions in one rigid cluster (" << u->cluster.size() << " particles, " << u->cluster.front()
    << ".." << u->cluster.back() << "): method '" << sc.integrator.method
    << "' keeps the Maxwell law under Langevin only with one friction per cluster; scale every type of a "
       "cluster alike, or use velocity-verlet or the impulse family";
  scale.fail(scale.has(tb) ? tb : ta, m.str());
}

}  // namespace

void read_thermostat(DeckTable& root, Scene& sc) {
  const MethodInfo& method = *find_method(sc.integrator.method);  // read_integrator checked it
  auto t = root.table("thermostat");
  if (!t) {
    if (method.needs_temperature)
      root.table("integrator")
          ->fail("method", "method '" + sc.integrator.method +
                               "' needs a temperature: Fixman's potential U_F = (kT/2) log det(K^1/2 G M^-1 G^T K^1/2) "
                               "is a free energy at kT; add a [thermostat] table (style, temperature, ...)");
    return;
  }
  ThermostatSettings& th = sc.integrator.thermostat;
  const std::string style = t->string("style");
  if (style == "langevin")
    th.style = ThermostatSettings::Style::langevin;
  else if (style == "csvr")
    th.style = ThermostatSettings::Style::csvr;
  else
    t->fail("style", "expected \"langevin\" or \"csvr\" (stochastic velocity rescaling), got \"" + style + "\"");
  const double temperature = t->number("temperature");
  t->require(temperature >= 0.0 && std::isfinite(temperature), "temperature",
             sc.units.reduced() ? "expected a temperature kT >= 0 (k_B = 1)" : "expected a temperature >= 0 (K)");
  th.temperature = sc.units.kT(temperature);
  const long seed = t->integer("seed");
  t->require(seed >= 0, "seed", "expected an integer seed >= 0");
  th.seed = static_cast<std::uint64_t>(seed);
  if (th.style == ThermostatSettings::Style::langevin) {
    const auto damp = t->maybe_number("damp");
    const auto friction = t->maybe_number("friction");
    if (damp && friction) t->fail("friction", "give either damp (= 1/friction) or friction, not both");
    if (!damp && !friction) t->fail_here("missing damp (time units, LAMMPS's fix langevin) or friction (= 1/damp)");
    if (damp) t->require(*damp > 0.0 && std::isfinite(*damp), "damp", "expected a damping time > 0");
    if (friction) t->require(*friction >= 0.0 && std::isfinite(*friction), "friction", "expected a friction >= 0");
    const double gamma = sc.units.rate_in(damp ? 1.0 / *damp : *friction);
    std::vector<double> type_scale(sc.types.size(), 1.0);
    auto scale = t->table("scale");
    if (scale) {
      // One key per particle type; finish() names the types when a key is none of them.
      for (size_t k = 0; k < sc.types.size(); ++k)
        if (const auto r = scale->maybe_number(sc.types[k].name)) {
          scale->require(*r > 0.0 && std::isfinite(*r), sc.types[k].name,
                         "expected a damping ratio > 0 for type " + sc.types[k].name + " (damp x ratio)");
          type_scale[k] = 1.0 / *r;
        }
      scale->finish();
    }
    const std::string splitting = t->string("splitting", "baoab");
    if (splitting == "lammps") {
      th.splitting = ThermostatSettings::Splitting::lammps;
      if (method.rigid_constraints)
        t->fail("splitting",
                "the \"lammps\" splitting (a friction and noise force inside velocity Verlet) is "
                "for velocity-verlet and the impulse family; method '" +
                    sc.integrator.method + "' takes \"baoab\" (constrained BAOAB)");
    } else if (splitting == "obabo") {
      th.splitting = ThermostatSettings::Splitting::obabo;
    } else if (splitting != "baoab") {
      t->fail("splitting",
              "expected \"baoab\" (an exact O step), \"lammps\" (LAMMPS's fix langevin force) or "
              "\"obabo\" (O steps of h/2 around the step), got \"" +
                  splitting + "\"");
    }
    th.friction.resize(sc.state.size());
    for (int i = 0; i < sc.state.size(); ++i) th.friction[i] = gamma * type_scale[sc.particle_type[i]];
    // A description's counted particles: their type's friction (no per-particle array of them).
    for (DescribedSource& d : sc.described_sources) {
      d.friction_of_type.resize(sc.types.size());
      for (std::size_t k = 0; k < sc.types.size(); ++k) d.friction_of_type[k] = gamma * type_scale[k];
    }
    if (method.rigid_constraints && scale) refuse_uneven_friction(*scale, sc);
  } else {
    const double tau = t->number("tau");
    t->require(tau >= 0.0 && std::isfinite(tau), "tau",
               "expected a relaxation time tau >= 0 (0: the kinetic energy redrawn every step)");
    th.tau = sc.units.time_in(tau);
  }
  t->finish();
  sc.observables.thermostat = th.style;
}

}  // namespace stiffmd
