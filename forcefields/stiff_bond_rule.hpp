// Which bonds of a topology are stiff, and their lengths and stiffnesses: the stiff-harmonic term's
// description as the deck gives it (docs/decks.md, stiff-harmonic), O(types), never a list of the
// system's bonds. The deck reader (engine/scene/force_registry.cpp) makes the whole system's stiff
// bonds with it, and a particle subset's term (a decomposed run's part, docs/parallel.md) makes its
// own from the subset's topology with it: the same rule on the system's items restricted to the
// subset, in their order, gives the whole list's items on the subset in the whole list's order.
//
//   1. each bond whose type the term claims (bond_types, or selected by mass: whole types), in the
//      topology's order, with its type's ℓ and α;
//   2. then for each rigid angle type (angle_types, in the deck's order), each angle i–j–k of that
//      type in the topology's order: a third bond i–k, as LAMMPS's fix shake/rattle `a` makes it,
//      of length ℓ_ik = √(ℓ_ij² + ℓ_jk² − 2 ℓ_ij ℓ_jk cos θ₀) on the lengths of its two arms, which
//      must be stiff bonds of step 1.
#pragma once

#include <algorithm>
#include <cmath>
#include <map>
#include <stdexcept>
#include <string>
#include <utility>
#include <vector>

#include "core/topology.hpp"
#include "forcefields/stiff_bond.hpp"

namespace stiffmd {

struct RigidAngleType {
  int type = 0;             // the topology's angle type
  double cos_theta0 = 0.0;  // cos θ₀ of the deck's θ₀
  double alpha = 1.0;       // α of the third bond
};

// The lengths of the stiff bonds by particle pair (i < j): the arms a rigid angle looks up.
using StiffArms = std::map<std::pair<int, int>, double>;

struct StiffBondRule {
  // Per bond type of the topology, the index of its coefficients in `bond_coeffs` (−1: not stiff).
  std::vector<int> bond_claim;
  std::vector<StiffBond> bond_coeffs;  // ℓ_b and α_b of each claimed type (i, j unused)
  std::vector<RigidAngleType> rigid_angles;

  bool empty() const { return bond_claim.empty() && rigid_angles.empty(); }
  // Whether angles of the topology's type `type` are rigid.
  bool rigid(int type) const {
    return std::any_of(rigid_angles.begin(), rigid_angles.end(),
                       [type](const RigidAngleType& r) { return r.type == type; });
  }

  // Step 1 on `top`: the claimed bonds, appended to `out`.
  void add_claimed_bonds(const Topology& top, std::vector<StiffBond>& out) const {
    for (const Bond& b : top.bonds) {
      const int c = b.type >= 0 && b.type < static_cast<int>(bond_claim.size()) ? bond_claim[b.type] : -1;
      if (c >= 0)
        out.push_back(
            {b.i, b.j, bond_coeffs[static_cast<size_t>(c)].length, bond_coeffs[static_cast<size_t>(c)].alpha});
    }
  }
  // The arms step 2 looks up: the lengths of `bonds` (step 1's) by particle pair.
  static StiffArms arms_of(const std::vector<StiffBond>& bonds) {
    StiffArms arm;
    for (const StiffBond& b : bonds) arm[{std::min(b.i, b.j), std::max(b.i, b.j)}] = b.length;
    return arm;
  }
  // Step 2 for one rigid angle type on `top`: its third bonds, appended to `out`. Returns the index
  // in top.angles of the first angle of the type whose arms are not both in `arm` (none appended
  // from it on), or −1.
  static int add_rigid_angle_bonds(const Topology& top, const RigidAngleType& rigid, const StiffArms& arm,
                                   std::vector<StiffBond>& out) {
    for (size_t n = 0; n < top.angles.size(); ++n) {
      const Angle& a = top.angles[n];
      if (a.type != rigid.type) continue;
      const auto l1 = arm.find({std::min(a.i, a.j), std::max(a.i, a.j)});
      const auto l2 = arm.find({std::min(a.j, a.k), std::max(a.j, a.k)});
      if (l1 == arm.end() || l2 == arm.end()) return static_cast<int>(n);
      const double c = rigid.cos_theta0;
      const double l = std::sqrt(l1->second * l1->second + l2->second * l2->second - 2.0 * l1->second * l2->second * c);
      out.push_back({a.i, a.k, l, rigid.alpha});
    }
    return -1;
  }
  // Steps 1 and 2 on `top`. A rigid angle whose arms are not both stiff bonds (a topology the
  // deck reader would have refused) throws std::invalid_argument naming it.
  std::vector<StiffBond> bonds_of(const Topology& top) const {
    std::vector<StiffBond> out;
    add_claimed_bonds(top, out);
    if (rigid_angles.empty()) return out;  // no arms to look up: no map of the bonds
    const StiffArms arm = arms_of(out);
    for (const RigidAngleType& rigid : rigid_angles)
      if (const int n = add_rigid_angle_bonds(top, rigid, arm, out); n >= 0) {
        const Angle& a = top.angles[static_cast<size_t>(n)];
        throw std::invalid_argument("the rigid angle " + std::to_string(a.i) + "–" + std::to_string(a.j) + "–" +
                                    std::to_string(a.k) + " has an arm that is not a stiff bond");
      }
    return out;
  }
};

}  // namespace stiffmd
