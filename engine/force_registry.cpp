#include "engine/force_registry.hpp"

#include <stdexcept>

#include "forcefields/gravity.hpp"
#include "forcefields/stiff_harmonic_bond.hpp"

namespace stiffmd {
namespace {

// [forces.NAME] style = "stiff-harmonic", epsilon = "eps",
// [forces.NAME.bond_types.TYPE] length = ℓ, alpha = α — one sub-table per bond type it claims.
std::unique_ptr<ForceTerm> read_stiff_harmonic(const std::string& name, Level level, DeckTable& t, TermContext& ctx) {
  StiffBonds sb;
  sb.epsilon = t.number("epsilon");
  t.require(sb.epsilon > 0.0, "epsilon", "expected a number > 0");
  auto types = t.table("bond_types");
  if (!types) t.fail_here("missing required table [" + t.key_path("bond_types") + ".NAME] (length, alpha)");
  std::vector<int> claimed(ctx.topology.bond_types.size(), -1);
  std::vector<double> length, alpha;
  for (auto& [type_name, bt] : types->named_tables()) {
    const double l = bt.number("length");
    bt.require(l > 0.0, "length", "expected a bond length > 0");
    const double a = bt.number("alpha");
    bt.require(a > 0.0, "alpha", "expected a stiffness alpha > 0");
    bt.finish();
    const int k = ctx.topology.bond_type_index(type_name);
    if (k < 0) continue;  // a type with no bonds in this scene is allowed
    if (!ctx.bond_type_owner[k].empty())
      types->fail(type_name, "bond type '" + type_name + "' is already defined by [forces." +
                                 ctx.bond_type_owner[k] + "]");
    ctx.bond_type_owner[k] = name;
    claimed[k] = static_cast<int>(length.size());
    length.push_back(l);
    alpha.push_back(a);
  }
  types->finish();
  for (const Bond& b : ctx.topology.bonds)
    if (claimed[b.type] >= 0) sb.bonds.push_back({b.i, b.j, length[claimed[b.type]], alpha[claimed[b.type]]});
  return std::make_unique<StiffHarmonicBond>(name, level, std::move(sb));
}

// [forces.NAME] style = "gravity", g = [gx, gy, gz]
std::unique_ptr<ForceTerm> read_gravity(const std::string& name, Level level, DeckTable& t, TermContext& ctx) {
  return std::make_unique<Gravity>(name, level, t.vector3("g"), ctx.inv_mass);
}

}  // namespace

const std::vector<ForceStyle>& force_styles() {
  static const std::vector<ForceStyle> styles = {
      {"stiff-harmonic", Level::fast, "stiff bond ½(α/ε)²(r−ℓ)², constraint-defining", read_stiff_harmonic},
      {"gravity", Level::slow, "uniform external field, F = m g", read_gravity},
  };
  return styles;
}

}  // namespace stiffmd
