// [barostat]
//   style           = "c-rescale"   (stochastic cell rescaling, Bernetti & Bussi 2020)
//   pressure        = P₀, or [P_x, P_y, P_z] (anisotropic), [P_xy, P_z] (semi-isotropic); deck
//                     pressure units (lj: ε/σ³, real: atm)
//   coupling        = "isotropic" | "semi-isotropic" (x with y, z alone) | "anisotropic"
//   tau             = τ_p, the volume's relaxation time (time units)
//   compressibility = β_T, an estimate of the isothermal compressibility (1/pressure units)
//   interval        = macro steps per cell move (default 10)
//   seed            = the cell noise's seed (default: the thermostat's)
#include "engine/scene/barostat_deck.hpp"

#include <algorithm>
#include <cmath>
#include <sstream>

#include "core/format.hpp"
#include "core/topology.hpp"
#include "engine/scene/scene.hpp"

namespace stiffmd {

namespace {

constexpr char kAxis[3] = {'x', 'y', 'z'};

// The first molecule that reaches half the box along an axis: a cell move shifts it as one, and the
// minimum image no longer tells its beads' neighbours apart.
void refuse_large_molecules(DeckTable& t, const Scene& sc, const std::vector<int>& molecule) {
  int count = 0;
  for (int m : molecule) count = std::max(count, m + 1);
  Eigen::Matrix3Xd lo = Eigen::Matrix3Xd::Constant(3, count, INFINITY), hi = -lo;
  for (int i = 0; i < sc.state.size(); ++i) {
    lo.col(molecule[i]) = lo.col(molecule[i]).cwiseMin(sc.state.x.col(i));
    hi.col(molecule[i]) = hi.col(molecule[i]).cwiseMax(sc.state.x.col(i));
  }
  for (int m = 0; m < count; ++m)
    for (int a = 0; a < 3; ++a) {
      const double extent = hi(a, m) - lo(a, m);
      if (extent < 0.5 * sc.box.lengths[a]) continue;
      int first = 0;
      while (molecule[first] != m) ++first;
      std::ostringstream s;
      s << "the molecule of particle " << first << " spans " << format_number(extent, 6) << " along " << kAxis[a]
        << ", at least half the box length " << format_number(sc.box.lengths[a], 6)
        << ": a barostat moves each molecule as one by its centre of mass and needs every molecule below half the "
           "box on each axis; enlarge the box";
      t.fail_here(s.str());
    }
}

}  // namespace

void read_barostat(DeckTable& root, Scene& sc) {
  auto t = root.table("barostat");
  if (!t) return;
  BarostatSettings& b = sc.integrator.barostat;
  b.on = true;
  const std::string style = t->string("style");
  if (style != "c-rescale")
    t->fail("style",
            "expected \"c-rescale\" (stochastic cell rescaling, Bernetti & Bussi 2020), got \"" + style + "\"");
  const std::string coupling = t->string("coupling", "isotropic");
  if (coupling == "isotropic")
    b.coupling = BarostatSettings::Coupling::isotropic;
  else if (coupling == "semi-isotropic")
    b.coupling = BarostatSettings::Coupling::semi_isotropic;
  else if (coupling == "anisotropic")
    b.coupling = BarostatSettings::Coupling::anisotropic;
  else
    t->fail("coupling", "expected \"isotropic\", \"semi-isotropic\" (x with y, z alone) or \"anisotropic\", got \"" +
                            coupling + "\"");
  // The pressure: one number, or one per group of coupled axes.
  const std::string units = sc.units.reduced() ? "epsilon/sigma^3" : "atm";
  std::vector<double> p;
  if (!t->is_array("pressure")) {
    p.assign(3, t->number("pressure"));
  } else {
    p = t->numbers("pressure");
    const size_t groups = b.coupling == BarostatSettings::Coupling::anisotropic      ? 3
                          : b.coupling == BarostatSettings::Coupling::semi_isotropic ? 2
                                                                                     : 1;
    t->require(p.size() == groups || p.size() == 1, "pressure",
               groups == 1
                   ? "expected one pressure for coupling \"isotropic\", got " + std::to_string(p.size())
                   : "expected one pressure or " + std::to_string(groups) + " (one per coupled group) for coupling \"" +
                         coupling + "\", got " + std::to_string(p.size()));
    if (p.size() == 1) p.assign(3, p[0]);
    if (p.size() == 2) p = {p[0], p[0], p[1]};
  }
  for (double v : p) t->require(std::isfinite(v), "pressure", "expected a finite pressure (" + units + ")");
  for (int a = 0; a < 3; ++a) b.pressure[a] = p[a] / sc.units.pressure;
  const double tau = t->number("tau");
  t->require(tau > 0.0 && std::isfinite(tau), "tau", "expected a relaxation time tau > 0");
  b.tau = sc.units.time_in(tau);
  const double beta = t->number("compressibility");
  t->require(beta > 0.0 && std::isfinite(beta), "compressibility",
             "expected an isothermal compressibility > 0 (1/" + units +
                 "; an estimate: with tau it sets how fast "
                 "the volume relaxes, not its fluctuations)");
  b.compressibility = beta * sc.units.pressure;
  const long interval = t->integer("interval", 10);
  t->require(interval >= 1 && interval <= 1000000, "interval", "expected a whole number of macro steps >= 1");
  b.interval = static_cast<int>(interval);
  const long seed = t->integer("seed", static_cast<long>(sc.integrator.thermostat.seed));
  t->require(seed >= 0, "seed", "expected an integer seed >= 0");
  b.seed = static_cast<std::uint64_t>(seed);
  t->finish();

  // What the scene must offer.
  if (!sc.thermostatted() || !(sc.integrator.thermostat.temperature > 0.0))
    t->fail("style", "a barostat needs a temperature: add a [thermostat] (langevin or csvr) with temperature > 0");
  b.temperature = sc.integrator.thermostat.temperature;
  // LAMMPS's Langevin force lives in the method's cached kick force, which a cell move discards (the
  // fresh forces after it have no friction and noise for that half kick): measured T = 0.964 for
  // kT = 1 on a Kremer-Grest melt, against 0.999 under BAOAB.
  if (sc.integrator.thermostat.style == ThermostatSettings::Style::langevin &&
      sc.integrator.thermostat.splitting == ThermostatSettings::Splitting::lammps)
    t->fail("style",
            "a barostat does not run with thermostat.splitting = \"lammps\" (the Langevin force in the cached kick "
            "force, which each cell move discards); use \"baoab\" or \"obabo\"");
  for (int a = 0; a < 3; ++a)
    if (!sc.box.periodic[a])
      t->fail("style", std::string("the box is open along ") + kAxis[a] +
                           ": a barostat scales a periodic box; make every axis periodic ([box] periodic)");
  for (int i = 0; i < sc.state.size(); ++i)
    if (sc.state.inv_mass[i] == 0.0)
      t->fail("style", "particle " + std::to_string(i) +
                           " is fixed (mass 0 or pinned): a barostat moves every molecule with the box");
  for (const auto& term : sc.forces->terms())
    if (!term->conserves_momentum())
      t->fail("style", "force term '" + term->name() + "' (" + std::string(term->style()) +
                           ") is an external field: its virial in a periodic box is not defined, so the pressure "
                           "the barostat needs is not");
  b.molecule = bonded_molecules(sc.topology, sc.state.size());
  refuse_large_molecules(*t, sc, b.molecule);
  sc.observables.barostat = true;
}

}  // namespace stiffmd
