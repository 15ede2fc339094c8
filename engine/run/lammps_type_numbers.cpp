#include "engine/run/lammps_type_numbers.hpp"

#include <algorithm>
#include <set>

namespace stiffmd {
namespace {

// LAMMPS type numbers for `count` scene types: those an [import] gave (`imported`, 0: none) kept,
// the others the smallest numbers still free, in scene order. Returns the number of each.
std::vector<int> lammps_numbers(const std::vector<int>& imported, size_t count) {
  std::vector<int> number(count, 0);
  std::set<int> used;
  for (size_t k = 0; k < count && k < imported.size(); ++k)
    if (imported[k] > 0) number[k] = imported[k], used.insert(imported[k]);
  int next = 1;
  for (int& n : number) {
    if (n > 0) continue;
    while (used.count(next)) ++next;
    n = next++;
  }
  return number;
}

int max_of(const std::vector<int>& v) {
  return v.empty() ? 0 : *std::max_element(v.begin(), v.end());
}

}  // namespace

LammpsTypes lammps_types(const Scene& sc) {
  const Topology& top = sc.topology;
  const LammpsTypeNumbers& imported = sc.lammps_types;
  LammpsTypes out;
  out.atom = lammps_numbers(imported.atom, sc.types.size());
  out.bond = lammps_numbers(imported.bond, top.bond_types.size());
  out.angle = lammps_numbers(imported.angle, top.angle_types.size());
  out.dihedral = lammps_numbers(imported.dihedral, top.dihedral_types.size());
  out.improper = lammps_numbers(imported.improper, top.improper_types.size());
  out.atom_types = max_of(out.atom);
  out.bond_types = max_of(out.bond);
  out.angle_types = max_of(out.angle);
  out.dihedral_types = max_of(out.dihedral);
  out.improper_types = max_of(out.improper);
  for (int t = 1; t <= out.atom_types; ++t)
    if (const auto it = imported.masses.find(t); it != imported.masses.end()) out.type_mass[t] = it->second;
  for (size_t k = 0; k < sc.types.size(); ++k) out.type_mass[out.atom[k]] = sc.types[k].mass;
  for (int t = 1; t <= out.atom_types; ++t) out.type_mass.emplace(t, 1.0);
  return out;
}

}  // namespace stiffmd
