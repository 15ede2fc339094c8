#include "engine/domain/part_molecules.hpp"

#include <algorithm>
#include <stdexcept>
#include <string>
#include <utility>

namespace stiffmd {

namespace {

// The particles of each kind of item, as pointers to members: one loop for the four kinds.
constexpr int Bond::*kBondMembers[] = {&Bond::i, &Bond::j};
constexpr int Angle::*kAngleMembers[] = {&Angle::i, &Angle::j, &Angle::k};
constexpr int Dihedral::*kDihedralMembers[] = {&Dihedral::i, &Dihedral::j, &Dihedral::k, &Dihedral::l};
constexpr int Improper::*kImproperMembers[] = {&Improper::i, &Improper::j, &Improper::k, &Improper::l};

template <class Item, std::size_t M>
void cut_items(const std::vector<Item>& whole, int Item::*const (&members)[M], const PartMolecules& part,
               std::vector<PartMolecules::Placed<Item>>& out) {
  for (std::size_t k = 0; k < whole.size(); ++k)
    if (part.local(whole[k].*members[0]) >= 0) out.push_back({static_cast<std::int64_t>(k), whole[k]});
}

template <class Item, std::size_t M>
std::vector<Item> renumbered(const std::vector<PartMolecules::Placed<Item>>& items, int Item::*const (&members)[M],
                             const PartMolecules& part) {
  std::vector<Item> out;
  out.reserve(items.size());
  for (const auto& placed : items) {
    Item it = placed.item;
    for (const auto member : members) {
      it.*member = part.local(placed.item.*member);
      if (it.*member < 0)
        throw std::logic_error("a part's bonded item joins particle " + std::to_string(placed.item.*member) +
                               ", which the part does not hold (a part holds whole molecules)");
    }
    out.push_back(it);
  }
  return out;
}

template <class Item, std::size_t M>
void split_items(const std::vector<PartMolecules::Placed<Item>>& items, int Item::*const (&members)[M],
                 const PartMolecules& part, std::span<const int> to,
                 std::vector<PartMolecules::Placed<Item>> PartMolecules::*list, PartMolecules& kept,
                 std::vector<PartMolecules>& pieces) {
  for (const auto& placed : items) {
    const int r = to[static_cast<std::size_t>(part.local(placed.item.*members[0]))];
    ((r < 0 ? kept : pieces[static_cast<std::size_t>(r)]).*list).push_back(placed);
  }
}

template <class Item, std::size_t M>
void pack_items(const std::vector<PartMolecules::Placed<Item>>& items, int Item::*const (&members)[M],
                std::vector<double>& out) {
  out.push_back(static_cast<double>(items.size()));
  for (const auto& placed : items) {
    out.push_back(static_cast<double>(placed.place));
    for (const auto member : members) out.push_back(placed.item.*member);
    out.push_back(placed.item.type);
  }
}

template <class Item, std::size_t M>
const double* unpack_items(const double* w, int Item::*const (&members)[M],
                           std::vector<PartMolecules::Placed<Item>>& items) {
  const auto count = static_cast<std::size_t>(*w++);
  for (std::size_t k = 0; k < count; ++k) {
    PartMolecules::Placed<Item> placed;
    placed.place = static_cast<std::int64_t>(*w++);
    for (const auto member : members) placed.item.*member = static_cast<int>(*w++);
    placed.item.type = static_cast<int>(*w++);
    items.push_back(placed);
  }
  return w;
}

template <class Item>
void sort_by_place(std::vector<PartMolecules::Placed<Item>>& items) {
  std::sort(items.begin(), items.end(), [](const auto& a, const auto& b) { return a.place < b.place; });
}

}  // namespace

int PartMolecules::local(int g) const {
  const auto it = std::lower_bound(global.begin(), global.end(), g);
  return it != global.end() && *it == g ? static_cast<int>(it - global.begin()) : -1;
}

Topology PartMolecules::topology(const Topology& names) const {
  Topology t;
  t.bond_types = names.bond_types;
  t.angle_types = names.angle_types;
  t.dihedral_types = names.dihedral_types;
  t.improper_types = names.improper_types;
  t.bonds = renumbered(bonds, kBondMembers, *this);
  t.angles = renumbered(angles, kAngleMembers, *this);
  t.dihedrals = renumbered(dihedrals, kDihedralMembers, *this);
  t.impropers = renumbered(impropers, kImproperMembers, *this);
  t.molecule = molecule_id;
  return t;
}

PartMolecules cut_part(const WholeParticles& whole, std::span<const int> global) {
  PartMolecules p;
  p.global.assign(global.begin(), global.end());
  const std::size_t n = global.size();
  p.inv_mass.resize(n), p.type.resize(n), p.charge.resize(n);
  if (!whole.molecule_id.empty()) p.molecule_id.resize(n);
  if (!whole.friction.empty()) p.friction.resize(n);
  for (std::size_t k = 0; k < n; ++k) {
    const auto g = static_cast<std::size_t>(global[k]);
    p.inv_mass[k] = whole.inv_mass[g];
    p.type[k] = whole.type[g];
    p.charge[k] = whole.charge[g];
    if (!p.molecule_id.empty()) p.molecule_id[k] = whole.molecule_id[g];
    if (!p.friction.empty()) p.friction[k] = whole.friction[g];
  }
  cut_items(whole.topology.bonds, kBondMembers, p, p.bonds);
  cut_items(whole.topology.angles, kAngleMembers, p, p.angles);
  cut_items(whole.topology.dihedrals, kDihedralMembers, p, p.dihedrals);
  cut_items(whole.topology.impropers, kImproperMembers, p, p.impropers);
  return p;
}

std::vector<int> whole_block(const Topology& topology, int n, int parts, int part) {
  const std::vector<int> molecule = bonded_molecules(topology, n);
  const std::int64_t molecules = molecule.empty() ? 0 : *std::max_element(molecule.begin(), molecule.end()) + 1;
  const std::int64_t first = molecules * part / parts, end = molecules * (part + 1) / parts;
  std::vector<int> out;
  for (int g = 0; g < n; ++g)
    if (molecule[g] >= first && molecule[g] < end) out.push_back(g);
  return out;
}

PartMolecules split_part(const PartMolecules& part, std::span<const int> to, std::vector<PartMolecules>& pieces) {
  PartMolecules kept;
  const bool ids = !part.molecule_id.empty(), friction = !part.friction.empty();
  for (int k = 0; k < part.size(); ++k) {
    const int r = to[static_cast<std::size_t>(k)];
    PartMolecules& p = r < 0 ? kept : pieces[static_cast<std::size_t>(r)];
    p.global.push_back(part.global[k]);
    p.inv_mass.push_back(part.inv_mass[k]);
    p.type.push_back(part.type[k]);
    p.charge.push_back(part.charge[k]);
    if (ids) p.molecule_id.push_back(part.molecule_id[k]);
    if (friction) p.friction.push_back(part.friction[k]);
  }
  split_items(part.bonds, kBondMembers, part, to, &PartMolecules::bonds, kept, pieces);
  split_items(part.angles, kAngleMembers, part, to, &PartMolecules::angles, kept, pieces);
  split_items(part.dihedrals, kDihedralMembers, part, to, &PartMolecules::dihedrals, kept, pieces);
  split_items(part.impropers, kImproperMembers, part, to, &PartMolecules::impropers, kept, pieces);
  return kept;
}

// [n, flags (1: molecule ids, 2: friction), per particle: global, inverse mass, type, charge,
// (molecule id), (friction); then per kind of item: its count, per item: place, particles, type].
void pack_part(const PartMolecules& part, std::vector<double>& out) {
  const bool ids = !part.molecule_id.empty(), friction = !part.friction.empty();
  out.push_back(part.size());
  out.push_back((ids ? 1 : 0) + (friction ? 2 : 0));
  for (int k = 0; k < part.size(); ++k) {
    out.push_back(part.global[k]);
    out.push_back(part.inv_mass[k]);
    out.push_back(part.type[k]);
    out.push_back(part.charge[k]);
    if (ids) out.push_back(part.molecule_id[k]);
    if (friction) out.push_back(part.friction[k]);
  }
  pack_items(part.bonds, kBondMembers, out);
  pack_items(part.angles, kAngleMembers, out);
  pack_items(part.dihedrals, kDihedralMembers, out);
  pack_items(part.impropers, kImproperMembers, out);
}

const double* unpack_part(const double* w, PartMolecules& part) {
  const auto n = static_cast<int>(*w++);
  const auto flags = static_cast<int>(*w++);
  const bool ids = (flags & 1) != 0, friction = (flags & 2) != 0;
  for (int k = 0; k < n; ++k) {
    part.global.push_back(static_cast<int>(*w++));
    part.inv_mass.push_back(*w++);
    part.type.push_back(static_cast<int>(*w++));
    part.charge.push_back(*w++);
    if (ids) part.molecule_id.push_back(static_cast<int>(*w++));
    if (friction) part.friction.push_back(*w++);
  }
  w = unpack_items(w, kBondMembers, part.bonds);
  w = unpack_items(w, kAngleMembers, part.angles);
  w = unpack_items(w, kDihedralMembers, part.dihedrals);
  return unpack_items(w, kImproperMembers, part.impropers);
}

PartMolecules merge_parts(std::vector<PartMolecules> parts) {
  PartMolecules out;
  std::size_t n = 0;
  bool ids = false, friction = false;
  for (const PartMolecules& p : parts) {
    n += p.global.size();
    ids |= !p.molecule_id.empty();
    friction |= !p.friction.empty();
  }
  // Each part's particles increase: their order by global index, part by part.
  std::vector<std::pair<int, std::pair<std::size_t, int>>> order;  // global, (part, index)
  order.reserve(n);
  for (std::size_t q = 0; q < parts.size(); ++q)
    for (int k = 0; k < parts[q].size(); ++k) order.push_back({parts[q].global[k], {q, k}});
  std::sort(order.begin(), order.end());
  for (std::size_t e = 1; e < order.size(); ++e)
    if (order[e].first == order[e - 1].first)
      throw std::logic_error("merge_parts: particle " + std::to_string(order[e].first) + " is in two parts");
  out.global.resize(n), out.inv_mass.resize(n), out.type.resize(n), out.charge.resize(n);
  if (ids) out.molecule_id.resize(n);
  if (friction) out.friction.resize(n);
  for (std::size_t e = 0; e < n; ++e) {
    const PartMolecules& p = parts[order[e].second.first];
    const int k = order[e].second.second;
    out.global[e] = p.global[k];
    out.inv_mass[e] = p.inv_mass[k];
    out.type[e] = p.type[k];
    out.charge[e] = p.charge[k];
    if (ids) out.molecule_id[e] = p.molecule_id[k];
    if (friction) out.friction[e] = p.friction[k];
  }
  for (PartMolecules& p : parts) {
    out.bonds.insert(out.bonds.end(), p.bonds.begin(), p.bonds.end());
    out.angles.insert(out.angles.end(), p.angles.begin(), p.angles.end());
    out.dihedrals.insert(out.dihedrals.end(), p.dihedrals.begin(), p.dihedrals.end());
    out.impropers.insert(out.impropers.end(), p.impropers.begin(), p.impropers.end());
  }
  sort_by_place(out.bonds);
  sort_by_place(out.angles);
  sort_by_place(out.dihedrals);
  sort_by_place(out.impropers);
  return out;
}

}  // namespace stiffmd
