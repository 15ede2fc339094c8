// What a rank's molecules carry of the system (docs/parallel.md, "The design"): per particle its
// global index, inverse mass, type, charge, the topology's molecule id and the thermostat's
// friction; and the bonded items among its particles (bonds, angles, dihedrals, impropers) by
// global index with their types, each with its place in the whole system's list. A rank's part is
// built from these alone (DomainIntegrator), and a molecule that migrates takes its share along
// (Decomposition::migrate: split, pack, unpack, merge), so that no rank reads the whole system's
// per-particle arrays or topology after the start.
//
// The items keep their places so that the part's lists are the whole system's, restricted to the
// part, in the whole system's order: the constraint clusters and the effective dynamics' modes
// (integrators/clusters.hpp) come in that order, and each term sums its items in it.
#pragma once

#include <cstdint>
#include <span>
#include <vector>

#include "core/topology.hpp"

namespace stiffmd {

// The whole system's per-particle arrays and topology, what the start cuts the parts from. Spans
// of N (molecule_id and friction: N or empty, as the scene has them).
struct WholeParticles {
  std::span<const double> inv_mass;
  std::span<const int> type;
  std::span<const double> charge;
  std::span<const int> molecule_id;  // the topology's molecule ids (Topology::molecule)
  std::span<const double> friction;  // the thermostat's per-particle friction
  const Topology& topology;
};

struct PartMolecules {
  // A bonded item with its index in the whole system's list; its particles by global index.
  template <class Item>
  struct Placed {
    std::int64_t place = 0;
    Item item;
  };
  std::vector<int> global;  // increasing
  std::vector<double> inv_mass, charge;
  std::vector<int> type;
  std::vector<int> molecule_id;  // empty when the system has none
  std::vector<double> friction;  // empty when the system has none
  std::vector<Placed<Bond>> bonds;
  std::vector<Placed<Angle>> angles;
  std::vector<Placed<Dihedral>> dihedrals;
  std::vector<Placed<Improper>> impropers;

  int size() const { return static_cast<int>(global.size()); }
  // The part's index of the system's particle g (−1: not here).
  int local(int g) const;
  // The part's topology in its numbering (0 … size() − 1 by increasing global index), each list
  // in the whole system's order; the type names from `names` (the whole system's).
  Topology topology(const Topology& names) const;
};

// The part of the particles `global` (increasing; whole molecules) of the whole system: their
// arrays and every item whose first particle is among them, in the whole system's order.
PartMolecules cut_part(const WholeParticles& whole, std::span<const int> global);

// The particles (increasing) of block `part` of `parts` contiguous blocks of the whole system's
// molecules (bonded_molecules' numbering, by first particle: molecules [M·part/parts,
// M·(part + 1)/parts) of M): a partition of whole molecules, which a start from the whole scene
// cuts (Decomposition::start sends each molecule to its anchor's rank).
std::vector<int> whole_block(const Topology& topology, int n, int parts, int part);

// The particles at the columns k with to[k] = r go to pieces[r] (r in 0 … ranks − 1), those with
// to[k] < 0 to the returned part; an item goes with its first particle (an item lies within one
// molecule, and a molecule moves whole).
PartMolecules split_part(const PartMolecules& part, std::span<const int> to, std::vector<PartMolecules>& pieces);

// One part as words (appended to `out`), and back: unpack reads from `w` and returns the word
// past it. Every number is an integer below 2⁵³ or the double itself: exact.
void pack_part(const PartMolecules& part, std::vector<double>& out);
const double* unpack_part(const double* w, PartMolecules& part);

// The union of disjoint parts: particles by increasing global index, items by their places.
PartMolecules merge_parts(std::vector<PartMolecules> parts);

}  // namespace stiffmd
