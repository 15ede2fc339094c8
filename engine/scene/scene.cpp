#include "engine/scene/scene.hpp"

#include <algorithm>
#include <array>
#include <cctype>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <limits>
#include <optional>
#include <set>
#include <sstream>
#include <string_view>

#include "core/errors.hpp"
#include "core/format.hpp"
#include "engine/scene/barostat_deck.hpp"
#include "engine/scene/ensemble_deck.hpp"
#include "engine/scene/force_registry.hpp"
#include "engine/scene/kspace_deck.hpp"
#include "engine/scene/scene_sources.hpp"
#include "engine/scene/thermostat_deck.hpp"
#include "forcefields/ewald_real_space.hpp"
#include "forcefields/stiff_harmonic_bond.hpp"
#include "integrators/methods.hpp"
#include "integrators/modes.hpp"

namespace stiffmd {
namespace {

// Chemical symbols: trajectories name species by element so that ASE and OVITO read them.
bool is_element(const std::string& s) {
  static const std::set<std::string> elements = {
      "H",  "He", "Li", "Be", "B",  "C",  "N",  "O",  "F",  "Ne", "Na", "Mg", "Al", "Si", "P",  "S",  "Cl",
      "Ar", "K",  "Ca", "Sc", "Ti", "V",  "Cr", "Mn", "Fe", "Co", "Ni", "Cu", "Zn", "Ga", "Ge", "As", "Se",
      "Br", "Kr", "Rb", "Sr", "Y",  "Zr", "Nb", "Mo", "Tc", "Ru", "Rh", "Pd", "Ag", "Cd", "In", "Sn", "Sb",
      "Te", "I",  "Xe", "Cs", "Ba", "La", "Ce", "Pr", "Nd", "Pm", "Sm", "Eu", "Gd", "Tb", "Dy", "Ho", "Er",
      "Tm", "Yb", "Lu", "Hf", "Ta", "W",  "Re", "Os", "Ir", "Pt", "Au", "Hg", "Tl", "Pb", "Bi", "Po", "At",
      "Rn", "Fr", "Ra", "Ac", "Th", "Pa", "U",  "Np", "Pu", "Am", "Cm", "Bk", "Cf", "Es", "Fm", "Md", "No",
      "Lr", "Rf", "Db", "Sg", "Bh", "Hs", "Mt", "Ds", "Rg", "Cn", "Nh", "Fl", "Mc", "Lv", "Ts", "Og"};
  return elements.count(s) > 0;
}

// Scene::num_steps and read_run: t_end / h within this relative distance of an integer n is n steps.
constexpr double kWholeStepTolerance = 1e-9;

// Distinct default elements for bead types that do not name one.
const std::array<const char*, 8> kDefaultElements = {"C", "O", "N", "S", "P", "H", "Fe", "Si"};

// units = "lj" (reduced, the default) or "real" (LAMMPS's: Å, fs, kcal/mol, g/mol, K, atm). Read
// first: every later key of time, temperature or velocity is converted with it.
void read_units(DeckTable& root, Scene& sc) {
  const std::string name = root.string("units", "lj");
  const auto u = Units::named(name);
  if (!u)
    root.fail("units", "expected \"lj\" (reduced units) or \"real\" (LAMMPS real: A, fs, kcal/mol, g/mol, K), got \"" +
                           name + "\"");
  sc.units = *u;
}

void read_box(DeckTable& root, Scene& sc) {
  auto t = root.table("box");
  if (!t) return;  // open space, or set by a builder's density or an imported file
  sc.box.periodic = t->bool3("periodic", false);
  sc.box.origin = t->vector3("origin", Eigen::Vector3d::Zero());
  if (sc.box.any_periodic() || t->has("lengths")) {
    sc.box.lengths = t->vector3("lengths");
    for (int a = 0; a < 3; ++a)
      if (sc.box.periodic[a])
        t->require(sc.box.lengths[a] > 0.0, "lengths", "expected box lengths > 0 on periodic axes");
  }
  t->finish();
}

void read_types(DeckTable& root, Scene& sc) {
  auto t = root.table("types");
  if (!t) root.missing("types", "missing required table [types.NAME] (mass, element)");
  size_t unnamed = 0;
  for (auto& [name, tt] : t->named_tables()) {
    ParticleType pt;
    pt.name = name;
    pt.mass = tt.number("mass");
    tt.require(pt.mass > 0.0, "mass", "expected a mass > 0 (use fixed = true on a particle to pin it)");
    const std::string fallback = is_element(name) ? name : kDefaultElements[unnamed++ % kDefaultElements.size()];
    pt.element = tt.string("element", fallback);
    if (!is_element(pt.element))
      tt.fail("element", "expected a chemical element symbol such as \"C\", got \"" + pt.element + "\"");
    pt.charge = tt.number("charge", 0.0);
    tt.require(std::isfinite(pt.charge), "charge", "expected a finite charge (in units of e)");
    tt.finish();
    sc.types.push_back(pt);
  }
  if (sc.types.empty()) t->fail_here("expected at least one particle type [types.NAME]");
}

void read_particles(DeckTable& root, Scene& sc) {
  for (DeckTable& p : root.array_of_tables("particles")) {
    std::string type_name = p.name("type", sc.types.size() == 1 ? sc.types[0].name : "");
    if (type_name.empty()) p.fail_here("missing required key 'type' (the deck defines several [types])");
    const int type = particle_type_index(sc, p, "type", type_name);
    const double mass = p.number("mass", sc.types[type].mass);
    p.require(mass > 0.0, "mass", "expected a mass > 0");
    const bool fixed = p.boolean("fixed", false);
    const double charge = p.number("charge", sc.types[type].charge);
    p.require(std::isfinite(charge), "charge", "expected a finite charge (in units of e)");
    const Eigen::Matrix3Xd x = p.vector3("position");
    const Eigen::Matrix3Xd v = sc.units.velocity_in(1.0) * p.vector3("velocity", Eigen::Vector3d::Zero());
    if (fixed && !v.isZero()) p.fail("velocity", "a fixed particle cannot have a velocity");
    const int i = append_particles(sc, x, v, {type}, {});
    sc.sources.push_back({i, 1, p.where()});
    sc.state.inv_mass[i] = fixed ? 0.0 : 1.0 / mass;
    sc.charge[i] = charge;
    p.finish();
  }
}

// Positions are unwrapped; on a periodic axis the minimum image rounds d/L to an integer and
// LAMMPS keeps image flags in 21 bits. A particle more than 2^20 box lengths away from the box is
// a mistake (units, a forgotten box), not a configuration, and would overflow that rounding.
void check_positions_near_box(DeckTable& root, const Scene& sc) {
  constexpr double kMaxImages = 1 << 20;
  auto particles = root.array_of_tables("particles");  // the first particles of the scene
  for (int a = 0; a < 3; ++a) {
    if (!sc.box.periodic[a]) continue;
    for (int i = 0; i < sc.state.size(); ++i) {
      const double images = (sc.state.x(a, i) - sc.box.origin[a]) / sc.box.lengths[a];
      if (std::abs(images) <= kMaxImages) continue;
      const std::string what = "particle " + std::to_string(i) + " is at " + static_cast<char>('x' + a) + " = " +
                               format_number(sc.state.x(a, i)) + ", more than 2^20 box lengths (" +
                               format_number(sc.box.lengths[a]) +
                               ") from the periodic box; expected a position near it";
      if (static_cast<size_t>(i) < particles.size()) particles[static_cast<size_t>(i)].fail("position", what);
      root.fail_here(what);
    }
  }
}

void read_bonds(DeckTable& root, Scene& sc) {
  const int n = sc.state.size();
  std::set<std::pair<int, int>> seen;
  for (const Bond& b : sc.topology.bonds) seen.insert({std::min(b.i, b.j), std::max(b.i, b.j)});
  for (DeckTable& b : root.array_of_tables("bonds")) {
    const std::vector<long> ij = b.integers("particles");
    if (ij.size() != 2) b.fail("particles", "expected two particle indices [i, j]");
    for (long k : ij)
      if (k < 0 || k >= n)
        b.fail("particles",
               "particle " + std::to_string(k) + " does not exist (particles are 0.." + std::to_string(n - 1) + ")");
    if (ij[0] == ij[1]) b.fail("particles", "a bond must join two different particles");
    const std::pair<int, int> key{static_cast<int>(std::min(ij[0], ij[1])), static_cast<int>(std::max(ij[0], ij[1]))};
    if (!seen.insert(key).second)
      b.fail("particles",
             "duplicate bond between particles " + std::to_string(key.first) + " and " + std::to_string(key.second));
    const std::string type = b.name("type");
    const int t = Topology::intern(sc.topology.bond_types, type);
    if ((sc.state.x.col(ij[0]) - sc.state.x.col(ij[1])).norm() == 0.0)
      b.fail("particles", "the two particles of this bond sit at the same position (zero-length bond)");
    b.finish();
    sc.topology.bonds.push_back({static_cast<int>(ij[0]), static_cast<int>(ij[1]), t});
  }
}

// [[integrator.levels]]: the r-RESPA levels (docs/design.md §3), innermost first as LAMMPS numbers
// them, each with LAMMPS's loop factor `substeps` (steps of the level inside it per step of this
// one). Read before [forces], whose terms name them; without it the levels are fast and slow.
void read_levels(DeckTable& root, Scene& sc) {
  auto t = root.table("integrator");
  if (!t || !t->has("levels")) return;  // read_integrator reports a missing [integrator]
  auto rows = t->array_of_tables("levels");
  if (rows.empty()) t->fail("levels", "expected at least one [[integrator.levels]] (name, substeps)");
  double product = 1.0;
  for (size_t k = 0; k < rows.size(); ++k) {
    DeckTable& r = rows[k];
    LevelSettings level{r.name("name"), 1, std::nullopt};
    // A level's name becomes a thermo column (potential_NAME: a CSV header, an H5MD observable
    // group), so it is a word: no comma, slash, quote or space to break those files.
    r.require(std::all_of(level.name.begin(), level.name.end(),
                          [](char c) { return std::isalnum(static_cast<unsigned char>(c)) || c == '_' || c == '-'; }),
              "name",
              "expected a level name of letters, digits, '_' and '-' (it names the thermo column potential_" +
                  level.name + "), got \"" + level.name + "\"");
    for (const LevelSettings& l : sc.integrator.levels)
      r.require(l.name != level.name, "name", "level \"" + level.name + "\" is given twice");
    if (k == 0) {
      if (r.has("substeps"))
        r.fail("substeps",
               "the first level is the innermost: it has no inner level to split its step into (give substeps "
               "on the levels outside it: the steps of the level before per step of this one)");
    } else {
      const long n = r.integer("substeps", 1);
      r.require(n >= 1 && n <= 100000000, "substeps",
                "expected an integer in 1..1e8 (steps of level \"" + sc.integrator.levels.back().name +
                    "\" per step of this one)");
      level.substeps = static_cast<int>(n);
      product *= static_cast<double>(n);
      r.require(product <= 1e8, "substeps", "expected at most 1e8 innermost steps per macro step in all");
    }
    // The level's kick (integrators/kick_forces.hpp); whether the method has kicks at all is
    // checked with the method (read_integrator).
    if (r.has("kick")) {
      const std::string name = r.name("kick");
      if (k == 0)
        r.fail("kick",
               "the first level is the innermost: its micro steps resolve the stiff bonds and apply its force "
               "plainly (give kick on the levels outside it)");
      level.kick = find_kick(name);
      r.require(level.kick.has_value(), "kick",
                "expected \"plain\", \"projected\" or \"mollified\", got \"" + name + "\"");
    }
    r.finish();
    sc.integrator.levels.push_back(level);
  }
  // Named levels other than the default pair get a thermo column potential_NAME each, beside the
  // columns every run has, potential_slow (all but the stiff bonds) and potential_stiff, and
  // potential_fixman (Fixman's potential under fixman): a level named slow, stiff or fixman would
  // write a column of that name with another meaning.
  const auto& levels = sc.integrator.levels;
  const bool default_pair = levels.size() == 2 && levels[0].name == "fast" && levels[1].name == "slow";
  if (!default_pair)
    for (size_t k = 0; k < levels.size(); ++k)
      if (levels[k].name == "slow" || levels[k].name == "stiff" || levels[k].name == "fixman")
        rows[k].fail("name", "level name \"" + levels[k].name + "\" would give the thermo a second potential_" +
                                 levels[k].name +
                                 " column (potential_slow, potential_stiff and potential_fixman are the energies of "
                                 "all but the stiff bonds, of the stiff bonds and Fixman's potential); choose another "
                                 "name");
}

// Every named level must hold a term: an empty one would be a kick by zero, most likely a typo.
void check_levels_used(DeckTable& root, const Scene& sc) {
  if (sc.integrator.levels.empty()) return;
  auto rows = root.table("integrator")->array_of_tables("levels");
  for (size_t k = 0; k < rows.size(); ++k) {
    const Level l{static_cast<int>(k)};
    const auto& terms = sc.forces->terms();
    if (std::none_of(terms.begin(), terms.end(), [&](const auto& t) { return t->level() == l; }))
      rows[k].fail("name", "level \"" + sc.integrator.levels[k].name +
                               "\" has no force term (give a [forces.NAME] level = \"" + sc.integrator.levels[k].name +
                               "\", or remove the level)");
  }
}

// A term defined on part of configuration space (FENE: r < R0; a 9-3 wall: its particles on one
// side; an angle: arms of non-zero length) would fail at the run's first force evaluation, after
// its outputs were opened, for an initial state outside it: that is the deck's fault, so it is
// refused here, at the key that defines the domain. Pair terms are left out: evaluating one would
// build its neighbour list at a state the run may not start from ([prepare]), and their kernels
// are finite for every r > 0.
void check_initial_state(DeckTable& t, const ForceTerm& term, const Scene& sc) {
  if (term.uses_neighbor_list()) return;
  Eigen::Matrix3Xd f = Eigen::Matrix3Xd::Zero(3, sc.state.size());
  try {
    term.add_forces(sc.state.x, sc.box, f);
  } catch (const NumericalError& e) {
    const std::string what = std::string(e.what()) + " in the initial state";
    for (const char* key : {"bond_types", "angle_types", "dihedral_types", "improper_types", "coefficients", "position",
                            "particles", "type"})
      if (t.has(key)) t.fail(key, what);
    t.fail_here(what);
  }
}

// `overlap`: where the pair terms put their finding of overlapping particles at the start (null:
// they refuse it at once).
// Charges act only through a term that reads them (ForceTerm::uses_charges): without one they
// would be lost, so the scene is refused, naming where the first charge came from. A net charge
// is said as a warning: the Ewald terms add a uniform neutralising background (as LAMMPS does),
// the cut-off styles simply sum what they see.
void check_charges(DeckTable& root, Scene& sc) {
  if (!sc.charged()) return;
  const auto& terms = sc.forces->terms();
  const bool used = std::any_of(terms.begin(), terms.end(), [](const auto& t) { return t->uses_charges(); });
  // The first charged particle: a loaded one, else the first of a described source of a charged
  // type (the loaded particles come first, scene.hpp).
  const auto first = std::find_if(sc.charge.begin(), sc.charge.end(), [](double q) { return q != 0.0; });
  int i = static_cast<int>(first - sc.charge.begin());
  double q_first = first != sc.charge.end() ? *first : 0.0;
  // A source's first charged particle: the one its reader found (a data file's, whose types are
  // mixed), else its first particle of a charged type (a chain's beads are of one type).
  if (first == sc.charge.end())
    for (const DescribedSource& d : sc.described_sources) {
      if (d.summed) {
        if (d.first_charged < 0) continue;
        i = d.first_charged, q_first = d.first_charge;
        break;
      }
      std::size_t k = 0;
      while (k < d.particles_of_type.size() && !(d.particles_of_type[k] > 0 && sc.types[k].charge != 0.0)) ++k;
      if (k == d.particles_of_type.size()) continue;
      i = d.first, q_first = sc.types[k].charge;
      break;
    }
  if (!used)
    root.fail_here(particle_and_source(sc, i) + " has charge " + format_number(q_first) +
                       ", but no force term acts on charges: they would be lost; add a Coulomb pair style "
                       "(coul/cut, coul/debye, lj/cut/coul/long with an ewald or pppm term, …) or set the charges to 0",
                   {"forces"});
  // Summed in particle order, a described source's particles each in turn (the whole scene's sum
  // to the last bit; no array of them).
  const ChargeSums sums = charge_sums(sc);
  if (std::abs(sums.sum_q) > 1e-5 * std::max(1.0, sums.max_abs))
    sc.notes.push_back("warning: the system's net charge is " + format_number(sums.sum_q) +
                       " e: the Ewald and PPPM terms add a uniform neutralising background (as LAMMPS does)");
}

void read_forces(DeckTable& root, Scene& sc, std::string* overlap = nullptr) {
  std::vector<std::string> level_names;
  for (const LevelSettings& l : sc.integrator.levels) level_names.push_back(l.name);
  sc.forces = level_names.empty() ? std::make_unique<ForceField>(sc.box, sc.state.size())
                                  : std::make_unique<ForceField>(sc.box, sc.state.size(), level_names);
  std::vector<std::string> owner(sc.topology.bond_types.size()), angle_owner(sc.topology.angle_types.size()),
      dihedral_owner(sc.topology.dihedral_types.size()), improper_owner(sc.topology.improper_types.size());
  std::vector<char> rigid_angle(sc.topology.angle_types.size(), 0);
  TermContext ctx{sc,      owner,   angle_owner, dihedral_owner, improper_owner, &sc.lammps_coeffs,
                  overlap, nullptr, &rigid_angle};
  ctx.overlap_rules = &sc.overlap_rules;
  auto forces = root.table("forces");
  if (forces) {
    std::string stiff_term;
    // The k-space terms last, whatever the tables' order: they set the splitting parameter of the
    // real-space (coul/long) terms read before them (engine/scene/kspace_deck.hpp).
    auto tables = forces->named_tables();
    const auto& styles = force_styles();
    const auto style_of = [&](DeckTable& t) {
      const std::string style = t.string("style");
      auto it = std::find_if(styles.begin(), styles.end(), [&](const ForceStyle& s) { return style == s.name; });
      if (it == styles.end()) {
        std::string known;
        for (const auto& s : styles) known += (known.empty() ? "" : ", ") + std::string(s.name);
        t.fail("style", "unknown force style '" + style + "' (known: " + known + ")");
      }
      return it;
    };
    // The terms with coefficients = "data" after those that name their types: a data term takes
    // every type of the file that no other term claims (a stiff term's bonds to hydrogen, say).
    std::vector<std::pair<int, size_t>> order;  // (rank, position in the deck)
    for (size_t k = 0; k < tables.size(); ++k) {
      DeckTable& t = tables[k].second;
      order.emplace_back(std::string_view(style_of(t)->kind) == "kspace" ? 2 : t.gives("coefficients") ? 1 : 0, k);
    }
    std::stable_sort(order.begin(), order.end(), [](const auto& a, const auto& b) { return a.first < b.first; });
    for (const auto& [rank, k] : order) {
      auto& [name, t] = tables[k];
      const auto it = style_of(t);
      const std::string style = it->name;
      // A style's default level is a role: the innermost level (Level::fast) or the outermost.
      const ForceField& ff = *sc.forces;
      const Level fallback = it->default_level == Level::fast ? ff.innermost() : ff.outermost();
      const std::string level_name_str = t.string("level", ff.level_name(fallback));
      const auto level = ff.find_level(level_name_str);
      if (!level) {
        std::string known;
        for (int k = 0; k < ff.num_levels(); ++k) known += (k ? ", \"" : "\"") + ff.level_name(Level{k}) + "\"";
        t.fail("level", "unknown level \"" + level_name_str + "\" (expected one of " + known +
                            (sc.integrator.levels.empty() ? "" : ", the [[integrator.levels]]") + ")");
      }
      std::unique_ptr<ForceTerm> term;
      try {
        term = it->read(name, *level, t, ctx);
      } catch (const std::invalid_argument& e) {
        t.fail_here(e.what());
      }
      // The constraint-defining term is what the impulse methods' micro steps resolve and what the
      // constrained methods replace by rigid constraints (docs/design.md §3–§4): on a slower level the impulse
      // methods would kick it with the macro step and blow up (energy 5.57 -> 263 210 on the pendulum).
      if (term->is_constraint_defining() && term->level() != ff.innermost())
        t.fail("level", "a constraint-defining term (" + style + ") must sit on the fastest level, \"" +
                            ff.level_name(ff.innermost()) + "\" (the innermost); got \"" + level_name_str + "\"");
      if (term->stiff_bonds()) {
        if (!stiff_term.empty())
          t.fail("style",
                 "only one constraint-defining (stiff-harmonic) term is allowed; [forces." + stiff_term + "] is one");
        stiff_term = name;
      }
      t.finish();
      check_initial_state(t, *term, sc);
      sc.forces->add(std::move(term));
    }
  }
  // Every bonded interaction must have its parameters somewhere: name the deck row of an
  // explicit bond, or the type for builder/imported bonds (which precede the explicit ones).
  auto bond_rows = root.array_of_tables("bonds");
  const std::vector<std::string> type_sources = {"build", "import"};  // what names the other types
  const size_t first_explicit = sc.topology.bonds.size() - bond_rows.size();
  for (size_t k = 0; k < sc.topology.bonds.size(); ++k) {
    const int t = sc.topology.bonds[k].type;
    if (!owner[t].empty()) continue;
    const std::string what = "bond type '" + sc.topology.bond_types[t] +
                             "' is not defined by any force term (add [forces.NAME.bond_types." +
                             sc.topology.bond_types[t] + "])";
    if (k >= first_explicit) bond_rows[k - first_explicit].fail("type", what);
    root.fail_here(what, type_sources);
  }
  // A description's counted bonds come after the loaded ones (scene.hpp), in source order; within
  // a source the first bond of an undefined type is of the first such type in the names' order
  // (each source's types are interned by their first bond).
  for (const DescribedSource& d : sc.described_sources)
    for (std::size_t t = 0; t < d.bonds_of_type.size(); ++t)
      if (d.bonds_of_type[t] > 0 && owner[t].empty())
        root.fail_here("bond type '" + sc.topology.bond_types[t] +
                           "' is not defined by any force term (add [forces.NAME.bond_types." +
                           sc.topology.bond_types[t] + "])",
                       type_sources);
  for (size_t t = 0; t < sc.topology.angle_types.size(); ++t)
    if (angle_owner[t].empty() && !rigid_angle[t])
      root.fail_here("angle type '" + sc.topology.angle_types[t] +
                         "' is not defined by any force term (add [forces.NAME.angle_types." +
                         sc.topology.angle_types[t] + "])",
                     type_sources);
  for (size_t t = 0; t < sc.topology.dihedral_types.size(); ++t)
    if (dihedral_owner[t].empty())
      root.fail_here("dihedral type '" + sc.topology.dihedral_types[t] +
                         "' is not defined by any force term (add [forces.NAME.dihedral_types." +
                         sc.topology.dihedral_types[t] + "])",
                     type_sources);
  // Impropers come only from an imported data file's Impropers section.
  for (size_t t = 0; t < sc.topology.improper_types.size(); ++t)
    if (improper_owner[t].empty())
      root.fail_here("improper type '" + sc.topology.improper_types[t] +
                         "' (the imported data file's Impropers section) is not defined by any force term (add "
                         "[forces.NAME] with an improper style and improper_types." +
                         sc.topology.improper_types[t] + ", or coefficients = \"data\")",
                     type_sources);
  check_charges(root, sc);
  // A coul/long term's splitting comes from the ewald or pppm term: without one it has none.
  for (const auto& term : sc.forces->terms())
    if (const auto* r = dynamic_cast<const EwaldRealSpace*>(term.get()); r && std::isnan(r->ewald_splitting()))
      forces->fail(term->name(), "pair style " + std::string(term->style()) +
                                     " is Ewald's real-space half and needs a [forces.NAME] term of style ewald or "
                                     "pppm (its reciprocal half, which chooses the splitting parameter)");
}

void read_integrator(DeckTable& root, Scene& sc) {
  auto t = root.table("integrator");
  if (!t) root.missing("integrator", "missing required table [integrator] (method, h)");
  IntegratorSettings& in = sc.integrator;
  in.method = t->string("method");
  const MethodInfo* method = find_method(in.method);
  if (!method) t->fail("method", "unknown method '" + in.method + "' (known: " + method_names() + ")");
  if (method->needs_stiff_bonds && !sc.forces->stiff_bonds())
    t->fail("method", "method '" + in.method +
                          "' needs constraint-defining stiff bonds (a [forces.NAME] of style stiff-harmonic)");
  in.h = sc.units.time_in(t->number("h"));
  t->require(in.h > 0.0, "h", "expected a macro step h > 0");
  auto micro_dt = t->maybe_number("micro_dt");
  if (micro_dt) *micro_dt = sc.units.time_in(*micro_dt);
  const auto micro_steps = t->maybe_integer("micro_steps");
  if (micro_dt && micro_steps) t->fail("micro_steps", "give either micro_dt or micro_steps, not both");
  auto level_rows = t->array_of_tables("levels");  // read by read_levels
  for (size_t k = 0; k < in.levels.size(); ++k) {
    if (!in.levels[k].kick) continue;
    if (!method->kick) {
      std::string family;
      for (const MethodInfo& m : methods())
        if (m.kick) (family += family.empty() ? "" : ", ") += m.name;
      level_rows[k].fail(
          "kick",
          "method '" + in.method + "' has no kicks to choose (the impulse family has: " + family + "); remove this key",
          {"integrator.method"});
    }
    if (*in.levels[k].kick != Kick::plain && !sc.forces->stiff_bonds())
      level_rows[k].fail("kick", "the " + std::string(kick_name(*in.levels[k].kick)) +
                                     " kick needs constraint-defining stiff bonds (a [forces.NAME] of style "
                                     "stiff-harmonic)");
  }
  if (!in.levels.empty()) {
    if (micro_dt || micro_steps)
      t->fail(micro_dt ? "micro_dt" : "micro_steps",
              "with [[integrator.levels]] the levels' substeps set the micro steps; remove this key");
    // The innermost steps per macro step: the product of the loop factors (the impulse family).
    in.micro_steps = 1;
    if (method->micro_steps)
      for (const LevelSettings& l : in.levels) in.micro_steps *= l.substeps;
    t->finish();
    return;
  }
  // Micro steps belong to the impulse family; other methods ignore them, so that one deck
  // serves every method (docs/design.md §8).
  if (!method->micro_steps) {
    in.micro_steps = 1;
  } else if (micro_dt) {
    t->require(*micro_dt > 0.0, "micro_dt", "expected a micro step > 0");
    if (!(*micro_dt <= in.h * (1 + 1e-12)))
      t->fail("micro_dt", "expected micro_dt <= h = " + format_number(in.h / sc.units.time), {"integrator.h"});
    // n = h/δ rounded up, so the micro step actually used never exceeds micro_dt; bounded as
    // micro_steps is (and before the conversion to int).
    const double n = std::ceil(in.h / *micro_dt - 1e-9);
    if (!(n <= 1e8))
      t->fail("micro_dt",
              "h / micro_dt = " + format_number(in.h / sc.units.time) + " / " +
                  format_number(*micro_dt / sc.units.time) + " = " + format_number(n) +
                  " micro steps per macro step; expected at most 1e8",
              {"integrator.h"});
    in.micro_steps = static_cast<int>(n);
  } else if (micro_steps) {
    t->require(*micro_steps >= 1 && *micro_steps <= 100000000, "micro_steps", "expected an integer in 1..1e8");
    in.micro_steps = static_cast<int>(*micro_steps);
  }
  t->finish();
}

// [prepare] vibrational_temperature gives the stiff bonds thermal vibrations (prepare_state). A
// method that holds the bonds rigid projects its initial data onto them (Rattle::prepare), which
// takes the vibrations out again: the run starts without their energy. The effective dynamics
// keeps it, as the actions it reads before that projection (EffectiveCorrection::prepare).
void warn_projected_vibrations(DeckTable& root, Scene& sc) {
  const MethodInfo& m = *find_method(sc.integrator.method);
  if (!sc.prepare.requested || !(sc.prepare.vibrational_temperature > 0.0) || !m.rigid_constraints || m.effective)
    return;
  sc.notes.push_back("warning: " + root.table("prepare")->where("vibrational_temperature", {"integrator.method"}) +
                     ": method '" + sc.integrator.method +
                     "' holds the stiff bonds rigid and projects the initial state onto them, which takes these "
                     "vibrations out again: the run starts without their energy (velocity-verlet and the impulse "
                     "family keep them, effective as its actions)");
}

// A run is a whole number of macro steps: t_end = n h to a relative 1e-9 (Scene::num_steps rounds
// to that n). Anything else would end past t_end — one step to t = 0.5 when t_end = 0.1 — so it is
// refused, naming the nearest valid end times.
// [parallel] grid = [px, py, pz] (each ≥ 1; their product must be the number of ranks, checked
// when the run starts on them), halo_margin > 0 (a length), halo_pairs, balance and balance_threshold.
void read_parallel(DeckTable& root, Scene& sc) {
  auto t = root.table("parallel");
  if (!t) return;
  if (t->has("grid")) {
    sc.parallel.grid_where = t->where("grid");
    const std::vector<long> g = t->integers("grid");
    t->require(g.size() == 3 && g[0] >= 1 && g[1] >= 1 && g[2] >= 1, "grid",
               "expected three domain counts >= 1, one per axis, e.g. [2, 2, 1]");
    sc.parallel.grid = Eigen::Vector3i(static_cast<int>(g[0]), static_cast<int>(g[1]), static_cast<int>(g[2]));
  }
  if (auto m = t->maybe_number("halo_margin")) {
    sc.parallel.halo_margin_where = t->where("halo_margin");
    t->require(std::isfinite(*m) && *m > 0.0, "halo_margin", "expected a length > 0");
    sc.parallel.halo_margin = *m;  // lengths are the same in every unit system (σ or Å)
  }
  // halo_pairs = "both" | "once": where a pair of a home bead and a halo bead is computed.
  if (t->has("halo_pairs")) {
    sc.parallel.halo_pairs_where = t->where("halo_pairs");
    const std::string pairs = t->string("halo_pairs");
    t->require(pairs == "both" || pairs == "once", "halo_pairs",
               "expected \"both\" (each bead's home computes its pairs: one process's bits) or \"once\" (each "
               "pair on one rank, the halo's forces sent back)");
    sc.parallel.halo_pairs_once = pairs == "once";
  }
  // balance = "off" | "start" | "dynamic", balance_threshold >= 1 (the measure's max/mean).
  if (t->has("balance")) {
    sc.parallel.balance_where = t->where("balance");
    const std::string when = t->string("balance");
    using When = BalanceSettings::When;
    t->require(when == "off" || when == "start" || when == "dynamic", "balance",
               "expected \"off\", \"start\" or \"dynamic\"");
    sc.parallel.balance.when = when == "off" ? When::off : when == "start" ? When::start : When::dynamic;
  }
  if (auto b = t->maybe_number("balance_threshold")) {
    if (sc.parallel.balance_where.empty()) sc.parallel.balance_where = t->where("balance_threshold");
    t->require(std::isfinite(*b) && *b >= 1.0, "balance_threshold",
               "expected a number >= 1 (the largest domain's home beads over the mean that starts a recut)");
    sc.parallel.balance.threshold = *b;
  }
  t->finish();
}

void read_run(DeckTable& root, Scene& sc) {
  auto t = root.table("run");
  if (!t) root.missing("run", "missing required table [run] (t_end or steps)");
  // run.steps = N: the run ends at step N, time N h (the run's time grid t_k = k h). Exactly one
  // of steps and t_end: two ends could disagree.
  if (t->has("steps")) {
    if (t->has("t_end"))
      t->fail("steps", "run.t_end is given too; expected either t_end (a time) or steps (a number of macro steps)");
    const long steps = t->integer("steps");
    // A stage may take no step (a stage that only minimises, at its start); a run takes one at least.
    const long least = sc.stage.staged() ? 0 : 1;
    t->require(steps >= least && steps <= 1'000'000'000'000L, "steps",
               "expected a number of macro steps " + std::to_string(least) + " .. 1e12");
    sc.run.steps = steps;
    sc.run.t_end = static_cast<double>(steps) * sc.integrator.h;
    t->finish();
    return;
  }
  // In the deck's units here (the messages quote them), in the engine's from the end on.
  const double t_end = t->number("t_end");
  t->require(t_end > 0.0, "t_end", "expected an end time > 0");
  const double h = sc.integrator.h / sc.units.time;
  const double steps = t_end / h;
  if (!(steps <= 1e12))
    t->fail("t_end",
            "t_end / integrator.h = " + format_number(t_end) + " / " + format_number(h) + " = " + format_number(steps) +
                " steps; expected at most 1e12 steps",
            {"integrator.h"});
  const double n = std::round(steps);
  if (n < 1 || std::abs(steps - n) > kWholeStepTolerance * steps) {
    std::ostringstream m;
    m.precision(12);
    m << "t_end = " << t_end << " is " << steps << " macro steps of integrator.h = " << h
      << "; expected a whole number of steps: t_end = ";
    const double below = std::floor(steps), above = std::ceil(steps);
    const auto steps_word = [](double k) { return k == 1 ? " step)" : " steps)"; };
    if (below >= 1) m << below * h << " (" << below << steps_word(below) << " or ";
    m << above * h << " (" << above << steps_word(above) << ", or an h that divides t_end";
    t->fail("t_end", m.str(), {"integrator.h"});
  }
  sc.run.t_end = sc.units.time_in(t_end);
  t->finish();
}

void read_observables(DeckTable& root, Scene& sc) {
  auto t = root.table("observables");
  if (!t) return;
  sc.observables.actions = t->boolean("actions", false);
  sc.observables.histograms = t->boolean("histograms", true);
  // The range StiffModes accepts (its dense eigen-decompositions have a fixed maximum size).
  const long m = t->integer("max_cluster_bonds", sc.observables.max_cluster_bonds);
  t->require(m >= 1 && m <= StiffModes::kMaxDenseBonds, "max_cluster_bonds",
             "expected an integer in 1.." + std::to_string(StiffModes::kMaxDenseBonds) + ", got " + std::to_string(m));
  sc.observables.max_cluster_bonds = static_cast<int>(m);
  if (sc.observables.actions && !sc.forces->stiff_bonds())
    t->fail("actions", "actions need constraint-defining stiff bonds (a stiff-harmonic term)");
  t->finish();
}

// The terminal's thermo lines by default: about ten per run, on the thermo grid (a whole number of
// thermo intervals, so that every line is a row of the thermo file). Ten lines show a short run's
// course at a glance and stay a screenful however long the run; the progress bar tells the wall
// time in between. (LAMMPS prints at its thermo interval; ours defaults to t_end/100, a page.)
double default_screen_interval(double t_end, double thermo_interval) {
  return thermo_interval * std::max(1.0, std::round(t_end / 10 / thermo_interval));
}

void read_output(DeckTable& root, Scene& sc) {
  OutputSettings& o = sc.output;
  // Engine units; the keys are in the deck's. A stage of no steps writes its one state whatever
  // the intervals: any interval > 0 will do.
  const double default_interval = sc.run.t_end > 0.0 ? sc.run.t_end / 100 : sc.integrator.h;
  auto t = root.table("output");
  if (!t) {
    o.xyz = "trajectory.xyz";
    o.thermo = "thermo.csv";
    o.xyz_interval = o.thermo_interval = o.state_interval = default_interval;
    o.screen_interval = default_screen_interval(sc.run.t_end, o.thermo_interval);
    return;
  }
  const auto interval = [&](const char* key, double fallback) {
    const double v = t->has(key) ? sc.units.time_in(t->number(key)) : fallback;
    t->require(v > 0.0, key, "expected a time interval > 0");
    return v;
  };
  o.xyz = t->string("xyz", "trajectory.xyz");
  o.xyz_interval = interval("xyz_interval", default_interval);
  o.xyz_velocities = t->boolean("xyz_velocities", false);
  o.thermo = t->string("thermo", "thermo.csv");
  o.thermo_interval = interval("thermo_interval", default_interval);
  o.thermo_norm = t->boolean("thermo_norm", false);
  o.screen_interval = t->has("screen_interval") ? sc.units.time_in(t->number("screen_interval"))
                                                : default_screen_interval(sc.run.t_end, o.thermo_interval);
  t->require(o.screen_interval >= 0.0, "screen_interval", "expected a time interval >= 0 (0: no thermo lines)");
  o.state = t->string("state", "");
  o.state_interval = interval("state_interval", default_interval);
  if (!o.state.empty() && !sc.forces->stiff_bonds())
    t->fail("state", "the state output holds projected momenta P(x)p: it needs stiff bonds");
  o.h5md = t->string("h5md", "");
  o.h5md_interval = interval("h5md_interval", o.xyz_interval);
  o.h5md_velocity = t->boolean("h5md_velocity", false);
  o.h5md_force = t->boolean("h5md_force", false);
  const long gz = t->integer("h5md_gzip", 0);
  t->require(gz >= 0 && gz <= 9, "h5md_gzip", "expected a deflate level 0..9 (0: no compression)");
  o.h5md_gzip = static_cast<int>(gz);
  o.author = t->string("author", "");
  o.lammps_data = t->string("lammps_data", "");
  o.checkpoint = t->string("checkpoint", o.checkpoint);
  if (o.checkpoint.empty()) t->fail("checkpoint", "expected a file name (checkpoints are always written at the end)");
  // Every output key is a time; checkpoint_every counted macro steps.
  if (t->has_retired("checkpoint_every")) {
    const double n = t->number("checkpoint_every");
    const double h = sc.integrator.h / sc.units.time;
    t->fail("checkpoint_every",
            "is no longer read (it counted steps; every output key is a time): write "
            "checkpoint_interval = " +
                format_number(n * h) + " (" + format_number(n) + " steps of h = " + format_number(h) +
                "; 0: only at the end)");
  }
  o.checkpoint_interval = t->has("checkpoint_interval") ? sc.units.time_in(t->number("checkpoint_interval")) : 0.0;
  t->require(o.checkpoint_interval >= 0.0, "checkpoint_interval",
             "expected a time interval >= 0 (0: only at the end and on a signal)");
  // An interval longer than the run gives the first and the final frame only (and a checkpoint
  // interval none but the final one): most likely a time meant in other units or a typo.
  const double time_out = sc.units.out(Dimension::time);
  const auto warn_if_longer = [&](const char* key, double interval, bool on) {
    if (on && t->has(key) && interval > sc.run.t_end && sc.run.t_end > 0.0)
      sc.notes.push_back("warning: " + t->where(key, {"run.t_end"}) + " = " + format_number(interval * time_out) +
                         " is longer than the run (run.t_end = " + format_number(sc.run.t_end * time_out) +
                         (std::string(key) == "checkpoint_interval"
                              ? "): no checkpoint before the final one"
                              : "): only the first and the final frames are written"));
  };
  warn_if_longer("xyz_interval", o.xyz_interval, !o.xyz.empty());
  warn_if_longer("thermo_interval", o.thermo_interval, true);
  warn_if_longer("state_interval", o.state_interval, !o.state.empty());
  warn_if_longer("h5md_interval", o.h5md_interval, !o.h5md.empty());
  warn_if_longer("screen_interval", o.screen_interval, o.screen_interval > 0.0);
  warn_if_longer("checkpoint_interval", o.checkpoint_interval, o.checkpoint_interval > 0.0);
  // The H5MD and state files are written only when named: their options given without the name
  // write nothing, most likely because the name was forgotten. (An output named "" is switched
  // off on purpose, e.g. by --set, and its options wait for it silently.)
  struct NamedOutput {
    const char *key, *example;
    std::vector<const char*> options;
  };
  for (const NamedOutput& out :
       {NamedOutput{"h5md", "trajectory.h5md", {"h5md_interval", "h5md_velocity", "h5md_force", "h5md_gzip"}},
        NamedOutput{"state", "state.csv", {"state_interval"}}})
    if (!t->has(out.key))
      for (const char* key : out.options)
        if (t->has(key))
          sc.notes.push_back("warning: " + t->where(key) + ": does nothing: output." + out.key +
                             " is not given, so no such file is written (e.g. output." + out.key + " = \"" +
                             out.example + "\" writes one)");
  std::vector<std::pair<std::string, std::string>> seen;  // what writes it, file name
  for (const auto& [k, f] : output_files(sc)) {
    const std::string what = k.empty() ? "the run's " + f : "output." + k;
    if (!k.empty()) {
      if (f.find('/') != std::string::npos || f == "." || f == "..")
        t->fail(k, "expected a plain file name (the directory comes from -o), got \"" + f + "\"");
      if (std::any_of(f.begin(), f.end(), [](char c) { return static_cast<unsigned char>(c) < 0x20; }))
        t->fail(k, "expected a plain file name without control characters");
      for (const auto& [other, name] : seen)
        if (name == f)
          t->fail(k, "\"" + f + "\" is also " + other + "; expected a file of its own",
                  other.rfind("output.", 0) == 0 ? std::vector<std::string>{other} : std::vector<std::string>{});
    }
    seen.emplace_back(what, f);
  }
  t->finish();
}

// What a Run (engine/run/run.hpp) will ask of the scene, asked now: the integrator is built once here and
// discarded, so that whatever its constructor refuses (the effective dynamics' cluster limit,
// constraints it cannot solve) is refused by `check` too, at integrator.method, before [prepare].
void check_integrator(DeckTable& root, Scene& sc) {
  auto t = root.table("integrator");
  const auto fail = [&](const std::string& what) {
    t->fail("method", "the scene cannot run method '" + sc.integrator.method + "': " + what);
  };
  try {
    make_integrator(sc.integrator, *sc.forces, sc.state.inv_mass);
  } catch (const std::invalid_argument& e) {
    fail(e.what());
  } catch (const InputError& e) {
    fail(e.what());
  } catch (const NumericalError& e) {
    fail(e.what());
  }
  // Likewise the observers a Run builds: the thermo row (with the modes when actions are
  // observed) and the projected momenta of the state output.
  auto refused_at = [&](const char* table, const char* key, const std::string& what) {
    if (auto t = root.table(table)) t->fail(key, "the scene cannot provide it: " + what);
    root.fail_here(std::string(table) + "." + key + ": the scene cannot provide it: " + what);
  };
  try {
    Thermo(*sc.forces, sc.state.inv_mass, sc.observables, &sc.topology);
  } catch (const std::exception& e) {
    refused_at("observables", "actions", e.what());
  }
  if (!sc.output.state.empty()) try {
      ProjectedMomenta(*sc.forces->stiff_bonds(), sc.state.inv_mass);
    } catch (const std::exception& e) {
      refused_at("output", "state", e.what());
    }
}

}  // namespace

std::vector<std::pair<std::string, std::string>> output_files(const Scene& sc) {
  const OutputSettings& o = sc.output;
  std::vector<std::pair<std::string, std::string>> out;
  // Fixed names first, so that a deck key that takes one of them is the one named.
  const bool bonded =
      !sc.topology.bonds.empty() || std::any_of(sc.described_sources.begin(), sc.described_sources.end(),
                                                [](const DescribedSource& d) { return d.bonds() > 0; });
  if (sc.observables.histograms && bonded) out.emplace_back("", "histograms.csv");
  out.emplace_back("", "summary.json");
  if (!o.xyz.empty() || !o.h5md.empty()) out.emplace_back("", kTopologyFile);
  for (const auto& [key, name] : {std::pair<const char*, const std::string*>{"xyz", &o.xyz},
                                  {"thermo", &o.thermo},
                                  {"state", &o.state},
                                  {"h5md", &o.h5md},
                                  {"lammps_data", &o.lammps_data},
                                  {"checkpoint", &o.checkpoint}})
    if (!name->empty()) out.emplace_back(key, *name);
  return out;
}

void check_output_paths(const Scene& sc, const std::string& dir) {
  namespace fs = std::filesystem;
  std::error_code ec;
  for (const auto& [key, name] : output_files(sc)) {
    // The files themselves and the temporaries that atomic writers rename into place.
    for (const std::string& f : {name, name + ".tmp"}) {
      const fs::path p = fs::path(dir) / f;
      // Through symbolic links: what a writer would open (a link to /dev/null is fine).
      if (fs::is_directory(fs::status(p, ec)))
        throw InputError(p.string() + ": output file (" + (key.empty() ? name : "output." + key) +
                         ") exists as a directory; remove it or choose another name");
    }
  }
  // A directory we may not write into (permissions, read-only file system) fails here, before
  // any step, rather than at the first frame or the final checkpoint.
  const fs::path probe = fs::path(dir) / ".stiffmd_write_test";
  {
    std::ofstream out(probe);
    if (!out) throw InputError(dir + ": output directory is not writable");
  }
  fs::remove(probe, ec);
}

std::string particle_and_source(const Scene& sc, int i) {
  for (const ParticleSource& src : sc.sources)
    if (i >= src.first && i < src.first + src.count) return "particle " + std::to_string(i) + " (" + src.what + ")";
  return "particle " + std::to_string(i);
}

int particle_type_index(const Scene& sc, DeckTable& t, std::string_view key, const std::string& name) {
  for (size_t k = 0; k < sc.types.size(); ++k)
    if (sc.types[k].name == name) return static_cast<int>(k);
  t.fail(key, "unknown particle type '" + name + "' (define it as [types." + name + "])");
}

int append_particles(Scene& sc, const Eigen::Matrix3Xd& x, const Eigen::Matrix3Xd& v, const std::vector<int>& type,
                     const std::vector<int>& molecule) {
  State& s = sc.state;
  const int first = s.size(), n = static_cast<int>(x.cols());
  s.x.conservativeResize(3, first + n);
  s.v.conservativeResize(3, first + n);
  s.inv_mass.conservativeResize(first + n);
  s.x.rightCols(n) = x;
  s.v.rightCols(n) = v;
  for (int k = 0; k < n; ++k) s.inv_mass[first + k] = 1.0 / sc.types[type[k]].mass;
  sc.particle_type.insert(sc.particle_type.end(), type.begin(), type.end());
  for (int k = 0; k < n; ++k) sc.charge.push_back(sc.types[type[k]].charge);
  // Molecule ids: particles without one get their own; a source's ids are offset past the
  // ids already used.
  auto& mol = sc.topology.molecule;
  int next = 0;
  for (int m : mol) next = std::max(next, m + 1);
  if (molecule.empty()) {
    for (int k = 0; k < n; ++k) mol.push_back(next + k);
  } else {
    // Dense ids: the source's ids (LAMMPS's start at 1, may have gaps) in sorted order.
    std::vector<int> ids(molecule.begin(), molecule.end());
    std::sort(ids.begin(), ids.end());
    ids.erase(std::unique(ids.begin(), ids.end()), ids.end());
    for (int m : molecule)
      mol.push_back(next + static_cast<int>(std::lower_bound(ids.begin(), ids.end(), m) - ids.begin()));
  }
  return first;
}

std::int64_t whole_steps(double span, double h) {
  const double r = span / h, nearest = std::round(r);
  return static_cast<std::int64_t>(std::abs(r - nearest) <= kWholeStepTolerance * std::max(1.0, r) ? nearest
                                                                                                   : std::ceil(r));
}

std::int64_t Scene::num_steps() const {
  return run.steps > 0 ? run.steps : whole_steps(run.t_end, integrator.h);
}

namespace {

// The Langevin frictions' least and largest over the whole scene's particles, a description's
// counted ones among them (their type's, DescribedSource::friction_of_type); nullopt without any.
std::optional<std::pair<double, double>> friction_range(const Scene& sc) {
  const Eigen::VectorXd& f = sc.integrator.thermostat.friction;
  std::optional<std::pair<double, double>> range;
  if (f.size() > 0) range = std::pair{f.minCoeff(), f.maxCoeff()};
  if (sc.integrator.thermostat.style == ThermostatSettings::Style::langevin)
    for (const DescribedSource& d : sc.described_sources)
      for (std::size_t t = 0; t < d.friction_of_type.size(); ++t) {
        if (DescribedSource::of(d.particles_of_type, t) == 0) continue;
        const double f = d.friction_of_type[t];
        range = range ? std::pair{std::min(range->first, f), std::max(range->second, f)} : std::pair{f, f};
      }
  return range;
}

// degrees_of_freedom (integrators/thermostat.hpp) of the whole scene: a description's counted
// particles are mobile (a type's mass is > 0) and feel every term as the loaded ones do.
long whole_degrees_of_freedom(const Scene& sc, int rigid) {
  const Eigen::VectorXd& w = sc.state.inv_mass;
  const bool conserved = momentum_conserved(*sc.forces, w, sc.integrator.thermostat);
  if (!sc.described()) return degrees_of_freedom(w, conserved, rigid);
  const long mobile = static_cast<long>((w.array() > 0.0).count()) + sc.undescribed_particles;
  return 3 * mobile - (conserved && mobile == sc.whole_particles() ? 3 : 0) - rigid;
}

}  // namespace

namespace {

// The stiff-harmonic term's rule (null: none, or a term made from its bonds alone).
const StiffBondRule* stiff_rule(const Scene& sc) {
  for (const auto& term : sc.forces->terms())
    if (const auto* s = dynamic_cast<const StiffHarmonicBond*>(term.get()); s && !s->rule().empty()) return &s->rule();
  return nullptr;
}

// The claimed bond types' indices into the rule's coefficients that a described source has bonds
// of (none for a whole scene).
std::vector<int> described_stiff_claims(const Scene& sc) {
  std::vector<int> claims;
  const StiffBondRule* rule = stiff_rule(sc);
  if (!rule) return claims;
  for (std::size_t t = 0; t < rule->bond_claim.size(); ++t)
    if (rule->bond_claim[t] >= 0 &&
        std::any_of(sc.described_sources.begin(), sc.described_sources.end(),
                    [&](const DescribedSource& d) { return DescribedSource::of(d.bonds_of_type, t) > 0; }))
      claims.push_back(rule->bond_claim[t]);
  return claims;
}

// The lengths and stiffnesses of the whole scene's stiff bonds: the term's bonds, and one bond of
// each claimed type a description counts (its bonds are the type's coefficients).
std::vector<StiffBond> stiff_bond_kinds(const Scene& sc) {
  std::vector<StiffBond> kinds = sc.forces->stiff_bonds()->bonds;
  if (const StiffBondRule* rule = stiff_rule(sc))
    for (const int c : described_stiff_claims(sc)) kinds.push_back(rule->bond_coeffs[static_cast<std::size_t>(c)]);
  return kinds;
}

}  // namespace

// What the monitor's default checks need of the scene, and the likely cause of a run that leaves
// its model: stiff bonds whose thermal vibration at the thermostat's kT, of rms amplitude
// ε√kT/α_b (equipartition on ε⁻² ½α²g²), is a good part of their length — in reduced units
// typically a temperature meant in kelvin. Said once now as a warning, and again with an alert.
namespace {

MonitorScene monitor_scene(DeckTable& root, Scene& sc) {
  MonitorScene m;
  m.conserves_energy = !sc.thermostatted();
  const ThermostatSettings& th = sc.integrator.thermostat;
  if (th.on()) {
    m.kT = th.temperature;
    const auto friction = friction_range(sc);
    m.relaxation = th.style == ThermostatSettings::Style::csvr ? th.tau
                   : friction && friction->first > 0.0         ? 1.0 / friction->first
                                                               : std::numeric_limits<double>::infinity();
  }
  const StiffBonds* stiff = sc.forces->stiff_bonds();
  if (!stiff) return m;
  const std::vector<StiffBond> kinds = stiff_bond_kinds(sc);
  if (kinds.empty()) return m;
  m.min_bond_length = std::numeric_limits<double>::infinity();
  double amplitude = 0.0, fraction = 0.0;  // the largest ε√kT/α_b and (ε√kT/α_b)/ℓ_b
  for (const StiffBond& b : kinds) {
    m.min_bond_length = std::min(m.min_bond_length, b.length);
    const double a = stiff->epsilon * std::sqrt(m.kT) / b.alpha;
    amplitude = std::max(amplitude, a);
    fraction = std::max(fraction, a / b.length);
  }
  constexpr double kLooseBonds = 0.2;  // rms vibration beyond a fifth of the length: not stiff
  if (find_method(sc.integrator.method)->rigid_constraints || !(fraction > kLooseBonds)) return m;
  std::ostringstream c;
  c.precision(3);
  if (sc.units.reduced())
    c << "kT = " << m.kT << " in LJ units (k_B = 1)";
  else
    c << "T = " << m.kT * sc.units.out(Dimension::temperature) << " K";
  c << ": the stiff bonds vibrate with rms amplitude eps sqrt(kT)/alpha = " << amplitude << ", " << fraction * 100.0
    << " % of their length";
  if (sc.units.reduced()) c << "; a temperature in kelvin needs units = \"real\"";
  m.likely_cause = c.str();
  sc.notes.push_back("warning: " + root.table("thermostat")->where("temperature") + ": " + m.likely_cause);
  return m;
}

}  // namespace

namespace {

// The force styles whose reader or whose term's description reads every particle, beyond what a
// description counts (the k-space terms read the charges' sums, which a description gives:
// charge_sums, engine/scene/kspace_deck.hpp): charmm-dihedral checks the particle types at its
// dihedrals' ends; the external terms select particles by index or type and refuse a selection
// of none (gravity holds every mass). stiff-harmonic checks its bonds with the particles' masses
// (find_stiff_bond_problem: two fixed particles, one bond per pair, realisable lengths around
// every cycle) and may select them by mass or add rigid angles' bonds: described only for the
// builder's chains by bond type (stiff_harmonic_described), whose bonds join mobile beads along a
// path, one per pair, and pass every rule by construction.
constexpr std::array<std::string_view, 4> kStylesReadingParticles = {"charmm-dihedral", "gravity", "harmonic-tether",
                                                                     "lj93-wall"};

bool stiff_harmonic_described(DeckTable& t, bool import) {
  return !import && !t.gives("masses") && !t.gives("angle_types");
}

bool grows_by_molecule(DeckTable& b) {
  return b.gives("style") && b.string("style") == "linear-chains" && b.gives("growth") &&
         b.string("growth") == "by-molecule";
}

// What SceneContent::description describes: the [[build]]s from index `builds` on (every one from
// it on grows linear chains by molecule, so that no loaded particle follows a described one), or
// the [import] of a LAMMPS data file that makes every particle; none: the deck is loaded whole.
// Read in a view of its own (the keys it reads stay unread for the load, whose messages are the
// whole load's), and any doubt — a key of the wrong kind, say — loads it whole, which reports it.
struct Described {
  std::size_t builds = static_cast<std::size_t>(-1);
  bool import = false;
};
std::optional<Described> described_sources(const Deck& deck) {
  try {
    DeckTable root = deck.root();
    // [[bonds]] name particles by index; a barostat checks every molecule's extent against the
    // box (refuse_large_molecules).
    if (root.gives("bonds") || root.gives("barostat")) return std::nullopt;
    Described d;
    if (root.gives("import")) {
      // The import numbers its particles after every [[build]] and [[particles]]: described when
      // it is the only source, a LAMMPS data file (an XYZ file is read whole).
      if (root.gives("build") || root.gives("particles") || !root.table("import")->gives("lammps_data"))
        return std::nullopt;
      d.import = true;
    } else {
      std::vector<DeckTable> builds = root.array_of_tables("build");
      std::size_t from = builds.size();
      while (from > 0 && grows_by_molecule(builds[from - 1])) --from;
      if (from == builds.size()) return std::nullopt;
      d.builds = from;
    }
    if (auto forces = root.table("forces"))
      for (auto& [name, t] : forces->named_tables()) {
        if (!t.gives("style")) return std::nullopt;
        const std::string style = t.string("style");
        if (std::find(kStylesReadingParticles.begin(), kStylesReadingParticles.end(), style) !=
            kStylesReadingParticles.end())
          return std::nullopt;
        if (style == "stiff-harmonic" && !stiff_harmonic_described(t, d.import)) return std::nullopt;
        // A data file's charges are per particle: its reader sums Σq in the file's order, not Σq²
        // in the particles' order, from which the k-space terms choose their parameters.
        if (d.import && (style == "ewald" || style == "pppm")) return std::nullopt;
      }
    return d;
  } catch (const std::exception&) {
    return std::nullopt;
  }
}

}  // namespace

Scene load_scene(const Deck& deck, const StageIdentity& stage, SceneContent content) {
  const std::optional<Described> described =
      content == SceneContent::description ? described_sources(deck) : std::nullopt;
  Scene sc;
  sc.deck_path = deck.path();
  sc.stage = stage;
  DeckTable root = deck.root();
  if (root.has_retired("stage"))
    root.fail("stage",
              "a deck with [[stage]] tables is a protocol of runs, one per stage (docs/decks.md, "
              "[[stage]]): `stiffmd run` and `stiffmd check` run and check it; this reader loads one run's deck");
  root.table("variables");  // resolved by Deck; mark as read
  read_units(root, sc);
  read_box(root, sc);
  read_types(root, sc);
  read_particles(root, sc);
  read_builders(root, sc, described ? described->builds : static_cast<std::size_t>(-1));
  read_import(root, sc, std::filesystem::path(deck.path()).parent_path().string(), described && described->import);
  if (sc.whole_particles() == 0)
    root.fail_here("the scene has no particles: give [[particles]], a [[build]] or an [import]");
  check_positions_near_box(root, sc);
  read_bonds(root, sc);
  make_scene_molecules_whole(root, sc);
  read_velocities(root, sc);
  read_levels(root, sc);
  std::string overlap;
  read_forces(root, sc, &overlap);
  check_levels_used(root, sc);
  read_prepare(root, sc);
  read_integrator(root, sc);
  read_minimize(root, sc);
  // Beads closer than the pair potentials bear: [minimize] relaxes them before the run (its soft
  // start, max_force, caps the forces there); without it the run would blow up at its first step.
  // A later stage of a staged protocol starts from the state the previous stage left, not from
  // the deck's: the deck's overlap is stage 1's to relax.
  if (!overlap.empty() && sc.stage.number <= 1) {
    if (!sc.minimize.requested) throw InputError(overlap);
    sc.notes.push_back("note: " + overlap.substr(0, overlap.rfind(": place the sources apart")) +
                       "; [minimize] relaxes them before the run");
  }
  warn_projected_vibrations(root, sc);
  read_run(root, sc);
  read_observables(root, sc);
  read_thermostat(root, sc);
  read_barostat(root, sc);
  sc.monitor = read_monitor(root, {sc.forces->stiff_bonds() != nullptr, sc.observables.actions, sc.thermostatted(),
                                   sc.thermostatted() && sc.integrator.thermostat.temperature == 0.0});
  apply_defaults(sc.monitor, monitor_scene(root, sc));
  read_output(root, sc);
  read_parallel(root, sc);
  read_ensemble(root);  // the members' overrides, validated here; run by engine/run/ensemble.*
  root.finish();
  check_integrator(root, sc);
  return sc;
}

std::string describe(const Scene& sc) {
  std::ostringstream s;
  s << describe_scene(sc) << describe_settings(sc);
  return s.str();
}

std::string describe_scene(const Scene& sc) {
  std::ostringstream s;
  const State& st = sc.state;
  int fixed = 0;
  for (int i = 0; i < st.size(); ++i) fixed += st.inv_mass[i] == 0.0;
  s << "deck:        " << sc.deck_path << "\n";
  if (!sc.units.reduced())
    s << "units:       " << sc.units.name << " (A, fs, kcal/mol, g/mol, K; internal time unit " << Units::kRealTimeFs
      << " fs)\n";
  // A description's counted particles and items (DescribedSource) are counted with the loaded ones.
  const auto& described = sc.described_sources;
  const auto counted = [&](auto&& of) {
    std::int64_t n = 0;
    for (const DescribedSource& d : described) n += of(d);
    return n;
  };
  s << "particles:   " << sc.whole_particles() << " (" << fixed << " fixed)\n";
  for (size_t k = 0; k < sc.types.size(); ++k) {
    const auto count = std::count(sc.particle_type.begin(), sc.particle_type.end(), static_cast<int>(k)) +
                       counted([&](const DescribedSource& d) { return DescribedSource::of(d.particles_of_type, k); });
    s << "  type " << sc.types[k].name << ": " << count << " particles, mass " << sc.types[k].mass << ", element "
      << sc.types[k].element << "\n";
  }
  s << "box:         ";
  if (!sc.box.any_periodic())
    s << "open\n";
  else
    s << "periodic (" << sc.box.periodic.transpose() << "), lengths " << sc.box.lengths.transpose() << "\n";
  using OfType = std::vector<std::int64_t> DescribedSource::*;
  const auto items_of = [&](OfType of_type, size_t k) {
    return counted([&](const DescribedSource& d) { return DescribedSource::of(d.*of_type, k); });
  };
  const auto items = [&](OfType of_type) {
    return counted([&](const DescribedSource& d) { return DescribedSource::total(d.*of_type); });
  };
  s << "bonds:       " << static_cast<std::int64_t>(sc.topology.bonds.size()) + items(&DescribedSource::bonds_of_type)
    << "\n";
  for (size_t k = 0; k < sc.topology.bond_types.size(); ++k) {
    const auto count = std::count_if(sc.topology.bonds.begin(), sc.topology.bonds.end(),
                                     [&](const Bond& b) { return b.type == static_cast<int>(k); }) +
                       items_of(&DescribedSource::bonds_of_type, k);
    s << "  type " << sc.topology.bond_types[k] << ": " << count << "\n";
  }
  const std::int64_t angles =
      static_cast<std::int64_t>(sc.topology.angles.size()) + items(&DescribedSource::angles_of_type);
  if (angles > 0) {
    s << "angles:      " << angles << "\n";
    for (size_t k = 0; k < sc.topology.angle_types.size(); ++k) {
      const auto count = std::count_if(sc.topology.angles.begin(), sc.topology.angles.end(),
                                       [&](const Angle& a) { return a.type == static_cast<int>(k); }) +
                         items_of(&DescribedSource::angles_of_type, k);
      s << "  type " << sc.topology.angle_types[k] << ": " << count << "\n";
    }
  }
  const std::int64_t dihedrals =
      static_cast<std::int64_t>(sc.topology.dihedrals.size()) + items(&DescribedSource::dihedrals_of_type);
  if (dihedrals > 0) {
    s << "dihedrals:   " << dihedrals << "\n";
    for (size_t k = 0; k < sc.topology.dihedral_types.size(); ++k) {
      const auto count = std::count_if(sc.topology.dihedrals.begin(), sc.topology.dihedrals.end(),
                                       [&](const Dihedral& d) { return d.type == static_cast<int>(k); }) +
                         items_of(&DescribedSource::dihedrals_of_type, k);
      s << "  type " << sc.topology.dihedral_types[k] << ": " << count << "\n";
    }
  }
  const std::int64_t impropers =
      static_cast<std::int64_t>(sc.topology.impropers.size()) + items(&DescribedSource::impropers_of_type);
  if (impropers > 0) {
    s << "impropers:   " << impropers << "\n";
    for (size_t k = 0; k < sc.topology.improper_types.size(); ++k) {
      const auto count = std::count_if(sc.topology.impropers.begin(), sc.topology.impropers.end(),
                                       [&](const Improper& d) { return d.type == static_cast<int>(k); }) +
                         items_of(&DescribedSource::impropers_of_type, k);
      s << "  type " << sc.topology.improper_types[k] << ": " << count << "\n";
    }
  }
  std::int64_t molecules = 0;
  for (int m : sc.topology.molecule) molecules = std::max<std::int64_t>(molecules, m + 1);
  molecules += counted([](const DescribedSource& d) { return d.molecules; });
  if (molecules < sc.whole_particles()) s << "molecules:   " << molecules << "\n";
  s << "force terms: " << sc.forces->terms().size() << "\n";
  for (const auto& t : sc.forces->terms())
    s << "  " << t->name() << " [" << t->style() << ", " << sc.forces->level_name(t->level()) << "]: " << t->describe()
      << "\n";
  return s.str();
}

std::string describe_settings(const Scene& sc) {
  std::ostringstream s;
  const double time_out = sc.units.out(Dimension::time);  // times and temperatures in the deck's units
  s << "integrator:  " << sc.integrator.method << ", h = " << sc.integrator.h * time_out;
  if (sc.integrator.micro_steps > 1)
    s << ", " << sc.integrator.micro_steps
      << " micro steps (micro_dt = " << sc.integrator.h * time_out / sc.integrator.micro_steps << ")";
  s << "\n";
  if (const auto& levels = sc.integrator.levels; !levels.empty()) {
    // Outermost first, as the step nests: each level's step, its loop factor, its kick and its
    // terms. The innermost level's force is applied plainly by its micro steps; the others kick
    // with the level's own kick or the method's.
    const MethodInfo& method = *find_method(sc.integrator.method);
    const bool nested = method.micro_steps;
    s << "levels:      " << levels.size() << ", innermost first in the deck";
    if (!nested)
      s << " (grouping only: " << sc.integrator.method << " steps all levels with h):\n";
    else
      s << "; r-RESPA, outermost first, " << sc.integrator.method << ":\n";
    double step = sc.integrator.h * time_out;
    for (int k = static_cast<int>(levels.size()) - 1; k >= 0; --k) {
      s << "  " << levels[k].name << ": step " << (nested ? step : sc.integrator.h * time_out);
      if (nested && k > 0) s << ", " << levels[k].substeps << " steps of " << levels[k - 1].name << " each";
      if (nested && method.kick)
        s << ", kick " << kick_name(k > 0 ? levels[k].kick.value_or(*method.kick) : Kick::plain);
      s << "; terms:";
      for (const auto& t : sc.forces->terms())
        if (t->level() == Level{k}) s << " " << t->name();
      s << "\n";
      step /= levels[k].substeps;
    }
  }
  if (const ThermostatSettings& th = sc.integrator.thermostat; th.on()) {
    s << "thermostat:  " << thermostat_style_name(th.style);
    if (sc.units.reduced())
      s << ", kT = " << th.temperature;
    else
      s << ", T = " << th.temperature * sc.units.out(Dimension::temperature);
    if (th.style == ThermostatSettings::Style::csvr) s << ", tau = " << th.tau * time_out;
    if (const auto friction = friction_range(sc))
      s << ", friction " << friction->first / time_out << ".." << friction->second / time_out;
    if (th.style == ThermostatSettings::Style::langevin)
      s << (th.splitting == ThermostatSettings::Splitting::lammps  ? ", as a force in the kick (lammps)"
            : th.splitting == ThermostatSettings::Splitting::obabo ? ", as O steps of h/2 around the step (obabo)"
                                                                   : ", as an O step (baoab)");
    const MethodInfo& m = *find_method(sc.integrator.method);
    const int rigid = m.rigid_constraints ? static_cast<int>(whole_stiff_bonds(sc)) : 0;
    s << ", seed " << th.seed << "; temperature over " << whole_degrees_of_freedom(sc, rigid)
      << " degrees of freedom\n";
  }
  if (const BarostatSettings& b = sc.integrator.barostat; b.on) {
    const double p_out = sc.units.out(Dimension::pressure);
    s << "barostat:    c-rescale, " << coupling_name(b.coupling) << ", P = " << b.pressure[0] * p_out;
    if (b.coupling != BarostatSettings::Coupling::isotropic)
      s << " / " << b.pressure[1] * p_out << " / " << b.pressure[2] * p_out;
    s << ", tau = " << b.tau * time_out << ", compressibility " << b.compressibility / p_out << ", a cell move every "
      << b.interval << " steps, seed " << b.seed << "\n";
  }
  s << "run:         t_end = " << sc.run.t_end * time_out << " (" << sc.num_steps() << " steps)\n";
  s << "outputs:     ";
  if (!sc.output.xyz.empty()) s << sc.output.xyz << " every " << sc.output.xyz_interval * time_out << "  ";
  if (!sc.output.thermo.empty()) s << sc.output.thermo << " every " << sc.output.thermo_interval * time_out;
  if (sc.output.thermo_norm) s << " (energies per particle)";
  if (sc.output.screen_interval > 0) s << "  a thermo line every " << sc.output.screen_interval * time_out;
  s << "\n";
  return s.str();
}

std::int64_t whole_stiff_bonds(const Scene& sc) {
  const StiffBonds* stiff = sc.forces->stiff_bonds();
  if (!stiff) return 0;
  auto n = static_cast<std::int64_t>(stiff->bonds.size());
  const StiffBondRule* rule = stiff_rule(sc);
  if (!rule) return n;
  for (const DescribedSource& d : sc.described_sources)
    for (std::size_t t = 0; t < rule->bond_claim.size(); ++t)
      if (rule->bond_claim[t] >= 0) n += DescribedSource::of(d.bonds_of_type, t);
  return n;
}

}  // namespace stiffmd
