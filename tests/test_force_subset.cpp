// A force field built on a subset of the particles (ForceField::on_subset, what a decomposed run's
// part is, docs/parallel.md): on whole molecules, every term acting within molecules and every
// external field gives the subset's particles the forces the whole system's terms give them, bit
// for bit; a tether or wall on particles outside the subset vanishes there; the levels, the
// evaluation order and the terms' definitions follow the whole field; a subset cutting a molecule,
// or a term that cannot be moved, is refused.
#include <gtest/gtest.h>

#include <cmath>
#include <set>
#include <stdexcept>
#include <string>
#include <vector>

#include "engine/scene/scene.hpp"
#include "forcefields/force_field.hpp"
#include "forcefields/type_claim.hpp"
#include "test_support.hpp"

namespace stiffmd {
namespace {

// The subset's particles (system indices, increasing), their types and the topology among them
// in the subset's numbering and the system's order, as a decomposed run's part builds them.
struct Subset {
  std::vector<int> global, types;
  Topology topology;
  ParticleSubset view() const { return {global, types, topology}; }
};

Subset subset_of(const Scene& sc, std::vector<int> global) {
  Subset s;
  s.global = std::move(global);
  for (const int g : s.global) s.types.push_back(sc.particle_type[g]);
  const ParticleSubset v = s.view();
  Topology& t = s.topology;
  for (const Bond& b : sc.topology.bonds)
    if (v.local(b.i) >= 0) t.bonds.push_back({v.local(b.i), v.local(b.j), b.type});
  for (const Angle& a : sc.topology.angles)
    if (v.local(a.i) >= 0) t.angles.push_back({v.local(a.i), v.local(a.j), v.local(a.k), a.type});
  for (const Dihedral& d : sc.topology.dihedrals)
    if (v.local(d.i) >= 0) t.dihedrals.push_back({v.local(d.i), v.local(d.j), v.local(d.k), v.local(d.l), d.type});
  return s;
}

// The particles of the given bonded molecules (bonded_molecules numbering), increasing.
std::vector<int> particles_of(const Scene& sc, const std::set<int>& molecules) {
  const std::vector<int> molecule = bonded_molecules(sc.topology, sc.state.size());
  std::vector<int> out;
  for (int i = 0; i < sc.state.size(); ++i)
    if (molecules.contains(molecule[i])) out.push_back(i);
  return out;
}

Eigen::Matrix3Xd columns(const Eigen::Matrix3Xd& x, const std::vector<int>& global) {
  Eigen::Matrix3Xd out(3, static_cast<Eigen::Index>(global.size()));
  for (size_t k = 0; k < global.size(); ++k) out.col(static_cast<Eigen::Index>(k)) = x.col(global[k]);
  return out;
}

std::uint64_t definition(const ForceTerm& t) {
  ParameterRecord r;
  t.define(r);
  return r.value();
}

// The deck with a term of every registered style: six chains of four beads, two of each particle
// type's builders; the tether holds particles 0 and 9 (molecules 0 and 2), the wall every B bead
// (molecules 2, 3 and 5).
Scene every_style() {
  return load_scene(Deck(test::source_path("tests/decks/every_force_style.toml"), {}));
}

// The levels, the terms (deck order: names, styles, levels) and the evaluation order of `part`
// are those of `whole`.
void expect_same_layout(const ForceField& whole, const ForceField& part, int particles) {
  EXPECT_EQ(part.num_particles(), particles);
  ASSERT_EQ(part.num_levels(), whole.num_levels());
  for (int k = 0; k < whole.num_levels(); ++k) EXPECT_EQ(part.level_name(Level{k}), whole.level_name(Level{k}));
  ASSERT_EQ(part.terms().size(), whole.terms().size());
  for (size_t k = 0; k < whole.terms().size(); ++k) {
    EXPECT_EQ(part.terms()[k]->name(), whole.terms()[k]->name());
    EXPECT_EQ(part.terms()[k]->style(), whole.terms()[k]->style());
    EXPECT_EQ(part.terms()[k]->level(), whole.terms()[k]->level());
  }
  for (size_t k = 0; k < whole.evaluation_order().size(); ++k)
    EXPECT_EQ(part.evaluation_order()[k]->name(), whole.evaluation_order()[k]->name()) << "position " << k;
  EXPECT_EQ(part.box().lengths, whole.box().lengths);
}

TEST(ForceFieldOnSubset, WholeMoleculesFeelWhatTheyFeelInTheWholeSystem) {
  const Scene sc = every_style();
  const ForceField& whole = *sc.forces;
  ASSERT_EQ(bonded_molecules(sc.topology, sc.state.size())[23], 5);  // six chains
  // {1, 3, 4}: neither tethered particle, some wall particles; {0, 2, 5}: the rest.
  const Subset a = subset_of(sc, particles_of(sc, {1, 3, 4})), b = subset_of(sc, particles_of(sc, {0, 2, 5}));
  const auto on_a = whole.on_subset(a.view()), on_b = whole.on_subset(b.view());
  expect_same_layout(whole, *on_a, 12);
  expect_same_layout(whole, *on_b, 12);
  int external = 0;
  for (size_t k = 0; k < whole.terms().size(); ++k) {
    const ForceTerm& w = *whole.terms()[k];
    if (w.uses_neighbor_list()) continue;  // pairs between molecules of the two subsets are missing
    SCOPED_TRACE(w.name());
    Eigen::Matrix3Xd fw = Eigen::Matrix3Xd::Zero(3, sc.state.size());
    const double ew = w.add_forces(sc.state.x, sc.box, fw);
    double e_parts = 0.0;
    for (const Subset* s : {&a, &b}) {
      const ForceTerm& p = *(s == &a ? on_a : on_b)->terms()[k];
      Eigen::Matrix3Xd f = Eigen::Matrix3Xd::Zero(3, 12);
      e_parts += p.add_forces(columns(sc.state.x, s->global), sc.box, f);
      for (int l = 0; l < 12; ++l)
        for (int c = 0; c < 3; ++c) EXPECT_EQ(f(c, l), fw(c, s->global[l])) << "particle " << s->global[l];
    }
    EXPECT_NEAR(e_parts, ew, 1e-12 * std::max(1.0, std::abs(ew)));
    if (!w.conserves_momentum()) ++external;
  }
  EXPECT_EQ(external, 3);  // gravity, tether, wall
  // The tether's particles 0 and 9 are not in {1, 3, 4}: there it acts on nothing.
  const auto tether = std::find_if(on_a->terms().begin(), on_a->terms().end(),
                                   [](const auto& t) { return t->style() == "harmonic-tether"; });
  ASSERT_NE(tether, on_a->terms().end());
  Eigen::Matrix3Xd f = Eigen::Matrix3Xd::Zero(3, 12);
  EXPECT_EQ((*tether)->add_forces(columns(sc.state.x, a.global), sc.box, f), 0.0);
  EXPECT_TRUE(f.isZero(0.0));
  EXPECT_NE((*tether)->describe().find("0 particles"), std::string::npos) << (*tether)->describe();
  // The stiff bonds of the subset, for the constraint toolbox, in the whole system's order.
  ASSERT_NE(on_a->stiff_bonds(), nullptr);
  EXPECT_EQ(on_a->stiff_bonds()->epsilon, whole.stiff_bonds()->epsilon);
  EXPECT_EQ(on_a->stiff_bonds()->bonds.size() + on_b->stiff_bonds()->bonds.size(), whole.stiff_bonds()->bonds.size());
}

// On every particle the subset's field is the whole field: each term's definition (the scene
// fingerprint), forces and energy bit for bit, the pair terms' included.
TEST(ForceFieldOnSubset, AllParticlesGiveTheSameField) {
  const Scene sc = every_style();
  std::vector<int> all(static_cast<size_t>(sc.state.size()));
  for (int i = 0; i < sc.state.size(); ++i) all[static_cast<size_t>(i)] = i;
  const Subset s = subset_of(sc, all);
  const auto part = sc.forces->on_subset(s.view());
  expect_same_layout(*sc.forces, *part, sc.state.size());
  for (size_t k = 0; k < part->terms().size(); ++k) {
    const ForceTerm &w = *sc.forces->terms()[k], &p = *part->terms()[k];
    SCOPED_TRACE(w.name());
    EXPECT_EQ(definition(p), definition(w));
    EXPECT_EQ(p.describe(), w.describe());
    EXPECT_EQ(p.pair_cutoff(), w.pair_cutoff());
    EXPECT_EQ(p.pair_skin(), w.pair_skin());
    Eigen::Matrix3Xd fw = Eigen::Matrix3Xd::Zero(3, sc.state.size()), fp = fw;
    EXPECT_EQ(p.add_forces(sc.state.x, sc.box, fp), w.add_forces(sc.state.x, sc.box, fw));
    EXPECT_TRUE(fp == fw);
  }
}

// The bonded terms read from a deck claim their types (TypeClaim): on a subset they take their
// items from the subset's topology, not from their own lists of the whole system — what a
// decomposed run's part, which carries its molecules' items, is built from. With the subset's
// topology emptied, each of them holds no item there and adds no force, while the whole term does.
TEST(ForceFieldOnSubset, ClaimedTermsTakeTheSubsetsTopology) {
  const Scene sc = every_style();
  const int n = sc.state.size();
  std::vector<int> all(static_cast<size_t>(n));
  for (int i = 0; i < n; ++i) all[static_cast<size_t>(i)] = i;
  Subset s = subset_of(sc, all);
  s.topology.bonds.clear();
  s.topology.angles.clear();
  s.topology.dihedrals.clear();
  const auto part = sc.forces->on_subset(s.view());
  std::set<std::string> styles;
  for (size_t k = 0; k < part->terms().size(); ++k) {
    const ForceTerm &w = *sc.forces->terms()[k], &p = *part->terms()[k];
    if (!dynamic_cast<const TypeClaim*>(&w)) continue;
    SCOPED_TRACE(w.name());
    styles.insert(std::string(w.style()));
    EXPECT_EQ(p.describe().rfind("0 ", 0), 0u) << p.describe();
    Eigen::Matrix3Xd fw = Eigen::Matrix3Xd::Zero(3, n), fp = fw;
    w.add_forces(sc.state.x, sc.box, fw);
    EXPECT_EQ(p.add_forces(sc.state.x, sc.box, fp), 0.0);
    EXPECT_FALSE(fw.isZero(0.0));
    EXPECT_TRUE(fp.isZero(0.0));
  }
  EXPECT_EQ(styles, (std::set<std::string>{"fene", "morse", "harmonic-angle", "cosine-angle", "harmonic-dihedral",
                                           "multi-harmonic-dihedral", "opls-dihedral"}));
}

// A subset holding part of a molecule cuts its bonds: refused, naming the bond.
TEST(ForceFieldOnSubset, RefusesAPartOfAMolecule) {
  const Scene sc = every_style();
  const Subset s = subset_of(sc, {0, 1, 2});  // three of chain 0's four beads
  try {
    sc.forces->on_subset(s.view());
    FAIL() << "a subset cutting a chain was accepted";
  } catch (const std::invalid_argument& e) {
    // The first term in the deck's order with an item across the cut: the bend 1–2–3.
    EXPECT_EQ(std::string(e.what()),
              "harmonic-angle 'bend_h': the angle of particles 1, 2, 3 lies partly outside the particle subset (a "
              "subset must hold whole molecules)");
  }
}

// A term that does not say how to act on a subset: refused, naming it.
TEST(ForceFieldOnSubset, RefusesATermThatCannot) {
  struct Fixed final : ForceTerm {
    Fixed() : ForceTerm("pin", Level::slow) {}
    double add_forces(const Eigen::Matrix3Xd&, const Box&, Eigen::Matrix3Xd&) const override { return 0.0; }
    std::string_view style() const override { return "test-pin"; }
    std::string describe() const override { return "a test term"; }
    void define(ParameterRecord&) const override {}
  };
  ForceField ff(Box{}, 2);
  ff.add(std::make_unique<Fixed>());
  const std::vector<int> global = {0}, types = {0};
  const Topology t;
  try {
    ff.on_subset({global, types, t});
    FAIL() << "a term without on_subset was moved";
  } catch (const std::invalid_argument& e) {
    EXPECT_EQ(std::string(e.what()), "force term 'pin' (test-pin) cannot be built on a subset of the particles");
  }
}

}  // namespace
}  // namespace stiffmd
