// Particles from the polymer builders and imported files, thermal velocities, and the
// preparation of a stiff state ([[build]], [import], [velocities], [prepare]: docs/decks.md).
#include "engine/scene/scene_sources.hpp"

#include <algorithm>
#include <cmath>
#include <filesystem>
#include <limits>
#include <sstream>

#include "core/disjoint_sets.hpp"
#include "core/errors.hpp"
#include "engine/io/lammps_data.hpp"
#include "engine/io/lammps_data_parts.hpp"
#include "engine/io/xyz_bonds.hpp"
#include "engine/scene/builders.hpp"
#include "engine/scene/chains_by_molecule.hpp"
#include "engine/scene/whole_molecules.hpp"
#include "integrators/methods.hpp"
#include "integrators/minimize.hpp"
#include "integrators/part_velocities.hpp"
#include "integrators/prepare.hpp"

namespace stiffmd {
namespace {

namespace fs = std::filesystem;

// Bounds on what a deck may ask for, checked before anything is allocated or run: a builder's
// beads (10^7 take minutes and gigabytes to grow) and [prepare]'s relaxation steps. A fuzzing
// build (libFuzzer's convention) keeps them small, so that an input runs in milliseconds.
// Imported files are bounded by their size (the readers check header counts against it); a
// fuzzing build refuses big ones too.
#ifdef FUZZING_BUILD_MODE_UNSAFE_FOR_PRODUCTION
constexpr long kMaxBuiltBeads = 500;
constexpr long kMaxRelaxSteps = 20;
constexpr long kMaxImportedAtoms = 500;
constexpr long kMaxMinimizeIterations = 20;
#else
constexpr long kMaxBuiltBeads = 10'000'000;
constexpr long kMaxRelaxSteps = 10'000'000;
constexpr long kMaxImportedAtoms = std::numeric_limits<int>::max();
constexpr long kMaxMinimizeIterations = 100'000'000;
#endif

void set_box(DeckTable& t, std::string_view key, Scene& sc, const Box& box) {
  if (sc.box.any_periodic() && !sc.box_from_source)
    t.fail(key, "the box is given twice: by [box] and here (remove one)");
  if (sc.box_from_source) t.fail(key, "the box is given twice: by an earlier [[build]] or [import] and here");
  sc.box = box;
  sc.box_from_source = true;
}

void add_topology(Scene& sc, int first, const std::vector<std::pair<int, int>>& bonds, const std::string& bond_type,
                  const std::vector<std::array<int, 3>>& angles, const std::string& angle_type,
                  const std::vector<std::array<int, 4>>& dihedrals = {}, const std::string& dihedral_type = "") {
  if (!bonds.empty()) {
    const int bt = Topology::intern(sc.topology.bond_types, bond_type);
    for (const auto& [i, j] : bonds) sc.topology.bonds.push_back({first + i, first + j, bt});
  }
  if (!angles.empty() && !angle_type.empty()) {
    const int at = Topology::intern(sc.topology.angle_types, angle_type);
    for (const auto& a : angles) sc.topology.angles.push_back({first + a[0], first + a[1], first + a[2], at});
  }
  if (!dihedrals.empty() && !dihedral_type.empty()) {
    const int dt = Topology::intern(sc.topology.dihedral_types, dihedral_type);
    for (const auto& d : dihedrals)
      sc.topology.dihedrals.push_back({first + d[0], first + d[1], first + d[2], first + d[3], dt});
  }
}

// A LAMMPS data file's box: periodic on every axis, LAMMPS's default boundary p p p.
Box box_of(const ImportedSystem& in) {
  Box box;
  box.origin = in.lo;
  box.lengths = in.hi - in.lo;
  box.periodic = Eigen::Vector3i::Ones();
  return box;
}

std::vector<std::pair<int, int>> bond_pairs(const std::vector<ImportedSystem::Bond>& bonds) {
  std::vector<std::pair<int, int>> pairs;
  for (const auto& b : bonds) pairs.emplace_back(b.i, b.j);
  return pairs;
}

// An XYZ file has no molecule ids: the molecules are the connected components of its bonds (its
// only bonded terms), numbered in the order of their first atom (the order append_particles
// keeps). Pinning needs no care: a molecule joins through a pinned particle (bonded_molecules), and
// an imported atom is never pinned (a type's mass is > 0; only [[particles]] pins).
std::vector<int> bond_components(int n, const std::vector<ImportedSystem::Bond>& bonds) {
  return connected_components(n, bond_pairs(bonds));
}

// Imported molecules made whole (core/state.hpp): unwrapped along their bonds, or, when the
// LAMMPS file has image flags, checked to be whole as the flags unwrap them. A failure names the
// file (through the deck key that gave it) and the atoms as the file numbers them.
void make_imported_molecules_whole(DeckTable& t, const char* file_key, ImportedSystem& in, const Box& box) {
  const auto problem = make_molecules_whole(in.x, bond_pairs(in.bonds), box, in.image_flags);
  if (!problem) return;
  const auto& b = in.bonds[static_cast<size_t>(problem->bond)];
  const bool lammps = std::string(file_key) == "lammps_data";
  t.fail(file_key, (lammps ? "bond between atom ids " + std::to_string(in.id[static_cast<size_t>(b.i)]) + " and " +
                                 std::to_string(in.id[static_cast<size_t>(b.j)])
                           : "bond between atoms " + std::to_string(b.i) + " and " + std::to_string(b.j) +
                                 " (0-based, as in the bonds file)") +
                       " " + problem->what);
}

// A [[build]] of linear chains by molecule described, not built (SceneContent::description): the
// checks the builder makes before it grows anything (validate_chain_spec, as
// build_linear_chains_by_molecule makes them), the offset, the `sources` entry of the particles it
// would build, its item types interned in the order add_topology interns them (bonds, then angles
// with three beads or more, then dihedrals with four or more), and the counts. Not made: the
// growth itself, so a chain that cannot be grown within the bounded tries (min_distance too large
// for the beads) is found by chains_part, on the rank that builds it.
void describe_chains(DeckTable& b, Scene& sc, const ChainSpec& spec, int type, const std::string& bond_type,
                     const std::string& angle_type, const std::string& dihedral_type) {
  const long long total = static_cast<long long>(spec.chains) * spec.beads;
  try {
    validate_chain_spec("build_linear_chains_by_molecule", spec, 2, sc.box, total);
  } catch (const std::exception& e) {
    b.fail_here(e.what());
  }
  const Eigen::Vector3d offset = b.vector3("offset", Eigen::Vector3d::Zero());
  b.require(offset.allFinite(), "offset", "expected a finite displacement [x, y, z]");
  b.finish();
  DescribedSource d;
  d.first = static_cast<int>(sc.whole_particles());
  d.count = static_cast<int>(total);
  d.molecules = spec.chains;
  d.particles_of_type.assign(sc.types.size(), 0);
  d.particles_of_type[static_cast<size_t>(type)] = total;
  const auto count = [](std::vector<std::int64_t>& of_type, int t, std::int64_t n) {
    of_type.resize(std::max(of_type.size(), static_cast<size_t>(t) + 1), 0);
    of_type[static_cast<size_t>(t)] += n;
  };
  count(d.bonds_of_type, Topology::intern(sc.topology.bond_types, bond_type),
        static_cast<std::int64_t>(spec.chains) * (spec.beads - 1));
  if (spec.beads >= 3 && !angle_type.empty())
    count(d.angles_of_type, Topology::intern(sc.topology.angle_types, angle_type),
          static_cast<std::int64_t>(spec.chains) * (spec.beads - 2));
  if (spec.beads >= 4 && !dihedral_type.empty())
    count(d.dihedrals_of_type, Topology::intern(sc.topology.dihedral_types, dihedral_type),
          static_cast<std::int64_t>(spec.chains) * (spec.beads - 3));
  sc.sources.push_back({d.first, d.count, b.where()});
  sc.described_sources.push_back(d);
  sc.undescribed_particles += d.count;
}

// The [import] of a LAMMPS data file described, not read into arrays (SceneContent::description):
// what read_import does with the whole file, in its order and with its messages at the same deck
// keys, from read_lammps_data_description's counts — the reader's one-line error behind
// lammps_data, the atom count's bound, the keys read and the table finished, each atom type the
// file uses mapped by atom_types to a deck type of the same mass (in the order of their first
// atoms, so the first failing atom's type is the one named), the box, the `sources` entry, each
// bonded type mapped and interned in the order of its first entry, the LAMMPS type numbers and
// masses, and what coefficients = "data" reads. Its atoms' and items' counts by scene type, their
// molecule ids' count, and the charges (the q column, or the types' charges) summed in the file's
// order go into the DescribedSource. Not made: what the lines of positions, velocities and
// charges hold (read by each rank in its block, data_file_part in engine/domain/part_load.hpp).
using LammpsTypeMap = std::vector<std::pair<std::string, std::string>>;

void describe_lammps_import(DeckTable& t, Scene& sc, const std::string& path, const std::string& style) {
  // The types' charges by file type number, as atom_types names them (read without a q column). A
  // map the deck cannot give is refused below, after the file, as read_import refuses it.
  std::vector<double> type_charge;
  LammpsTypeMap ahead;
  try {
    ahead = t.string_map("atom_types");
  } catch (const InputError&) {
  }
  for (const auto& [number, name] : ahead) {
    long n = 0;
    try {
      n = std::stol(number);
    } catch (const std::exception&) {
      continue;
    }
    if (n < 1 || n > std::numeric_limits<int>::max() || std::to_string(n) != number) continue;
    for (const ParticleType& pt : sc.types)
      if (pt.name == name) {
        type_charge.resize(std::max(type_charge.size(), static_cast<size_t>(n) + 1), 0.0);
        type_charge[static_cast<size_t>(n)] = pt.charge;
      }
  }
  ImportedDescription in;
  try {
    in = read_lammps_data_description(path, style, &type_charge);
  } catch (const InputError& e) {
    t.fail("lammps_data", e.what());
  }
  const LammpsTypeMap atom_map = t.string_map("atom_types");
  const LammpsTypeMap bond_map = t.string_map("bond_types"), angle_map = t.string_map("angle_types"),
                      dihedral_map = t.string_map("dihedral_types"), improper_map = t.string_map("improper_types");
  if (in.num_atoms > kMaxImportedAtoms)
    t.fail("lammps_data",
           std::to_string(in.num_atoms) + " atoms; expected at most " + std::to_string(kMaxImportedAtoms));
  t.boolean("velocities", true);
  t.finish();
  const auto lookup = [&](const LammpsTypeMap& map, int lammps_type, const char* key) {
    if (auto name = lammps_type_name(map, std::string_view(key) == "atom_types" || t.has(key), lammps_type))
      return *name;
    const std::string what = "no name for LAMMPS type " + std::to_string(lammps_type) + " (add \"" +
                             std::to_string(lammps_type) + "\" = \"NAME\" to " + key + ")";
    if (t.has(key)) t.fail(key, what);
    t.fail_here(std::string(key) + ": " + what);
  };
  DescribedSource d;
  d.first = static_cast<int>(sc.whole_particles());
  d.count = in.num_atoms;
  d.molecules = in.num_molecule_ids;
  d.particles_of_type.assign(sc.types.size(), 0);
  LammpsTypeNumbers& numbers = sc.lammps_types;
  const auto remember = [](std::vector<int>& of_type, int scene_type, int lammps_type) {
    if (of_type.size() <= static_cast<size_t>(scene_type)) of_type.resize(static_cast<size_t>(scene_type) + 1, 0);
    int& k = of_type[static_cast<size_t>(scene_type)];
    if (k == 0 || lammps_type < k) k = lammps_type;
  };
  for (const int lt : in.types_used.atom) {
    const std::string name = lookup(atom_map, lt, "atom_types");
    const int type = particle_type_index(sc, t, "atom_types", name);
    if (in.type_mass.count(lt) && in.type_mass.at(lt) != sc.types[static_cast<size_t>(type)].mass)
      t.fail("atom_types", "types." + name + ".mass = " + std::to_string(sc.types[static_cast<size_t>(type)].mass) +
                               " but the data file's Masses give " + std::to_string(in.type_mass.at(lt)) +
                               " for LAMMPS type " + std::to_string(lt));
    d.particles_of_type[static_cast<size_t>(type)] += in.atoms_of_type[static_cast<size_t>(lt)];
    remember(numbers.atom, type, lt);
  }
  Box box;
  box.origin = in.lo;
  box.lengths = in.hi - in.lo;
  box.periodic = Eigen::Vector3i::Ones();
  set_box(t, "lammps_data", sc, box);
  sc.sources.push_back({d.first, d.count, t.where() + " " + t.string("lammps_data")});
  numbers.masses = in.type_mass;
  // Each bonded kind: its types named and interned by first entry, counted, remembered.
  LammpsDataCoeffs& data = sc.lammps_data_coeffs;
  const auto kind = [&](int k, const LammpsTypeMap& map, const char* key, std::vector<std::string>& names,
                        std::vector<std::int64_t>& of_type, std::vector<int>& first_numbers,
                        std::vector<std::vector<int>>& all_numbers) {
    const std::vector<int>& used = k == 0   ? in.types_used.bond
                                   : k == 1 ? in.types_used.angle
                                   : k == 2 ? in.types_used.dihedral
                                            : in.types_used.improper;
    std::vector<int> scene_type;
    for (const int lt : used) {
      const int st = Topology::intern(names, lookup(map, lt, key));
      scene_type.push_back(st);
      of_type.resize(std::max(of_type.size(), static_cast<size_t>(st) + 1), 0);
      of_type[static_cast<size_t>(st)] += in.items_of_type[static_cast<size_t>(k)][static_cast<size_t>(lt)];
      remember(first_numbers, st, lt);
    }
    if (used.empty()) return;
    all_numbers.resize(names.size());
    for (size_t u = 0; u < used.size(); ++u) {
      auto& v = all_numbers[static_cast<size_t>(scene_type[u])];
      if (std::find(v.begin(), v.end(), used[u]) == v.end())
        v.insert(std::upper_bound(v.begin(), v.end(), used[u]), used[u]);
    }
  };
  Topology& top = sc.topology;
  kind(0, bond_map, "bond_types", top.bond_types, d.bonds_of_type, numbers.bond, data.bond);
  kind(1, angle_map, "angle_types", top.angle_types, d.angles_of_type, numbers.angle, data.angle);
  kind(2, dihedral_map, "dihedral_types", top.dihedral_types, d.dihedrals_of_type, numbers.dihedral, data.dihedral);
  kind(3, improper_map, "improper_types", top.improper_types, d.impropers_of_type, numbers.improper, data.improper);
  data.file = t.string("lammps_data");
  for (const auto& section : in.coeffs) data.sections.push_back({section.name, section.style, section.rows});
  // The charges: the file's q column replaces the types' (read_import), summed in the file's order.
  d.summed = true;
  d.charge_sum = in.charge_sum, d.charge_scale = in.charge_scale, d.first_charge = in.first_charge;
  d.first_charged = in.first_charged < 0 ? -1 : d.first + in.first_charged;
  sc.described_sources.push_back(d);
  sc.undescribed_particles += d.count;
}

}  // namespace

// Every molecule of the scene made whole (core/state.hpp): builders and imports already are,
// explicit [[bonds]] between [[particles]] (or joining sources) are unwrapped here. A failure
// names the [[bonds]] row when an explicit bond is the one that cannot be made whole.
void make_scene_molecules_whole(DeckTable& root, Scene& sc) {
  std::vector<std::pair<int, int>> pairs;
  for (const Bond& b : sc.topology.bonds) pairs.emplace_back(b.i, b.j);
  const auto problem = make_molecules_whole(sc.state.x, pairs, sc.box);
  if (!problem) return;
  const Bond& b = sc.topology.bonds[static_cast<size_t>(problem->bond)];
  const std::string what =
      "bond between particles " + std::to_string(b.i) + " and " + std::to_string(b.j) + " " + problem->what;
  auto rows = root.array_of_tables("bonds");
  const size_t first_explicit = sc.topology.bonds.size() - rows.size();
  if (static_cast<size_t>(problem->bond) >= first_explicit)
    rows[static_cast<size_t>(problem->bond) - first_explicit].fail("particles", what);
  root.fail_here(what);
}

// [[build]] style = "linear-chains" | "rings" | "stars", type, chains, beads, (arms), bond_length,
// bond_type, angle_type and dihedral_type (optional), density (optional: sets a periodic cubic box), min_distance,
// seed, growth = "together" | "by-molecule" (linear chains).
void read_builders(DeckTable& root, Scene& sc, std::size_t describe_from) {
  std::vector<DeckTable> builds = root.array_of_tables("build");
  for (std::size_t index = 0; index < builds.size(); ++index) {
    DeckTable& b = builds[index];
    const std::string style = b.string("style");
    if (style != "linear-chains" && style != "rings" && style != "stars")
      b.fail("style", "unknown builder '" + style + "' (known: linear-chains, rings, stars)");
    const int type = particle_type_index(sc, b, "type", b.name("type", sc.types[0].name));
    // Counts are checked as read, before the narrowing to int and before anything is built.
    const long chains = b.integer("chains", 1);
    b.require(chains >= 1 && chains <= kMaxBuiltBeads, "chains",
              "expected 1 .. " + std::to_string(kMaxBuiltBeads) + " molecules");
    const long beads = b.integer("beads");
    const long min_beads = style == "rings" ? 3 : style == "stars" ? 1 : 2;
    b.require(beads >= min_beads && beads <= kMaxBuiltBeads, "beads",
              (style == "rings"   ? std::string("a ring needs 3 .. ")
               : style == "stars" ? std::string("expected 1 .. ")
                                  : std::string("expected 2 .. ")) +
                  std::to_string(kMaxBuiltBeads) + " beads" + (style == "stars" ? " per arm" : ""));
    const long arms = style == "stars" ? b.integer("arms") : 0;
    if (style == "stars")
      b.require(arms >= 1 && arms <= kMaxStarArms, "arms",
                "expected 1 .. " + std::to_string(kMaxStarArms) + " arms (a core with n arms has n(n - 1)/2 angles)");
    // Each factor is at most 10^7 here: per molecule at most 10^14 + 1, and the product is only
    // formed once that is at most 10^7.
    const long per_molecule = style == "stars" ? 1 + arms * beads : beads;
    if (per_molecule > kMaxBuiltBeads || chains * per_molecule > kMaxBuiltBeads)
      b.fail(style == "stars" ? "arms" : "beads",
             std::to_string(chains) + " molecules of " + std::to_string(per_molecule) + " beads" +
                 (per_molecule > kMaxBuiltBeads ? std::string()
                                                : " = " + std::to_string(chains * per_molecule) + " beads") +
                 "; expected at most " + std::to_string(kMaxBuiltBeads) + " beads per [[build]]");
    const long total = chains * per_molecule;
    ChainSpec spec;
    spec.chains = static_cast<int>(chains);
    spec.beads = static_cast<int>(beads);
    spec.bond_length = b.number("bond_length", spec.bond_length);
    spec.min_distance = b.number("min_distance", spec.min_distance);
    spec.seed = static_cast<std::uint64_t>(b.integer("seed", 1));
    b.require(spec.bond_length > 0, "bond_length", "expected a bond length > 0");
    const std::string bond_type = b.name("bond_type");
    const std::string angle_type = b.name("angle_type", "");
    const std::string dihedral_type = b.name("dihedral_type", "");
    if (auto density = b.maybe_number("density")) {
      b.require(*density > 0, "density", "expected a number density > 0");
      try {
        set_box(b, "density", sc, box_for_density(static_cast<int>(total), *density));
      } catch (const std::invalid_argument& e) {
        b.fail("density", e.what());
      }
    }
    // How the molecules grow: all together, each bead kept clear of every other molecule's, or
    // each from its own random stream (engine/scene/chains_by_molecule.hpp: the same molecule on
    // any number of ranks; overlaps between molecules are left to [minimize]'s soft start).
    const std::string growth = b.string("growth", "together");
    if (growth != "together" && growth != "by-molecule")
      b.fail("growth", "unknown growth '" + growth + "' (known: together, by-molecule)");
    if (growth == "by-molecule" && style != "linear-chains")
      b.fail("growth",
             "growth = \"by-molecule\" builds linear chains only; expected style = \"linear-chains\" "
             "or growth = \"together\"");
    if (index >= describe_from && growth == "by-molecule") {
      describe_chains(b, sc, spec, type, bond_type, angle_type, dihedral_type);
      continue;
    }
    Polymer p;
    try {
      if (growth == "by-molecule")
        p = build_linear_chains_by_molecule(spec, sc.box);
      else if (style == "linear-chains")
        p = build_linear_chains(spec, sc.box);
      else if (style == "rings")
        p = build_rings(spec, sc.box);
      else
        p = build_stars(spec, static_cast<int>(arms), sc.box);
    } catch (const std::exception& e) {  // invalid parameters or a builder that could not place a chain
      b.fail_here(e.what());
    }
    // A shift of every built bead: several builders in open space all grow from the origin.
    const Eigen::Vector3d offset = b.vector3("offset", Eigen::Vector3d::Zero());
    b.require(offset.allFinite(), "offset", "expected a finite displacement [x, y, z]");
    p.x.colwise() += offset;
    b.finish();
    const int first = append_particles(sc, p.x, Eigen::Matrix3Xd::Zero(3, p.x.cols()),
                                       std::vector<int>(static_cast<size_t>(p.x.cols()), type), p.molecule);
    sc.sources.push_back({first, static_cast<int>(p.x.cols()), b.where()});
    add_topology(sc, first, p.bonds, bond_type, p.angles, angle_type, p.dihedrals, dihedral_type);
  }
}

// [import] lammps_data = PATH (atom_style, atom_types = {"1" = "bead"}, bond_types = {...},
// angle_types = {...}, dihedral_types = {...}, improper_types = {...}, velocities = true) — or xyz =
// PATH, bonds = PATH, type, bond_type. A bond, angle, dihedral or improper map left out names each
// type by its number in the file ("1", "2", …); atom_types is always needed (the deck's [types]
// give the masses).
void read_import(DeckTable& root, Scene& sc, const std::string& deck_dir, bool describe) {
  auto t = root.table("import");
  if (!t) return;
  auto resolve = [&](const std::string& p) {
    return fs::path(p).is_absolute() || deck_dir.empty() ? p : (fs::path(deck_dir) / p).string();
  };
  const bool lammps = t->has("lammps_data"), xyz = t->has("xyz");
  if (lammps == xyz) t->fail_here("expected either lammps_data = PATH or xyz = PATH (with bonds = PATH)");
  ImportedSystem in;
  std::vector<std::pair<std::string, std::string>> atom_map, bond_map, angle_map, dihedral_map, improper_map;
  std::string single_type, single_bond_type;
  // The reader's one-line error (file, line, section) behind the deck key that named the file.
  const char* file_key = lammps ? "lammps_data" : "xyz";
  if (lammps) {
    const std::string path = resolve(t->string("lammps_data"));
    const std::string style = t->string("atom_style", "auto");
    if (describe) return describe_lammps_import(*t, sc, path, style);
    try {
      in = read_lammps_data(path, style);
    } catch (const InputError& e) {
      t->fail("lammps_data", e.what());
    }
    atom_map = t->string_map("atom_types");
    bond_map = t->string_map("bond_types");
    angle_map = t->string_map("angle_types");
    dihedral_map = t->string_map("dihedral_types");
    improper_map = t->string_map("improper_types");
  } else {
    const std::string xyz_path = resolve(t->string("xyz")), bonds_path = resolve(t->string("bonds"));
    try {
      in = read_xyz_with_bonds(xyz_path, bonds_path);
    } catch (const InputError& e) {
      t->fail(std::string(e.what()).rfind(bonds_path + ":", 0) == 0 ? "bonds" : "xyz", e.what());
    }
    single_type = t->string("type", sc.types[0].name);
    single_bond_type = t->string("bond_type", "bond");
  }
  if (in.x.cols() > kMaxImportedAtoms)
    t->fail(file_key, std::to_string(in.x.cols()) + " atoms; expected at most " + std::to_string(kMaxImportedAtoms));
  make_imported_molecules_whole(*t, file_key, in, lammps ? box_of(in) : sc.box);
  if (!lammps) in.molecule = bond_components(static_cast<int>(in.x.cols()), in.bonds);
  // A bond between two atoms at the same position has no direction: its force and its
  // constraint gradient are 0/0.
  for (const auto& b : in.bonds)
    if ((in.x.col(b.i) - in.x.col(b.j)).norm() == 0.0)
      t->fail(file_key, (lammps ? "bond between atom ids " + std::to_string(in.id[static_cast<size_t>(b.i)]) + " and " +
                                      std::to_string(in.id[static_cast<size_t>(b.j)])
                                : "bond between atoms " + std::to_string(b.i) + " and " + std::to_string(b.j) +
                                      " (0-based, as in the bonds file)") +
                            ": both atoms sit at the same position (zero-length bond)");
  // Charges (atom_style full's q column, in e) replace the types' own: a non-finite one is refused.
  for (size_t k = 0; k < in.charge.size(); ++k)
    if (!std::isfinite(in.charge[k]))
      t->fail(file_key, t->string(file_key) + ": atom id " + std::to_string(in.id[k]) + " has charge " +
                            (std::ostringstream() << in.charge[k]).str() +
                            "; expected a finite charge (in units of e)");
  const bool use_velocities = t->boolean("velocities", true);
  t->finish();  // a mistyped key is reported as such, not as the mapping it failed to give
  // Particle types: a LAMMPS type maps to a deck type; masses must agree.
  auto lookup = [&](const std::vector<std::pair<std::string, std::string>>& map, int lammps_type, const char* key) {
    if (auto name = lammps_type_name(map, std::string_view(key) == "atom_types" || t->has(key), lammps_type))
      return *name;
    const std::string what = "no name for LAMMPS type " + std::to_string(lammps_type) + " (add \"" +
                             std::to_string(lammps_type) + "\" = \"NAME\" to " + key + ")";
    if (t->has(key)) t->fail(key, what);
    t->fail_here(std::string(key) + ": " + what);
  };
  const int n = static_cast<int>(in.x.cols());
  std::vector<int> type(n);
  for (int i = 0; i < n; ++i) {
    const std::string name = lammps ? lookup(atom_map, in.type[i], "atom_types") : single_type;
    type[i] = particle_type_index(sc, *t, lammps ? "atom_types" : "type", name);
    if (lammps && in.type_mass.count(in.type[i]) && in.type_mass.at(in.type[i]) != sc.types[type[i]].mass)
      t->fail("atom_types", "types." + name + ".mass = " + std::to_string(sc.types[type[i]].mass) +
                                " but the data file's Masses give " + std::to_string(in.type_mass.at(in.type[i])) +
                                " for LAMMPS type " + std::to_string(in.type[i]));
  }
  if (lammps) set_box(*t, "lammps_data", sc, box_of(in));
  // LAMMPS data velocities are in its units' (real: Å/fs), as the deck's.
  const Eigen::Matrix3Xd v =
      use_velocities ? Eigen::Matrix3Xd(sc.units.velocity_in(1.0) * in.v) : Eigen::Matrix3Xd::Zero(3, n);
  const int first = append_particles(sc, in.x, v, type, in.molecule);
  for (size_t k = 0; k < in.charge.size(); ++k) sc.charge[first + k] = in.charge[k];
  sc.sources.push_back({first, n, t->where() + " " + t->string(file_key)});
  // The file's type numbers, kept per scene type so that a data file written back numbers them
  // alike (several LAMMPS types mapped to one name: the smallest).
  const auto remember = [&](std::vector<int>& numbers, int scene_type, int lammps_type) {
    if (!lammps) return;
    if (numbers.size() <= static_cast<size_t>(scene_type)) numbers.resize(static_cast<size_t>(scene_type) + 1, 0);
    int& k = numbers[static_cast<size_t>(scene_type)];
    if (k == 0 || lammps_type < k) k = lammps_type;
  };
  LammpsTypeNumbers& numbers = sc.lammps_types;
  if (lammps) numbers.masses = in.type_mass;
  for (int i = 0; i < n; ++i) remember(numbers.atom, type[i], in.type[i]);
  for (const auto& b : in.bonds) {
    const std::string name = lammps ? lookup(bond_map, b.type, "bond_types") : single_bond_type;
    const int bt = Topology::intern(sc.topology.bond_types, name);
    remember(numbers.bond, bt, b.type);
    sc.topology.bonds.push_back({first + b.i, first + b.j, bt});
  }
  for (const auto& a : in.angles) {
    const int at = Topology::intern(sc.topology.angle_types, lookup(angle_map, a.type, "angle_types"));
    remember(numbers.angle, at, a.type);
    sc.topology.angles.push_back({first + a.i, first + a.j, first + a.k, at});
  }
  for (const auto& d : in.dihedrals) {
    const int dt = Topology::intern(sc.topology.dihedral_types, lookup(dihedral_map, d.type, "dihedral_types"));
    remember(numbers.dihedral, dt, d.type);
    sc.topology.dihedrals.push_back({first + d.i, first + d.j, first + d.k, first + d.l, dt});
  }
  for (const auto& d : in.impropers) {
    const int it = Topology::intern(sc.topology.improper_types, lookup(improper_map, d.type, "improper_types"));
    remember(numbers.improper, it, d.type);
    sc.topology.impropers.push_back({first + d.i, first + d.j, first + d.k, first + d.l, it});
  }
  if (!lammps) return;
  // What coefficients = "data" reads: the Coeffs sections, and every file number of each scene type.
  LammpsDataCoeffs& data = sc.lammps_data_coeffs;
  data.file = t->string("lammps_data");
  for (const auto& section : in.coeffs) data.sections.push_back({section.name, section.style, section.rows});
  const auto all_numbers = [](std::vector<std::vector<int>>& out, size_t types, int scene_type, int lammps_type) {
    out.resize(types);
    auto& v = out[static_cast<size_t>(scene_type)];
    if (std::find(v.begin(), v.end(), lammps_type) == v.end())
      v.insert(std::upper_bound(v.begin(), v.end(), lammps_type), lammps_type);
  };
  const Topology& top = sc.topology;
  for (const auto& b : in.bonds)
    all_numbers(data.bond, top.bond_types.size(), top.bond_type_index(lookup(bond_map, b.type, "bond_types")), b.type);
  for (const auto& a : in.angles)
    all_numbers(data.angle, top.angle_types.size(), top.angle_type_index(lookup(angle_map, a.type, "angle_types")),
                a.type);
  for (const auto& d : in.dihedrals)
    all_numbers(data.dihedral, top.dihedral_types.size(),
                top.dihedral_type_index(lookup(dihedral_map, d.type, "dihedral_types")), d.type);
  for (const auto& d : in.impropers)
    all_numbers(data.improper, top.improper_types.size(),
                top.improper_type_index(lookup(improper_map, d.type, "improper_types")), d.type);
}

std::optional<std::string> lammps_type_name(const std::vector<std::pair<std::string, std::string>>& map, bool given,
                                            int number) {
  if (!given) return std::to_string(number);  // the file's number
  for (const auto& [k, v] : map)
    if (k == std::to_string(number)) return v;
  return std::nullopt;
}

// [velocities] temperature, seed: Maxwell–Boltzmann velocities for every mobile particle,
// zero total momentum, kinetic temperature exactly T (replacing any velocities given so far).
void read_velocities(DeckTable& root, Scene& sc) {
  auto t = root.table("velocities");
  if (!t) return;
  const double temperature = t->number("temperature");
  t->require(temperature >= 0, "temperature", "expected a temperature >= 0");
  const auto seed = static_cast<std::uint64_t>(t->integer("seed", 1));
  // One stream over the particles in order, or each particle's normals keyed by its index
  // (integrators/part_velocities.hpp: the same velocities whichever rank holds the particle).
  const bool by_particle = t->boolean("by_particle", false);
  // 3 N_mobile − 3 degrees of freedom once the total momentum is removed: none, and T > 0 cannot
  // be given (every particle fixed, or one free particle), so say so rather than start at rest.
  // A described source's particles are mobile (a type's mass is > 0).
  const auto loaded_mobile = (sc.state.inv_mass.array() > 0.0).count();
  const auto mobile = loaded_mobile + sc.undescribed_particles;
  if (temperature > 0 && 3 * mobile - 3 <= 0)
    t->fail("temperature", "the scene has no degree of freedom to thermalise (" + std::to_string(mobile) +
                               " mobile particle(s), total momentum removed); expected temperature = 0 or more "
                               "mobile particles");
  t->finish();
  // A description's loaded particles (none but in a deck that mixes sources) draw theirs among
  // themselves: the per-particle arrays of a described scene are not the whole scene's.
  if (sc.described() && 3 * loaded_mobile - 3 <= 0) return;
  if (by_particle) {
    std::vector<int> global(static_cast<size_t>(sc.state.inv_mass.size()));
    for (size_t i = 0; i < global.size(); ++i) global[i] = static_cast<int>(i);
    sc.state.v = maxwell_boltzmann_by_particle(sc.state.inv_mass, global, sc.units.kT(temperature), seed, nullptr);
  } else {
    sc.state.v = maxwell_boltzmann(sc.state.inv_mass, sc.units.kT(temperature), seed);
  }
}

// [prepare]: the settings of prepare_state (integrators/prepare.*, where the physics is) and
// the table's file:line for its errors.
void read_prepare(DeckTable& root, Scene& sc) {
  auto t = root.table("prepare");
  if (!t) return;
  PrepareTable& p = sc.prepare;
  p.requested = true;
  p.where = t->where();
  p.project = t->boolean("project", true);
  p.vibrational_temperature = t->number("vibrational_temperature", 0.0);
  t->require(p.vibrational_temperature >= 0, "vibrational_temperature", "expected a temperature >= 0");
  p.vibrational_temperature = sc.units.kT(p.vibrational_temperature);
  p.seed = static_cast<std::uint64_t>(t->integer("seed", 1));
  p.by_particle = t->boolean("by_particle", false);
  p.relax_steps = t->integer("relax_steps", 0);
  t->require(p.relax_steps >= 0 && p.relax_steps <= kMaxRelaxSteps, "relax_steps",
             "expected a number of steps 0 .. " + std::to_string(kMaxRelaxSteps));
  p.relax_max_displacement = t->number("relax_max_displacement", 0.02);
  t->require(p.relax_max_displacement > 0, "relax_max_displacement", "expected a length > 0");
  if (!sc.forces->stiff_bonds())
    t->fail_here("[prepare] needs constraint-defining stiff bonds (a stiff-harmonic term)");
  t->finish();
}

// [minimize]: the settings of minimize (integrators/minimize.*, where the algorithms are) and the
// table's file:line for its errors. Read after [integrator]: FIRE's step dt defaults to its h,
// and a method with rigid constraints minimises on g(x) = 0.
void read_minimize(DeckTable& root, Scene& sc) {
  auto t = root.table("minimize");
  if (!t) return;
  MinimizeTable& p = sc.minimize;
  p.requested = true;
  p.where = t->where();
  const std::string style = t->string("style", "fire");
  if (style == "fire")
    p.style = MinimizeStyle::fire;
  else if (style == "cg")
    p.style = MinimizeStyle::cg;
  else if (style == "sd")
    p.style = MinimizeStyle::sd;
  else
    t->fail("style",
            "expected \"fire\" (FIRE 2.0), \"cg\" (Polak-Ribiere conjugate gradient) or \"sd\" (steepest "
            "descent), got \"" +
                style + "\"");
  p.etol = t->number("etol", 0.0);
  t->require(p.etol >= 0 && p.etol < 1, "etol", "expected a relative energy change 0 <= etol < 1 (0: off)");
  p.ftol = t->number("ftol", 1e-6);
  t->require(p.ftol >= 0 && std::isfinite(p.ftol), "ftol", "expected a force >= 0 (0: off)");
  p.maxiter = t->integer("maxiter", std::min(10'000L, kMaxMinimizeIterations));
  t->require(p.maxiter >= 1 && p.maxiter <= kMaxMinimizeIterations, "maxiter",
             "expected a number of iterations 1 .. " + std::to_string(kMaxMinimizeIterations));
  p.maxeval = t->integer("maxeval", std::min(100'000L, kMaxMinimizeIterations));
  t->require(p.maxeval >= 1 && p.maxeval <= kMaxMinimizeIterations, "maxeval",
             "expected a number of force evaluations 1 .. " + std::to_string(kMaxMinimizeIterations));
  const double h = sc.integrator.h / sc.units.time;
  if (p.style == MinimizeStyle::fire) {
    const double dt = t->number("dt", h);
    t->require(dt > 0 && std::isfinite(dt), "dt", "expected a time step > 0");
    p.dt = sc.units.time_in(dt);
  } else if (t->has("dt")) {
    t->fail("dt", "FIRE's initial time step; style \"" + style + "\" moves by a line search and has none (remove it)");
  }
  p.dmax = t->number("dmax", 0.1);
  t->require(p.dmax > 0 && std::isfinite(p.dmax), "dmax", "expected a length > 0");
  p.max_force = t->number("max_force", 0.0);
  t->require(p.max_force >= 0 && std::isfinite(p.max_force), "max_force", "expected a force >= 0 (0: no cap)");
  const MethodInfo* m = find_method(sc.integrator.method);
  p.rigid = m && m->rigid_constraints && sc.forces->stiff_bonds() != nullptr;
  t->finish();
}

void prepare_scene(Scene& sc, std::ostream& log, std::ostream* progress) {
  const PrepareTable& p = sc.prepare;
  const MinimizeTable& mt = sc.minimize;
  // The order: project, relax, minimise, then the thermal bond vibrations (a minimisation after
  // them would take them out again).
  const bool vibrate_after = p.requested && mt.requested && p.vibrational_temperature > 0.0;
  auto prepare = [&](const PrepareSettings& settings) {
    std::string note;
    try {
      note = prepare_state(*sc.forces, *sc.forces->stiff_bonds(), sc.state, settings, progress);
    } catch (const NumericalError& e) {
      throw InputError(p.where + ": could not project the initial state: " + e.what());
    } catch (const InputError& e) {
      throw InputError(p.where + ": " + e.what());
    }
    if (!note.empty()) log << note << "\n";
  };
  if (p.requested) {
    PrepareSettings first = p;
    if (vibrate_after) first.vibrational_temperature = 0.0;
    prepare(first);
  }
  if (mt.requested) {
    try {
      sc.minimized = minimize(*sc.forces, sc.forces->stiff_bonds(), sc.state, mt, progress);
    } catch (const NumericalError& e) {
      throw InputError(mt.where + ": " + e.what());
    }
    log << describe(*sc.minimized) << "\n";
  }
  if (vibrate_after) {
    PrepareSettings vibrate = p;
    vibrate.project = false;
    vibrate.relax_steps = 0;
    prepare(vibrate);
  }
}

}  // namespace stiffmd
