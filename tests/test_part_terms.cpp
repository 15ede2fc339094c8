// A part's force terms made from the terms' descriptions (docs/parallel.md, "What is not
// distributed yet"): every term's on_subset builds the part's term from its coefficients and
// selection rule (type claims, StiffBondRule, ParticleSelection) and the subset's own data (its
// indices, types, charges, inverse masses and topology), never from the whole system's lists.
// - On 1–4 random partitions into whole molecules of decks holding every term style, each term
//   made again from its description alone (on_subset on a subset of no particle: no item, no
//   particle list, no per-particle array) gives each part the term the whole term's cut gives it
//   (the whole list cut to the part, the charges and masses by global index): the same definition
//   (ParameterRecord), and on the part's particles the whole term's forces bit for bit. On random
//   subsets that cut molecules, both refuse alike or agree.
// - A decomposed run of inputs/peptide.toml (stiff bonds with rigid water angles, a charmm
//   dihedral with 1-4 charges, PPPM), drifting so that molecules migrate, on 1–4 fake ranks whose
//   whole force terms are replaced after the start by their descriptions alone is the same
//   trajectory, bit for bit, as the run that keeps them (a k-space sum over several ranks is not
//   one process's bits; on one rank it is, and so is the run): the parts built again at each
//   migration read nothing of the whole terms' lists.
#include <gtest/gtest.h>

#include <algorithm>
#include <memory>
#include <random>
#include <set>
#include <stdexcept>
#include <string>
#include <vector>

#include "domain_run_support.hpp"
#include "engine/scene/scene.hpp"
#include "forcefields/force_field.hpp"
#include "forcefields/stiff_harmonic_bond.hpp"
#include "test_support.hpp"

namespace stiffmd {
namespace {

// A subset of the particles with what a decomposed run's part carries of them: indices, types,
// charges (a charged scene), inverse masses, and the topology among them in the subset's
// numbering and the system's order (an item with particles outside the subset: those −1).
struct Part {
  std::vector<int> global, types;
  std::vector<double> charges, inv_mass;
  Topology topology;
  // With the carried charges and masses, or without (the terms then take theirs by index).
  ParticleSubset view(bool carried) const {
    if (!carried) return {global, types, topology};
    return {global, types, topology, charges, inv_mass};
  }
};

Part part_of(const Scene& sc, std::vector<int> global) {
  Part p;
  p.global = std::move(global);
  for (const int g : p.global) {
    p.types.push_back(sc.particle_type[static_cast<size_t>(g)]);
    if (sc.charged()) p.charges.push_back(sc.charge[static_cast<size_t>(g)]);
    p.inv_mass.push_back(sc.state.inv_mass[g]);
  }
  const ParticleSubset v = p.view(false);
  Topology& t = p.topology;
  const auto in = [&v](std::initializer_list<int> members) {
    for (const int m : members)
      if (v.local(m) >= 0) return true;
    return false;
  };
  for (const Bond& b : sc.topology.bonds)
    if (in({b.i, b.j})) t.bonds.push_back({v.local(b.i), v.local(b.j), b.type});
  for (const Angle& a : sc.topology.angles)
    if (in({a.i, a.j, a.k})) t.angles.push_back({v.local(a.i), v.local(a.j), v.local(a.k), a.type});
  for (const Dihedral& d : sc.topology.dihedrals)
    if (in({d.i, d.j, d.k, d.l}))
      t.dihedrals.push_back({v.local(d.i), v.local(d.j), v.local(d.k), v.local(d.l), d.type});
  for (const Improper& d : sc.topology.impropers)
    if (in({d.i, d.j, d.k, d.l}))
      t.impropers.push_back({v.local(d.i), v.local(d.j), v.local(d.k), v.local(d.l), d.type});
  return p;
}

// The same part whose topology also holds an item of each kind of no type (−1): a claimed term
// and the stiff term then cut their own lists of the whole system (the old way, the reference).
Part with_unknown_items(Part p) {
  p.topology.bonds.push_back({0, 0, -1});
  p.topology.angles.push_back({0, 0, 0, -1});
  p.topology.dihedrals.push_back({0, 0, 0, 0, -1});
  p.topology.impropers.push_back({0, 0, 0, 0, -1});
  return p;
}

// Each term of the whole field made again from its description alone: on a subset of no particle.
std::vector<std::unique_ptr<ForceTerm>> descriptions(const ForceField& whole) {
  const std::vector<int> none;
  const Topology empty;
  const ParticleSubset nobody{none, none, empty};
  std::vector<std::unique_ptr<ForceTerm>> out;
  for (const auto& term : whole.terms()) out.push_back(term->on_subset(nobody, whole.box()));
  return out;
}

std::uint64_t definition(const ForceTerm& t) {
  ParameterRecord r;
  t.define(r);
  return r.value();
}

Eigen::Matrix3Xd columns(const Eigen::Matrix3Xd& x, const std::vector<int>& global) {
  Eigen::Matrix3Xd out(3, static_cast<Eigen::Index>(global.size()));
  for (size_t k = 0; k < global.size(); ++k) out.col(static_cast<Eigen::Index>(k)) = x.col(global[k]);
  return out;
}

bool acts_within_molecules(const ForceTerm& t) {
  return !t.uses_neighbor_list() && t.phase() != Phase::kspace;
}

// On 1–4 random partitions of the molecules, every term's part from its description is the whole
// term's cut: definitions equal, and the whole term's forces on the part's particles, bit for bit.
// Returns the styles checked.
std::set<std::string> check_whole_molecules(const Scene& sc, unsigned seed) {
  const test::OneThread one_thread;
  const ForceField& whole = *sc.forces;
  const auto described = descriptions(whole);
  const int n = sc.state.size();
  const std::vector<int> molecule = bonded_molecules(sc.topology, n);
  std::vector<Eigen::Matrix3Xd> whole_forces;
  for (const auto& term : whole.terms()) {
    Eigen::Matrix3Xd f = Eigen::Matrix3Xd::Zero(3, n);
    if (acts_within_molecules(*term)) term->add_forces(sc.state.x, sc.box, f);
    whole_forces.push_back(f);
  }
  std::mt19937 rng(seed);
  std::set<std::string> styles;
  for (int parts = 1; parts <= 4; ++parts) {
    std::uniform_int_distribution<int> pick(0, parts - 1);
    std::vector<int> part_of_molecule(static_cast<size_t>(n));
    for (int& r : part_of_molecule) r = pick(rng);
    for (int r = 0; r < parts; ++r) {
      std::vector<int> global;
      for (int i = 0; i < n; ++i)
        if (part_of_molecule[static_cast<size_t>(molecule[i])] == r) global.push_back(i);
      const Part part = part_of(sc, global), reference = with_unknown_items(part);
      const Eigen::Matrix3Xd x = columns(sc.state.x, global);
      for (size_t k = 0; k < whole.terms().size(); ++k) {
        const ForceTerm& w = *whole.terms()[k];
        SCOPED_TRACE(w.name() + " on part " + std::to_string(r) + " of " + std::to_string(parts));
        styles.insert(std::string(w.style()));
        // The cut: the whole term's lists and arrays (a pair term's special pairs come from the
        // part's bonds, so it gets the part's topology as it is).
        const auto cut = w.on_subset((w.uses_neighbor_list() ? part : reference).view(false), sc.box);
        const auto mine = described[k]->on_subset(part.view(true), sc.box);
        EXPECT_EQ(definition(*mine), definition(*cut));
        EXPECT_EQ(mine->describe(), cut->describe());
        if (!acts_within_molecules(w)) continue;
        Eigen::Matrix3Xd f = Eigen::Matrix3Xd::Zero(3, x.cols());
        mine->add_forces(x, sc.box, f);
        EXPECT_TRUE(f == columns(whole_forces[k], global));
      }
      // The stiff bonds the constraint toolbox takes: the whole list's on the part, in its order.
      for (size_t k = 0; k < whole.terms().size(); ++k)
        if (const StiffBonds* all = whole.terms()[k]->stiff_bonds()) {
          const auto mine = described[k]->on_subset(part.view(true), sc.box);
          std::vector<StiffBond> want;
          const ParticleSubset v = part.view(true);
          for (const StiffBond& b : all->bonds)
            if (v.local(b.i) >= 0) want.push_back({v.local(b.i), v.local(b.j), b.length, b.alpha});
          const auto& got = mine->stiff_bonds()->bonds;
          EXPECT_EQ(got.size(), want.size());
          for (size_t b = 0; b < std::min(want.size(), got.size()); ++b) {
            EXPECT_EQ(got[b].i, want[b].i) << "bond " << b;
            EXPECT_EQ(got[b].j, want[b].j) << "bond " << b;
            EXPECT_EQ(got[b].length, want[b].length) << "bond " << b;
            EXPECT_EQ(got[b].alpha, want[b].alpha) << "bond " << b;
          }
        }
    }
  }
  return styles;
}

// On random subsets that cut molecules (each particle in or out by a coin), the term from its
// description and the whole term's cut both refuse, or agree.
void check_cut_subsets(const Scene& sc, unsigned seed) {
  const ForceField& whole = *sc.forces;
  const auto described = descriptions(whole);
  std::mt19937 rng(seed);
  std::bernoulli_distribution coin(0.5);
  int refused = 0;
  for (int trial = 0; trial < 4; ++trial) {
    std::vector<int> global;
    for (int i = 0; i < sc.state.size(); ++i)
      if (coin(rng)) global.push_back(i);
    const Part part = part_of(sc, global);
    for (size_t k = 0; k < whole.terms().size(); ++k) {
      const ForceTerm& w = *whole.terms()[k];
      SCOPED_TRACE(w.name() + ", cut subset " + std::to_string(trial));
      std::unique_ptr<ForceTerm> cut, mine;
      bool cut_refused = false, mine_refused = false;
      try {
        cut = w.on_subset(part.view(false), sc.box);
      } catch (const std::invalid_argument&) {
        cut_refused = true;
      }
      try {
        mine = described[k]->on_subset(part.view(true), sc.box);
      } catch (const std::invalid_argument&) {
        mine_refused = true;
      }
      EXPECT_EQ(mine_refused, cut_refused);
      refused += cut_refused;
      if (cut && mine) EXPECT_EQ(definition(*mine), definition(*cut));
    }
  }
  EXPECT_GT(refused, 0) << "no subset cut an item";
}

Scene scene(const std::string& deck) {
  return load_scene(Deck(test::source_path(deck), {}));
}

TEST(PartTermsFromDescriptions, EveryForceStyle) {
  const Scene sc = scene("tests/decks/every_force_style.toml");
  const auto styles = check_whole_molecules(sc, 5);
  for (const char* s : {"stiff-harmonic", "gravity", "harmonic-tether", "lj93-wall", "fene", "harmonic-angle"})
    EXPECT_TRUE(styles.contains(s)) << s;
  check_cut_subsets(sc, 6);
}

TEST(PartTermsFromDescriptions, EveryAllAtomStyle) {
  const Scene sc = scene("tests/decks/every_all_atom_style.toml");
  const auto styles = check_whole_molecules(sc, 7);
  for (const char* s : {"charmm-angle", "charmm-dihedral", "harmonic-improper", "umbrella-improper"})
    EXPECT_TRUE(styles.contains(s)) << s;
  check_cut_subsets(sc, 8);
}

TEST(PartTermsFromDescriptions, EwaldAndMesh) {
  for (const char* deck : {"tests/decks/every_charged_style.toml", "tests/decks/every_mesh_style.toml"}) {
    SCOPED_TRACE(deck);
    const Scene sc = scene(deck);
    const auto styles = check_whole_molecules(sc, 9);
    EXPECT_TRUE(styles.contains("ewald") || styles.contains("pppm"));
    check_cut_subsets(sc, 10);
  }
}

// The peptide in water: stiff bonds with rigid water angles (a third bond per angle), a charmm
// dihedral with 1-4 charges, PPPM.
TEST(PartTermsFromDescriptions, Peptide) {
  const Scene sc = scene("inputs/peptide.toml");
  const auto styles = check_whole_molecules(sc, 11);
  for (const char* s : {"stiff-harmonic", "charmm-dihedral", "pppm"}) EXPECT_TRUE(styles.contains(s)) << s;
  const StiffBonds* stiff = sc.forces->stiff_bonds();
  ASSERT_NE(stiff, nullptr);
  // Its rigid angles' bonds follow the claimed bonds: the rule's second step is exercised.
  for (const auto& term : sc.forces->terms())
    if (const auto* bonds = dynamic_cast<const StiffHarmonicBond*>(term.get()))
      EXPECT_EQ(bonds->rule().rigid_angles.size(), 1u);
  check_cut_subsets(sc, 12);
}

// A decomposed run whose whole force terms are replaced after the start by their descriptions
// alone (every item list, particle list and per-particle array of the whole system gone) is the
// run that keeps them, bit for bit, on 1–4 fake ranks; with molecules migrating, the parts are
// made again within the run from those descriptions.
constexpr int kSteps = 40;
constexpr double kDrift = 6.0;  // along the box's diagonal, about 8 Å in the run: molecules cross the faces

Scene drifting_peptide() {
  Scene sc = test::load("inputs/peptide.toml");
  sc.state.v.array() += kDrift;
  return sc;
}

// The whole field with each term made again from its description (the pair terms, which a pair
// set takes as a template, on every particle as they were).
std::unique_ptr<ForceField> described_field(const Scene& sc) {
  const ForceField& whole = *sc.forces;
  std::vector<std::string> levels;
  for (int k = 0; k < whole.num_levels(); ++k) levels.push_back(whole.level_name(Level{k}));
  auto out = std::make_unique<ForceField>(whole.box(), sc.state.size(), levels);
  std::vector<int> every(static_cast<size_t>(sc.state.size()));
  for (int i = 0; i < sc.state.size(); ++i) every[static_cast<size_t>(i)] = i;
  const ParticleSubset all{every, sc.particle_type, sc.topology,
                           sc.charged() ? std::span<const double>(sc.charge) : std::span<const double>()};
  auto described = descriptions(whole);
  for (size_t k = 0; k < described.size(); ++k)
    out->add(whole.terms()[k]->uses_neighbor_list() ? whole.terms()[k]->on_subset(all, whole.box())
                                                    : std::move(described[k]));
  return out;
}

class PartTermsOnFakeRanks : public ::testing::TestWithParam<int> {};

TEST_P(PartTermsOnFakeRanks, TheRunIsTheSameWithTheWholeTermsReducedToTheirDescriptions) {
  const int ranks = GetParam();
  const test::OneThread one_thread;
  const auto nothing = [](int, const DomainIntegrator&, Scene&, State&) {};
  const test::DomainRun kept = test::run_on_fake_ranks(ranks, kSteps, drifting_peptide, nothing);
  // The whole fields the ranks' integrators were made on stay alive (unused) until the end.
  std::vector<std::unique_ptr<ForceField>> old(static_cast<size_t>(ranks));
  std::vector<int> stiff_bonds_left(static_cast<size_t>(ranks), -1);
  const test::DomainRun described = test::run_on_fake_ranks(
      ranks, kSteps, drifting_peptide, [&](int rank, const DomainIntegrator&, Scene& sc, State&) {
        auto field = described_field(sc);
        old[static_cast<size_t>(rank)] = std::move(sc.forces);
        sc.forces = std::move(field);
        stiff_bonds_left[static_cast<size_t>(rank)] = static_cast<int>(sc.forces->stiff_bonds()->bonds.size());
      });
  for (int r = 0; r < ranks; ++r) EXPECT_EQ(stiff_bonds_left[static_cast<size_t>(r)], 0);
  if (ranks > 1) EXPECT_GE(described.migrated, 5.0) << "molecules should migrate within the run";
  EXPECT_EQ(described.migrated, kept.migrated);
  EXPECT_TRUE(described.x == kept.x);
  EXPECT_TRUE(described.v == kept.v);
  if (ranks == 1) {  // one rank's k-space sum is one process's: the trajectory too
    Scene serial = drifting_peptide();
    test::run_one_process(serial, kSteps);
    EXPECT_TRUE(described.x == serial.state.x);
    EXPECT_TRUE(described.v == serial.state.v);
  }
}

INSTANTIATE_TEST_SUITE_P(Ranks, PartTermsOnFakeRanks, ::testing::Values(1, 2, 3, 4));

}  // namespace
}  // namespace stiffmd
