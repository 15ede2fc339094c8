#include "engine/domain/import_part.hpp"

#include <algorithm>
#include <filesystem>

#include "core/errors.hpp"
#include "engine/scene/scene_sources.hpp"
#include "engine/scene/whole_molecules.hpp"

namespace stiffmd {

namespace {

[[noreturn]] void fail_at(const std::string& where, const std::string& what) {
  throw InputError(where + ": " + what);
}

// The message's place as DeckTable::fail gives it: the key's when the deck gives the key, else
// the table's.
const std::string& at_key(const LammpsImportDeck& deck, const std::string& where_key) {
  return where_key.empty() ? deck.where : where_key;
}

// The scene type of each file type number the file uses, and the names the whole import interns
// in the order of their first entry (Topology::intern over the file's items in order).
struct KindMap {
  std::vector<int> scene;  // per file type number (0: unused)
  std::vector<std::string> names;
};

KindMap map_kind(const LammpsImportDeck& deck, const std::vector<int>& used, const LammpsImportDeck::TypeMap& map,
                 bool given, const char* key, const std::string& where_key) {
  KindMap k;
  for (const int t : used) {
    const std::optional<std::string> name = lammps_type_name(map, given, t);
    if (!name) {
      const std::string what = "no name for LAMMPS type " + std::to_string(t) + " (add \"" + std::to_string(t) +
                               "\" = \"NAME\" to " + key + ")";
      if (given) fail_at(at_key(deck, where_key), what);
      fail_at(deck.where, std::string(key) + ": " + what);
    }
    if (k.scene.size() <= static_cast<size_t>(t)) k.scene.resize(static_cast<size_t>(t) + 1, 0);
    k.scene[static_cast<size_t>(t)] = Topology::intern(k.names, *name);
  }
  return k;
}

// What read_import keeps of the file's type numbers per scene type: the smallest (a data file
// written back numbers them so), and every one (coefficients = "data").
void remember(std::vector<int>& numbers, int scene_type, int lammps_type) {
  if (numbers.size() <= static_cast<size_t>(scene_type)) numbers.resize(static_cast<size_t>(scene_type) + 1, 0);
  int& k = numbers[static_cast<size_t>(scene_type)];
  if (k == 0 || lammps_type < k) k = lammps_type;
}

void all_numbers(std::vector<std::vector<int>>& out, const KindMap& kind, const std::vector<int>& used) {
  if (used.empty()) return;
  out.resize(kind.names.size());
  for (const int t : used) {
    auto& v = out[static_cast<size_t>(kind.scene[static_cast<size_t>(t)])];
    if (std::find(v.begin(), v.end(), t) == v.end()) v.insert(std::upper_bound(v.begin(), v.end(), t), t);
  }
}

}  // namespace

LammpsImportDeck read_lammps_import(DeckTable& t, const std::string& deck_dir) {
  if (!t.has("lammps_data")) t.fail_here("a part's import reads a LAMMPS data file; expected lammps_data = PATH");
  LammpsImportDeck d;
  d.where = t.where();
  d.file = t.string("lammps_data");
  d.path = std::filesystem::path(d.file).is_absolute() || deck_dir.empty()
               ? d.file
               : (std::filesystem::path(deck_dir) / d.file).string();
  d.where_lammps_data = t.where("lammps_data");
  d.atom_style = t.string("atom_style", "auto");
  d.atom_types = t.string_map("atom_types");
  d.bond_types = t.string_map("bond_types");
  d.angle_types = t.string_map("angle_types");
  d.dihedral_types = t.string_map("dihedral_types");
  d.improper_types = t.string_map("improper_types");
  d.bond_types_given = t.has("bond_types");
  d.angle_types_given = t.has("angle_types");
  d.dihedral_types_given = t.has("dihedral_types");
  d.improper_types_given = t.has("improper_types");
  if (t.has("atom_types")) d.where_atom_types = t.where("atom_types");
  if (d.bond_types_given) d.where_bond_types = t.where("bond_types");
  if (d.angle_types_given) d.where_angle_types = t.where("angle_types");
  if (d.dihedral_types_given) d.where_dihedral_types = t.where("dihedral_types");
  if (d.improper_types_given) d.where_improper_types = t.where("improper_types");
  d.velocities = t.boolean("velocities", true);
  return d;
}

ImportedMolecules import_part(const LammpsImportDeck& deck, const ImportTypes& types,
                              const ImportSelection& selection) {
  ImportedPart in;
  try {
    in = selection.keep ? read_lammps_data_part(deck.path, deck.atom_style, selection.keep)
                        : read_lammps_data_part(deck.path, deck.atom_style, selection.block);
  } catch (const InputError& e) {
    fail_at(at_key(deck, deck.where_lammps_data), e.what());
  }
  ImportedSystem& s = in.system;
  ImportedMolecules out;
  out.num_particles = in.num_atoms;
  out.num_molecules = in.num_molecules;
  out.box.origin = s.lo;
  out.box.lengths = s.hi - s.lo;
  out.box.periodic = Eigen::Vector3i::Ones();

  // The molecules whole, as read_import makes the whole file's: each molecule's bonds traversed
  // from its least atom in the same order (the part keeps whole molecules, its atoms and bonds in
  // the whole import's relative order), so the same shifts, bit for bit.
  std::vector<std::pair<int, int>> pairs;
  pairs.reserve(s.bonds.size());
  for (const auto& b : s.bonds) pairs.emplace_back(b.i, b.j);
  const auto name_bond = [&](const ImportedSystem::Bond& b) {
    return "bond between atom ids " + std::to_string(s.id[static_cast<size_t>(b.i)]) + " and " +
           std::to_string(s.id[static_cast<size_t>(b.j)]);
  };
  if (const auto problem = make_molecules_whole(s.x, pairs, out.box, s.image_flags))
    fail_at(at_key(deck, deck.where_lammps_data),
            name_bond(s.bonds[static_cast<size_t>(problem->bond)]) + " " + problem->what);
  for (const auto& b : s.bonds)
    if ((s.x.col(b.i) - s.x.col(b.j)).norm() == 0.0)
      fail_at(at_key(deck, deck.where_lammps_data),
              name_bond(b) + ": both atoms sit at the same position (zero-length bond)");

  // The atoms' types: each file type the file uses named by atom_types, a deck type of the same
  // mass (read_import checks each atom; the same types, checked once each).
  std::vector<int> atom_scene;
  for (const int t : in.types_used.atom) {
    const std::optional<std::string> name = lammps_type_name(deck.atom_types, true, t);
    const std::string& where = at_key(deck, deck.where_atom_types);
    if (!name)
      fail_at(where, std::string(deck.where_atom_types.empty() ? "atom_types: " : "") + "no name for LAMMPS type " +
                         std::to_string(t) + " (add \"" + std::to_string(t) + "\" = \"NAME\" to atom_types)");
    int k = 0;
    while (k < static_cast<int>(types.types.size()) && types.types[static_cast<size_t>(k)].name != *name) ++k;
    if (k == static_cast<int>(types.types.size()))
      fail_at(where, "unknown particle type '" + *name + "' (define it as [types." + *name + "])");
    const ParticleType& pt = types.types[static_cast<size_t>(k)];
    if (s.type_mass.count(t) && s.type_mass.at(t) != pt.mass)
      fail_at(where, "types." + *name + ".mass = " + std::to_string(pt.mass) + " but the data file's Masses give " +
                         std::to_string(s.type_mass.at(t)) + " for LAMMPS type " + std::to_string(t));
    if (atom_scene.size() <= static_cast<size_t>(t)) atom_scene.resize(static_cast<size_t>(t) + 1, 0);
    atom_scene[static_cast<size_t>(t)] = k;
  }
  const KindMap bond =
      map_kind(deck, in.types_used.bond, deck.bond_types, deck.bond_types_given, "bond_types", deck.where_bond_types);
  const KindMap angle = map_kind(deck, in.types_used.angle, deck.angle_types, deck.angle_types_given, "angle_types",
                                 deck.where_angle_types);
  const KindMap dihedral = map_kind(deck, in.types_used.dihedral, deck.dihedral_types, deck.dihedral_types_given,
                                    "dihedral_types", deck.where_dihedral_types);
  const KindMap improper = map_kind(deck, in.types_used.improper, deck.improper_types, deck.improper_types_given,
                                    "improper_types", deck.where_improper_types);
  out.names.bond_types = bond.names;
  out.names.angle_types = angle.names;
  out.names.dihedral_types = dihedral.names;
  out.names.improper_types = improper.names;

  // The particles as append_particles and the file's q column give them.
  PartMolecules& p = out.molecules;
  const size_t n = in.global.size();
  p.global = in.global;
  p.type.resize(n), p.inv_mass.resize(n), p.charge.resize(n), p.molecule_id.resize(n);
  if (!types.friction.empty()) p.friction.resize(n);
  for (size_t k = 0; k < n; ++k) {
    const int t = atom_scene[static_cast<size_t>(s.type[k])];
    const ParticleType& pt = types.types[static_cast<size_t>(t)];
    p.type[k] = t;
    p.inv_mass[k] = 1.0 / pt.mass;
    p.charge[k] = s.charge.empty() ? pt.charge : s.charge[k];
    p.molecule_id[k] = in.molecule_rank[k];
    if (!p.friction.empty()) p.friction[k] = types.friction[static_cast<size_t>(t)];
  }
  const auto g = [&](int local) { return p.global[static_cast<size_t>(local)]; };
  const auto scene_type = [](const KindMap& kind, int file_type) { return kind.scene[static_cast<size_t>(file_type)]; };
  p.bonds.reserve(s.bonds.size());
  for (size_t e = 0; e < s.bonds.size(); ++e) {
    const auto& b = s.bonds[e];
    p.bonds.push_back({in.bond_place[e], Bond{g(b.i), g(b.j), scene_type(bond, b.type)}});
  }
  p.angles.reserve(s.angles.size());
  for (size_t e = 0; e < s.angles.size(); ++e) {
    const auto& a = s.angles[e];
    p.angles.push_back({in.angle_place[e], Angle{g(a.i), g(a.j), g(a.k), scene_type(angle, a.type)}});
  }
  p.dihedrals.reserve(s.dihedrals.size());
  for (size_t e = 0; e < s.dihedrals.size(); ++e) {
    const auto& d = s.dihedrals[e];
    p.dihedrals.push_back(
        {in.dihedral_place[e], Dihedral{g(d.i), g(d.j), g(d.k), g(d.l), scene_type(dihedral, d.type)}});
  }
  p.impropers.reserve(s.impropers.size());
  for (size_t e = 0; e < s.impropers.size(); ++e) {
    const auto& d = s.impropers[e];
    p.impropers.push_back(
        {in.improper_place[e], Improper{g(d.i), g(d.j), g(d.k), g(d.l), scene_type(improper, d.type)}});
  }
  out.x = std::move(s.x);
  out.v = deck.velocities ? Eigen::Matrix3Xd(types.velocity_unit * s.v) : Eigen::Matrix3Xd::Zero(3, s.v.cols());

  // The O(types) rest, from the types the whole file uses.
  LammpsTypeNumbers& numbers = out.lammps_types;
  numbers.masses = s.type_mass;
  for (const int t : in.types_used.atom) remember(numbers.atom, atom_scene[static_cast<size_t>(t)], t);
  for (const int t : in.types_used.bond) remember(numbers.bond, scene_type(bond, t), t);
  for (const int t : in.types_used.angle) remember(numbers.angle, scene_type(angle, t), t);
  for (const int t : in.types_used.dihedral) remember(numbers.dihedral, scene_type(dihedral, t), t);
  for (const int t : in.types_used.improper) remember(numbers.improper, scene_type(improper, t), t);
  LammpsDataCoeffs& data = out.lammps_data_coeffs;
  data.file = deck.file;
  for (const auto& section : s.coeffs) data.sections.push_back({section.name, section.style, section.rows});
  all_numbers(data.bond, bond, in.types_used.bond);
  all_numbers(data.angle, angle, in.types_used.angle);
  all_numbers(data.dihedral, dihedral, in.types_used.dihedral);
  all_numbers(data.improper, improper, in.types_used.improper);
  return out;
}

}  // namespace stiffmd
