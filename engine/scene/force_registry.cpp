#include "engine/scene/force_registry.hpp"

#include <algorithm>
#include <cmath>
#include <map>
#include <numbers>
#include <optional>
#include <set>
#include <sstream>
#include <stdexcept>
#include <type_traits>
#include <utility>

#include "core/errors.hpp"
#include "core/format.hpp"
#include "engine/io/lammps_data.hpp"
#include "engine/scene/kspace_deck.hpp"
#include "engine/scene/overlap_rule.hpp"
#include "forcefields/angle_terms.hpp"
#include "forcefields/bond_term.hpp"
#include "forcefields/charmm_terms.hpp"
#include "forcefields/coefficients.hpp"
#include "forcefields/coulomb_potentials.hpp"
#include "forcefields/dihedral_terms.hpp"
#include "forcefields/external_terms.hpp"
#include "forcefields/gravity.hpp"
#include "forcefields/improper_terms.hpp"
#include "forcefields/pair_term.hpp"
#include "forcefields/stiff_harmonic_bond.hpp"
#include "integrators/methods.hpp"

namespace stiffmd {
namespace {

// A style parameter read from a deck key and checked against the range of its kind (a length
// > 0, an energy >= 0, …: forcefields/coefficients.hpp). A bad value fails at that key: its
// file:line, or the --set that supplied it.
double read(DeckTable& t, std::string_view key, const Quantity& q) {
  const double v = t.number(key);
  t.require(q.admits(v), key, "expected " + q.expected(v));
  return v;
}
double read(DeckTable& t, std::string_view key, const Quantity& q, double fallback) {
  const double v = t.number(key, fallback);
  t.require(q.admits(v), key, "expected " + q.expected(v));
  return v;
}

// LAMMPS coefficient rows (Scene::lammps_coeffs): numbers in the shortest text that reads back
// as the same double, so that a data file written back gives LAMMPS the deck's values.
std::string numbers(std::initializer_list<double> values) {
  std::string out;
  for (const double v : values) {
    if (!out.empty()) out += ' ';
    append_shortest(out, v);
  }
  return out;
}

// The rows of the types a bonded term claims (index: per scene type, its coefficients in
// `coeffs`, or -1), under the LAMMPS style `style` ("" when LAMMPS has no style of that form).
template <class Coeffs, class Row>
void note_lammps(LammpsCoeffs::Section* section, const std::string& style, const std::vector<int>& index,
                 const std::vector<Coeffs>& coeffs, Row row) {
  if (!section) return;
  section->claim(style);
  for (size_t k = 0; k < index.size(); ++k)
    if (index[k] >= 0) section->rows[{static_cast<int>(k), -1}] = row(coeffs[static_cast<size_t>(index[k])]);
}

// Bonded styles claim named bond (or angle) types: [forces.NAME.bond_types.TYPE] = {params}.
// Returns, per type of the scene, the index of its coefficients in `coeffs` (−1: not claimed
// by this term). A type claimed by two terms, or a table that is missing, is an error.
template <class Coeffs, class Read>
std::vector<int> claim_types(DeckTable& t, const char* key, const std::vector<std::string>& names,
                             std::vector<std::string>& owner, const std::string& term, Read read,
                             std::vector<Coeffs>& coeffs) {
  auto types = t.table(key);
  if (!types) t.fail_here(std::string("missing required table [") + t.key_path(key) + ".TYPE]");
  std::vector<int> index(names.size(), -1);
  for (auto& [type_name, tt] : types->named_tables()) {
    Coeffs c = read(tt);
    tt.finish();
    const int k = Topology::index_of(names, type_name);
    if (k < 0) continue;  // a type with nothing of it in this scene is allowed
    if (!owner[k].empty())
      types->fail(type_name, "type '" + type_name + "' is already defined by [forces." + owner[k] + "]");
    owner[k] = term;
    index[k] = static_cast<int>(coeffs.size());
    coeffs.push_back(c);
  }
  types->finish();
  return index;
}

// The bonds (or angles) of the claimed types, their type renumbered into `coeffs`.
template <class Item>
std::vector<Item> claimed(const std::vector<Item>& items, const std::vector<int>& index) {
  return claimed_items(items, index);
}

// A bonded term made with its claim on the scene's types (TypeClaim, forcefields/type_claim.hpp):
// on a decomposed run's part it takes its items from the part's own topology.
template <class Term, class... Args>
std::unique_ptr<ForceTerm> claiming(const std::vector<int>& index, Args&&... args) {
  auto term = std::make_unique<Term>(std::forward<Args>(args)...);
  term->set_type_claim(index);
  return term;
}

// One kind of bonded type, as a reader claims it: its deck key, its data-file section, the
// scene's names, which term owns each, and the data file's numbers of each (LammpsDataCoeffs).
struct TypeKind {
  const char* types_key;  // "angle_types"
  const char* section;    // "Angle Coeffs"
  const char* word;       // "angle"
  const std::vector<std::string>& names;
  std::vector<std::string>& owner;
  const std::vector<std::vector<int>>& numbers;
};
TypeKind bond_kind(TermContext& ctx) {
  return {"bond_types",
          "Bond Coeffs",
          "bond",
          ctx.scene.topology.bond_types,
          ctx.bond_type_owner,
          ctx.scene.lammps_data_coeffs.bond};
}
TypeKind angle_kind(TermContext& ctx) {
  return {"angle_types",
          "Angle Coeffs",
          "angle",
          ctx.scene.topology.angle_types,
          ctx.angle_type_owner,
          ctx.scene.lammps_data_coeffs.angle};
}
TypeKind dihedral_kind(TermContext& ctx) {
  return {"dihedral_types",
          "Dihedral Coeffs",
          "dihedral",
          ctx.scene.topology.dihedral_types,
          ctx.dihedral_type_owner,
          ctx.scene.lammps_data_coeffs.dihedral};
}
TypeKind improper_kind(TermContext& ctx) {
  return {"improper_types",
          "Improper Coeffs",
          "improper",
          ctx.scene.topology.improper_types,
          ctx.improper_type_owner,
          ctx.scene.lammps_data_coeffs.improper};
}

// A LAMMPS coefficient row's layout, for `coefficients = "data"`: the LAMMPS style whose row it is
// and the names of the numbers after the type ("K theta0 K_UB r_UB").
struct DataRow {
  const char* lammps_style;
  const char* layout;
};

// A data-file coefficient that LAMMPS reads as an integer (n, d): refused when it is not one.
int data_integer(double v, const char* what) {
  if (!(v == std::floor(v)) || std::abs(v) > 1e6)
    throw std::invalid_argument(std::string(what) + ": expected an integer, got " + format_number(v));
  return static_cast<int>(v);
}

// The numbers of scene type k's row in the imported data file's `kind.section` (LAMMPS
// `row.lammps_style`, laid out as `row.layout`); several file types mapped onto k must have equal
// rows. k must have come from the data file (kind.numbers[k] not empty). Every failure is one line at
// `key` naming the data file, the section, the type and what was expected; `reader` is what reads
// the row, for the messages (coefficients = "data").
std::vector<double> data_row(DeckTable& t, const char* key, const std::string& reader, TermContext& ctx,
                             const TypeKind& kind, const DataRow& row, size_t k) {
  const LammpsDataCoeffs& data = ctx.scene.lammps_data_coeffs;
  const std::string where = data.file + ": " + kind.section;
  const size_t columns = detail::split_ws(row.layout).size();
  const auto expected_row = [&](int number) { return "'" + std::to_string(number) + " " + row.layout + "'"; };
  const LammpsDataCoeffs::Section* section = nullptr;
  for (const auto& sec : data.sections)
    if (sec.name == kind.section) section = &sec;
  if (section && !section->style.empty() && section->style != row.lammps_style)
    t.fail(key, where + " is marked '# " + section->style + "', but [" + t.path() + "] takes LAMMPS " + kind.word +
                    "_style " + row.lammps_style + " rows ('TYPE " + row.layout + "')");
  // The numbers of the row of file type `number`.
  const auto values_of = [&](int number) {
    if (!section)
      t.fail(key, data.file + ": no " + kind.section + " section; " + reader + " needs the row " +
                      expected_row(number) + " for " + kind.word + " type " + std::to_string(number));
    for (const std::string& text : section->rows) {
      const auto tok = detail::split_ws(text);
      long long type = 0;
      if (tok.empty() || !detail::parse_long(tok[0], type) || type != number) continue;
      if (tok.size() - 1 != columns)
        t.fail(key, where + ": " + kind.word + " type " + std::to_string(number) + ": expected " +
                        std::to_string(columns) + " coefficients " + expected_row(number) + " (LAMMPS " +
                        row.lammps_style + "), found " + std::to_string(tok.size() - 1));
      std::vector<double> v(columns);
      for (size_t c = 0; c < columns; ++c)
        if (!detail::parse_double(tok[c + 1], v[c]))
          t.fail(key, where + ": " + kind.word + " type " + std::to_string(number) + ": expected a number for " +
                          std::string(detail::split_ws(row.layout)[c]) + ", found " + detail::quote(tok[c + 1]));
      return v;
    }
    t.fail(key, where + ": no row for " + kind.word + " type " + std::to_string(number) + "; expected " +
                    expected_row(number));
  };
  const std::vector<int>& numbers = kind.numbers[k];
  const std::vector<double> first = values_of(numbers[0]);
  for (size_t m = 1; m < numbers.size(); ++m)
    if (values_of(numbers[m]) != first)
      t.fail(key, where + ": " + kind.word + " types " + std::to_string(numbers[0]) + " and " +
                      std::to_string(numbers[m]) + " are both named '" + kind.names[k] +
                      "' but their coefficients differ; expected one row per name (map them to different names in "
                      "[import] " +
                      kind.types_key + ")");
  return first;
}

// coefficients = "data": every type of `kind` that the [import] mapped from the LAMMPS data file
// takes the numbers of its row in the file's section (data_row: in LAMMPS's units and conventions),
// turned into Coeffs by `make` (std::invalid_argument naming a coefficient when they are out of
// range). Every failure is one line at the `coefficients` key.
template <class Coeffs, class Make>
std::vector<int> claim_data_types(DeckTable& t, TermContext& ctx, const TypeKind& kind, const std::string& term,
                                  const DataRow& row, Make make, std::vector<Coeffs>& coeffs) {
  const LammpsDataCoeffs& data = ctx.scene.lammps_data_coeffs;
  if (data.file.empty())
    t.fail("coefficients",
           "coefficients = \"data\" takes the coefficients from an imported LAMMPS data file, and "
           "there is none ([import] lammps_data = PATH)");
  std::vector<int> index(kind.names.size(), -1);
  for (size_t k = 0; k < kind.names.size() && k < kind.numbers.size(); ++k) {
    if (kind.numbers[k].empty()) continue;
    if (!kind.owner[k].empty()) continue;  // a term that names the type takes it (read first: scene.cpp)
    const std::vector<double> first = data_row(t, "coefficients", "coefficients = \"data\"", ctx, kind, row, k);
    try {
      coeffs.push_back(make(first));
    } catch (const std::invalid_argument& e) {
      t.fail("coefficients", data.file + ": " + kind.section + ": " + kind.word + " type " +
                                 std::to_string(kind.numbers[k][0]) + ": " + e.what());
    }
    kind.owner[k] = term;
    index[k] = static_cast<int>(coeffs.size()) - 1;
  }
  if (std::all_of(index.begin(), index.end(), [](int i) { return i < 0; }))
    t.fail("coefficients",
           "coefficients = \"data\": every " + std::string(kind.word) +
               " type of the data file is already defined by another term; expected some left for [forces." + term +
               "]");
  return index;
}

// The types a bonded term claims: from the deck's `kind.types_key`.TYPE tables (read by `read`), or
// with coefficients = "data" from the imported data file (claim_data_types; `row` and `make`).
template <class Coeffs, class Read, class Make>
std::vector<int> claim_kind(DeckTable& t, TermContext& ctx, const TypeKind& kind, const std::string& term, Read read,
                            const DataRow& row, Make make, std::vector<Coeffs>& coeffs) {
  if (!t.has("coefficients")) return claim_types(t, kind.types_key, kind.names, kind.owner, term, read, coeffs);
  const std::string v = t.string("coefficients");
  if (v != "data")
    t.fail("coefficients",
           "expected \"data\" (the imported LAMMPS data file's " + std::string(kind.section) + "), got \"" + v + "\"");
  if (t.has(kind.types_key))
    t.fail(kind.types_key,
           "give either coefficients = \"data\" or " + t.key_path(kind.types_key) + ".TYPE tables, not both");
  return claim_data_types(t, ctx, kind, term, row, make, coeffs);
}

// stiff-harmonic's angle_types.TYPE = {theta0 (degrees), alpha}: each angle i–j–k of the type
// made rigid by a third stiff bond i–k, as LAMMPS's fix shake/rattle `a` does (rigid water: a
// triangle of three constraints). Its length is the law of cosines on the two arms, which must be
// stiff bonds of this term: ℓ_ik² = ℓ_ij² + ℓ_jk² − 2 ℓ_ij ℓ_jk cos θ₀. The angle type needs no
// angle term then; one may still claim it (under RATTLE its energy is a constant, as in LAMMPS).
// type_of gets −1 for them.
void add_rigid_angles(DeckTable& t, TermContext& ctx, StiffBonds& sb, StiffBondRule& rule, std::vector<int>& type_of) {
  auto types = t.table("angle_types");
  if (!types) return;
  const Topology& top = ctx.scene.topology;
  const StiffArms arm = StiffBondRule::arms_of(sb.bonds);  // the claimed bonds' lengths
  for (auto& [type_name, tt] : types->named_tables()) {
    const double deg = tt.number("theta0");
    tt.require(deg > 0.0 && deg < 180.0, "theta0", "expected the rigid angle in degrees, strictly between 0 and 180");
    const double alpha = read(tt, "alpha", kPositive);
    tt.finish();
    const int k = top.angle_type_index(type_name);
    if (k < 0) continue;  // no angle of that type in this scene
    if (ctx.rigid_angle_type) (*ctx.rigid_angle_type)[static_cast<size_t>(k)] = 1;
    const RigidAngleType rigid{k, std::cos(deg * std::numbers::pi / 180.0), alpha};
    rule.rigid_angles.push_back(rigid);
    const size_t before = sb.bonds.size();
    if (const int n = StiffBondRule::add_rigid_angle_bonds(top, rigid, arm, sb.bonds); n >= 0) {
      const Angle& a = top.angles[static_cast<size_t>(n)];
      types->fail(type_name,
                  "angle " + std::to_string(a.i) + "–" + std::to_string(a.j) + "–" + std::to_string(a.k) +
                      " of type '" + type_name +
                      "': a rigid angle needs both of its bonds to be stiff bonds of this term (bond_types)");
    }
    type_of.resize(type_of.size() + (sb.bonds.size() - before), -1);
  }
  types->finish();
}

// LAMMPS's fix shake/rattle `m` tolerance (fix_shake.cpp, MASSDELTA): a particle's mass matches a
// listed mass within it, in the deck's mass unit.
constexpr double kMassDelta = 0.1;

// stiff-harmonic's masses = [m, …]: a bond is rigid when either of its particles has a mass within
// kMassDelta of a listed one, as LAMMPS's fix shake/rattle `m` selects bonds. The term takes
// whole bond types (`index`, `coeffs`: as claim_types fills them), each with its bond_types entry
// when named there, else its row in the imported data file's Bond Coeffs (bond_style harmonic
// K r0: ℓ = r0 and α = ε√(2K), so that the stiff potential ½(α/ε)²(r − r0)² is LAMMPS's
// K(r − r0)²). LAMMPS selects per bond; a bond type of which only some bonds are selected would have
// to be split between this term and a flexible one, so it is refused, naming a bond of each kind.
void add_bonds_by_mass(DeckTable& t, TermContext& ctx, const std::string& term, double epsilon, std::vector<int>& index,
                       std::vector<StiffBond>& coeffs) {
  const std::vector<double> masses = t.numbers("masses");
  t.require(!masses.empty(), "masses", "expected a list of one or more masses, e.g. masses = [1.008]");
  for (const double m : masses)
    t.require(std::isfinite(m) && m > 0.0, "masses", "expected masses > 0, got " + format_number(m));
  const Scene& sc = ctx.scene;
  const Topology& top = sc.topology;
  // A pinned particle (inverse mass 0) is matched by its type's mass.
  const auto mass_of = [&](int i) {
    const double w = sc.state.inv_mass[i];
    return w > 0.0 ? 1.0 / w : sc.types[static_cast<size_t>(sc.particle_type[static_cast<size_t>(i)])].mass;
  };
  const auto listed = [&](double m) {
    return std::any_of(masses.begin(), masses.end(), [m](double l) { return std::abs(l - m) <= kMassDelta; });
  };
  std::string list;
  for (const double m : masses) list += (list.empty() ? "" : ", ") + format_number(m);
  list = "[" + list + "]";
  // Per bond type: a bond selected and a bond not selected (−1: none).
  const size_t ntypes = top.bond_types.size();
  std::vector<int> selected(ntypes, -1), unselected(ntypes, -1);
  for (size_t k = 0; k < top.bonds.size(); ++k) {
    const Bond& b = top.bonds[k];
    auto& slot = listed(mass_of(b.i)) || listed(mass_of(b.j)) ? selected : unselected;
    if (slot[static_cast<size_t>(b.type)] < 0) slot[static_cast<size_t>(b.type)] = static_cast<int>(k);
  }
  const auto bond_text = [&](int k) {
    const Bond& b = top.bonds[static_cast<size_t>(k)];
    return "particles " + std::to_string(b.i) + " and " + std::to_string(b.j) + ", masses " +
           format_number(mass_of(b.i)) + " and " + format_number(mass_of(b.j));
  };
  if (std::all_of(selected.begin(), selected.end(), [](int k) { return k < 0; }))
    t.fail("masses", "no bond has a particle of mass within " + format_number(kMassDelta) + " of " + list +
                         "; expected at least one bond to make rigid");
  const TypeKind kind = bond_kind(ctx);
  const bool from_data = !sc.lammps_data_coeffs.file.empty();
  for (size_t type = 0; type < ntypes; ++type) {
    if (selected[type] < 0 || index[type] >= 0) continue;  // none selected, or named in bond_types
    const std::string name = "bond type '" + top.bond_types[type] + "'";
    if (unselected[type] >= 0)
      t.fail("masses", name + " has bonds with a particle of mass within " + format_number(kMassDelta) + " of " + list +
                           " (" + bond_text(selected[type]) + ") and bonds without (" + bond_text(unselected[type]) +
                           "); this term makes whole bond types rigid: give the selected bonds a bond type of "
                           "their own, or name the type in bond_types to make all of its bonds rigid");
    if (!ctx.bond_type_owner[type].empty())
      t.fail("masses", name + " (" + bond_text(selected[type]) + ") is already defined by [forces." +
                           ctx.bond_type_owner[type] + "]");
    if (!from_data || type >= kind.numbers.size() || kind.numbers[type].empty())
      t.fail("masses", name + " is selected by mass (" + bond_text(selected[type]) +
                           ") but has no length: expected bond_types." + top.bond_types[type] +
                           " = { length, alpha }, or the type imported from a LAMMPS data file with its Bond Coeffs "
                           "row 'K r0'");
    const std::vector<double> v = data_row(t, "masses", "masses", ctx, kind, DataRow{"harmonic", "K r0"}, type);
    const std::string where = sc.lammps_data_coeffs.file + ": Bond Coeffs: bond type " +
                              std::to_string(kind.numbers[type][0]) + " (selected by mass)";
    t.require(std::isfinite(v[0]) && v[0] > 0.0, "masses",
              where + ": expected K > 0 for a rigid bond, got " + format_number(v[0]));
    t.require(std::isfinite(v[1]) && v[1] > 0.0, "masses",
              where + ": expected r0 > 0 for a rigid bond, got " + format_number(v[1]));
    t.require(std::isfinite(v[0] * v[1] * v[1]), "masses",
              where + ": the energy K r0^2 of the stiff potential overflows; expected a smaller K");
    StiffBond c;
    c.length = v[1];
    c.alpha = epsilon * std::sqrt(2.0 * v[0]);
    ctx.bond_type_owner[type] = term;
    index[type] = static_cast<int>(coeffs.size());
    coeffs.push_back(c);
  }
}

// stiff-harmonic: epsilon; bond_types.TYPE = {length, alpha}; angle_types.TYPE = {theta0, alpha};
// masses = [m, …] (add_bonds_by_mass).
std::unique_ptr<ForceTerm> read_stiff_harmonic(const std::string& name, Level level, DeckTable& t, TermContext& ctx) {
  StiffBonds sb;
  sb.epsilon = read(t, "epsilon", kPositive);
  // LAMMPS's fix shake/rattle tolerance for the rigid methods' SHAKE (StiffBonds::shake_tolerance);
  // absent: SHAKE iterates to max |g| <= 1e-12.
  if (t.has("shake_tolerance")) sb.shake_tolerance = read(t, "shake_tolerance", kPositive);
  std::vector<StiffBond> coeffs;
  // The bond types named in bond_types (required unless masses selects the bonds), then those of
  // the bonds selected by mass.
  const bool by_mass = t.has("masses");
  auto index = by_mass && !t.has("bond_types")
                   ? std::vector<int>(ctx.scene.topology.bond_types.size(), -1)
                   : claim_types(
                         t, "bond_types", ctx.scene.topology.bond_types, ctx.bond_type_owner, name,
                         [&sb](DeckTable& bt) {
                           StiffBond c;
                           c.length = read(bt, "length", kLength);
                           c.alpha = read(bt, "alpha", kPositive);
                           // The spring constant (α/ε)² and the energy ½(α/ε)²ℓ² of a bond stretched by its length
                           // must be finite doubles: else the first force evaluation overflows (exit 3 at step 1).
                           const double k = (c.alpha / sb.epsilon) * (c.alpha / sb.epsilon);
                           bt.require(std::isfinite(0.5 * k * c.length * c.length), "alpha",
                                      "the spring constant (alpha/epsilon)^2 = (" + format_number(c.alpha) + "/" +
                                          format_number(sb.epsilon) +
                                          ")^2 times length^2 overflows; expected a smaller alpha/epsilon");
                           return c;
                         },
                         coeffs);
  if (by_mass) add_bonds_by_mass(t, ctx, name, sb.epsilon, index, coeffs);
  // LAMMPS bond_style harmonic: E = K(r − r0)², K = ½(α/ε)².
  note_lammps(ctx.lammps ? &ctx.lammps->bond : nullptr, "harmonic", index, coeffs, [&sb](const StiffBond& c) {
    return numbers({0.5 * (c.alpha / sb.epsilon) * (c.alpha / sb.epsilon), c.length});
  });
  // The term's description (StiffBondRule): the whole list is made by it here, and a decomposed
  // run's part makes its own by it from the part's topology (StiffHarmonicBond::on_subset).
  StiffBondRule rule;
  rule.bond_claim = index;
  rule.bond_coeffs = coeffs;
  rule.add_claimed_bonds(ctx.scene.topology, sb.bonds);
  std::vector<int> type_of;  // the scene's bond type of each stiff bond, for the message
  for (const Bond& b : ctx.scene.topology.bonds)
    if (index[static_cast<size_t>(b.type)] >= 0) type_of.push_back(b.type);
  add_rigid_angles(t, ctx, sb, rule, type_of);
  // The rules the constraint toolbox and the stiff modes will enforce (forcefields/stiff_bond.hpp),
  // checked now with the masses, so that a deck no run could use is refused at load.
  if (const auto problem = find_stiff_bond_problem(sb.bonds, &ctx.scene.state.inv_mass)) {
    const std::string type = problem->bond < 0 ? ""
                             : type_of[problem->bond] < 0
                                 ? " (a rigid angle's bond, angle_types)"
                                 : " (bond type '" + ctx.scene.topology.bond_types[type_of[problem->bond]] + "')";
    t.fail(by_mass && !t.has("bond_types") ? "masses" : "bond_types", problem->what + type);
  }
  auto term = std::make_unique<StiffHarmonicBond>(name, level, std::move(sb));
  term->set_rule(std::move(rule));
  return term;
}

// The LAMMPS rows of the bond kernels: bond_style fene K R0 epsilon sigma, morse D0 alpha r0.
std::string lammps_row(const Fene::Coeffs& c) {
  return numbers({c.K, c.R0, c.epsilon, c.sigma});
}
std::string lammps_row(const Morse::Coeffs& c) {
  return numbers({c.D0, c.alpha, c.r0});
}

// Bond styles (BondTerm over a kernel of forcefields/bond_potentials.hpp): bond_types.TYPE =
// {coefficients}, each read by `coeffs` from its table.
template <class Kernel, typename Kernel::Coeffs (*coeffs)(DeckTable&)>
std::unique_ptr<ForceTerm> read_bond(const std::string& name, Level level, DeckTable& t, TermContext& ctx) {
  std::vector<typename Kernel::Coeffs> types;
  const auto index =
      claim_types(t, "bond_types", ctx.scene.topology.bond_types, ctx.bond_type_owner, name, coeffs, types);
  note_lammps(ctx.lammps ? &ctx.lammps->bond : nullptr, std::string(Kernel::kStyle), index, types,
              [](const typename Kernel::Coeffs& c) { return lammps_row(c); });
  // A bond that starts outside the kernel's domain (FENE: r >= R0) is refused by read_forces
  // (engine/scene/scene.cpp, check_initial_state), as every term's initial state is.
  return claiming<BondTerm<Kernel>>(index, name, level, claimed(ctx.scene.topology.bonds, index), types);
}

// fene: {K, R0, epsilon = 0, sigma = 1} (LAMMPS bond_style fene).
Fene::Coeffs fene_coeffs(DeckTable& d) {
  return {read(d, "K", kStiffness), read(d, "R0", kLength), read(d, "epsilon", kEnergy, 0.0),
          read(d, "sigma", kLength, 1.0)};
}

// morse: {D0, alpha, r0} (LAMMPS bond_style morse).
Morse::Coeffs morse_coeffs(DeckTable& d) {
  return {read(d, "D0", kEnergy), read(d, "alpha", kInverseLength), read(d, "r0", kLength)};
}

// harmonic-bond: bond_types.TYPE = {k, r0}, E = ½k(r − r0)²; or coefficients = "data" (LAMMPS
// bond_style harmonic rows 'K r0', E = K(r − r0)²: k = 2K).
HarmonicBond::Coeffs harmonic_bond_coeffs(DeckTable& d) {
  return {read(d, "k", kStiffness), read(d, "r0", kLength)};
}
std::unique_ptr<ForceTerm> read_harmonic_bond(const std::string& name, Level level, DeckTable& t, TermContext& ctx) {
  std::vector<HarmonicBond::Coeffs> types;
  const auto index = claim_kind(
      t, ctx, bond_kind(ctx), name, harmonic_bond_coeffs, DataRow{"harmonic", "K r0"},
      [](const std::vector<double>& v) {
        require(v[0], kStiffness, "K");
        require(v[1], kLength, "r0");
        return HarmonicBond::Coeffs{2.0 * v[0], v[1]};
      },
      types);
  note_lammps(ctx.lammps ? &ctx.lammps->bond : nullptr, "harmonic", index, types, [](const HarmonicBond::Coeffs& c) {
    return numbers({0.5 * c.k, c.r0});
  });
  return claiming<BondTerm<HarmonicBond>>(index, name, level, claimed(ctx.scene.topology.bonds, index), types);
}

// An angle in degrees 0 .. 180 (a deck key or a data-file column), in radians.
double angle_in_degrees(double deg, const char* what) {
  if (!(deg >= 0 && deg <= 180))
    throw std::invalid_argument(std::string(what) + ": expected an angle in degrees, 0..180, got " +
                                format_number(deg));
  return deg * M_PI / 180.0;
}

// harmonic-angle / cosine-angle: angle_types.TYPE = {k, theta0 (degrees, default 180)}; harmonic-angle
// also coefficients = "data" (LAMMPS angle_style harmonic rows 'K theta0', E = K(θ − θ0)²: k = 2K).
template <class Term>
std::unique_ptr<ForceTerm> read_angle(const std::string& name, Level level, DeckTable& t, TermContext& ctx) {
  std::vector<AngleCoeffs> coeffs;
  const auto read_one = [](DeckTable& at) {
    AngleCoeffs c;
    c.k = read(at, "k", kStiffness);
    const double deg = at.number("theta0", 180.0);
    at.require(deg >= 0 && deg <= 180, "theta0", "expected an angle in degrees, 0..180");
    c.theta0 = deg * M_PI / 180.0;
    return c;
  };
  const bool harmonic = std::is_same_v<Term, HarmonicAngle>;
  std::vector<int> index;
  if (harmonic)
    index = claim_kind(
        t, ctx, angle_kind(ctx), name, read_one, DataRow{"harmonic", "K theta0"},
        [](const std::vector<double>& v) {
          require(v[0], kStiffness, "K");
          return AngleCoeffs{2.0 * v[0], angle_in_degrees(v[1], "theta0")};
        },
        coeffs);
  else
    index = claim_types(t, "angle_types", ctx.scene.topology.angle_types, ctx.angle_type_owner, name, read_one, coeffs);
  // LAMMPS angle_style harmonic: K(θ − θ0)², K = k/2; angle_style cosine: K[1 + cos θ], which is
  // k[1 − cos(θ − θ0)] only for θ0 = 180°.
  bool straight = true;
  for (const AngleCoeffs& c : coeffs) straight &= std::abs(c.theta0 - M_PI) < 1e-12;
  const std::string style = harmonic ? "harmonic" : straight ? "cosine" : "";
  note_lammps(ctx.lammps ? &ctx.lammps->angle : nullptr, style, index, coeffs, [harmonic](const AngleCoeffs& c) {
    return harmonic ? numbers({0.5 * c.k, c.theta0 * 180.0 / M_PI}) : numbers({c.k});
  });
  return claiming<Term>(index, name, level, claimed(ctx.scene.topology.angles, index), coeffs);
}

// charmm-angle: angle_types.TYPE = {K, theta0 (degrees), K_UB = 0, r_UB = 0} or coefficients =
// "data", both LAMMPS angle_style charmm's coefficients: E = K(θ − θ0)² + K_UB(r13 − r_UB)².
CharmmAngleCoeffs charmm_angle_of(double K, double theta0_deg, double K_ub, double r_ub) {
  require(K, kStiffness, "K");
  require(K_ub, kStiffness, "K_UB");
  if (!(std::isfinite(r_ub) && r_ub >= 0))
    throw std::invalid_argument("r_UB: expected a length >= 0, got " + format_number(r_ub));
  return {K, angle_in_degrees(theta0_deg, "theta0"), K_ub, r_ub};
}
std::unique_ptr<ForceTerm> read_charmm_angle(const std::string& name, Level level, DeckTable& t, TermContext& ctx) {
  std::vector<CharmmAngleCoeffs> coeffs;
  const auto index = claim_kind(
      t, ctx, angle_kind(ctx), name,
      [](DeckTable& at) {
        const double K = read(at, "K", kStiffness), deg = at.number("theta0");
        at.require(deg >= 0 && deg <= 180, "theta0", "expected an angle in degrees, 0..180");
        const double K_ub = read(at, "K_UB", kStiffness, 0.0), r_ub = at.number("r_UB", 0.0);
        at.require(std::isfinite(r_ub) && r_ub >= 0, "r_UB", "expected a length >= 0");
        return charmm_angle_of(K, deg, K_ub, r_ub);
      },
      DataRow{"charmm", "K theta0 K_UB r_UB"},
      [](const std::vector<double>& v) { return charmm_angle_of(v[0], v[1], v[2], v[3]); }, coeffs);
  note_lammps(ctx.lammps ? &ctx.lammps->angle : nullptr, "charmm", index, coeffs, [](const CharmmAngleCoeffs& c) {
    return numbers({c.K, c.theta0 * 180.0 / M_PI, c.K_ub, c.r_ub});
  });
  return claiming<CharmmAngle>(index, name, level, claimed(ctx.scene.topology.angles, index), coeffs);
}

// The LAMMPS dihedral styles of the same form: harmonic K d n, multi/harmonic A1..A5, opls K1..K4.
std::string lammps_dihedral_style(const HarmonicDihedralKernel::Coeffs&) {
  return "harmonic";
}
std::string lammps_dihedral_style(const MultiHarmonicDihedralKernel::Coeffs&) {
  return "multi/harmonic";
}
std::string lammps_dihedral_style(const OplsDihedralKernel::Coeffs&) {
  return "opls";
}
std::string lammps_row(const HarmonicDihedralKernel::Coeffs& c) {
  return numbers({c.K}) + " " + std::to_string(c.d) + " " + std::to_string(c.n);
}
std::string lammps_row(const MultiHarmonicDihedralKernel::Coeffs& c) {
  return numbers({c.A[0], c.A[1], c.A[2], c.A[3], c.A[4]});
}
std::string lammps_row(const OplsDihedralKernel::Coeffs& c) {
  return numbers({c.K[0], c.K[1], c.K[2], c.K[3]});
}

// Dihedral styles (DihedralTerm over a kernel of forcefields/dihedral_terms.hpp):
// dihedral_types.TYPE = {coefficients}, each read by `coeffs` from its table.
template <class Kernel, typename Kernel::Coeffs (*coeffs)(DeckTable&)>
std::unique_ptr<ForceTerm> read_dihedral(const std::string& name, Level level, DeckTable& t, TermContext& ctx) {
  std::vector<typename Kernel::Coeffs> types;
  const auto index =
      claim_types(t, "dihedral_types", ctx.scene.topology.dihedral_types, ctx.dihedral_type_owner, name, coeffs, types);
  note_lammps(ctx.lammps ? &ctx.lammps->dihedral : nullptr, lammps_dihedral_style(typename Kernel::Coeffs{}), index,
              types, [](const typename Kernel::Coeffs& c) { return lammps_row(c); });
  return claiming<DihedralTerm<Kernel>>(index, name, level, claimed(ctx.scene.topology.dihedrals, index), types);
}

// harmonic-dihedral: {K, d = +1|-1, n >= 0} (LAMMPS dihedral_style harmonic).
HarmonicDihedralKernel::Coeffs harmonic_dihedral_coeffs(DeckTable& d) {
  HarmonicDihedralKernel::Coeffs c;
  c.K = read(d, "K", kTorsionEnergy);
  const long sign = d.integer("d");
  d.require(sign == 1 || sign == -1, "d", "expected +1 or -1");
  c.d = static_cast<int>(sign);
  const long n = d.integer("n");
  d.require(n >= 0 && n <= 12, "n", "expected a multiplicity 0 .. 12");
  c.n = static_cast<int>(n);
  return c;
}

// multi-harmonic-dihedral: {A1, …, A5} (LAMMPS dihedral_style multi/harmonic), each default 0.
MultiHarmonicDihedralKernel::Coeffs multi_harmonic_dihedral_coeffs(DeckTable& d) {
  MultiHarmonicDihedralKernel::Coeffs c;
  for (int n = 0; n < 5; ++n)
    c.A[n] = read(d, std::array<const char*, 5>{"A1", "A2", "A3", "A4", "A5"}[n], kTorsionEnergy, 0.0);
  return c;
}

// opls-dihedral: {K1, …, K4} (LAMMPS dihedral_style opls), each default 0.
OplsDihedralKernel::Coeffs opls_dihedral_coeffs(DeckTable& d) {
  OplsDihedralKernel::Coeffs c;
  for (int n = 0; n < 4; ++n)
    c.K[n] = read(d, std::array<const char*, 4>{"K1", "K2", "K3", "K4"}[n], kTorsionEnergy, 0.0);
  return c;
}

// Mixing rules (LAMMPS pair_modify mix): the coefficients of an unlike pair from those of its two
// types. Both rules take ε_ab = √(ε_a ε_b); a length (σ, and the cutoff, as LAMMPS's lj/cut
// init_one mixes cut[i][i] and cut[j][j] with mix_distance) is √(σ_a σ_b) under "geometric"
// (LAMMPS's default) and (σ_a + σ_b)/2 under "arithmetic" (Lorentz–Berthelot). Checked with lmp
// (29 Sep 2021): per-type cutoffs 2 and 3, a 1-2 pair at r = 2.47 interacts under arithmetic
// (cut 2.5) and not under geometric (cut √6).
enum class Mix { geometric, arithmetic };
double mix_energy(double a, double b) {
  return std::sqrt(a * b);
}
double mix_length(double a, double b, Mix m) {
  return m == Mix::geometric ? std::sqrt(a * b) : 0.5 * (a + b);
}
// charmm-dihedral: dihedral_types.TYPE = {K, n, d, w} or coefficients = "data" (LAMMPS dihedral_style
// charmm's 'K n d w': n >= 0 and d integers, d in degrees, w the 1-4 weight 0 .. 1), and
// lj14 = { TYPE = { epsilon, sigma } } per particle type, mixed as lj/charmm/coul/charmm mixes its
// 1-4 coefficients (arithmetic: ε = √(ε_a ε_b), σ = (σ_a + σ_b)/2); needed for the particle types at
// the ends of the dihedrals with w > 0.
CharmmDihedralKernel::Coeffs charmm_dihedral_of(double K, int n, int d, double w) {
  require(K, kTorsionEnergy, "K");
  if (n < 0 || n > 12) throw std::invalid_argument("n: expected a multiplicity 0 .. 12, got " + std::to_string(n));
  if (d < -360 || d > 360)
    throw std::invalid_argument("d: expected a phase in degrees -360 .. 360, got " + std::to_string(d));
  if (!(w >= 0.0 && w <= 1.0)) throw std::invalid_argument("w: expected a weight 0 .. 1, got " + format_number(w));
  return {K, n, d, w};
}
// The particles' charges for the 1-4 Coulomb part (none in an uncharged scene: LJ 1-4 only).
std::vector<double> particle_charges(const Scene& sc) {
  return sc.charged() ? sc.charge : std::vector<double>();
}
std::unique_ptr<ForceTerm> read_charmm_dihedral(const std::string& name, Level level, DeckTable& t, TermContext& ctx) {
  const Scene& sc = ctx.scene;
  std::vector<CharmmDihedralKernel::Coeffs> coeffs;
  const auto index = claim_kind(
      t, ctx, dihedral_kind(ctx), name,
      [](DeckTable& d) {
        const double K = read(d, "K", kTorsionEnergy);
        const long n = d.integer("n");
        d.require(n >= 0 && n <= 12, "n", "expected a multiplicity 0 .. 12");
        const long phase = d.integer("d");
        d.require(phase >= -360 && phase <= 360, "d", "expected a phase in integer degrees -360 .. 360");
        const double w = d.number("w");
        d.require(w >= 0 && w <= 1, "w", "expected a weight 0 .. 1 (LAMMPS's weighting factor of the 1-4 pair)");
        return charmm_dihedral_of(K, static_cast<int>(n), static_cast<int>(phase), w);
      },
      DataRow{"charmm", "K n d w"},
      [](const std::vector<double>& v) {
        return charmm_dihedral_of(v[0], data_integer(v[1], "n"), data_integer(v[2], "d"), v[3]);
      },
      coeffs);
  note_lammps(ctx.lammps ? &ctx.lammps->dihedral : nullptr, "charmm", index, coeffs,
              [](const CharmmDihedralKernel::Coeffs& c) {
                return numbers({c.K}) + " " + std::to_string(c.n) + " " + std::to_string(c.d) + " " + numbers({c.w});
              });
  const std::vector<Dihedral> dihedrals = claimed(sc.topology.dihedrals, index);
  // The per-type 1-4 coefficients, and which particle types need them.
  const int ntypes = static_cast<int>(sc.types.size());
  std::vector<std::optional<Lj14>> own(static_cast<size_t>(ntypes));
  if (auto table = t.table("lj14")) {
    for (auto& [type_name, tt] : table->named_tables()) {
      int k = -1;
      for (int q = 0; q < ntypes; ++q)
        if (sc.types[q].name == type_name) k = q;
      if (k < 0) table->fail(type_name, "unknown particle type '" + type_name + "'");
      own[static_cast<size_t>(k)] = Lj14{read(tt, "epsilon", kEnergy), read(tt, "sigma", kLength)};
      tt.finish();
    }
    table->finish();
  }
  for (const Dihedral& d : dihedrals)
    if (coeffs[static_cast<size_t>(d.type)].w > 0.0)
      for (const int end : {d.i, d.l}) {
        const int k = sc.particle_type[end];
        if (own[static_cast<size_t>(k)]) continue;
        const std::string what = "no 1-4 coefficients for particle type '" + sc.types[k].name + "' (particle " +
                                 std::to_string(end) + ", an end of a dihedral with w > 0); expected " +
                                 t.key_path("lj14") + "." + sc.types[k].name + " = { epsilon = …, sigma = … }";
        if (t.has("lj14")) t.fail("lj14", what);
        t.fail_here(what);
      }
  TypePairMatrix<Lj14> lj14(ntypes);
  for (int a = 0; a < ntypes; ++a)
    for (int b = a; b < ntypes; ++b)
      if (own[a] && own[b])
        lj14.set(a, b,
                 Lj14{mix_energy(own[a]->epsilon, own[b]->epsilon),
                      mix_length(own[a]->sigma, own[b]->sigma, Mix::arithmetic)});
  std::vector<int> types(sc.particle_type.begin(), sc.particle_type.end());
  return claiming<CharmmDihedral>(index, name, level, dihedrals, coeffs, std::move(types), std::move(lj14),
                                  particle_charges(sc), sc.units.coulomb);
}

// harmonic-improper: improper_types.TYPE = {K, chi0 (degrees)}; cvff-improper: {K, d = +1|-1, n};
// umbrella-improper: {K, omega0 (degrees)}; each LAMMPS's improper style of the same name, or
// coefficients = "data" (its rows 'K chi0', 'K d n', 'K omega0').
HarmonicImproperKernel::Coeffs harmonic_improper_of(double K, double chi0_deg) {
  require(K, kStiffness, "K");
  return {K, angle_in_degrees(chi0_deg, "chi0")};
}
UmbrellaCoeffs umbrella_of(double K, double omega0_deg) {
  require(K, kStiffness, "K");
  if (!(omega0_deg >= 0 && omega0_deg <= 90))
    throw std::invalid_argument("omega0: expected an angle in degrees, 0..90, got " + format_number(omega0_deg));
  return {K, omega0_deg * M_PI / 180.0};
}
template <class Term, class Read, class Make>
std::unique_ptr<ForceTerm> read_improper_term(const std::string& name, Level level, DeckTable& t, TermContext& ctx,
                                              const char* lammps_style, const char* layout, Read read_one, Make make,
                                              std::string (*row)(const typename Term::Coeffs&)) {
  std::vector<typename Term::Coeffs> coeffs;
  const auto index =
      claim_kind(t, ctx, improper_kind(ctx), name, read_one, DataRow{lammps_style, layout}, make, coeffs);
  note_lammps(ctx.lammps ? &ctx.lammps->improper : nullptr, lammps_style, index, coeffs, row);
  return claiming<Term>(index, name, level, claimed(ctx.scene.topology.impropers, index), coeffs);
}
std::unique_ptr<ForceTerm> read_harmonic_improper(const std::string& name, Level level, DeckTable& t,
                                                  TermContext& ctx) {
  return read_improper_term<HarmonicImproper>(
      name, level, t, ctx, "harmonic", "K chi0",
      [](DeckTable& d) {
        const double K = read(d, "K", kStiffness), deg = d.number("chi0");
        d.require(deg >= 0 && deg <= 180, "chi0", "expected an angle in degrees, 0..180");
        return harmonic_improper_of(K, deg);
      },
      [](const std::vector<double>& v) { return harmonic_improper_of(v[0], v[1]); },
      [](const HarmonicImproperKernel::Coeffs& c) {
        return numbers({c.K, c.chi0 * 180.0 / M_PI});
      });
}
std::unique_ptr<ForceTerm> read_cvff_improper(const std::string& name, Level level, DeckTable& t, TermContext& ctx) {
  return read_improper_term<CvffImproper>(
      name, level, t, ctx, "cvff", "K d n", harmonic_dihedral_coeffs,
      [](const std::vector<double>& v) {
        HarmonicDihedralKernel::Coeffs c{v[0], data_integer(v[1], "d"), data_integer(v[2], "n")};
        HarmonicDihedralKernel::validate(c);
        if (c.n > 6)
          throw std::invalid_argument("n: expected a multiplicity 0 .. 6 (LAMMPS's cvff), got " + std::to_string(c.n));
        return c;
      },
      [](const HarmonicDihedralKernel::Coeffs& c) { return lammps_row(c); });
}
std::unique_ptr<ForceTerm> read_umbrella_improper(const std::string& name, Level level, DeckTable& t,
                                                  TermContext& ctx) {
  return read_improper_term<UmbrellaImproper>(
      name, level, t, ctx, "umbrella", "K omega0",
      [](DeckTable& d) {
        const double K = read(d, "K", kStiffness), deg = d.number("omega0");
        d.require(deg >= 0 && deg <= 90, "omega0", "expected an angle in degrees, 0..90");
        return umbrella_of(K, deg);
      },
      [](const std::vector<double>& v) { return umbrella_of(v[0], v[1]); },
      [](const UmbrellaCoeffs& c) {
        return numbers({c.K, c.omega0 * 180.0 / M_PI});
      });
}

// Particles an external term acts on: particles = [i, …], or type = "NAME", or all. The term's
// selection (ParticleSelection: what a decomposed run's part selects from its own particles) and
// the whole system's list: the deck's indices in its order, or the selection on every particle.
struct Selected {
  ParticleSelection selection;
  std::vector<int> particles;
};
Selected selected_particles(DeckTable& t, const Scene& sc) {
  Selected out;
  ParticleSelection& sel = out.selection;
  if (t.has("particles") && t.has("type")) t.fail("type", "give either particles or type, not both");
  if (t.has("particles")) {
    sel.kind = ParticleSelection::Kind::listed;
    const std::vector<long> ids = t.integers("particles");
    for (long i : ids) {
      if (i < 0 || i >= sc.state.size()) t.fail("particles", "particle " + std::to_string(i) + " does not exist");
      sel.listed.push_back(static_cast<int>(i));
    }
    out.particles = sel.listed;
  } else {
    if (t.has("type")) {
      const std::string type = t.name("type");
      int k = -1;
      for (size_t m = 0; m < sc.types.size(); ++m)
        if (sc.types[m].name == type) k = static_cast<int>(m);
      if (k < 0) t.fail("type", "unknown particle type '" + type + "'");
      sel.kind = ParticleSelection::Kind::type;
      sel.type = k;
    }
    std::vector<int> every(static_cast<size_t>(sc.state.size()));
    for (int i = 0; i < sc.state.size(); ++i) every[static_cast<size_t>(i)] = i;
    out.particles = sel.on(ParticleSubset{every, sc.particle_type, sc.topology});
  }
  if (out.particles.empty()) t.fail(t.has("type") ? "type" : "particles", "selects no particle");
  return out;
}

// harmonic-tether: k, center = [x, y, z], particles or type.
std::unique_ptr<ForceTerm> read_tether(const std::string& name, Level level, DeckTable& t, TermContext& ctx) {
  const double k = read(t, "k", kStiffness);
  const Eigen::Vector3d c = t.vector3("center");
  Selected sel = selected_particles(t, ctx.scene);
  auto term = std::make_unique<HarmonicTether>(name, level, std::move(sel.particles), c, k);
  term->set_selection(std::move(sel.selection));
  return term;
}

// lj93-wall: axis = "x"|"y"|"z", position, side = 1 | -1, epsilon, sigma, cutoff, particles or type.
std::unique_ptr<ForceTerm> read_wall(const std::string& name, Level level, DeckTable& t, TermContext& ctx) {
  LJ93WallParams p;
  const std::string axis = t.string("axis");
  if (axis != "x" && axis != "y" && axis != "z") t.fail("axis", "expected \"x\", \"y\" or \"z\"");
  p.axis = axis[0] - 'x';
  if (ctx.scene.box.periodic[p.axis])
    t.fail("axis", "the box is periodic along " + axis + ": a wall there has no meaning");
  p.position = t.number("position");
  const long side = t.integer("side", 1);  // checked before the conversion to int
  t.require(side == 1 || side == -1, "side", "expected 1 (particles above the wall) or -1 (below)");
  p.side = static_cast<int>(side);
  p.epsilon = read(t, "epsilon", kEnergy, p.epsilon);
  p.sigma = read(t, "sigma", kLength, p.sigma);
  p.cutoff = read(t, "cutoff", kLength, p.cutoff);
  Selected sel = selected_particles(t, ctx.scene);
  auto term = std::make_unique<LJ93Wall>(name, level, p, std::move(sel.particles));
  term->set_selection(std::move(sel.selection));
  return term;
}

// The neighbour list needs every periodic box length >= 2 (cutoff + skin) (check_box_for_cutoff):
// an error at the key that sets the range (`range_key`: cutoff, or sigma for wca), naming the box.
template <class Kernel>
void check_box_for_pairs(DeckTable& t, const TypePairMatrix<typename Kernel::Coeffs>& coeffs, double skin,
                         const Scene& sc, const char* range_key) {
  double rc = 0.0;
  for (int a = 0; a < coeffs.num_types(); ++a)
    for (int b = a; b < coeffs.num_types(); ++b) {
      try {
        Kernel::validate(coeffs(a, b));
      } catch (const std::invalid_argument&) {
        return;  // the term's constructor names the bad coefficient
      }
      rc = std::max(rc, Kernel::cutoff(coeffs(a, b)));
    }
  const double need = 2.0 * (rc + skin);
  for (int a = 0; a < 3; ++a)
    if (sc.box.periodic[a] && !(sc.box.lengths[a] >= need)) {
      const char axis = static_cast<char>('x' + a);
      const std::string what =
          std::string("cutoff ") + format_number(rc) + " + skin " + format_number(skin) + ": the periodic box is " +
          format_number(sc.box.lengths[a]) + " long on " + axis + " (" +
          (sc.box_from_source ? "set by a [[build]] density or the [import]" : "box.lengths") +
          "), but the neighbour list needs every periodic length >= 2 × (cutoff + skin) = " + format_number(need) +
          "; enlarge the box or reduce " + t.key_path(range_key) + " or " + t.key_path("skin");
      if (t.has(range_key)) t.fail(range_key, what);
      if (t.has("skin")) t.fail("skin", what);
      t.fail_here(what);
    }
}

// Two particles closer than this fraction of the pair cutoff (in practice: at the same position)
// make a pair force singular — for `soft` too, whose force has no direction at r = 0.
constexpr double kOverlapFraction = 1e-6;
// A kernel with a core length σ (lj, wca) cannot bear a pair closer than σ/2: there
// E = 4ε[(σ/r)¹² − (σ/r)⁶] ≥ 4ε(2¹² − 2⁶) ≈ 1.6e4 ε and |F| ≥ 24ε(2·2¹² − 2⁶)·2/σ ≈ 3.9e5 ε/σ, so the
// first step throws the pair apart at a speed no step resolves (with stiff bonds SHAKE then fails
// to converge). A melt at kT ≤ 10 ε comes there with probability e^(−1600): no thermal state is
// refused. Builders keep their own beads min_distance (0.8 σ by default) apart, but not from
// another source's, hence the check on the scene as assembled.
constexpr double kCoreFraction = 0.5;

// The distance below which a pair of the kernel counts as overlapping at the start.
template <class Kernel>
double overlap_distance(const typename Kernel::Coeffs& c) {
  double d = kOverlapFraction * Kernel::cutoff(c);
  if constexpr (requires { c.sigma; })
    if (!requires { c.epsilon; } || c.epsilon > 0.0) d = std::max(d, kCoreFraction * c.sigma);
  return d;
}

// The kernel's overlap rule for every pair of types (overlap_rule.hpp), the term's `where` and name.
template <class Kernel>
OverlapRule overlap_rule(DeckTable& t, const std::string& name, const TypePairMatrix<typename Kernel::Coeffs>& coeffs) {
  OverlapRule rule{t.where(), name, coeffs.num_types(), {}, {}};
  for (int a = 0; a < coeffs.num_types(); ++a)
    for (int b = 0; b < coeffs.num_types(); ++b) {
      const auto& c = coeffs(a, b);
      const double limit = overlap_distance<Kernel>(c);
      std::string why;
      if constexpr (requires { c.sigma; })
        why = limit > kOverlapFraction * Kernel::cutoff(c)
                  ? "sigma/2 = " + format_number(limit) + " (the pair energy there is above 1.6e4 epsilon)"
                  : "";
      if (why.empty())
        why = format_number(kOverlapFraction) + " x cutoff " + format_number(Kernel::cutoff(c)) +
              " (the pair force there is singular)";
      rule.below.push_back(limit);
      rule.rule.push_back(std::move(why));
    }
  return rule;
}

// Overlapping particles at the start, with every pair the term acts on (special weight ≠ 0)
// considered: an error naming the closest two and the sources they came from.
void check_overlaps(DeckTable& t, const OverlapRule& rule, SpecialWeights w, const Scene& sc, std::string* found) {
  const int n = sc.state.size();
  std::vector<std::pair<int, int>> excluded;
  for (const SpecialPair& sp : special_pairs(n, sc.topology.bonds, w))
    if (sp.weight == 0.0) excluded.emplace_back(std::min(sp.i, sp.j), std::max(sp.i, sp.j));
  std::sort(excluded.begin(), excluded.end());
  long overlapping = 0;
  int ci = -1, cj = -1;
  double closest = 0.0;
  close_pairs(sc.state.x, sc.box, rule.range(), [&](int i, int j, double r) {
    const double below = rule.distance(sc.particle_type[i], sc.particle_type[j]);
    if (!(r < below) || std::binary_search(excluded.begin(), excluded.end(), std::pair{i, j})) return;
    ++overlapping;
    if (ci < 0 || r < closest || (r == closest && std::pair{i, j} < std::pair{ci, cj})) ci = i, cj = j, closest = r;
  });
  if (ci < 0) return;
  const std::string what = overlap_message(rule, particle_and_source(sc, ci), particle_and_source(sc, cj), closest,
                                           sc.particle_type[ci], sc.particle_type[cj], overlapping);
  if (!found) t.fail_here(what);
  if (found->empty()) found->assign(t.where() + ": " + what);  // the first term's finding
}

// The LAMMPS pair styles of the same form, cut and shifted as stiffmd's (with pair_modify shift
// yes): lj/cut ε σ rc (wca: rc = 2^(1/6) σ), soft A rc, yukawa A rc (κ in pair_style). Returns
// the style and sets `row`.
std::string lammps_pair(const LennardJones::Coeffs& c, std::string& row) {
  row = numbers({c.epsilon, c.sigma, c.rc});
  return "lj/cut";
}
std::string lammps_pair(const WeeksChandlerAndersen::Coeffs& c, std::string& row) {
  row = numbers({c.epsilon, c.sigma, WeeksChandlerAndersen::cutoff(c)});
  return "lj/cut";
}
std::string lammps_pair(const SoftCosine::Coeffs& c, std::string& row) {
  row = numbers({c.A, c.rc});
  return "soft";
}
std::string lammps_pair(const Yukawa::Coeffs& c, std::string& row) {
  row = numbers({c.A, c.rc});
  return "yukawa";
}
// The charged styles: LAMMPS's own names; PairIJ Coeffs rows as pair_coeff i j takes them.
std::string lammps_pair(const CoulombCut::Coeffs& c, std::string& row) {
  row = numbers({c.coulomb_cutoff});
  return "coul/cut";
}
std::string lammps_pair(const CoulombDebye::Coeffs& c, std::string& row) {
  row = numbers({c.coulomb_cutoff});
  return "coul/debye";
}
std::string lammps_pair(const CoulombLong::Coeffs&, std::string& row) {
  row.clear();
  return "coul/long";
}
std::string lammps_pair(const LjCoulCoeffs& c, std::string& row) {
  row = numbers({c.epsilon, c.sigma, c.rc, c.coulomb_cutoff});
  return "";  // lj/cut/coul/*: the caller names it
}
std::string lammps_pair(const LjCharmmCoulLong::Coeffs& c, std::string& row) {
  row = numbers({c.epsilon, c.sigma, c.epsilon14, c.sigma14});
  return "lj/charmm/coul/long";
}

// LAMMPS special_bonds presets (special_bonds amber, charmm, dreiding, fene): {lj, coul}.
struct SpecialBondsPreset {
  const char* name;
  SpecialWeights lj, coul;
};
constexpr SpecialBondsPreset kSpecialPresets[] = {
    {"amber", {0.0, 0.0, 0.5}, {0.0, 0.0, 5.0 / 6.0}},
    {"charmm", {0.0, 0.0, 0.0}, {0.0, 0.0, 0.0}},
    {"dreiding", {0.0, 0.0, 1.0}, {0.0, 0.0, 1.0}},
    {"fene", {0.0, 1.0, 1.0}, {0.0, 1.0, 1.0}},
};

// Three weights w12, w13(, w14) in 0..1 from a list key.
SpecialWeights read_weights(DeckTable& t, const char* key, bool allow_two) {
  const auto sb = t.numbers(key);
  const bool in_range = std::all_of(sb.begin(), sb.end(), [](double x) { return x >= 0 && x <= 1; });
  if (!((sb.size() == 3) || (allow_two && sb.size() == 2)) || !in_range)
    t.fail(key, std::string(allow_two ? "expected [w12, w13] or [w12, w13, w14]" : "expected [w12, w13, w14]") +
                    ", weights in 0..1");
  return {sb[0], sb[1], sb.size() == 3 ? sb[2] : 1.0};
}

// The special-bond weights of a pair term: `special_bonds` (both the van der Waals and the Coulomb
// weights: a list [w12, w13(, w14)] or a LAMMPS preset name), then, for a charged style,
// `special_lj` and `special_coul` ([w12, w13, w14] each) over it.
std::pair<SpecialWeights, SpecialWeights> read_special_bonds(DeckTable& t, bool charged) {
  SpecialWeights lj, coul;
  if (t.has("special_bonds")) {
    if (t.is_array("special_bonds")) {
      lj = coul = read_weights(t, "special_bonds", true);
    } else {
      const std::string preset = t.string("special_bonds");
      const auto* p = std::find_if(std::begin(kSpecialPresets), std::end(kSpecialPresets),
                                   [&](const SpecialBondsPreset& q) { return preset == q.name; });
      if (p == std::end(kSpecialPresets))
        t.fail("special_bonds",
               "expected [w12, w13(, w14)] or one of \"amber\", \"charmm\", \"dreiding\", "
               "\"fene\" (LAMMPS special_bonds presets), got \"" +
                   preset + "\"");
      lj = p->lj, coul = p->coul;
    }
  }
  if (charged && t.has("special_lj")) lj = read_weights(t, "special_lj", false);
  if (charged && t.has("special_coul")) coul = read_weights(t, "special_coul", false);
  if (!charged) coul = lj;
  return {lj, coul};
}

// `defaults`: the term's values where its table gives none; a [[pair]] override starts from the
// pair's values (the term's global epsilon, sigma, …, or the mixed ones), not from the defaults;
// per-type tables are mixed by mix_energy and mix_length (above).
// A style without mixing rules: the reader refuses per-type tables for it.
struct NoMixing {};

// Per type, the particles a description counts and does not load (Scene::described_sources; none
// for a whole scene): the pair terms' tail correction adds them to the loaded particles' types.
std::vector<std::int64_t> counted_particles_by_type(const Scene& sc) {
  if (sc.described_sources.empty()) return {};
  std::vector<std::int64_t> n(sc.types.size(), 0);
  for (const DescribedSource& d : sc.described_sources)
    for (std::size_t t = 0; t < d.particles_of_type.size() && t < n.size(); ++t) n[t] += d.particles_of_type[t];
  return n;
}

// Pair styles: parameters for every type pair from the term's table — or, with per-type tables
// types.NAME = {…} (a style with a `mix` function), from every type's coefficients by the mixing
// rule `mix` = "geometric" | "arithmetic" — overridden per pair by [[forces.NAME.pair]] types =
// ["A", "B"] (which then starts from the pair's mixed values); special_bonds = [w12, w13(, w14)]; skin.
template <class Kernel, class ReadCoeffs, class MixCoeffs = NoMixing>
std::unique_ptr<ForceTerm> read_pair(const std::string& name, Level level, DeckTable& t, TermContext& ctx,
                                     ReadCoeffs read_coeffs, const char* range_key,
                                     typename Kernel::Coeffs defaults = typename Kernel::Coeffs{},
                                     MixCoeffs mix_coeffs = {}, const char* default_mix = "geometric") {
  using Coeffs = typename Kernel::Coeffs;
  const Scene& sc = ctx.scene;
  const int ntypes = static_cast<int>(sc.types.size());
  TypePairMatrix<Coeffs> coeffs(ntypes);
  const Coeffs global = read_coeffs(t, defaults);
  for (int a = 0; a < ntypes; ++a)
    for (int b = a; b < ntypes; ++b) coeffs.set(a, b, global);
  if constexpr (std::is_same_v<MixCoeffs, NoMixing>) {
    (void)mix_coeffs;
  } else if (auto per_type = t.table("types")) {
    const std::string rule = t.string("mix", default_mix);
    if (rule != "geometric" && rule != "arithmetic")
      t.fail("mix", "expected \"geometric\" or \"arithmetic\" (LAMMPS pair_modify mix), got \"" + rule + "\"");
    const Mix m = rule == "geometric" ? Mix::geometric : Mix::arithmetic;
    std::vector<std::optional<Coeffs>> own(static_cast<size_t>(ntypes));
    for (auto& [type_name, tt] : per_type->named_tables()) {
      int k = -1;
      for (int q = 0; q < ntypes; ++q)
        if (sc.types[q].name == type_name) k = q;
      if (k < 0) per_type->fail(type_name, "unknown particle type '" + type_name + "'");
      own[static_cast<size_t>(k)] = read_coeffs(tt, global);  // a key it does not give: the term's value
      tt.finish();
    }
    for (int a = 0; a < ntypes; ++a)
      if (!own[static_cast<size_t>(a)])
        t.fail("types", "no coefficients for particle type '" + sc.types[a].name +
                            "'; with per-type tables every "
                            "type needs one (" +
                            t.key_path("types") + "." + sc.types[a].name + " = {…})");
    per_type->finish();
    for (int a = 0; a < ntypes; ++a)
      for (int b = a; b < ntypes; ++b) coeffs.set(a, b, mix_coeffs(*own[a], *own[b], m));
  } else if (t.has("mix")) {
    t.fail("mix", "a mixing rule needs per-type coefficients " + t.key_path("types") + ".NAME = {…}");
  }
  std::set<std::pair<int, int>> overridden;  // a pair given twice would silently keep the last
  for (DeckTable& p : t.array_of_tables("pair")) {
    const auto names = p.strings("types");
    if (names.size() != 2) p.fail("types", "expected two particle type names [\"A\", \"B\"]");
    int ab[2];
    for (int m = 0; m < 2; ++m) {
      ab[m] = -1;
      for (int k = 0; k < ntypes; ++k)
        if (sc.types[k].name == names[m]) ab[m] = k;
      if (ab[m] < 0) p.fail("types", "unknown particle type '" + names[m] + "'");
    }
    if (!overridden.insert({std::min(ab[0], ab[1]), std::max(ab[0], ab[1])}).second)
      p.fail("types",
             "the pair [\"" + names[0] + "\", \"" + names[1] + "\"] is overridden twice; expected one entry per pair");
    coeffs.set(ab[0], ab[1], read_coeffs(p, coeffs(ab[0], ab[1])));
    p.finish();
  }
  // LAMMPS special_bonds lj w12 w13 w14 (coul w12 w13 w14): the weights of 1-2, 1-3 and 1-4 bonded
  // pairs (default: bonded neighbours do not interact, 1-3 and 1-4 pairs do).
  const auto [w, w_coul] = read_special_bonds(t, ChargedKernel<Kernel>);
  constexpr bool kTail = PairTerm<Kernel>::kHasTail;
  const bool tail = kTail && t.boolean("tail", false);
  if (tail && !(sc.box.periodic[0] && sc.box.periodic[1] && sc.box.periodic[2]))
    t.fail("tail", "the tail correction (LAMMPS pair_modify tail yes) needs a box periodic on every axis");
  const double skin = read(t, "skin", kSkin, 0.3);
  check_box_for_pairs<Kernel>(t, coeffs, skin, sc, range_key);
  // Special bonds list the 1-3 pairs through every particle: deg·(deg − 1)/2 of them. A hub with
  // a million bonds (a few megabytes of data file) would ask for terabytes; refuse it up front.
  constexpr int kMaxBondsPerParticle = 1000;
  std::vector<int> degree(static_cast<size_t>(sc.state.size()), 0);
  for (const Bond& b : sc.topology.bonds)
    for (const int i : {b.i, b.j})
      if (++degree[static_cast<size_t>(i)] > kMaxBondsPerParticle)
        t.fail_here("particle " + std::to_string(i) + " has more than " + std::to_string(kMaxBondsPerParticle) +
                    " bonds; a pair term's special bonds (its 1-3 pairs) allow at most that many per particle");
  std::vector<int> types(sc.particle_type.begin(), sc.particle_type.end());
  Electrostatics electrostatics;
  if constexpr (ChargedKernel<Kernel>) {
    if (!sc.charged())
      t.fail_here("pair style " + std::string(Kernel::kStyle) +
                  " needs charges; every particle of this scene has charge 0 (give them in [[particles]] charge, "
                  "[types.NAME] charge or an [import] of atom_style full)");
    electrostatics = {sc.charge, sc.units.coulomb, w_coul};
  }
  std::unique_ptr<PairTerm<Kernel>> term;
  try {
    term = std::make_unique<PairTerm<Kernel>>(name, level, std::move(types), coeffs, sc.topology.bonds, w, sc.box, skin,
                                              std::move(electrostatics));
  } catch (const std::invalid_argument& e) {
    if constexpr (EwaldKernel<Kernel>)  // the one Coulomb cutoff an Ewald sum needs
      if (std::string(e.what()).find("Coulomb cutoff") != std::string::npos) t.fail("coulomb_cutoff", e.what());
    throw;
  }
  if (tail) term->set_tail(true, counted_particles_by_type(sc));
  // The term accepted the coefficients. A description (SceneContent::description) holds no
  // position of its counted chains: their overlaps are left to the run's soft start, [minimize]
  // on the parts or the deck's soft pairs (docs/parallel.md, "The start from the source's parts").
  // The rule is kept for the run, which applies it to the parts at the start.
  OverlapRule rule = overlap_rule<Kernel>(t, name, coeffs);
  if (!sc.described())
    check_overlaps(t, rule, w, sc, ctx.overlap);
  else if (ctx.overlap_rules)
    ctx.overlap_rules->push_back(std::move(rule));
  if (ctx.lammps) {  // PairIJ Coeffs: every type pair, mixed and overridden as the term uses them
    LammpsCoeffs::Section& section = ctx.lammps->pair;
    section.pairwise = true;
    std::string style;
    for (int a = 0; a < ntypes; ++a)
      for (int b = a; b < ntypes; ++b) style = lammps_pair(coeffs(a, b), section.rows[{a, b}]);
    if constexpr (std::is_same_v<Kernel, Yukawa>)  // κ is pair_style yukawa's one global argument
      for (int a = 0; a < ntypes; ++a)
        for (int b = a; b < ntypes; ++b)
          if (coeffs(a, b).kappa != coeffs(0, 0).kappa) style.clear();
    if constexpr (std::is_same_v<typename Kernel::Coeffs, LjCoulCoeffs>) {
      style = std::string(Kernel::kStyle);
      for (int a = 0; a < ntypes; ++a)  // lj/cut/coul/long: pair_coeff i j ε σ rc_lj (its rc_coul is global)
        for (int b = a; b < ntypes; ++b)
          if constexpr (EwaldKernel<Kernel>)
            section.rows[{a, b}] = numbers({coeffs(a, b).epsilon, coeffs(a, b).sigma, coeffs(a, b).rc});
    }
    section.claim(style);
  }
  return term;
}

std::unique_ptr<ForceTerm> read_lj(const std::string& name, Level level, DeckTable& t, TermContext& ctx) {
  return read_pair<LennardJones>(
      name, level, t, ctx,
      [](DeckTable& d, LennardJones::Coeffs c) {
        c.epsilon = read(d, "epsilon", kEnergy, c.epsilon);  // a per-pair override inherits the term's values
        c.sigma = read(d, "sigma", kLength, c.sigma);
        c.rc = read(d, "cutoff", kLength, c.rc);
        return c;
      },
      "cutoff", LennardJones::Coeffs{1.0, 1.0, 2.5},
      [](const LennardJones::Coeffs& a, const LennardJones::Coeffs& b, Mix m) {
        return LennardJones::Coeffs{mix_energy(a.epsilon, b.epsilon), mix_length(a.sigma, b.sigma, m),
                                    mix_length(a.rc, b.rc, m)};
      });
}

std::unique_ptr<ForceTerm> read_wca(const std::string& name, Level level, DeckTable& t, TermContext& ctx) {
  return read_pair<WeeksChandlerAndersen>(
      name, level, t, ctx,
      [](DeckTable& d, WeeksChandlerAndersen::Coeffs c) {
        c.epsilon = read(d, "epsilon", kEnergy, c.epsilon);
        c.sigma = read(d, "sigma", kLength, c.sigma);
        return c;
      },
      "sigma", WeeksChandlerAndersen::Coeffs{},
      [](const WeeksChandlerAndersen::Coeffs& a, const WeeksChandlerAndersen::Coeffs& b, Mix m) {
        return WeeksChandlerAndersen::Coeffs{mix_energy(a.epsilon, b.epsilon), mix_length(a.sigma, b.sigma, m)};
      });
}

std::unique_ptr<ForceTerm> read_soft(const std::string& name, Level level, DeckTable& t, TermContext& ctx) {
  return read_pair<SoftCosine>(
      name, level, t, ctx,
      [](DeckTable& d, SoftCosine::Coeffs c) {
        c.A = read(d, "A", kEnergy, c.A);
        c.rc = read(d, "cutoff", kLength, c.rc);
        return c;
      },
      "cutoff");
}

// yukawa: A, kappa, cutoff (LAMMPS pair_style yukawa kappa cutoff, pair_coeff A; shifted).
std::unique_ptr<ForceTerm> read_yukawa(const std::string& name, Level level, DeckTable& t, TermContext& ctx) {
  return read_pair<Yukawa>(
      name, level, t, ctx,
      [](DeckTable& d, Yukawa::Coeffs c) {
        c.A = d.number("A", c.A);  // any sign: A < 0 attracts
        c.kappa = read(d, "kappa", kInverseLength, c.kappa);
        c.rc = read(d, "cutoff", kLength, c.rc);
        return c;
      },
      "cutoff");
}

// The charged styles (forcefields/coulomb_potentials.hpp; LAMMPS's names). The Coulomb cutoff
// `coulomb_cutoff` defaults to the LJ cutoff `cutoff` (a table that gives `cutoff` alone sets both, as
// LAMMPS's pair_coeff with one cutoff); every coefficient per type pair as for lj.
std::unique_ptr<ForceTerm> read_coul_cut(const std::string& name, Level level, DeckTable& t, TermContext& ctx) {
  return read_pair<CoulombCut>(
      name, level, t, ctx,
      [](DeckTable& d, CoulombCut::Coeffs c) {
        c.coulomb_cutoff = read(d, "coulomb_cutoff", kLength, c.coulomb_cutoff);
        return c;
      },
      "coulomb_cutoff");
}

std::unique_ptr<ForceTerm> read_coul_debye(const std::string& name, Level level, DeckTable& t, TermContext& ctx) {
  return read_pair<CoulombDebye>(
      name, level, t, ctx,
      [](DeckTable& d, CoulombDebye::Coeffs c) {
        c.kappa = read(d, "kappa", kInverseLength, c.kappa);
        c.coulomb_cutoff = read(d, "coulomb_cutoff", kLength, c.coulomb_cutoff);
        return c;
      },
      "coulomb_cutoff");
}

std::unique_ptr<ForceTerm> read_coul_long(const std::string& name, Level level, DeckTable& t, TermContext& ctx) {
  return read_pair<CoulombLong>(
      name, level, t, ctx,
      [](DeckTable& d, CoulombLong::Coeffs c) {
        c.coulomb_cutoff = read(d, "coulomb_cutoff", kLength, c.coulomb_cutoff);
        return c;
      },
      "coulomb_cutoff");
}

// lj/cut/coul/cut, lj/cut/coul/debye (kappa), lj/cut/coul/long: epsilon, sigma, cutoff (LJ),
// coulomb_cutoff, shift (LAMMPS pair_modify shift; default false); mixed geometrically by default.
template <class Kernel>
std::unique_ptr<ForceTerm> read_lj_coul(const std::string& name, Level level, DeckTable& t, TermContext& ctx) {
  LjCoulCoeffs defaults;
  defaults.epsilon = 1.0, defaults.sigma = 1.0, defaults.rc = 2.5, defaults.coulomb_cutoff = 2.5, defaults.kappa = 1.0;
  return read_pair<Kernel>(
      name, level, t, ctx,
      [](DeckTable& d, LjCoulCoeffs c) {
        c.epsilon = read(d, "epsilon", kEnergy, c.epsilon);
        c.sigma = read(d, "sigma", kLength, c.sigma);
        const bool lj_cut_given = d.has("cutoff");
        c.rc = read(d, "cutoff", kLength, c.rc);
        c.coulomb_cutoff = read(d, "coulomb_cutoff", kLength, lj_cut_given ? c.rc : c.coulomb_cutoff);
        if constexpr (Kernel::kStyle == "lj/cut/coul/debye") c.kappa = read(d, "kappa", kInverseLength, c.kappa);
        c.shift = d.boolean("shift", c.shift);
        return c;
      },
      "cutoff", defaults,
      [](const LjCoulCoeffs& a, const LjCoulCoeffs& b, Mix m) {
        LjCoulCoeffs c = a;
        c.epsilon = mix_energy(a.epsilon, b.epsilon);
        c.sigma = mix_length(a.sigma, b.sigma, m);
        c.rc = mix_length(a.rc, b.rc, m);
        c.coulomb_cutoff = mix_length(a.coulomb_cutoff, b.coulomb_cutoff, m);
        return c;
      });
}

// lj/charmm/coul/long: epsilon, sigma, epsilon14, sigma14 (default epsilon, sigma), inner, cutoff
// (outer), coulomb_cutoff (default the outer cutoff); mixed arithmetically by default (LAMMPS).
std::unique_ptr<ForceTerm> read_lj_charmm_coul_long(const std::string& name, Level level, DeckTable& t,
                                                    TermContext& ctx) {
  return read_pair<LjCharmmCoulLong>(
      name, level, t, ctx,
      [](DeckTable& d, LjCharmmCoulLong::Coeffs c) {
        const bool eps_given = d.has("epsilon"), sigma_given = d.has("sigma");
        c.epsilon = read(d, "epsilon", kEnergy, c.epsilon);
        c.sigma = read(d, "sigma", kLength, c.sigma);
        c.epsilon14 = read(d, "epsilon14", kEnergy, eps_given ? c.epsilon : c.epsilon14);
        c.sigma14 = read(d, "sigma14", kLength, sigma_given ? c.sigma : c.sigma14);
        c.inner = read(d, "inner", kLength, c.inner);
        const bool outer_given = d.has("cutoff");
        c.rc = read(d, "cutoff", kLength, c.rc);
        c.coulomb_cutoff = read(d, "coulomb_cutoff", kLength, outer_given ? c.rc : c.coulomb_cutoff);
        d.require(c.inner < c.rc, "inner",
                  "expected the inner cutoff " + format_number(c.inner) + " below the outer cutoff " +
                      format_number(c.rc) + " (key cutoff)");
        return c;
      },
      "cutoff", LjCharmmCoulLong::Coeffs{1.0, 1.0, 1.0, 1.0, 8.0, 10.0, 10.0},
      [](const LjCharmmCoulLong::Coeffs& a, const LjCharmmCoulLong::Coeffs& b, Mix m) {
        LjCharmmCoulLong::Coeffs c = a;
        c.epsilon = mix_energy(a.epsilon, b.epsilon);
        c.sigma = mix_length(a.sigma, b.sigma, m);
        c.epsilon14 = mix_energy(a.epsilon14, b.epsilon14);
        c.sigma14 = mix_length(a.sigma14, b.sigma14, m);
        return c;
      },
      "arithmetic");
}

// gravity: g = [gx, gy, gz].
std::unique_ptr<ForceTerm> read_gravity(const std::string& name, Level level, DeckTable& t, TermContext& ctx) {
  return std::make_unique<Gravity>(name, level, t.vector3("g"), ctx.scene.state.inv_mass);
}

}  // namespace

const std::vector<ForceStyle>& force_styles() {
  static const std::vector<ForceStyle> styles = {
      {"stiff-harmonic", "bond", Level::fast, "stiff bond ½(α/ε)²(r−ℓ)², constraint-defining", read_stiff_harmonic},
      {"fene", "bond", Level::slow, "FENE bond −½KR₀² ln(1−(r/R₀)²) [+ WCA]", read_bond<Fene, fene_coeffs>},
      {"morse", "bond", Level::slow, "Morse bond D₀[1 − e^(−α(r−r₀))]²", read_bond<Morse, morse_coeffs>},
      {"harmonic-bond", "bond", Level::slow, "harmonic bond ½k(r−r₀)² (LAMMPS harmonic, K = k/2)", read_harmonic_bond},
      {"harmonic-angle", "angle", Level::slow, "angle ½k(θ−θ₀)²", read_angle<HarmonicAngle>},
      {"cosine-angle", "angle", Level::slow, "angle k[1 − cos(θ−θ₀)]", read_angle<CosineAngle>},
      {"charmm-angle", "angle", Level::slow, "angle K(θ−θ₀)² + K_UB(r₁₃−r_UB)² (LAMMPS charmm)", read_charmm_angle},
      {"harmonic-dihedral", "dihedral", Level::slow, "dihedral K[1 + d cos(nφ)] (LAMMPS harmonic)",
       read_dihedral<HarmonicDihedralKernel, harmonic_dihedral_coeffs>},
      {"multi-harmonic-dihedral", "dihedral", Level::slow, "dihedral Σ Aₙ cosⁿ⁻¹φ (LAMMPS multi/harmonic)",
       read_dihedral<MultiHarmonicDihedralKernel, multi_harmonic_dihedral_coeffs>},
      {"opls-dihedral", "dihedral", Level::slow,
       "dihedral ½K₁(1+cos φ) + ½K₂(1−cos 2φ) + ½K₃(1+cos 3φ) + ½K₄(1−cos 4φ)",
       read_dihedral<OplsDihedralKernel, opls_dihedral_coeffs>},
      {"charmm-dihedral", "dihedral", Level::slow,
       "dihedral K[1 + cos(nφ−d)] + w·(LJ 1-4 + Coulomb 1-4) (LAMMPS charmm)", read_charmm_dihedral},
      {"harmonic-improper", "improper", Level::slow, "improper K(χ−χ₀)² (LAMMPS harmonic)", read_harmonic_improper},
      {"cvff-improper", "improper", Level::slow, "improper K[1 + d cos(nφ)] (LAMMPS cvff)", read_cvff_improper},
      {"umbrella-improper", "improper", Level::slow,
       "improper ½K(cos ω − cos ω₀)²/sin²ω₀, K(1 − cos ω) for ω₀ = 0 (LAMMPS umbrella)", read_umbrella_improper},
      {"lj", "pair", Level::slow, "Lennard-Jones, cut and shifted", read_lj},
      {"wca", "pair", Level::slow, "Weeks–Chandler–Andersen (purely repulsive LJ)", read_wca},
      {"soft", "pair", Level::slow, "soft cosine pair A[1 + cos(πr/rc)], to push overlaps apart", read_soft},
      {"yukawa", "pair", Level::slow, "screened Coulomb pair A e^(−κr)/r, cut and shifted", read_yukawa},
      {"coul/cut", "pair", Level::slow, "Coulomb qqrd2e q_i q_j / r, cut (LAMMPS coul/cut)", read_coul_cut},
      {"coul/debye", "pair", Level::slow, "screened Coulomb qqrd2e q_i q_j e^(−κr)/r, cut (LAMMPS coul/debye)",
       read_coul_debye},
      {"coul/long", "pair", Level::slow, "Ewald real-space Coulomb qqrd2e q_i q_j erfc(g r)/r (needs ewald/pppm)",
       read_coul_long},
      {"lj/cut/coul/cut", "pair", Level::slow, "LJ 12-6 + cut Coulomb (LAMMPS lj/cut/coul/cut)",
       read_lj_coul<LjCutCoulCut>},
      {"lj/cut/coul/debye", "pair", Level::slow, "LJ 12-6 + screened Coulomb (LAMMPS lj/cut/coul/debye)",
       read_lj_coul<LjCutCoulDebye>},
      {"lj/cut/coul/long", "pair", Level::slow, "LJ 12-6 + Ewald real-space Coulomb (needs ewald/pppm)",
       read_lj_coul<LjCutCoulLong>},
      {"lj/charmm/coul/long", "pair", Level::slow, "CHARMM-switched LJ + Ewald real-space Coulomb (needs ewald/pppm)",
       read_lj_charmm_coul_long},
      {"ewald", "kspace", Level::slow, "Ewald reciprocal sum of the coul/long terms' charges (LAMMPS kspace ewald)",
       read_ewald},
      {"pppm", "kspace", Level::slow, "PPPM mesh reciprocal sum, ik differentiation (LAMMPS kspace pppm)", read_pppm},
      {"gravity", "external", Level::slow, "uniform external field, F = m g", read_gravity},
      {"harmonic-tether", "external", Level::slow, "harmonic tether ½k|x − c|²", read_tether},
      {"lj93-wall", "external", Level::slow, "flat LJ 9-3 wall", read_wall},
  };
  return styles;
}

std::string list_styles() {
  std::ostringstream o;
  const auto row = [&o](std::string_view name, std::string_view summary) {
    o << "  " << name << std::string(name.size() < 26 ? 26 - name.size() : 1, ' ') << summary << "\n";
  };
  o << "integrator.method:\n";
  for (const MethodInfo& m : methods()) row(m.name, m.summary);
  for (const char* kind : {"bond", "angle", "dihedral", "improper", "pair", "kspace", "external"}) {
    o << "forces.NAME.style, " << kind << (std::string_view(kind) == "external" ? " fields" : " styles") << ":\n";
    for (const ForceStyle& s : force_styles())
      if (std::string_view(s.kind) == kind) row(s.name, s.summary);
  }
  o << "thermostat.style:\n";
  row("langevin", "Langevin friction and noise (BAOAB; splitting = \"obabo\" or \"lammps\")");
  row("csvr", "stochastic velocity rescaling (Bussi-Donadio-Parrinello)");
  o << "barostat.style:\n";
  row("c-rescale", "stochastic cell rescaling on molecules (Bernetti-Bussi; isotropic, semi-isotropic, anisotropic)");
  o << "minimize.style:\n";
  row("fire", "FIRE 2.0 (LAMMPS min_style fire)");
  row("cg", "Polak-Ribiere conjugate gradient, quadratic line search (min_style cg)");
  row("sd", "steepest descent with the same line search (min_style sd)");
  o << "build.style:\n";
  row("linear-chains", "random-walk linear chains (chains, beads, bond_length, min_distance)");
  row("rings", "closed rings (chains, beads >= 3)");
  row("stars", "star polymers: a core with `arms` arms of `beads` beads");
  return o.str();
}

}  // namespace stiffmd
