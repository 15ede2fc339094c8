#include "engine/domain/part_load.hpp"

#include <cmath>
#include <cstdint>
#include <filesystem>
#include <stdexcept>

#include "core/errors.hpp"
#include "core/format.hpp"

#include "engine/domain/import_part.hpp"
#include "engine/scene/chains_by_molecule.hpp"
#include "forcefields/particle_subset.hpp"
#include "integrators/methods.hpp"
#include "integrators/part_velocities.hpp"

namespace stiffmd {

namespace {

// The deck's one [[build]] of linear chains by molecule, as read_builders reads it
// (engine/scene/scene_sources.cpp): its spec, type, item types and offset.
struct ChainsDeck {
  ChainSpec spec;
  std::string type, bond_type, angle_type, dihedral_type;
  Eigen::Vector3d offset = Eigen::Vector3d::Zero();
};

ChainsDeck chains_deck(const Deck& deck, const Scene& sc) {
  DeckTable root = deck.root();
  std::vector<DeckTable> builds = root.array_of_tables("build");
  if (builds.size() != 1) throw std::logic_error("chains_part: expected one [[build]]");
  DeckTable& b = builds.front();
  ChainsDeck c;
  c.type = b.name("type", sc.types[0].name);
  c.spec.chains = static_cast<int>(b.integer("chains", 1));
  c.spec.beads = static_cast<int>(b.integer("beads"));
  c.spec.bond_length = b.number("bond_length", c.spec.bond_length);
  c.spec.min_distance = b.number("min_distance", c.spec.min_distance);
  c.spec.seed = static_cast<std::uint64_t>(b.integer("seed", 1));
  c.bond_type = b.name("bond_type");
  c.angle_type = b.name("angle_type", "");
  c.dihedral_type = b.name("dihedral_type", "");
  c.offset = b.vector3("offset", Eigen::Vector3d::Zero());
  return c;
}

int type_index(const std::vector<std::string>& names, const std::string& name) {
  for (size_t k = 0; k < names.size(); ++k)
    if (names[k] == name) return static_cast<int>(k);
  throw std::logic_error("chains_part: the topology has no type '" + name + "'");
}

// The Langevin friction of a particle of type `type` as read_thermostat gives it
// (engine/scene/thermostat_deck.cpp): γ (damp = 1/γ, or friction = γ) times 1/ratio of the type's
// [thermostat.scale].
double langevin_friction(const Deck& deck, const Scene& sc, int type) {
  DeckTable root = deck.root();
  auto t = root.table("thermostat");
  if (!t) throw std::logic_error("chains_part: a Langevin thermostat without [thermostat]");
  const auto damp = t->maybe_number("damp");
  const auto friction = t->maybe_number("friction");
  const double gamma = sc.units.rate_in(damp ? 1.0 / *damp : *friction);
  double type_scale = 1.0;
  const std::string& type_name = sc.types[static_cast<size_t>(type)].name;
  if (auto scale = t->table("scale"))
    if (const auto r = scale->maybe_number(type_name)) type_scale = 1.0 / *r;
  return gamma * type_scale;
}

}  // namespace

namespace {

// The velocities [velocities] draws by particle (read_velocities, engine/scene/scene_sources.cpp)
// for the part's particles, or `v` as it is without [velocities] (collective: the sums over the
// ranks).
void velocities_by_particle(const Deck& deck, const Scene& sc, const PartMolecules& mine, const Communicator& ranks,
                            Eigen::Matrix3Xd& v) {
  DeckTable root = deck.root();
  auto t = root.table("velocities");
  if (!t) return;
  const double temperature = t->number("temperature");
  const auto seed = static_cast<std::uint64_t>(t->integer("seed", 1));
  const Eigen::VectorXd w = Eigen::Map<const Eigen::VectorXd>(mine.inv_mass.data(), mine.size());
  v = maxwell_boltzmann_by_particle(w, mine.global, sc.units.kT(temperature), seed, &ranks);
}

// Positions are unwrapped; a particle more than 2^20 box lengths from the periodic box is refused,
// as the whole load refuses it (check_positions_near_box, engine/scene/scene.cpp): the part's
// particles, by their whole-scene index.
void refuse_far_positions(DeckTable& root, const Box& box, const ImportedMolecules& in) {
  constexpr double kMaxImages = 1 << 20;
  for (int a = 0; a < 3; ++a) {
    if (!box.periodic[a]) continue;
    for (Eigen::Index k = 0; k < in.x.cols(); ++k) {
      const double images = (in.x(a, k) - box.origin[a]) / box.lengths[a];
      if (std::abs(images) <= kMaxImages) continue;
      root.fail_here("particle " + std::to_string(in.molecules.global[static_cast<size_t>(k)]) + " is at " +
                     static_cast<char>('x' + a) + " = " + format_number(in.x(a, k)) + ", more than 2^20 box lengths (" +
                     format_number(box.lengths[a]) + ") from the periodic box; expected a position near it");
    }
  }
}

// The bonded terms on the part at its initial positions: a term defined on part of configuration
// space (FENE's r < R0, an angle's arms of non-zero length) refuses a state outside it, as the
// whole load refuses the whole state (check_initial_state, engine/scene/scene.cpp); each term made
// on the part from its description (ForceTerm::on_subset). The pair terms are left out, as there;
// only a description needs it (its styles hold no k-space term, whose sums span the ranks).
void refuse_initial_state(const Scene& sc, const ImportedMolecules& in) {
  const PartMolecules& p = in.molecules;
  const Topology topology = p.topology(sc.topology);
  const ParticleSubset subset{p.global, p.type, topology, p.charge, p.inv_mass};
  Eigen::Matrix3Xd f = Eigen::Matrix3Xd::Zero(3, in.x.cols());
  for (const auto& term : sc.forces->terms()) {
    if (term->uses_neighbor_list()) continue;
    try {
      term->on_subset(subset, sc.box)->add_forces(in.x, sc.box, f);
    } catch (const NumericalError& e) {
      throw InputError(std::string(e.what()) + " in the initial state");
    }
  }
}

// The whole load's message for a deck whose data file one rank found a fault in (its block's
// lines, which no other rank reads): the file loaded whole, on that rank alone, so that a run on
// several ranks words the fault as one process does (its first fault in the file's order). ""
// when the whole load accepts the deck (the part's own message stands).
std::string whole_load_problem(const Deck& deck) {
  try {
    load_scene(deck);
  } catch (const InputError& e) {
    return e.what();
  }
  return "";
}

// Why the particles cannot come from `root`'s one [[build]] by parts ("": they can).
std::string chains_refusal(DeckTable& root) {
  const std::vector<DeckTable> builds = root.array_of_tables("build");
  if (builds.size() != 1) return "not one [[build]]";
  DeckTable b = builds.front();
  if (b.string("style") != "linear-chains" || b.string("growth", "together") != "by-molecule")
    return "the [[build]] grows its molecules together (growth = \"by-molecule\" builds them by parts)";
  return "";
}

// Why the particles cannot come from `root`'s [import] by parts ("": they can).
std::string data_file_refusal(DeckTable& root) {
  if (root.gives("build")) return "a [[build]] beside the [import] numbers the particles after it";
  auto t = root.table("import");
  if (!t->has("lammps_data")) return "an XYZ [import] is read whole (a LAMMPS data file is read by parts)";
  return "";
}

}  // namespace

PartSource part_source(const Deck& deck, const Scene& sc) {
  DeckTable root = deck.root();
  auto refused = [](std::string why) { return PartSource{nullptr, std::move(why)}; };
  if (root.gives("particles")) return refused("[[particles]] are listed whole");
  if (root.gives("bonds")) return refused("[[bonds]] are listed whole");
  // [prepare] runs on the parts after the start (DomainIntegrator::prepare_parts), its bond
  // vibrations drawn by bond and particle.
  if (sc.prepare.requested && sc.prepare.vibrational_temperature > 0.0 && !sc.prepare.by_particle)
    return refused(
        "[prepare]'s bond vibrations are drawn from one stream over the bonds (by_particle = true draws them by "
        "parts)");
  // A rigid method projects the parts onto its constraints after the start (project_parts); the
  // effective dynamics takes its actions from the whole state before the start.
  if (find_method(sc.integrator.method)->effective)
    return refused(sc.integrator.method + " takes its actions from the whole state before the start");
  // [minimize] (FIRE, CG or SD) runs on the parts after the start (DomainIntegrator::minimize).
  if (auto v = root.table("velocities"); v && !v->boolean("by_particle", false))
    return refused(
        "[velocities] are drawn from one stream over the particles (by_particle = true draws them by parts)");
  if (sc.stage.staged()) return refused("a staged protocol hands the whole state from stage to stage");
  if (root.gives("import")) {
    if (std::string why = data_file_refusal(root); !why.empty()) return refused(why);
    return {data_file_part, ""};
  }
  if (std::string why = chains_refusal(root); !why.empty()) return refused(why);
  return {chains_part, ""};
}

ScenePart chains_part(const Deck& deck, const Scene& sc, const Communicator& ranks) {
  const ChainsDeck c = chains_deck(deck, sc);
  const int type = [&] {
    for (size_t k = 0; k < sc.types.size(); ++k)
      if (sc.types[k].name == c.type) return static_cast<int>(k);
    throw std::logic_error("chains_part: no type '" + c.type + "'");
  }();
  const double inv_mass = 1.0 / sc.types[static_cast<size_t>(type)].mass;  // as append_particles
  const double charge = sc.types[static_cast<size_t>(type)].charge;
  // Molecules [r·M/P, (r+1)·M/P): contiguous, so the items' places are too.
  const std::int64_t m = c.spec.chains, p = ranks.size(), r = ranks.rank();
  const int first = static_cast<int>(r * m / p), end = static_cast<int>((r + 1) * m / p);
  BuiltMolecules built = build_linear_chains_by_molecule(c.spec, sc.box, first, end, inv_mass);
  ScenePart part;
  PartMolecules& mine = part.molecules;
  const int n = static_cast<int>(built.global.size());
  mine.global = std::move(built.global);
  mine.inv_mass.assign(static_cast<size_t>(n), inv_mass);
  mine.charge.assign(static_cast<size_t>(n), charge);
  mine.type.assign(static_cast<size_t>(n), type);
  if (sc.integrator.thermostat.style == ThermostatSettings::Style::langevin)
    mine.friction.assign(static_cast<size_t>(n), langevin_friction(deck, sc, type));
  // One [[build]]: its molecule ids are the molecules' indices (append_particles: dense, from 0).
  mine.molecule_id = std::move(built.molecule);
  // The items in the whole build's order, each at its place in the whole lists: every chain has
  // beads − 1 bonds, beads − 2 angles and beads − 3 dihedrals (chains_by_molecule.hpp).
  const std::int64_t beads = c.spec.beads;
  const Topology& names = sc.topology;
  const int bt = type_index(names.bond_types, c.bond_type);
  for (size_t k = 0; k < built.bonds.size(); ++k)
    mine.bonds.push_back(
        {first * (beads - 1) + static_cast<std::int64_t>(k), {built.bonds[k].first, built.bonds[k].second, bt}});
  if (!c.angle_type.empty()) {
    const int at = type_index(names.angle_types, c.angle_type);
    for (size_t k = 0; k < built.angles.size(); ++k) {
      const auto& a = built.angles[k];
      mine.angles.push_back(
          {first * std::max<std::int64_t>(0, beads - 2) + static_cast<std::int64_t>(k), {a[0], a[1], a[2], at}});
    }
  }
  if (!c.dihedral_type.empty()) {
    const int dt = type_index(names.dihedral_types, c.dihedral_type);
    for (size_t k = 0; k < built.dihedrals.size(); ++k) {
      const auto& d = built.dihedrals[k];
      mine.dihedrals.push_back(
          {first * std::max<std::int64_t>(0, beads - 3) + static_cast<std::int64_t>(k), {d[0], d[1], d[2], d[3], dt}});
    }
  }
  part.x = std::move(built.x);
  part.x.colwise() += c.offset;
  // The velocities by particle (read_velocities, engine/scene/scene_sources.cpp), or none.
  part.v = Eigen::Matrix3Xd::Zero(3, n);
  velocities_by_particle(deck, sc, mine, ranks, part.v);
  return part;
}

ScenePart data_file_part(const Deck& deck, const Scene& sc, const Communicator& ranks) {
  DeckTable root = deck.root();
  auto import = root.table("import");
  if (!import) throw std::logic_error("data_file_part: the deck has no [import]");
  const LammpsImportDeck d = read_lammps_import(*import, std::filesystem::path(deck.path()).parent_path().string());
  // The friction each particle of a type gets under Langevin, as read_thermostat forms it.
  std::vector<double> friction;
  if (sc.integrator.thermostat.style == ThermostatSettings::Style::langevin)
    for (size_t k = 0; k < sc.types.size(); ++k) friction.push_back(langevin_friction(deck, sc, static_cast<int>(k)));
  // Each rank reads its block alone: a fault only its lines hold is agreed before any collective
  // call (docs/parallel.md, "Errors"), in the whole load's words.
  ImportedMolecules in;
  std::string problem;
  try {
    in = import_part(d, {sc.types, sc.units.velocity_in(1.0), friction},
                     {nullptr, KeepBlock{ranks.rank(), ranks.size()}});
    refuse_far_positions(root, sc.box, in);
    if (sc.described()) refuse_initial_state(sc, in);  // a whole scene's load checked it
  } catch (const InputError& e) {
    problem = *e.what() ? e.what() : "input error";
  }
  if (const Communicator::Problem first = ranks.first_problem(problem); first.rank >= 0) {
    std::string text = first.text;
    if (ranks.rank() == first.rank)
      if (std::string whole = whole_load_problem(deck); !whole.empty()) text = std::move(whole);
    ranks.broadcast(text, first.rank);
    throw AgreedInputError(Communicator::Problem{first.rank, text}.said(), ranks.root());
  }
  ScenePart part{std::move(in.molecules), std::move(in.x), std::move(in.v)};
  velocities_by_particle(deck, sc, part.molecules, ranks, part.v);
  return part;
}

}  // namespace stiffmd
