#include "engine/scene/kspace_deck.hpp"

#include <algorithm>
#include <cmath>
#include <limits>
#include <string>
#include <utility>
#include <vector>

#include "core/format.hpp"
#include "engine/scene/scene.hpp"
#include "forcefields/ewald_real_space.hpp"
#include "forcefields/kspace/ewald_parameters.hpp"
#include "forcefields/kspace/ewald_sum.hpp"
#include "forcefields/kspace/pppm.hpp"

namespace stiffmd {
namespace {

// The real-space terms (coul/long and its LJ combinations) already read: every one takes the g
// the k-space term chooses. None, or two with different Coulomb cutoffs, is the deck's mistake.
std::vector<EwaldRealSpace*> real_space_terms(DeckTable& t, const Scene& sc, const std::string& style) {
  std::vector<EwaldRealSpace*> out;
  for (const auto& term : sc.forces->terms()) {
    if (term->phase() == Phase::kspace)
      t.fail("style", style + ": [forces." + term->name() + "] (" + std::string(term->style()) +
                          ") is the scene's k-space term already; expected one, as LAMMPS has one kspace_style");
    if (auto* r = dynamic_cast<EwaldRealSpace*>(term.get())) out.push_back(r);
  }
  if (out.empty())
    t.fail("style", style +
                        " is the reciprocal-space half of Ewald summation and needs its real-space half: a "
                        "[forces.NAME] of pair style coul/long, lj/cut/coul/long or lj/charmm/coul/long");
  for (const EwaldRealSpace* r : out)
    if (r->coulomb_cutoff() != out.front()->coulomb_cutoff())
      t.fail("style", style + ": the coul/long terms have different Coulomb cutoffs (" +
                          format_number(out.front()->coulomb_cutoff()) + " and " + format_number(r->coulomb_cutoff()) +
                          "); expected one, as LAMMPS's kspace styles do");
  return out;
}

// What both styles read first: a charged, fully periodic scene, and the accuracy.
double read_accuracy(DeckTable& t, const Scene& sc, const std::string& style) {
  if (!sc.charged())
    t.fail_here(style + ": the scene has no charges (a type's or particle's charge, or a data file's q column)");
  if (!is_kspace_box(sc.box))
    t.fail_here(style + ": expected a box periodic on every axis (the reciprocal sum is over a periodic lattice)");
  const double a = t.number("accuracy");
  t.require(a > 0.0 && a < 1.0, "accuracy",
            "expected LAMMPS's relative RMS force accuracy, between 0 and 1 exclusive (e.g. 1e-4)");
  return a;
}

double read_splitting(DeckTable& t, double chosen) {
  if (!t.has("g_ewald")) return chosen;
  const double g = t.number("g_ewald");
  t.require(std::isfinite(g) && g > 0.0, "g_ewald", "expected a splitting parameter > 0 (inverse length)");
  return g;
}

// Three integers ≥ lo, ≤ hi, at `key`.
void read_triple(DeckTable& t, const char* key, int lo, int hi, int* out) {
  const std::vector<double> v = t.numbers(key);
  if (v.size() != 3) t.fail(key, "expected three integers [nx, ny, nz]");
  for (int a = 0; a < 3; ++a) {
    if (!(v[a] == std::floor(v[a]) && v[a] >= lo && v[a] <= hi))
      t.fail(key,
             "expected integers " + std::to_string(lo) + " .. " + std::to_string(hi) + ", got " + format_number(v[a]));
    out[a] = static_cast<int>(v[a]);
  }
}

// N (the charged particles, as LAMMPS's estimates after the choice count them) and q2 = qqrd2e Σ q²,
// the error estimates' inputs (ewald_parameters.hpp) at the deck's own g_ewald or resolution.
std::pair<double, double> charge_moments(const ChargeSums& c, const Scene& sc) {
  return {static_cast<double>(c.charged), sc.units.coulomb * c.sum_q2};
}

// What both styles do once LAMMPS's choice is made: the deck's g_ewald and resolution (`key`,
// the k-vectors or the mesh) over it, with the error estimate at the parameters given; the real-
// space terms' g; the term.
template <class Term, class Params, class KspaceError>
std::unique_ptr<ForceTerm> finish_kspace(const std::string& name, Level level, DeckTable& t, const Scene& sc,
                                         const std::vector<EwaldRealSpace*>& real, const ChargeSums& charges, Params p,
                                         const char* key, int lo, int hi, int (Params::*resolution)[3],
                                         KspaceError kspace_error) {
  p.g_ewald = read_splitting(t, p.g_ewald);
  if (t.has(key)) read_triple(t, key, lo, hi, p.*resolution);
  if (t.has("g_ewald") || t.has(key)) {
    const auto [n, q2] = charge_moments(charges, sc);
    p.estimated_error =
        std::hypot(real_space_error(p.g_ewald, real.front()->coulomb_cutoff(), n, q2, sc.box.lengths.prod()),
                   kspace_error(p, sc.box, n, q2));
  }
  for (EwaldRealSpace* r : real) r->set_ewald_splitting(p.g_ewald);
  // A description's sc.charge holds its loaded particles' only (none for the builder's chains):
  // the term is then a description, each part's made from it with the part's charges (on_subset).
  return std::make_unique<Term>(name, level, sc.charge, p, sc.units.coulomb, sc.box);
}

}  // namespace

ChargeSums charge_sums(const Scene& sc) {
  ChargeSums c;
  c.add(sc.charge);  // the loaded particles come first (scene.hpp)
  for (const DescribedSource& d : sc.described_sources) {
    if (d.summed) {
      // A data file's charges, per particle, summed by its reader in the whole scene's order (the
      // scene's only source): Σq and max |q| alone. Σq² and the charged count are not summed — a
      // description of a data file with a k-space term is loaded whole (load_scene) — and are NaN
      // and −1 here, so that no parameter can be chosen from them unnoticed.
      c.particles += d.count;
      c.sum_q += d.charge_sum;
      c.max_abs = std::max(c.max_abs, d.charge_scale);
      c.sum_q2 = std::numeric_limits<double>::quiet_NaN();
      c.charged = -1;
      continue;
    }
    // Carried by type: a by-molecule build's one type (the particles in order, type by type).
    for (std::size_t t = 0; t < d.particles_of_type.size(); ++t) c.add(sc.types[t].charge, d.particles_of_type[t]);
  }
  return c;
}

std::unique_ptr<ForceTerm> read_ewald(const std::string& name, Level level, DeckTable& t, TermContext& ctx) {
  const Scene& sc = ctx.scene;
  const double accuracy = read_accuracy(t, sc, "ewald");
  const auto real = real_space_terms(t, sc, "ewald");
  const ChargeSums charges = charge_sums(sc);
  EwaldParameters p;
  try {
    p = choose_ewald(accuracy, real.front()->coulomb_cutoff(), charges, sc.box, sc.units.coulomb);
  } catch (const std::invalid_argument& e) {
    t.fail("accuracy", e.what());
  }
  return finish_kspace<EwaldSum>(name, level, t, sc, real, charges, p, "kmax", 1, 1000, &EwaldParameters::kmax,
                                 ewald_kspace_error);
}

std::unique_ptr<ForceTerm> read_pppm(const std::string& name, Level level, DeckTable& t, TermContext& ctx) {
  const Scene& sc = ctx.scene;
  const double accuracy = read_accuracy(t, sc, "pppm");
  const double order = t.number("order", 5.0);
  t.require(order == std::floor(order) && order >= 1 && order <= 7, "order",
            "expected the charge-assignment order, an integer 1 .. 7 (LAMMPS kspace_modify order)");
  const auto real = real_space_terms(t, sc, "pppm");
  const ChargeSums charges = charge_sums(sc);
  MeshParameters p;
  try {
    p = choose_pppm(accuracy, real.front()->coulomb_cutoff(), charges, sc.box, sc.units.coulomb,
                    static_cast<int>(order));
  } catch (const std::invalid_argument& e) {
    t.fail("accuracy", e.what());
  }
  return finish_kspace<ParticleParticleParticleMesh>(name, level, t, sc, real, charges, p, "mesh", 2, 4096,
                                                     &MeshParameters::mesh, pppm_kspace_error);
}

}  // namespace stiffmd
