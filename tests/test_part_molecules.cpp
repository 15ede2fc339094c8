// A rank's part built from what its molecules carry (engine/domain/part_molecules.hpp,
// docs/parallel.md "The design"): the carried data cut, split, packed, unpacked and merged is the
// whole system's restricted to the part, items in the whole system's order; on 1–4 fake ranks
// (tests/fake_processes.hpp) a decomposed run's part equals the one cut from the whole scene —
// ids, masses, types, charges, molecule ids, frictions, items in order — at the start and after
// molecules with bonds, angles and dihedrals have migrated between ranks; and with the whole
// scene's per-particle arrays and topology poisoned after the start (NaN masses, charges and
// frictions, a scrambled topology), the ranks' trajectory is still one process's bit for bit, which
// fails if anything reads them.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <limits>
#include <memory>
#include <random>
#include <sstream>
#include <string>
#include <vector>

#include "core/parallel.hpp"
#include "decomposition_fixtures.hpp"
#include "domain_run_support.hpp"
#include "engine/domain/domain_integrator.hpp"
#include "engine/domain/part_molecules.hpp"
#include "engine/run/run.hpp"
#include "fake_processes.hpp"
#include "integrators/methods.hpp"
#include "test_support.hpp"

namespace stiffmd {
namespace {

using fake::FakeCommunicator;
using fake::run_ranks;

// The whole system's topology restricted to the particles `global` (increasing), renumbered into
// them, in the whole system's order: an item is kept when its first particle is there. Written
// here, independently of PartMolecules.
Topology restricted(const Topology& whole, const std::vector<int>& global, const std::vector<int>& molecule_id) {
  const auto at = [&](int g) {
    const auto it = std::lower_bound(global.begin(), global.end(), g);
    return it != global.end() && *it == g ? static_cast<int>(it - global.begin()) : -1;
  };
  Topology t;
  for (const Bond& b : whole.bonds)
    if (at(b.i) >= 0) t.bonds.push_back({at(b.i), at(b.j), b.type});
  for (const Angle& a : whole.angles)
    if (at(a.i) >= 0) t.angles.push_back({at(a.i), at(a.j), at(a.k), a.type});
  for (const Dihedral& d : whole.dihedrals)
    if (at(d.i) >= 0) t.dihedrals.push_back({at(d.i), at(d.j), at(d.k), at(d.l), d.type});
  for (const Improper& d : whole.impropers)
    if (at(d.i) >= 0) t.impropers.push_back({at(d.i), at(d.j), at(d.k), at(d.l), d.type});
  if (!molecule_id.empty())
    for (const int g : global) t.molecule.push_back(molecule_id[static_cast<size_t>(g)]);
  return t;
}

template <class Item>
std::vector<std::vector<int>> rows(const std::vector<Item>& items) {
  std::vector<std::vector<int>> out;
  for (const Item& it : items) {
    if constexpr (requires { it.l; })
      out.push_back({it.i, it.j, it.k, it.l, it.type});
    else if constexpr (requires { it.k; })
      out.push_back({it.i, it.j, it.k, it.type});
    else
      out.push_back({it.i, it.j, it.type});
  }
  return out;
}

void expect_same_topology(const Topology& got, const Topology& want) {
  EXPECT_EQ(rows(got.bonds), rows(want.bonds));
  EXPECT_EQ(rows(got.angles), rows(want.angles));
  EXPECT_EQ(rows(got.dihedrals), rows(want.dihedrals));
  EXPECT_EQ(rows(got.impropers), rows(want.impropers));
  EXPECT_EQ(got.molecule, want.molecule);
}

// The straddling melt (tests/decomposition_fixtures.hpp: chains, a molecule joined by an angle
// alone, lone beads; permuted indices) with a dihedral along each chain of the builder, an
// improper on each, molecule ids, types, charges and frictions distinct per particle.
struct System {
  fake::Melt melt;
  std::vector<int> type, molecule_id;
  std::vector<double> charge, friction;
  WholeParticles whole() const {
    return {std::span<const double>(melt.state.inv_mass.data(), static_cast<size_t>(melt.size())),
            type,
            charge,
            molecule_id,
            friction,
            melt.topology};
  }
};

System system() {
  System s{fake::straddling_melt(), {}, {}, {}, {}};
  const int n = s.melt.size();
  for (int g = 0; g < n; ++g) {
    s.type.push_back(g % 3);
    s.molecule_id.push_back(s.melt.label[static_cast<size_t>(g)]);
    s.charge.push_back(0.25 * (g % 5) - 0.5);
    s.friction.push_back(1.0 + 0.125 * g);
  }
  // Along each bonded path of three bonds a dihedral, and an improper on every other one.
  const std::vector<Bond> bonds = s.melt.topology.bonds;
  for (size_t b = 0; b + 2 < bonds.size(); ++b)
    if (bonds[b].j == bonds[b + 1].i && bonds[b + 1].j == bonds[b + 2].i) {
      s.melt.topology.dihedrals.push_back(
          {bonds[b].i, bonds[b].j, bonds[b + 1].j, bonds[b + 2].j, static_cast<int>(b % 2)});
      if (b % 2 == 0) s.melt.topology.impropers.push_back({bonds[b].j, bonds[b].i, bonds[b + 1].j, bonds[b + 2].j, 0});
    }
  return s;
}

void expect_is_cut_of(const PartMolecules& p, const System& s) {
  const PartMolecules want = cut_part(s.whole(), p.global);
  EXPECT_EQ(p.global, want.global);
  EXPECT_EQ(p.inv_mass, want.inv_mass);
  EXPECT_EQ(p.type, want.type);
  EXPECT_EQ(p.charge, want.charge);
  EXPECT_EQ(p.molecule_id, want.molecule_id);
  EXPECT_EQ(p.friction, want.friction);
  expect_same_topology(p.topology(s.melt.topology), restricted(s.melt.topology, p.global, s.molecule_id));
}

// The molecules dealt to `parts` parts at random, then split to random destinations, packed,
// unpacked and merged, as a migration moves them: every part is the whole system's cut.
TEST(PartMolecules, CutSplitPackUnpackAndMergeKeepTheWholeSystemsData) {
  const System s = system();
  const int n = s.melt.size();
  EXPECT_FALSE(s.melt.topology.dihedrals.empty());
  EXPECT_FALSE(s.melt.topology.angles.empty());
  const std::vector<int> molecule = bonded_molecules(s.melt.topology, n);
  std::mt19937 rng(5);
  for (int parts = 1; parts <= 4; ++parts) {
    std::uniform_int_distribution<int> pick(0, parts - 1), go(-1, parts - 1);  // −1: stays
    std::vector<int> owner_of_molecule(static_cast<size_t>(n)), destination(static_cast<size_t>(n));
    for (int m = 0; m < n; ++m) owner_of_molecule[m] = pick(rng), destination[m] = go(rng);
    std::vector<PartMolecules> part(static_cast<size_t>(parts));
    for (int r = 0; r < parts; ++r) {
      std::vector<int> global;
      for (int g = 0; g < n; ++g)
        if (owner_of_molecule[molecule[g]] == r) global.push_back(g);
      part[r] = cut_part(s.whole(), global);
      expect_is_cut_of(part[r], s);
    }
    // Each part sends its molecules with destination ≥ 0 there; what arrives is merged with what stays.
    std::vector<std::vector<PartMolecules>> arriving(static_cast<size_t>(parts));
    std::vector<PartMolecules> kept;
    for (int r = 0; r < parts; ++r) {
      std::vector<int> to;
      for (const int g : part[r].global) to.push_back(destination[molecule[g]] >= 0 ? destination[molecule[g]] : -1);
      std::vector<PartMolecules> pieces(static_cast<size_t>(parts));
      kept.push_back(split_part(part[r], to, pieces));
      for (int q = 0; q < parts; ++q) {
        std::vector<double> words;
        pack_part(pieces[q], words);
        PartMolecules back;
        EXPECT_EQ(unpack_part(words.data(), back), words.data() + words.size());
        arriving[q].push_back(std::move(back));
      }
    }
    int total = 0;
    for (int r = 0; r < parts; ++r) {
      std::vector<PartMolecules> all = std::move(arriving[r]);
      all.push_back(kept[r]);
      const PartMolecules merged = merge_parts(std::move(all));
      expect_is_cut_of(merged, s);
      total += merged.size();
      for (const int g : merged.global) {
        const int m = molecule[g];
        EXPECT_EQ(destination[m] >= 0 ? destination[m] : owner_of_molecule[m], r) << "particle " << g;
      }
    }
    EXPECT_EQ(total, n);
  }
}

// The butane fluid (bonds, angles, dihedrals) under velocity Verlet and Langevin, with a uniform
// drift along the box's diagonal, so that molecules cross the domains' faces whichever axes the
// grid cuts and migrate within the run (3.6 σ along each axis; a domain is 3.9 σ wide or more).
constexpr int kSteps = 150;
const std::vector<std::string> kButane = {"variables.eps=0.1",          "integrator.method=velocity-verlet",
                                          "integrator.h=0.002",         "thermostat.style=langevin",
                                          "thermostat.temperature=1.0", "thermostat.damp=20.0",
                                          "thermostat.seed=3",          "prepare.relax_steps=20"};
constexpr double kDrift = 12.0;

Scene butane() {
  Scene sc = test::load("inputs/butane_torsions.toml", kButane);
  sc.state.v.array() += kDrift;
  return sc;
}

// The whole scene's per-particle arrays and topology made useless: whatever reads them after the
// start gets NaN masses, charges and frictions, items joining other particles in another order.
// (The pair sets' types, charges and special pairs, carried with the beads, are poisoned in
// tests/test_pair_set_data.cpp.)
void poison(Scene& sc, State& s) {
  const double nan = std::numeric_limits<double>::quiet_NaN();
  const int n = sc.state.size();
  sc.state.inv_mass.setConstant(nan);
  s.inv_mass.setConstant(nan);
  std::fill(sc.charge.begin(), sc.charge.end(), nan);
  sc.integrator.thermostat.friction.setConstant(nan);
  Topology& t = sc.topology;
  std::reverse(t.bonds.begin(), t.bonds.end());
  std::reverse(t.angles.begin(), t.angles.end());
  std::reverse(t.dihedrals.begin(), t.dihedrals.end());
  for (Bond& b : t.bonds) b.i = (b.i + 1) % n, b.j = (b.j + 3) % n;
  for (Angle& a : t.angles) a.i = (a.i + 5) % n;
  for (Dihedral& d : t.dihedrals) d.l = (d.l + 7) % n;
  std::reverse(t.molecule.begin(), t.molecule.end());
}

void expect_part_is_the_whole_cut(const DomainIntegrator& d, const Scene& reference) {
  const Scene& p = d.part_scene();
  const std::vector<int>& ids = d.owned_ids();
  ASSERT_EQ(p.global_id, ids);
  ASSERT_EQ(p.state.inv_mass.size(), static_cast<Eigen::Index>(ids.size()));
  for (size_t k = 0; k < ids.size(); ++k) {
    const int g = ids[k];
    EXPECT_EQ(p.state.inv_mass[static_cast<Eigen::Index>(k)], reference.state.inv_mass[g]) << "particle " << g;
    EXPECT_EQ(p.particle_type[k], reference.particle_type[static_cast<size_t>(g)]) << "particle " << g;
    EXPECT_EQ(p.charge[k], reference.charge[static_cast<size_t>(g)]) << "particle " << g;
    EXPECT_EQ(p.integrator.thermostat.friction[static_cast<Eigen::Index>(k)],
              reference.integrator.thermostat.friction[g])
        << "particle " << g;
  }
  expect_same_topology(p.topology, restricted(reference.topology, ids, reference.topology.molecule));
}

class PartsOnFakeRanks : public ::testing::TestWithParam<int> {};

TEST_P(PartsOnFakeRanks, ThePartIsTheWholeCutAndTheRunOneProcesssWithTheWholeArraysPoisoned) {
  const int ranks = GetParam();
  const test::OneThread one_thread;  // the scenes' [prepare] too: one thread, as on the ranks
  Scene serial = butane();
  test::run_one_process(serial, kSteps);
  const Scene reference = butane();  // the same scene, never poisoned (read only, by every rank)
  auto started = [&](int, const DomainIntegrator& d, Scene& sc, State& s) {
    expect_part_is_the_whole_cut(d, reference);
    poison(sc, s);
  };
  auto ended = [&](int, const DomainIntegrator& d) { expect_part_is_the_whole_cut(d, reference); };
  const test::DomainRun run = test::run_on_fake_ranks(ranks, kSteps, butane, started, ended);
  if (ranks > 1) {
    EXPECT_GE(run.migrated, 10.0) << "too few molecules migrated to test the carried data";
  }
  // Bit for bit one process's trajectory.
  EXPECT_TRUE(run.x == serial.state.x);
  EXPECT_TRUE(run.v == serial.state.v);
}

INSTANTIATE_TEST_SUITE_P(Ranks, PartsOnFakeRanks, ::testing::Values(1, 2, 3, 4));

}  // namespace
}  // namespace stiffmd
