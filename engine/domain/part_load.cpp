#include "engine/domain/part_load.hpp"

#include <cstdint>
#include <stdexcept>

#include "engine/scene/chains_by_molecule.hpp"
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

std::string chains_part_refusal(const Deck& deck, const Scene& sc) {
  DeckTable root = deck.root();
  if (root.gives("particles")) return "[[particles]] are listed whole";
  if (root.gives("bonds")) return "[[bonds]] are listed whole";
  if (root.gives("import")) return "the [import] is read whole";
  if (root.gives("prepare")) return "[prepare] acts on the whole state";
  if (root.gives("minimize")) return "[minimize] acts on the whole state";
  const std::vector<DeckTable> builds = root.array_of_tables("build");
  if (builds.size() != 1) return "not one [[build]]";
  DeckTable b = builds.front();
  if (b.string("style") != "linear-chains" || b.string("growth", "together") != "by-molecule")
    return "the [[build]] grows its molecules together (growth = \"by-molecule\" builds them by parts)";
  if (auto v = root.table("velocities"); v && !v->boolean("by_particle", false))
    return "[velocities] are drawn from one stream over the particles (by_particle = true draws them by parts)";
  if (sc.stage.staged()) return "a staged protocol hands the whole state from stage to stage";
  return "";
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
  DeckTable root = deck.root();
  if (auto t = root.table("velocities")) {
    const double temperature = t->number("temperature");
    const auto seed = static_cast<std::uint64_t>(t->integer("seed", 1));
    const Eigen::VectorXd w = Eigen::VectorXd::Constant(n, inv_mass);
    part.v = maxwell_boltzmann_by_particle(w, mine.global, sc.units.kT(temperature), seed, &ranks);
  } else {
    part.v = Eigen::Matrix3Xd::Zero(3, n);
  }
  return part;
}

}  // namespace stiffmd
